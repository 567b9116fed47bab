//! Render world: the VPLs' GPU layouts, the buffers of the VPLs, points and shadow maps (uploaded when
//! the set changes), and the pipelines of the shadow-map passes and the gather.

use bevy::math::Vec4;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{storage_buffer_read_only_sized, storage_buffer_sized, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::shader::Shader;

use super::extract::{ExtractedVplSet, ExtractedVplSettings};
use crate::camera::{GiDebugView, GiMethod};
use crate::composite::{ExtractedDiffuseGi, GiViewPass};

/// The VPL shaders.
#[derive(Resource, Clone)]
pub struct VplShaders {
    /// The `vpl_types` import library, kept alive by this handle.
    #[expect(dead_code, reason = "only holds the library shader's handle")]
    pub types: Handle<Shader>,
    pub ism: Handle<Shader>,
    pub gather: Handle<Shader>,
}

/// One VPL on the GPU (`Vpl` in `shaders/vpl/vpl_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct GpuVpl {
    pub position: Vec4,
    pub normal: Vec4,
    pub flux: Vec4,
}

/// The VPL uniform (`VplUniform` in `shaders/vpl/vpl_types.wgsl`): one entry for the shadow-map passes,
/// one per VPL camera for its gather.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct VplUniform {
    pub vpl_count: u32,
    pub ism_resolution: u32,
    pub ism_stride: u32,
    pub points_per_ism: u32,
    pub point_count: u32,
    pub geometry_bound: f32,
    pub ism_bias: f32,
    pub intensity: f32,
    pub point_radius: f32,
    /// Multiplies the slope-scaled part of the depth tolerance: 1 for splatted maps, 0 for traced ones
    /// (they store the far side of the first occluder and its first surface, which leave its own surface
    /// lit).
    pub slope_tolerance: f32,
    /// 1 when the maps are traced (each texel two half floats: the far side of the first occluder and its
    /// first surface, [`encode_traced_texel`](super::generate::encode_traced_texel)), 0 when splatted.
    pub traced: u32,
    /// Traced maps: [`TRACED_PLANE_TOLERANCE`](super::generate::TRACED_PLANE_TOLERANCE).
    pub plane_tolerance: f32,
}

/// The depth tolerance of traced shadow maps, as a fraction of the distance. They store the far side of
/// the first occluder, so the first surface needs little: imperfect maps' 5 % lit the surfaces just past
/// a wall's far side (`cellar`'s ceiling beside the dividing wall at 2.2× the truth), while a tolerance
/// near zero leaves some of a room's light shadowed by the neighbouring texels of the 2×2 test.
/// Measured (lavapipe, block relative RMSE) with 0.2 / 1 / 2 / 5 %: `cellar` 0.303 / 0.314 / – / 0.422,
/// room_3 0.279 / 0.267 / 0.256 / 0.239, room_2 – / 0.490 / 0.511 / 0.557; 1 % is the compromise.
pub const TRACED_DEPTH_BIAS: f32 = 0.01;

/// `u32` words of one VPL's shadow map and its two pull-push levels.
pub fn ism_stride(resolution: u32) -> u32 {
    let r = resolution;
    r * r + (r / 2) * (r / 2) + (r / 4) * (r / 4)
}

/// The shadow-map side actually used: a multiple of 4 (two pull-push levels) in 8–128.
pub fn ism_side(requested: u32) -> u32 {
    (requested.clamp(8, 128) / 4) * 4
}

/// Key of the gather pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VplGatherKey {
    pub half_resolution: bool,
    pub positions: bool,
}

/// Layouts and pipelines of the VPL passes.
#[derive(Resource)]
pub struct VplPipelines {
    pub(super) ism_layout: BindGroupLayoutDescriptor,
    pub(super) pass: GiViewPass,
    pub(super) gather_layout: BindGroupLayoutDescriptor,
    pub(super) splat: CachedComputePipelineId,
    pub(super) pull_push: CachedComputePipelineId,
    shaders: VplShaders,
}

impl SpecializedRenderPipeline for VplPipelines {
    type Key = VplGatherKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let defs = if key.positions { vec!["VPL_POSITIONS".into()] } else { vec![] };
        let layouts = [&self.gather_layout];
        self.pass.pipeline("diffuse_gi_vpl_gather_pipeline", &self.shaders.gather, "gather", key.half_resolution, &layouts, defs, None)
    }
}

