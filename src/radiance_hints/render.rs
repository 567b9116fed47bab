//! The volume update (once per frame, before the cameras) and the per-camera reconstruction.

use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::diagnostic::FrameCount;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::*;
use bevy::app::SubApp;
use bevy::render::renderer::{RenderContext, ViewQuery};
use bevy::render::texture::GpuImage;
use bevy::render::view::{ViewUniformOffset, ViewUniforms};

use super::prepare::{RhPipelines, RhVolumesGpu};
use crate::camera::{GiMethod, GiOutput};
use crate::composite::{ExtractedDiffuseGi, GiView, GiViewPassParams};
use crate::rsm::RsmAtlas;

/// Updates the volumes that need it, once per frame and before any camera renders (the `RenderGraph`
/// schedule): injection, extra bounces, blend, export. Volumes with the §8 depth occlusion, which reads a
/// camera's depth, are updated in the first GI camera's `Core3d` run instead
/// ([`update_depth_occluded_volumes`]).
pub(crate) fn update_gi_volumes(
    mut state: ResMut<RhVolumesGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<RhPipelines>,
    pipeline_cache: Res<PipelineCache>,
    images: Res<RenderAssets<GpuImage>>,
    frame: Res<FrameCount>,
    mut ctx: RenderContext,
) {
    if state.updated_frame == Some(frame.0) {
        return;
    }
    state.updated_frame = Some(frame.0);
    update_volumes(&mut state, &atlas, &pipelines, &pipeline_cache, &images, None, &mut ctx);
}

/// The §8 volumes' update, in the first GI camera's `Core3d` run after its prepass (whose depth it reads).
#[expect(clippy::too_many_arguments, reason = "the frame's whole volume update")]
pub(crate) fn update_depth_occluded_volumes(
    view: ViewQuery<(&ExtractedDiffuseGi, &ViewUniformOffset, &ViewPrepassTextures)>,
    mut state: ResMut<RhVolumesGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<RhPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    images: Res<RenderAssets<GpuImage>>,
    frame: Res<FrameCount>,
    mut ctx: RenderContext,
) {
    let (gi, view_offset, prepass) = view.into_inner();
    if gi.0.method != GiMethod::RadianceHints || state.depth_updated_frame == Some(frame.0) {
        return;
    }
    if !state.volumes.iter().any(|v| v.settings.depth_occlusion.is_some()) {
        return;
    }
    let (Some(uniforms), Some(depth)) = (view_uniforms.uniforms.binding(), prepass.depth_view()) else {
        return;
    };
    state.depth_updated_frame = Some(frame.0);
    let depth_group = ctx.render_device().create_bind_group(
        "diffuse_gi_rh_depth_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.depth_layout),
        &BindGroupEntries::sequential((uniforms, depth)),
    );
    update_volumes(&mut state, &atlas, &pipelines, &pipeline_cache, &images, Some((&depth_group, view_offset.offset)), &mut ctx);
}

