//! Render world: the sample photons (once per frame before the cameras, only after an RSM changed) and
//! the per-view gather.

use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::core_pipeline::schedule::camera_driver;
use bevy::core_pipeline::{Core3d, FullscreenShader};
use bevy::math::Vec4;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only, storage_buffer_read_only_sized, storage_buffer_sized, texture_2d, texture_2d_array, texture_depth_2d,
    uniform_buffer,
};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderGraph, RenderGraphSystems, RenderQueue, ViewQuery};
use bevy::render::sync_world::RenderEntity;
use bevy::render::view::{ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::render::{Extract, ExtractSchedule, Render, RenderStartup, RenderSystems};
use bevy::shader::{Shader, ShaderDefVal};

use super::{DrmSettings, DrmSolidAngle};
use crate::camera::{DiffuseGi, GiMethod};
use crate::composite::{ExtractedDiffuseGi, GI_TARGET_FORMAT, GiViewSystems, GiViewTarget, clear_gi_target};
use crate::rsm::{GpuGiLight, RsmAtlas, RsmFaceUniform};
use crate::settings::GiSettings;

/// The DRM shaders.
#[derive(Resource, Clone)]
pub struct DrmShaders {
    /// The `drm_types` import library, kept alive by this handle.
    #[expect(dead_code, reason = "only holds the library shader's handle")]
    pub types: Handle<Shader>,
    pub photons: Handle<Shader>,
    pub gather: Handle<Shader>,
}

/// One sample photon (`DrmPhoton` in `shaders/drm/drm_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct DrmPhoton {
    /// xyz: world position; w: surface area `A_p` in m² (0 = no surface).
    pub position: Vec4,
    /// xyz: unit normal facing the light; w: area across the beam `A'_p` in m².
    pub normal: Vec4,
    /// rgb: reflected flux `ρΦ` in lumens; w: Eq. 11's solid angle `2π / M` of its light.
    pub flux: Vec4,
}

/// One light face whose map is cut into photons (`DrmFaceJob` in `shaders/drm/drm_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct DrmFaceJob {
    /// Its layer of the RSM atlas.
    pub layer: u32,
    /// Its light's index in the atlas's light list.
    pub light: u32,
    /// Photons of its light (`n² × faces`): Eq. 11's M.
    pub light_photons: u32,
}

/// The photon pass's uniform.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct DrmPhotonsUniform {
    pub samples_per_axis: u32,
    pub photon_count: u32,
    /// 1: the cell's mip-map texel; 0: its centre texel.
    pub mip_mapped: u32,
}

/// The gather's uniform, one per camera.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct DrmGatherUniform {
    pub photon_count: u32,
    /// `‖B_max − B_min‖²` of the scene (Eq. 15), m².
    pub scene_diagonal_squared: f32,
    pub intensity: f32,
}

/// The camera's [`DrmSettings`] in the render world (sanitised), for cameras using the method.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ExtractedDrmSettings(pub DrmSettings);

fn extract_drm_cameras(mut commands: Commands, cameras: Extract<Query<(RenderEntity, &DiffuseGi, Option<&DrmSettings>)>>) {
    for (entity, gi, settings) in &cameras {
        let Ok(mut entity) = commands.get_entity(entity) else {
            continue;
        };
        if gi.method == GiMethod::Drm {
            entity.insert(ExtractedDrmSettings(settings.cloned().unwrap_or_default().sanitized().0));
        } else {
            entity.remove::<ExtractedDrmSettings>();
        }
    }
}

/// Key of the gather pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DrmGatherKey {
    pub half_resolution: bool,
    pub solid_angle: DrmSolidAngle,
}

/// Layouts and pipelines of the DRM passes.
#[derive(Resource)]
pub struct DrmPipelines {
    photons_layout: BindGroupLayoutDescriptor,
    view_layout: BindGroupLayoutDescriptor,
    gather_layout: BindGroupLayoutDescriptor,
    photons: CachedComputePipelineId,
    shaders: DrmShaders,
    fullscreen: VertexState,
}