pub(super) fn init_vpl_pipelines(world: &mut World) {
    let shaders = world.resource::<VplShaders>().clone();
    let ism_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_vpl_ism_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer::<VplUniform>(true),
                storage_buffer_read_only_sized(false, None),
                storage_buffer_read_only_sized(false, None),
                storage_buffer_sized(false, None),
            ),
        ),
    );
    let gather_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_vpl_gather_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (
                uniform_buffer::<VplUniform>(true),
                storage_buffer_read_only_sized(false, None),
                storage_buffer_read_only_sized(false, None),
            ),
        ),
    );
    let pipeline_cache = world.resource::<PipelineCache>();
    let compute = |label: &'static str, entry: &'static str| {
        pipeline_cache.queue_compute_pipeline(ComputePipelineDescriptor {
            label: Some(label.into()),
            layout: vec![ism_layout.clone()],
            shader: shaders.ism.clone(),
            shader_defs: crate::shared_shader_defs(),
            entry_point: Some(entry.into()),
            ..default()
        })
    };
    let splat = compute("diffuse_gi_vpl_splat_pipeline", "splat");
    let pull_push = compute("diffuse_gi_vpl_pull_push_pipeline", "pull_push");
    let pass = GiViewPass::from_world(world);
    world.insert_resource(VplPipelines { ism_layout, pass, gather_layout, splat, pull_push, shaders });
}

/// The VPL method's GPU state, shared by every VPL camera.
#[derive(Resource, Default)]
pub struct VplGpu {
    pub(super) vpls: Option<Buffer>,
    pub(super) points: Option<Buffer>,
    pub(super) ism: Option<Buffer>,
    pub(super) vpl_count: u32,
    point_count: u32,
    ism_resolution: u32,
    pub(super) points_per_ism: u32,
    uploaded: Option<(u64, u64)>,
    /// The shadow maps need splatting (new VPLs, points or settings, and no traced maps for them).
    pub(super) ism_dirty: bool,
    /// The shadow maps are the set's traced ones (no splat disks: no disk radius in the depth test).
    traced: bool,
    pub(super) uniforms: DynamicUniformBuffer<VplUniform>,
    /// Offset of the shadow-map passes' uniform.
    pub(super) ism_offset: u32,
    /// Per VPL camera: its gather uniform's offset and pipeline.
    pub(super) views: HashMap<Entity, (u32, CachedRenderPipelineId)>,
}

fn storage(device: &RenderDevice, label: &'static str, contents: &[u8]) -> Buffer {
    device.create_buffer_with_data(&BufferInitDescriptor {
        label: Some(label),
        contents,
        usage: BufferUsages::STORAGE,
    })
}

/// The most VPLs whose shadow maps fit in one storage binding of this device.
fn max_vpls_for(device: &RenderDevice, stride: u32) -> u32 {
    let limit = device.limits().max_storage_buffer_binding_size;
    (limit / (stride as u64 * 4)).min(u32::MAX as u64) as u32
}