/// Runs the update of the volumes whose §8 setting matches `depth` (present: the §8 volumes with this
/// camera's depth; absent: all others).
fn update_volumes(
    state: &mut RhVolumesGpu,
    atlas: &RsmAtlas,
    pipelines: &RhPipelines,
    pipeline_cache: &PipelineCache,
    images: &RenderAssets<GpuImage>,
    depth: Option<(&BindGroup, u32)>,
    ctx: &mut RenderContext,
) {
    if depth.is_none() {
        prepare_visibility_masks(state, pipeline_cache, ctx);
    }
    let wants = |v: &super::prepare::RhVolumeGpu| v.settings.depth_occlusion.is_some() == depth.is_some();
    if !state.volumes.iter().any(|v| wants(v) && (v.update_this_frame || v.export.is_some())) {
        return;
    }
    let (Some(lights), Some(faces), Some(emitters)) = (atlas.lights.binding(), atlas.faces.binding(), state.emitters.as_ref()) else {
        return;
    };
    let device = ctx.render_device().clone();
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let rsm_bind_group = device.create_bind_group(
        "diffuse_gi_rh_rsm_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.rsm_layout),
        &BindGroupEntries::sequential((
            &atlas.position_view,
            &atlas.normal_view,
            &atlas.flux_view,
            lights,
            emitters.as_entire_binding(),
            faces,
        )),
    );

    for v in &mut state.volumes {
        if !wants(v) {
            continue;
        }
        let (Some(groups), Some(ids)) = (v.bind_groups.as_ref(), v.pipelines) else {
            continue;
        };
        let base = v.uniform_offsets[0];
        if v.update_this_frame {
            let (Some(inject), Some(bounce), Some(decide), Some(blend)) = (
                pipeline_cache.get_compute_pipeline(ids.inject),
                pipeline_cache.get_compute_pipeline(ids.bounce),
                pipeline_cache.get_compute_pipeline(ids.decide),
                pipeline_cache.get_compute_pipeline(ids.blend),
            ) else {
                continue;
            };

            // The volume moved by whole cells: first carry its field along (copied to `delta[0]`, which
            // the injection overwrites next, and read back shifted). The packed form follows in the blend.
            if v.scroll.is_some()
                && let Some(scroll) = pipeline_cache.get_compute_pipeline(ids.scroll)
            {
                ctx.command_encoder().copy_buffer_to_buffer(&v.result, 0, &v.delta[0], 0, v.result.size());
                let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
                    label: Some("diffuse_gi_rh_scroll"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(scroll);
                pass.set_bind_group(0, &groups.scroll, &[base]);
                pass.dispatch_workgroups(v.workgroups, 1, 1);
            }

            // Spans inside the passes: on lavapipe, timestamps written between compute passes do not
            // bracket the compute work (the injection's span read 1.6 ms for 64 samples and 4.1 ms for
            // 256 while the frame took 115 ms longer).
            {
                let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
                    label: Some("diffuse_gi_rh_inject"),
                    timestamp_writes: None,
                });
                let span = diagnostics.pass_span(&mut pass, "diffuse_gi/rh_inject");
                pass.set_pipeline(inject);
                pass.set_bind_group(0, &groups.inject_output, &[base]);
                pass.set_bind_group(1, &rsm_bind_group, &[]);
                pass.set_bind_group(2, &groups.occupancy, &[]);
                if let Some((group, offset)) = depth {
                    pass.set_bind_group(3, group, &[offset]);
                }
                pass.dispatch_workgroups(v.workgroups, 1, 1);
                span.end(&mut pass);
            }

            {
                let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
                    label: Some("diffuse_gi_rh_bounce"),
                    timestamp_writes: None,
                });
                let span = diagnostics.pass_span(&mut pass, "diffuse_gi/rh_bounce");
                if v.motion_update() {
                    // One bounce gathered from the displayed field (all bounces so far, a frame old):
                    // repeated every frame, the field converges to injection plus every bounce.
                    pass.set_pipeline(bounce);
                    pass.set_bind_group(0, &groups.bounce[1].0, &[]);
                    pass.set_bind_group(1, &groups.sample_result, &[v.uniform_offsets[1]]);
                    pass.set_bind_group(2, &groups.bounce_occupancy, &[]);
                    pass.dispatch_workgroups(v.workgroups, 1, 1);
                }
                for k in (1..=v.settings.extra_bounces).filter(|_| !v.motion_update()) {
                    let offset = v.uniform_offsets[k as usize];
                    let (output, sample) = &groups.bounce[(k % 2) as usize];
                    pass.set_pipeline(bounce);
                    pass.set_bind_group(0, output, &[]);
                    pass.set_bind_group(1, sample, &[offset]);
                    pass.set_bind_group(2, &groups.bounce_occupancy, &[]);
                    // Dispatched with zero workgroups once a bounce added too little (see decide.wgsl).
                    pass.dispatch_workgroups_indirect(&v.args, 12 * (k as u64 - 1));
                    pass.set_pipeline(decide);
                    pass.set_bind_group(0, &groups.decide, &[offset]);
                    pass.dispatch_workgroups(1, 1, 1);
                }
                pass.set_pipeline(blend);
                pass.set_bind_group(0, &groups.blend, &[base]);
                pass.dispatch_workgroups(v.workgroups, 1, 1);
                span.end(&mut pass);
            }
            // The count of extra bounces this full update ran, for the panel (read back without waiting).
            if !v.motion_update()
                && v.settings.extra_bounces > 0
                && v.bounce_readback.state.load(std::sync::atomic::Ordering::Acquire) == super::activity::IDLE
            {
                ctx.command_encoder().copy_buffer_to_buffer(&v.stats, 0, &v.bounce_readback.buffer, 0, 4);
                v.bounce_readback.state.store(super::activity::COPIED, std::sync::atomic::Ordering::Release);
            }
            v.updates_left = v.updates_left.saturating_sub(1);
            v.first_update = false;
            v.age += 1;
        }

        // The IrradianceVolume export, when a camera uses it.
        if let Some(image) = v.export.as_ref().and_then(|h| images.get(h))
            && let Some(export) = pipeline_cache.get_compute_pipeline(ids.export)
            && (v.update_this_frame || !v.export_written(image))
        {
            let storage_view = image.texture.create_view(&TextureViewDescriptor {
                label: Some("diffuse_gi_rh_export_view"),
                dimension: Some(TextureViewDimension::D3),
                ..default()
            });
            let output = device.create_bind_group(
                "diffuse_gi_rh_export_bind_group",
                &pipeline_cache.get_bind_group_layout(&pipelines.export_layout),
                &BindGroupEntries::single(&storage_view),
            );
            let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
                label: Some("diffuse_gi_rh_export"),
                timestamp_writes: None,
            });
            pass.set_pipeline(export);
            pass.set_bind_group(0, &output, &[]);
            pass.set_bind_group(1, &groups.sample_result, &[base]);
            pass.dispatch_workgroups(v.workgroups, 1, 1);
            drop(pass);
            v.mark_export_written(image);
        }
    }
}