impl SpecializedRenderPipeline for DrmPipelines {
    type Key = DrmGatherKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let mut shader_defs = crate::shared_shader_defs();
        shader_defs.push(ShaderDefVal::Int("GI_SCALE".into(), if key.half_resolution { 2 } else { 1 }));
        shader_defs.push(ShaderDefVal::UInt("DRM_SOLID_ANGLE".into(), key.solid_angle.equation()));
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_drm_gather_pipeline".into()),
            layout: vec![self.view_layout.clone(), self.gather_layout.clone()],
            vertex: self.fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: self.shaders.gather.clone(),
                shader_defs,
                entry_point: Some("gather".into()),
                targets: vec![Some(ColorTargetState { format: GI_TARGET_FORMAT, blend: None, write_mask: ColorWrites::ALL })],
            }),
            ..default()
        }
    }
}

fn init_drm_pipelines(world: &mut World) {
    let shaders = world.resource::<DrmShaders>().clone();
    let unfilterable = TextureSampleType::Float { filterable: false };
    let photons_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_drm_photons_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer::<DrmPhotonsUniform>(false),
                storage_buffer_read_only::<DrmFaceJob>(false),
                texture_2d_array(unfilterable),
                texture_2d_array(unfilterable),
                texture_2d_array(unfilterable),
                storage_buffer_read_only::<GpuGiLight>(false),
                storage_buffer_read_only::<RsmFaceUniform>(false),
                storage_buffer_sized(false, None),
            ),
        ),
    );
    let view_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_drm_view_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (uniform_buffer::<ViewUniform>(true), texture_depth_2d(), texture_2d(TextureSampleType::Uint)),
        ),
    );
    let gather_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_drm_gather_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (uniform_buffer::<DrmGatherUniform>(true), storage_buffer_read_only_sized(false, None)),
        ),
    );
    let photons = world.resource::<PipelineCache>().queue_compute_pipeline(ComputePipelineDescriptor {
        label: Some("diffuse_gi_drm_photons_pipeline".into()),
        layout: vec![photons_layout.clone()],
        shader: shaders.photons.clone(),
        shader_defs: crate::shared_shader_defs(),
        entry_point: Some("make_photons".into()),
        ..default()
    });
    world.insert_resource(DrmPipelines {
        photons_layout,
        view_layout,
        gather_layout,
        photons,
        shaders,
        fullscreen: world.resource::<FullscreenShader>().to_vertex_state(),
    });
}

/// One set of sample photons: `n × n` per light face, mip-mapped or not.
struct PhotonSet {
    /// `None` until the set's layout is first known.
    photons: Option<Buffer>,
    /// The faces cut into photons, in atlas order.
    jobs: StorageBuffer<Vec<DrmFaceJob>>,
    uniform: UniformBuffer<DrmPhotonsUniform>,
    count: u32,
    /// The light faces `(layer, light)` the buffers are laid out for.
    faces: Vec<(u32, u32)>,
    /// The RSM atlas version the photons were made from (`None`: not yet, or the layout changed).
    built_version: Option<u64>,
}

/// The DRM method's GPU state: photon sets by `(n, mip_mapped)` (shared by the cameras that use the
/// same), the gather uniforms and each camera's offset, set and pipeline.
#[derive(Resource, Default)]
pub struct DrmGpu {
    sets: HashMap<(u32, bool), PhotonSet>,
    uniforms: DynamicUniformBuffer<DrmGatherUniform>,
    views: HashMap<Entity, (u32, (u32, bool), CachedRenderPipelineId)>,
}