#[expect(clippy::too_many_arguments, reason = "prepares every per-frame VPL input")]
pub(super) fn prepare_vpls(
    set: Res<ExtractedVplSet>,
    mut gpu: ResMut<VplGpu>,
    views: Query<(Entity, &ExtractedDiffuseGi, &ExtractedVplSettings)>,
    pipelines: Res<VplPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<VplPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let set = &set.0;
    let gpu = &mut *gpu;
    gpu.views.clear();
    if set.vpls.is_empty() && set.points.is_empty() {
        // No VPL camera (or no light): free everything.
        if gpu.vpls.is_some() || gpu.ism.is_some() {
            *gpu = VplGpu::default();
        }
        return;
    }
    let side = ism_side(set.settings.ism_resolution);
    let stride = ism_stride(side);
    let key = (set.generation, set.points_generation);
    if gpu.uploaded != Some(key) {
        let mut vpls: Vec<GpuVpl> = set
            .vpls
            .iter()
            .map(|v| GpuVpl {
                position: v.position.extend(1.0),
                normal: v.normal.extend(0.0),
                flux: v.flux.extend(v.bounce as f32),
            })
            .collect();
        let limit = max_vpls_for(&device, stride) as usize;
        if vpls.len() > limit {
            bevy::log::warn_once!(
                "bevy_diffuse_gi: {} VPLs' shadow maps exceed max_storage_buffer_binding_size; using the first {limit}",
                vpls.len()
            );
            vpls.truncate(limit);
        }
        gpu.vpl_count = vpls.len() as u32;
        if vpls.is_empty() {
            vpls.push(GpuVpl::default());
        }
        let mut bytes = StorageBuffer::<Vec<GpuVpl>>::from(vpls);
        bytes.write_buffer(&device, &queue);
        gpu.vpls = bytes.buffer().cloned();
        let mut points: Vec<[f32; 4]> = set.points.iter().map(|p| p.position.extend(1.0).to_array()).collect();
        gpu.point_count = points.len() as u32;
        if points.is_empty() {
            points.push([0.0; 4]);
        }
        gpu.points = Some(storage(&device, "diffuse_gi_vpl_points", bytemuck::cast_slice(&points)));
        let words = (gpu.vpl_count.max(1) as u64) * stride as u64;
        // Traced maps of these VPLs at this side go into level 0 of each VPL's run of words (the gather
        // reads only level 0); otherwise the maps are splatted.
        let texels = (side * side) as usize;
        let traced = set
            .shadow_maps
            .as_ref()
            .filter(|(traced_side, maps)| *traced_side == side && maps.len() == set.vpls.len() * texels && gpu.vpl_count > 0);
        gpu.ism = Some(match traced {
            Some((_, maps)) => {
                let mut words = vec![0u32; words as usize];
                for (v, map) in maps.chunks(texels).take(gpu.vpl_count as usize).enumerate() {
                    let at = v * stride as usize;
                    words[at..at + texels].copy_from_slice(map);
                }
                device.create_buffer_with_data(&BufferInitDescriptor {
                    label: Some("diffuse_gi_vpl_ism"),
                    contents: bytemuck::cast_slice(&words),
                    usage: BufferUsages::STORAGE | BufferUsages::COPY_DST,
                })
            }
            None => device.create_buffer(&BufferDescriptor {
                label: Some("diffuse_gi_vpl_ism"),
                size: words * 4,
                usage: BufferUsages::STORAGE | BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        });
        gpu.ism_resolution = side;
        gpu.points_per_ism = set.settings.ism_points.min(gpu.point_count.max(1));
        gpu.uploaded = Some(key);
        gpu.traced = traced.is_some();
        gpu.ism_dirty = !gpu.traced;
    }

    let base = VplUniform {
        vpl_count: gpu.vpl_count,
        ism_resolution: gpu.ism_resolution,
        ism_stride: stride,
        points_per_ism: gpu.points_per_ism,
        point_count: gpu.point_count,
        geometry_bound: set.automatic_bound,
        ism_bias: if gpu.traced { TRACED_DEPTH_BIAS } else { set.settings.ism_bias },
        intensity: 1.0,
        slope_tolerance: if gpu.traced { 0.0 } else { 1.0 },
        traced: gpu.traced as u32,
        plane_tolerance: super::generate::TRACED_PLANE_TOLERANCE,
        // Each of a splatted shadow map's points stands for an equal share of the scene's surface: a disk
        // of this radius.
        point_radius: if gpu.traced {
            0.0
        } else {
            (set.surface_area / (std::f32::consts::PI * gpu.points_per_ism.max(1) as f32)).sqrt()
        },
    };
    gpu.uniforms.clear();
    gpu.ism_offset = gpu.uniforms.push(&base);
    for (entity, gi, settings) in &views {
        if gi.0.method != GiMethod::Vpl {
            continue;
        }
        let s = &settings.0;
        let uniform = VplUniform {
            geometry_bound: effective_bound(s.geometry_bound, set.automatic_bound),
            ism_bias: if gpu.traced { TRACED_DEPTH_BIAS } else { s.ism_bias },
            intensity: s.intensity,
            ..base
        };
        let offset = gpu.uniforms.push(&uniform);
        let pipeline = specialized.specialize(
            &pipeline_cache,
            &pipelines,
            VplGatherKey {
                half_resolution: gi.0.half_resolution,
                positions: gi.0.debug_view == GiDebugView::VplPositions,
            },
        );
        gpu.views.insert(entity, (offset, pipeline));
    }
    gpu.uniforms.write_buffer(&device, &queue);
}

/// The bound `b` a camera uses: its own, or the VPL set's automatic one when it asks for 0.
pub fn effective_bound(setting: f32, automatic: f32) -> f32 {
    if setting > 0.0 { setting } else { automatic }
}