/// Threads per dimension of a 2D dispatch: a grid of 256³ voxels has 2²² words, more than 65 535 groups.
const VISIBILITY_GROUPS_X: u32 = 4096;

/// Redoes the visibility masks of the volumes whose voxels changed (`visibility.wgsl`), before any camera
/// reconstructs from them.
fn prepare_visibility_masks(state: &mut RhVolumesGpu, pipeline_cache: &PipelineCache, ctx: &mut RenderContext) {
    if !state.volumes.iter().any(|v| v.visibility_pending.is_some()) {
        return;
    }
    // A scrolled volume shifts its masks from a copy of them (`visibility.wgsl`).
    for v in &state.volumes {
        if let (Some(previous), Some(_)) = (&v.visibility_previous, v.visibility_pending.filter(|r| r.shift.w != 0)) {
            ctx.command_encoder().copy_buffer_to_buffer(&v.visibility, 0, previous, 0, v.visibility.size());
        }
    }
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
        label: Some("diffuse_gi_rh_visibility"),
        timestamp_writes: None,
    });
    let span = diagnostics.pass_span(&mut pass, "diffuse_gi/rh_visibility");
    for v in &mut state.volumes {
        let (Some(region), Some(groups), Some(ids)) = (v.visibility_pending, v.bind_groups.as_ref(), v.pipelines) else {
            continue;
        };
        let Some(pipeline) = pipeline_cache.get_compute_pipeline(ids.visibility) else {
            continue;
        };
        let workgroups = region.words().div_ceil(super::prepare::WORKGROUP_SIZE);
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &groups.visibility_output, &[]);
        pass.set_bind_group(1, &groups.sample_result, &[v.uniform_offsets[0]]);
        pass.set_bind_group(2, &groups.occupancy, &[]);
        pass.dispatch_workgroups(workgroups.min(VISIBILITY_GROUPS_X), workgroups.div_ceil(VISIBILITY_GROUPS_X), 1);
        v.visibility_pending = None;
    }
    span.end(&mut pass);
}