#[expect(clippy::too_many_arguments, reason = "per-view preparation")]
fn prepare_drm(
    mut gpu: ResMut<DrmGpu>,
    views: Query<(Entity, &ExtractedDiffuseGi, &ExtractedDrmSettings)>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<DrmPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<DrmPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let gpu = &mut *gpu;
    gpu.uniforms.clear();
    gpu.views.clear();
    // Every light face, in atlas order: (layer, light index).
    let faces: Vec<(u32, u32)> = atlas
        .slots
        .iter()
        .enumerate()
        .flat_map(|(light, slot)| (0..slot.faces).map(move |f| (slot.first_layer + f, light as u32)))
        .collect();
    let diagonal_squared = atlas.scene_bounds.map_or(1.0, |(lo, hi)| (hi - lo).length_squared().max(1e-6));
    let mut used = Vec::new();
    for (entity, gi, settings) in &views {
        if gi.0.method != GiMethod::Drm {
            continue;
        }
        let s = &settings.0;
        let key = (s.samples_per_axis, s.mip_mapped);
        used.push(key);
        let cells = s.samples_per_axis * s.samples_per_axis;
        let count = faces.len() as u32 * cells;
        let set = gpu.sets.entry(key).or_insert_with(|| PhotonSet {
            photons: None,
            jobs: StorageBuffer::default(),
            uniform: UniformBuffer::default(),
            count: 0,
            faces: Vec::new(),
            built_version: None,
        });
        // A new layout (lights, faces or photon count; the set is keyed by n and the mip mode): new
        // buffers, and photons to make before the next gather.
        if set.count != count || set.faces != faces || set.photons.is_none() {
            set.photons = Some(device.create_buffer(&BufferDescriptor {
                label: Some("diffuse_gi_drm_photons"),
                size: DrmPhoton::min_size().get() * count.max(1) as u64,
                usage: BufferUsages::STORAGE,
                mapped_at_creation: false,
            }));
            let faces_of = |light: u32| atlas.slots[light as usize].faces;
            let mut jobs: Vec<DrmFaceJob> = faces
                .iter()
                .map(|&(layer, light)| DrmFaceJob { layer, light, light_photons: cells * faces_of(light) })
                .collect();
            if jobs.is_empty() {
                // Storage buffers may not be empty.
                jobs.push(DrmFaceJob::default());
            }
            *set.jobs.get_mut() = jobs;
            set.jobs.set_label(Some("diffuse_gi_drm_jobs"));
            set.jobs.write_buffer(&device, &queue);
            set.count = count;
            set.uniform.set(DrmPhotonsUniform {
                samples_per_axis: s.samples_per_axis,
                photon_count: count,
                mip_mapped: s.mip_mapped as u32,
            });
            set.uniform.write_buffer(&device, &queue);
            set.faces = faces.clone();
            set.built_version = None;
        }
        let offset = gpu.uniforms.push(&DrmGatherUniform {
            photon_count: count,
            scene_diagonal_squared: diagonal_squared,
            intensity: s.intensity,
        });
        let pipeline = specialized.specialize(
            &pipeline_cache,
            &pipelines,
            DrmGatherKey { half_resolution: gi.0.half_resolution, solid_angle: s.solid_angle },
        );
        gpu.views.insert(entity, (offset, key, pipeline));
    }
    gpu.sets.retain(|key, _| used.contains(key));
    gpu.uniforms.write_buffer(&device, &queue);
}

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
    view: ViewQuery<(Entity, &ExtractedDiffuseGi, &ViewUniformOffset, &ViewPrepassTextures, &GiViewTarget)>,
    gpu: Res<DrmGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<DrmPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    mut ctx: RenderContext,
) {
    let (entity, gi, view_offset, prepass, target) = view.into_inner();
    if gi.0.method != GiMethod::Drm {
        return;
    }
    let Some(&(offset, key, pipeline_id)) = gpu.views.get(&entity) else {
        return;
    };
    let Some(set) = gpu.sets.get(&key).filter(|s| s.count > 0 && s.built_version == Some(atlas.version)) else {
        return;
    };
    let (Some(pipeline), Some(uniforms), Some(depth), Some(gbuffer), Some(gather_uniforms), Some(photons)) = (
        pipeline_cache.get_render_pipeline(pipeline_id),
        view_uniforms.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
        gpu.uniforms.binding(),
        set.photons.as_ref(),
    ) else {
        return;
    };
    let device = ctx.render_device().clone();
    let view_group = device.create_bind_group(
        "diffuse_gi_drm_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer)),
    );
    let gather_group = device.create_bind_group(
        "diffuse_gi_drm_gather_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.gather_layout),
        &BindGroupEntries::sequential((gather_uniforms, photons.as_entire_binding())),
    );
    crate::composite::draw_into_target(
        &mut ctx,
        "diffuse_gi/drm",
        "diffuse_gi_drm_gather",
        target,
        pipeline,
        &[(&view_group, &[view_offset.offset]), (&gather_group, &[offset])],
    );
}

/// Adds the DRM render-world systems; called from [`super::DrmPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    render_app
        .init_resource::<DrmGpu>()
        .init_resource::<SpecializedRenderPipelines<DrmPipelines>>()
        .add_systems(RenderStartup, init_drm_pipelines)
        .add_systems(ExtractSchedule, extract_drm_cameras)
        .add_systems(Render, prepare_drm.in_set(RenderSystems::PrepareResources).after(crate::rsm::prepare_rsm))
        .add_systems(
            RenderGraph,
            build_photons.in_set(RenderGraphSystems::Render).after(crate::rsm::draw_rsm).before(camera_driver),
        )
        .add_systems(Core3d, gather_drm.in_set(GiViewSystems::Produce).after(clear_gi_target));
}
