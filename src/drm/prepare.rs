//! Render world: DRM's GPU layouts, pipelines, photon sets and per-view uniforms.

use bevy::math::Vec4;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only, storage_buffer_read_only_sized, storage_buffer_sized, texture_2d_array, uniform_buffer,
};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::shader::{Shader, ShaderDefVal};

use super::DrmSolidAngle;
use super::extract::ExtractedDrmSettings;
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GiViewPass};
use crate::rsm::{GpuGiLight, RsmAtlas, RsmFaceUniform};

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

/// Key of the gather pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DrmGatherKey {
    pub half_resolution: bool,
    pub solid_angle: DrmSolidAngle,
}

/// Layouts and pipelines of the DRM passes.
#[derive(Resource)]
pub struct DrmPipelines {
    pub(super) photons_layout: BindGroupLayoutDescriptor,
    pub(super) pass: GiViewPass,
    pub(super) gather_layout: BindGroupLayoutDescriptor,
    pub(super) photons: CachedComputePipelineId,
    shaders: DrmShaders,
}

impl SpecializedRenderPipeline for DrmPipelines {
    type Key = DrmGatherKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let defs = vec![ShaderDefVal::UInt("DRM_SOLID_ANGLE".into(), key.solid_angle.equation())];
        let layouts = [&self.gather_layout];
        self.pass.pipeline("diffuse_gi_drm_gather_pipeline", &self.shaders.gather, "gather", key.half_resolution, &layouts, defs, None)
    }
}

pub(super) fn init_drm_pipelines(world: &mut World) {
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
    world.insert_resource(DrmPipelines { photons_layout, pass: GiViewPass::from_world(world), gather_layout, photons, shaders });
}

/// One set of sample photons: `n × n` per light face, mip-mapped or not.
pub(super) struct PhotonSet {
    /// `None` until the set's layout is first known.
    pub(super) photons: Option<Buffer>,
    /// The faces cut into photons, in atlas order.
    pub(super) jobs: StorageBuffer<Vec<DrmFaceJob>>,
    pub(super) uniform: UniformBuffer<DrmPhotonsUniform>,
    pub(super) count: u32,
    /// The light faces `(layer, light)` the buffers are laid out for.
    pub(super) faces: Vec<(u32, u32)>,
    /// The RSM atlas version the photons were made from (`None`: not yet, or the layout changed).
    pub(super) built_version: Option<u64>,
}

/// The DRM method's GPU state: photon sets by `(n, mip_mapped)` (shared by the cameras that use the
/// same), the gather uniforms and each camera's offset, set and pipeline.
#[derive(Resource, Default)]
pub struct DrmGpu {
    pub(super) sets: HashMap<(u32, bool), PhotonSet>,
    pub(super) uniforms: DynamicUniformBuffer<DrmGatherUniform>,
    pub(super) views: HashMap<Entity, (u32, (u32, bool), CachedRenderPipelineId)>,
}

#[expect(clippy::too_many_arguments, reason = "per-view preparation")]
pub(super) fn prepare_drm(
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
