//! Render world: the sample photons (once per frame before the cameras, only after an RSM changed) and
//! the per-view gather.

use bevy::core_pipeline::schedule::camera_driver;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderGraph, RenderGraphSystems, ViewQuery};

use super::prepare::{DrmGpu, DrmPipelines, init_drm_pipelines, prepare_drm};
use crate::camera::GiMethod;
use crate::composite::{GiView, GiViewPassParams, add_view_method};
use crate::rsm::RsmAtlas;

/// Makes the sample photons of every set whose RSMs changed (a new atlas version, compared after this
/// frame's RSM faces were drawn) or whose layout changed, once per frame before the cameras.
fn build_photons(
    mut gpu: ResMut<DrmGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<DrmPipelines>,
    pipeline_cache: Res<PipelineCache>,
    mut ctx: RenderContext,
) {
    let version = atlas.version;
    if gpu.sets.values().all(|s| s.built_version == Some(version)) {
        return;
    }
    let (Some(pipeline), Some(lights), Some(faces)) =
        (pipeline_cache.get_compute_pipeline(pipelines.photons), atlas.lights.binding(), atlas.faces.binding())
    else {
        return;
    };
    let layout = pipeline_cache.get_bind_group_layout(&pipelines.photons_layout);
    let device = ctx.render_device().clone();
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
        label: Some("diffuse_gi_drm_photons"),
        timestamp_writes: None,
    });
    let span = diagnostics.pass_span(&mut pass, "diffuse_gi/drm_photons");
    pass.set_pipeline(pipeline);
    for set in gpu.sets.values_mut() {
        if set.built_version == Some(version) {
            continue;
        }
        let (Some(uniform), Some(jobs), Some(photons)) = (set.uniform.binding(), set.jobs.binding(), set.photons.as_ref())
        else {
            continue;
        };
        if set.count > 0 {
            let group = device.create_bind_group(
                "diffuse_gi_drm_photons_bind_group",
                &layout,
                &BindGroupEntries::sequential((
                    uniform,
                    jobs,
                    &atlas.position_view,
                    &atlas.normal_view,
                    &atlas.flux_view,
                    lights.clone(),
                    faces.clone(),
                    photons.as_entire_binding(),
                )),
            );
            pass.set_bind_group(0, &group, &[]);
            // One workgroup per photon, in rows of at most 65535.
            pass.dispatch_workgroups(set.count.min(65535), set.count.div_ceil(65535), 1);
        }
        set.built_version = Some(version);
    }
    span.end(&mut pass);
}

/// The gather of one camera into its indirect-light target.
fn gather_drm(
    view: ViewQuery<GiView>,
    gpu: Res<DrmGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<DrmPipelines>,
    params: GiViewPassParams,
    mut ctx: RenderContext,
) {
    let view = view.into_inner();
    if view.gi.0.method != GiMethod::Drm {
        return;
    }
    let Some(&(offset, key, pipeline_id)) = gpu.views.get(&view.entity) else {
        return;
    };
    let Some(set) = gpu.sets.get(&key).filter(|s| s.count > 0 && s.built_version == Some(atlas.version)) else {
        return;
    };
    let (Some(pipeline), Some(gather_uniforms), Some(photons)) =
        (params.pipeline_cache.get_render_pipeline(pipeline_id), gpu.uniforms.binding(), set.photons.as_ref())
    else {
        return;
    };
    let gather_group = ctx.render_device().create_bind_group(
        "diffuse_gi_drm_gather_bind_group",
        &params.pipeline_cache.get_bind_group_layout(&pipelines.gather_layout),
        &BindGroupEntries::sequential((gather_uniforms, photons.as_entire_binding())),
    );
    pipelines.pass.draw(
        &mut ctx,
        &params,
        &view,
        GiMethod::Drm,
        ("diffuse_gi/drm", "diffuse_gi_drm_gather"),
        pipeline,
        &[(&gather_group, &[offset])],
        0..3,
    );
}

/// Adds the DRM render-world systems; called from [`super::DrmPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    super::extract::add_extract_systems(render_app);
    add_view_method::<DrmGpu, DrmPipelines, _, _, _>(render_app, init_drm_pipelines, prepare_drm.after(crate::rsm::prepare_rsm), gather_drm);
    render_app.add_systems(
        RenderGraph,
        build_photons.in_set(RenderGraphSystems::Render).after(crate::rsm::draw_rsm).before(camera_driver),
    );
}