/// Reconstructs the indirect light of every volume into the camera's GI target (§5, Eq. 6–7).
pub(crate) fn reconstruct_gi(
    view: ViewQuery<GiView>,
    state: Res<RhVolumesGpu>,
    pipelines: Res<RhPipelines>,
    params: GiViewPassParams,
    mut ctx: RenderContext,
) {
    let view = view.into_inner();
    let gi = view.gi;
    if gi.0.method != GiMethod::RadianceHints || gi.0.output != GiOutput::Composite {
        return;
    }
    // Volumes side by side first, then nested ones from coarse to fine, each drawn over the last.
    let mut order: Vec<&super::prepare::RhVolumeGpu> = state.volumes.iter().collect();
    order.sort_by(|a, b| a.nested.cmp(&b.nested).then(b.cell_diagonal.total_cmp(&a.cell_diagonal)));
    let draws: Vec<_> = order
        .into_iter()
        .filter_map(|v| {
            let key = super::prepare::reconstruct_key(v, &gi.0);
            let pipeline = state.reconstruct_pipelines.get(&key).and_then(|id| params.pipeline_cache.get_render_pipeline(*id))?;
            let groups = v.bind_groups.as_ref()?;
            Some((pipeline, groups, v.uniform_offsets[0]))
        })
        .collect();
    if draws.is_empty() {
        return;
    }
    let Some(view_group) = pipelines.reconstruct.view_group(ctx.render_device(), &params, &view) else {
        return;
    };
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let span = diagnostics.time_span(ctx.command_encoder(), "diffuse_gi/rh_reconstruct");
    {
        let mut pass = crate::composite::begin_target_pass(&mut ctx, "diffuse_gi_rh_reconstruct", &view.target.texture.default_view);
        for (pipeline, groups, offset) in draws {
            pass.set_render_pipeline(pipeline);
            pass.set_bind_group(0, &view_group, &[view.view_offset.offset]);
            pass.set_bind_group(1, &groups.sample_result, &[offset]);
            pass.set_bind_group(2, &groups.lookup, &[]);
            pass.draw(0..3, 0..1);
        }
    }
    span.end(ctx.command_encoder());
    params.status.drew(GiMethod::RadianceHints);
}

fn init_rh_pipelines(world: &mut World) {
    let pipelines = super::prepare::RhPipelines::from_world(world);
    world.insert_resource(pipelines);
}

/// Adds the Radiance Hints render-world systems; called from [`super::RadianceHintsPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    use super::{activity, extract, prepare};
    use bevy::core_pipeline::Core3d;
    use bevy::core_pipeline::schedule::camera_driver;
    use bevy::render::renderer::{RenderGraph, RenderGraphSystems};
    use bevy::render::{ExtractSchedule, Render, RenderStartup, RenderSystems};
    use crate::composite::GiViewSystems;
    render_app
        .init_resource::<extract::ExtractedRhVolumes>()
        .init_resource::<prepare::RhVolumesGpu>()
        .init_resource::<SpecializedComputePipelines<prepare::RhPipelines>>()
        .init_resource::<SpecializedRenderPipelines<prepare::RhPipelines>>()
        .add_systems(RenderStartup, init_rh_pipelines)
        .add_systems(ExtractSchedule, extract::extract_volumes)
        .add_systems(
            Render,
            (
                prepare::prepare_rh_volumes
                    .in_set(RenderSystems::PrepareResources)
                    .after(crate::rsm::prepare_rsm),
                prepare::prepare_rh_bind_groups.in_set(RenderSystems::PrepareBindGroups),
                activity::map_bounce_counts.in_set(RenderSystems::Cleanup),
            ),
        )
        .add_systems(
            RenderGraph,
            update_gi_volumes
                .in_set(RenderGraphSystems::Render)
                .after(crate::rsm::draw_rsm)
                .before(camera_driver),
        )
        .add_systems(
            Core3d,
            (update_depth_occluded_volumes, reconstruct_gi)
                .chain()
                .in_set(GiViewSystems::Produce)
                .after(crate::composite::clear_gi_target),
        );
    #[cfg(feature = "tools")]
    render_app.add_systems(Render, super::dump::dump_volume.in_set(RenderSystems::Cleanup));
}
