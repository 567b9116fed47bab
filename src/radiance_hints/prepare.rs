//! Render world: pipelines, the per-volume buffers, which volumes update this frame, and bind groups.

use bevy::diagnostic::FrameCount;
use bevy::math::{IVec3, IVec4, Mat4, UVec3, UVec4, Vec3, Vec4};
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only_sized, storage_buffer_sized, texture_2d_array, texture_depth_2d,
    texture_storage_3d, uniform_buffer,
};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::render::view::ViewUniform;
use bevy::shader::ShaderDefVal;

use super::extract::ExtractedRhVolumes;
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GiViewPass};
use super::settings::RadianceHintsVolume;
use super::voxelize::VoxelChange;
use super::{PACKED_BYTES, RhShaders, field_floats, field_terms};
use crate::emitters::{EmitterSamples, GpuEmitter};
use crate::rsm::RsmAtlas;
use crate::sh::ShOrder;

/// Workgroup size of every volume pass (threads per group, one hint each); the shaders get it as the
/// `WORKGROUP_SIZE` shader def.
pub const WORKGROUP_SIZE: u32 = crate::WORKGROUP_SIZE;

/// The volume uniform (`RhVolume` in `shaders/radiance_hints/rh_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct RhVolumeUniform {
    pub world_from_local: Mat4,
    pub local_from_world: Mat4,
    pub resolution: UVec4,
    pub cell: Vec4,
    pub r_max: f32,
    pub jitter: f32,
    pub rsm_samples: u32,
    pub light_count: u32,
    pub secondary_samples: u32,
    pub seed: u32,
    pub coverage: f32,
    pub temporal_blend: f32,
    pub intensity: f32,
    pub bounce_threshold: f32,
    pub albedo_volume: u32,
    pub depth_occlusion_samples: u32,
    pub depth_occlusion_strength: f32,
    pub reconstruction_samples: u32,
    pub reconstruction_reach: f32,
    /// 1 when the blend adds the geometric tail of the bounces not run (`blend.wgsl`).
    pub bounce_tail: u32,
    pub workgroups: u32,
    pub bounce: u32,
    pub emitter_count: u32,
    pub emitter_fraction: f32,
    pub blend_band: f32,
    pub blend_faces: u32,
    pub occupancy_resolution: UVec4,
    pub near_field_range: f32,
    /// The bounce pass recomputes the workgroups `w` with `(w + motion_phase) % motion_period == 0` and
    /// adds the bounce the others kept (`bounce.wgsl`;
    /// [`motion_bounce_period`](super::RadianceHintsVolume::motion_bounce_period)).
    pub motion_period: u32,
    pub motion_phase: u32,
    /// The injection does the same with `inject_period` ≤ `motion_period`, the others keeping the
    /// injection of their last turn (`inject.wgsl`;
    /// [`motion_hints_per_update`](super::RadianceHintsVolume::motion_hints_per_update)).
    pub inject_period: u32,
    /// Cells the volume moved by since the last frame, when it moved by whole cells (`scroll.wgsl`).
    pub scroll: IVec4,
}

/// The box of occupancy voxels whose visibility masks a dispatch redoes (`VisibilityRegion` in
/// `shaders/radiance_hints/visibility.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VisibilityRegion {
    /// First voxel (x a multiple of 4: masks are written four voxels to a word).
    pub origin: UVec4,
    /// Words along x, voxels along y and z.
    pub size: UVec4,
    /// After a scroll ([`VoxelChange::Scrolled`]): xyz, the voxel shift (voxel `v` now holds what `v +
    /// shift` held); w = 1 copies the masks of voxels more than a cell from the old and new faces from
    /// the masks before the move instead of recomputing them. w = 0: recompute the region.
    pub shift: IVec4,
}

impl VisibilityRegion {
    /// The voxels `lo..=hi` of a grid of `res` voxels, widened to whole words.
    pub fn covering(lo: UVec3, hi: UVec3, res: UVec3) -> Self {
        let hi = hi.min(res.max(UVec3::ONE) - 1);
        let lo = lo.min(hi);
        let x0 = lo.x / 4 * 4;
        let words = (hi.x + 1).div_ceil(4) - x0 / 4;
        Self {
            origin: UVec4::new(x0, lo.y, lo.z, 0),
            size: UVec4::new(words, hi.y - lo.y + 1, hi.z - lo.z + 1, 0),
            shift: IVec4::ZERO,
        }
    }

    /// Threads of the dispatch (one per word).
    pub fn words(&self) -> u32 {
        self.size.x * self.size.y * self.size.z
    }
}

/// How a volume's visibility masks were last redone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VisibilityUpdate {
    /// Not yet.
    #[default]
    None,
    /// Every voxel (a full voxelisation).
    All,
    /// The voxels around an incremental voxelisation's change.
    Region,
    /// Shifted with a scroll, recomputed within a cell of the faces.
    Shifted,
}

/// The volume passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RhPass {
    Inject { depth_occlusion: bool, voxel_visibility: bool },
    Bounce { paper: bool },
    Decide,
    Blend,
    Export,
    /// The per-voxel hint masks of the reconstruction (`visibility.wgsl`).
    Visibility,
    /// Moving the displayed field with a volume that moved by whole cells (`scroll.wgsl`).
    Scroll,
}

/// Key of the compute pipelines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RhPipelineKey {
    pub pass: RhPass,
    pub sh_order: ShOrder,
}

/// Key of the reconstruction pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RhReconstructKey {
    pub sh_order: ShOrder,
    pub half_resolution: bool,
    /// The [`GiDebugView::HintGrid`](crate::camera::GiDebugView::HintGrid) view: the nearest hint's
    /// irradiance with cell borders instead of the reconstruction.
    pub hint_grid: bool,
    /// The volume lies inside a coarser one: it is drawn after it and over it, fading in over
    /// [`NESTED_BLEND_CELLS`] inside its box, instead of being averaged with it.
    pub nested: bool,
    /// [`IrradianceReconstruction::NonLinear`](super::settings::IrradianceReconstruction::NonLinear).
    pub nonlinear_irradiance: bool,
}

/// Cells over which a volume nested inside a coarser one fades in from its box's faces.
pub const NESTED_BLEND_CELLS: f32 = 2.0;

/// Layouts and shaders of every Radiance Hints pass.
#[derive(Resource)]
pub struct RhPipelines {
    /// Group 0 of the injection: uniform, delta, sum, distances.
    pub inject_output_layout: BindGroupLayoutDescriptor,
    /// Group 1 of the injection: the RSM atlas, the GI lights, the emitter samples and the RSM faces.
    pub rsm_layout: BindGroupLayoutDescriptor,
    /// Group 3 of the injection with §8 occlusion: the camera's view and depth.
    pub depth_layout: BindGroupLayoutDescriptor,
    /// Group 2 of the injection and the visibility masks' pass: the occupancy bits (`rh_occupancy.wgsl`).
    pub occupancy_layout: BindGroupLayoutDescriptor,
    /// Group 2 of the bounces: the occupancy bits and the visibility masks (`rh_masks.wgsl`).
    pub bounce_occupancy_layout: BindGroupLayoutDescriptor,
    /// Group 1 of every pass that reads a volume (`rh_sampling.wgsl`): uniform, SH, distances, albedo.
    pub sample_layout: BindGroupLayoutDescriptor,
    /// Group 0 of a bounce: delta out, sum, partial energies.
    pub bounce_output_layout: BindGroupLayoutDescriptor,
    pub decide_layout: BindGroupLayoutDescriptor,
    pub blend_layout: BindGroupLayoutDescriptor,
    /// Group 0 of the scroll: uniform, the copy of the field before the move, the field.
    pub scroll_layout: BindGroupLayoutDescriptor,
    pub export_layout: BindGroupLayoutDescriptor,
    /// The reconstruction's per-view pass (group 0: view, depth, G-buffer).
    pub reconstruct: GiViewPass,
    /// Group 0 of the visibility-mask pass: the region to redo and the masks.
    pub visibility_output_layout: BindGroupLayoutDescriptor,
    /// Group 2 of the reconstruction: the occupancy bits, the visibility masks and the packed field.
    pub lookup_layout: BindGroupLayoutDescriptor,
    shaders: RhShaders,
}

impl FromWorld for RhPipelines {
    fn from_world(world: &mut World) -> Self {
        let shaders = world.resource::<RhShaders>().clone();
        let reconstruct = GiViewPass::from_world(world);
        let rw = || storage_buffer_sized(false, None);
        let ro = || storage_buffer_read_only_sized(false, None);
        let uniform = || uniform_buffer::<RhVolumeUniform>(true);
        let compute = ShaderStages::COMPUTE;
        let unfilterable = TextureSampleType::Float { filterable: false };
        Self {
            inject_output_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_inject_output_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform(), rw(), rw(), rw(), ro())),
            ),
            occupancy_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_occupancy_layout",
                &BindGroupLayoutEntries::single(ShaderStages::COMPUTE | ShaderStages::FRAGMENT, ro()),
            ),
            bounce_occupancy_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_bounce_occupancy_layout",
                &BindGroupLayoutEntries::sequential(compute, (ro(), ro())),
            ),
            rsm_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_rsm_layout",
                &BindGroupLayoutEntries::sequential(
                    compute,
                    (
                        texture_2d_array(unfilterable),
                        texture_2d_array(unfilterable),
                        texture_2d_array(unfilterable),
                        ro(),
                        ro(),
                        ro(),
                    ),
                ),
            ),
            depth_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_depth_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform_buffer::<ViewUniform>(true), texture_depth_2d())),
            ),
            sample_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_sample_layout",
                &BindGroupLayoutEntries::sequential(
                    ShaderStages::COMPUTE | ShaderStages::FRAGMENT,
                    (uniform(), ro(), ro(), ro()),
                ),
            ),
            bounce_output_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_bounce_output_layout",
                &BindGroupLayoutEntries::sequential(compute, (rw(), rw(), rw())),
            ),
            decide_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_decide_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform(), ro(), rw(), rw())),
            ),
            blend_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_blend_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform(), ro(), rw(), rw(), ro(), ro(), ro())),
            ),
            scroll_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_scroll_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform(), ro(), rw())),
            ),
            export_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_export_layout",
                &BindGroupLayoutEntries::single(
                    compute,
                    texture_storage_3d(TextureFormat::Rgba16Float, StorageTextureAccess::WriteOnly),
                ),
            ),
            visibility_output_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_visibility_output_layout",
                &BindGroupLayoutEntries::sequential(compute, (uniform_buffer::<VisibilityRegion>(false), rw(), ro())),
            ),
            lookup_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_rh_lookup_layout",
                &BindGroupLayoutEntries::sequential(ShaderStages::FRAGMENT, (ro(), ro(), ro())),
            ),
            reconstruct,
            shaders,
        }
    }
}

/// The field's shader defs (on top of the crate's shared ones).
fn sh_defs(order: ShOrder) -> Vec<ShaderDefVal> {
    vec![
        ShaderDefVal::UInt("SH_COEFS".into(), order.coefficients() as u32),
        ShaderDefVal::UInt("FIELD_TERMS".into(), field_terms(order) as u32),
        // The free extents packed into a hint's validity (`voxelize::encode_free_extents`).
        ShaderDefVal::UInt("RH_FREE_BITS".into(), super::voxelize::FREE_BITS),
        ShaderDefVal::UInt("RH_FREE_STEPS".into(), super::voxelize::FREE_STEPS),
        ShaderDefVal::UInt("RH_FREE_MARKER_BIT".into(), super::voxelize::FREE_MARKER_BIT),
    ]
}

impl SpecializedComputePipeline for RhPipelines {
    type Key = RhPipelineKey;

    fn specialize(&self, key: Self::Key) -> ComputePipelineDescriptor {
        let mut shader_defs = crate::shared_shader_defs();
        shader_defs.extend(sh_defs(key.sh_order));
        let (label, layout, shader, entry) = match key.pass {
            RhPass::Inject { depth_occlusion, voxel_visibility } => {
                // Group 2 (occupancy) is always in the layout; group 3 (a camera's view and depth) only
                // with §8, whose volumes update in a camera's pass.
                let mut layout = vec![
                    self.inject_output_layout.clone(),
                    self.rsm_layout.clone(),
                    self.occupancy_layout.clone(),
                ];
                if depth_occlusion {
                    layout.push(self.depth_layout.clone());
                    shader_defs.push("DEPTH_OCCLUSION".into());
                }
                if voxel_visibility {
                    shader_defs.push("VOXEL_VISIBILITY".into());
                }
                ("diffuse_gi_rh_inject_pipeline", layout, &self.shaders.inject, "inject")
            }
            RhPass::Bounce { paper } => {
                if paper {
                    shader_defs.push("SECONDARY_PAPER".into());
                }
                (
                    "diffuse_gi_rh_bounce_pipeline",
                    vec![
                        self.bounce_output_layout.clone(),
                        self.sample_layout.clone(),
                        self.bounce_occupancy_layout.clone(),
                    ],
                    &self.shaders.bounce,
                    "bounce",
                )
            }
            RhPass::Decide => ("diffuse_gi_rh_decide_pipeline", vec![self.decide_layout.clone()], &self.shaders.decide, "decide"),
            RhPass::Blend => ("diffuse_gi_rh_blend_pipeline", vec![self.blend_layout.clone()], &self.shaders.blend, "blend"),
            RhPass::Visibility => (
                "diffuse_gi_rh_visibility_pipeline",
                vec![
                    self.visibility_output_layout.clone(),
                    self.sample_layout.clone(),
                    self.occupancy_layout.clone(),
                ],
                &self.shaders.visibility,
                "visibility_masks",
            ),
            RhPass::Scroll => ("diffuse_gi_rh_scroll_pipeline", vec![self.scroll_layout.clone()], &self.shaders.scroll, "scroll_field"),
            RhPass::Export => (
                "diffuse_gi_rh_export_pipeline",
                vec![self.export_layout.clone(), self.sample_layout.clone()],
                &self.shaders.export,
                "export_irradiance",
            ),
        };
        ComputePipelineDescriptor {
            label: Some(label.into()),
            layout,
            shader: shader.clone(),
            shader_defs,
            entry_point: Some(entry.into()),
            ..default()
        }
    }
}

impl SpecializedRenderPipeline for RhPipelines {
    type Key = RhReconstructKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let mut defs = sh_defs(key.sh_order);
        if key.hint_grid {
            defs.push("HINT_GRID".into());
        }
        if key.nonlinear_irradiance {
            defs.push("NONLINEAR_IRRADIANCE".into());
        }
        let add = BlendComponent { src_factor: BlendFactor::One, dst_factor: BlendFactor::One, operation: BlendOperation::Add };
        // Volumes side by side add up; the composite divides by the summed weight in alpha. A nested
        // volume is drawn over the coarser ones (premultiplied by its weight).
        let blend = if key.nested { BlendState::PREMULTIPLIED_ALPHA_BLENDING } else { BlendState { color: add, alpha: add } };
        self.reconstruct.pipeline(
            "diffuse_gi_rh_reconstruct_pipeline",
            &self.shaders.reconstruct,
            "reconstruct",
            key.half_resolution,
            &[&self.sample_layout, &self.lookup_layout],
            defs,
            Some(blend),
        )
    }
}

/// What a volume's current result was computed from; a change starts a new round of updates.
#[derive(Clone, Debug, PartialEq)]
struct BuildKey {
    rsm_version: u64,
    emitter_generation: u64,
    settings: RadianceHintsVolume,
    transform: [u32; 16],
    voxel_generation: u64,
}

/// GPU state of one volume.
pub struct RhVolumeGpu {
    pub entity: Entity,
    pub settings: RadianceHintsVolume,
    pub world_from_local: Mat4,
    pub hints: u32,
    pub workgroups: u32,
    /// The increments of the last two bounces (ping-pong), the running sum, the displayed result.
    pub delta: [Buffer; 2],
    pub sum: Buffer,
    pub result: Buffer,
    pub distances: Buffer,
    /// Per hint: albedo (rgb) and validity (a).
    pub albedo: Buffer,
    /// The occupancy bits.
    pub occupancy: Buffer,
    /// Per occupancy voxel, the mask of its stencil's hints a lookup may use (8 bits, 4 voxels a word).
    pub visibility: Buffer,
    /// The masks before a scroll, copied for `visibility.wgsl` to shift; made on the volume's first
    /// scroll (a still volume does not pay for it).
    pub visibility_previous: Option<Buffer>,
    /// How the masks were last redone (for measurements and tests).
    pub last_visibility_update: VisibilityUpdate,
    /// The displayed result in the reconstruction's compact irradiance form (`rh_packed.wgsl`, 32 B per
    /// hint), written by the blend.
    pub packed: Buffer,
    /// The region uniform of the visibility-mask pass.
    pub visibility_region: Buffer,
    /// The masks to redo before the next reconstruction (after the voxels changed).
    pub visibility_pending: Option<VisibilityRegion>,
    pub occupancy_resolution: UVec3,
    pub partials: Buffer,
    /// Indirect dispatch arguments, one slot of three `u32` per extra bounce.
    pub args: Buffer,
    pub stats: Buffer,
    /// Where `stats` (the extra bounces the last full update ran) is read back to the CPU.
    pub bounce_readback: super::activity::BounceReadback,
    /// Frames in a row that reused the field.
    pub frames_reused: u32,
    allocated_for: (UVec3, ShOrder, u32),
    voxel_generation: Option<u64>,
    built_from: Option<BuildKey>,
    /// Updates still to run before the temporal blend has converged.
    pub updates_left: u32,
    /// Whether the next update replaces the result instead of blending into it.
    pub first_update: bool,
    /// Updates since the last change of the inputs.
    pub age: u32,
    /// Whether the volume runs inject/bounce/blend this frame.
    pub update_this_frame: bool,
    /// The volume lies inside a coarser one (see [`RhReconstructKey::nested`]).
    pub nested: bool,
    /// Edge of a cell's diagonal, metres (coarser volumes are drawn first).
    pub cell_diagonal: f32,
    /// The volume moved by whole cells since the last frame: its displayed field is scrolled with it
    /// before this frame's update (`scroll.wgsl`) instead of being shown a cell off.
    pub scroll: Option<IVec3>,
    /// Amortised updates in a row, this one included (0: this frame's update, if any, is a full one). An
    /// amortised update ([`motion_update`](Self::motion_update)) runs while the inputs change every
    /// frame, as they do while a light or mesh moves: injection plus a single bounce gathered from the
    /// displayed field, so bounces accumulate over frames instead of all running every frame. The first
    /// recomputes every hint's bounce, the next ones one workgroup in
    /// [`motion_bounce_period`](super::RadianceHintsVolume::motion_bounce_period), and in a volume larger
    /// than [`motion_hints_per_update`](super::RadianceHintsVolume::motion_hints_per_update) inject in
    /// turns as well.
    pub motion_streak: u32,
    /// Dynamic offsets: `[0]` for injection, blending, export and sampling; `[k]` for extra bounce `k`.
    pub uniform_offsets: Vec<u32>,
    pub export: Option<Handle<Image>>,
    pub pipelines: Option<RhVolumePipelines>,
    pub bind_groups: Option<RhVolumeBindGroups>,
    /// The export texture written since the last update.
    export_written: Option<TextureId>,
}

/// Cached pipeline ids of one volume.
#[derive(Clone, Copy, Debug)]
pub struct RhVolumePipelines {
    pub inject: CachedComputePipelineId,
    pub bounce: CachedComputePipelineId,
    pub decide: CachedComputePipelineId,
    pub blend: CachedComputePipelineId,
    pub export: CachedComputePipelineId,
    pub visibility: CachedComputePipelineId,
    pub scroll: CachedComputePipelineId,
}

/// Bind groups of one volume, rebuilt every frame (the uniform buffer may move).
pub struct RhVolumeBindGroups {
    pub inject_output: BindGroup,
    pub occupancy: BindGroup,
    /// Group 2 of the bounces: occupancy and visibility masks.
    pub bounce_occupancy: BindGroup,
    /// Reading the displayed result (reconstruction, export, debug views).
    pub sample_result: BindGroup,
    /// For extra bounce `k`: output group (writes `delta[k % 2]`) and sample group (reads the other).
    pub bounce: [(BindGroup, BindGroup); 2],
    pub decide: BindGroup,
    pub blend: BindGroup,
    /// The scroll of the displayed field, from its copy in `delta[0]`.
    pub scroll: BindGroup,
    /// The visibility-mask pass's output (group 0).
    pub visibility_output: BindGroup,
    /// Group 2 of the reconstruction: occupancy and visibility masks.
    pub lookup: BindGroup,
}

/// Every volume's GPU state, their uniforms, and the per-frame bookkeeping.
#[derive(Resource, Default)]
pub struct RhVolumesGpu {
    pub volumes: Vec<RhVolumeGpu>,
    pub uniforms: DynamicUniformBuffer<RhVolumeUniform>,
    /// The frame whose volume update has run.
    pub updated_frame: Option<u32>,
    /// The frame whose §8 volumes have been updated (by the first GI camera's pass).
    pub depth_updated_frame: Option<u32>,
    /// Reconstruction pipelines per key the cameras use this frame.
    pub reconstruct_pipelines: HashMap<RhReconstructKey, CachedRenderPipelineId>,
    /// The scene's emitter samples ([`crate::emitters`]), shared by every volume (one unused sample
    /// when there are none: storage buffers may not be empty), and the generation they were uploaded at.
    pub emitters: Option<Buffer>,
    emitters_uploaded: Option<u64>,
    emitter_count: u32,
}

/// For each volume, whether its box lies inside the box of another volume with cells at least 10 %
/// larger — such a volume refines the coarser one where they overlap instead of averaging with it — as a
/// mask of the faces it fades in from: bit `2·axis + side` (side 0 at −0.5, 1 at +0.5 of its unit cube)
/// is set for a face that lies inside the coarser volume, clear for one that lies on its boundary (walls
/// there belong to both volumes, and the coarser field does not go beyond them). 0: not nested.
pub fn nested_volumes(volumes: &[super::extract::ExtractedRhVolume]) -> Vec<u32> {
    let cell = |v: &super::extract::ExtractedRhVolume| {
        (super::settings::box_size(v.world_from_local) / v.settings.resolution.as_vec3()).length()
    };
    let corner = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { -0.5 } else { 0.5 },
            if i & 2 == 0 { -0.5 } else { 0.5 },
            if i & 4 == 0 { -0.5 } else { 0.5 },
        )
    };
    volumes
        .iter()
        .map(|inner| {
            let Some(outer) = volumes.iter().find(|outer| {
                let local_from_world = outer.world_from_local.inverse();
                outer.entity != inner.entity
                    && cell(outer) > 1.1 * cell(inner)
                    && (0..8).all(|i| {
                        let p = inner.world_from_local.transform_point3(corner(i));
                        local_from_world.transform_point3(p).abs().max_element() <= 0.5 + 1e-4
                    })
            }) else {
                return 0;
            };
            let local_from_world = outer.world_from_local.inverse();
            let outer_size = super::settings::box_size(outer.world_from_local);
            let margin = cell(inner) / outer_size.max_element().max(1e-6);
            let mut faces = 0;
            for axis in 0..3 {
                for side in 0..2 {
                    let mut centre = Vec3::ZERO;
                    centre[axis] = if side == 0 { -0.5 } else { 0.5 };
                    let p = local_from_world.transform_point3(inner.world_from_local.transform_point3(centre));
                    if p[axis].abs() < 0.5 - margin {
                        faces |= 1 << (2 * axis + side);
                    }
                }
            }
            // Nested with every face on the boundary: the finer volume simply replaces the coarser one.
            faces | 1 << 6
        })
        .collect()
}

/// The weight of an update in the displayed field: everything on the very first update; the temporal
/// blend on the update that follows a change (every update while the inputs change each frame, and every
/// update without refinement); then `1/k` on the `k`-th still update, which makes the field the running
/// mean of the updates since the change — the field from before the change is gone from the first still
/// update on (an intensity change alone scales the field exactly).
pub fn blend_weight(first_update: bool, age: u32, settings: &RadianceHintsVolume) -> f32 {
    if first_update {
        1.0
    } else if age == 0 || settings.refinement_updates == 0 {
        settings.temporal_blend
    } else {
        1.0 / age as f32
    }
}

/// Updates that bring the temporal blend within 1 % of a new result: `(1 − α)^n ≤ 0.01`.
pub fn convergence_updates(temporal_blend: f32) -> u32 {
    let alpha = temporal_blend.clamp(0.05, 1.0);
    if alpha >= 1.0 {
        return 1;
    }
    ((0.01f32).ln() / (1.0 - alpha).ln()).ceil() as u32 + 1
}

/// `u32` words of the occupancy bits of a volume with `hints` per axis.
fn occupancy_words(hints: UVec3) -> u64 {
    let r = super::voxelize::occupancy_resolution(hints);
    (r.x as u64 * r.y as u64 * r.z as u64).div_ceil(32)
}

fn buffer(device: &RenderDevice, label: &'static str, size: u64, usage: BufferUsages) -> Buffer {
    device.create_buffer(&BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage,
        mapped_at_creation: false,
    })
}

impl RhVolumeGpu {
    /// This frame's update is an amortised one (see [`motion_streak`](Self::motion_streak)).
    pub fn motion_update(&self) -> bool {
        self.motion_streak > 0
    }

    fn new(device: &RenderDevice, entity: Entity, settings: &RadianceHintsVolume) -> Self {
        let hints = settings.hint_count();
        let workgroups = hints.div_ceil(WORKGROUP_SIZE);
        let sh_bytes = hints as u64 * field_floats(settings.sh_order) as u64 * 4;
        let storage = BufferUsages::STORAGE | BufferUsages::COPY_DST | BufferUsages::COPY_SRC;
        Self {
            entity,
            settings: settings.clone(),
            world_from_local: Mat4::IDENTITY,
            hints,
            workgroups,
            delta: [
                buffer(device, "diffuse_gi_rh_delta_a", sh_bytes, storage),
                buffer(device, "diffuse_gi_rh_delta_b", sh_bytes, storage),
            ],
            sum: buffer(device, "diffuse_gi_rh_sum", sh_bytes, storage),
            result: buffer(device, "diffuse_gi_rh_result", sh_bytes, storage | BufferUsages::COPY_SRC),
            distances: buffer(device, "diffuse_gi_rh_distances", hints as u64 * 16, storage),
            albedo: buffer(device, "diffuse_gi_rh_albedo", hints as u64 * 16, storage),
            occupancy: buffer(
                device,
                "diffuse_gi_rh_occupancy",
                occupancy_words(settings.resolution) * 4,
                storage,
            ),
            visibility: buffer(device, "diffuse_gi_rh_visibility", occupancy_words(settings.resolution) * 32, storage),
            visibility_previous: None,
            last_visibility_update: VisibilityUpdate::None,
            packed: buffer(device, "diffuse_gi_rh_packed", hints as u64 * PACKED_BYTES, storage),
            visibility_region: buffer(
                device,
                "diffuse_gi_rh_visibility_region",
                VisibilityRegion::min_size().get(),
                BufferUsages::UNIFORM | BufferUsages::COPY_DST,
            ),
            visibility_pending: None,
            occupancy_resolution: super::voxelize::occupancy_resolution(settings.resolution),
            partials: buffer(device, "diffuse_gi_rh_partials", workgroups as u64 * 8, storage),
            args: buffer(
                device,
                "diffuse_gi_rh_bounce_args",
                (settings.extra_bounces.max(1) as u64 + 1) * 12,
                storage | BufferUsages::INDIRECT,
            ),
            stats: buffer(device, "diffuse_gi_rh_stats", 16, storage | BufferUsages::COPY_SRC),
            bounce_readback: super::activity::BounceReadback::new(buffer(
                device,
                "diffuse_gi_rh_stats_readback",
                4,
                BufferUsages::MAP_READ | BufferUsages::COPY_DST,
            )),
            frames_reused: 0,
            allocated_for: (settings.resolution, settings.sh_order, settings.extra_bounces),
            voxel_generation: None,
            built_from: None,
            updates_left: 0,
            first_update: true,
            age: 0,
            update_this_frame: false,
            nested: false,
            cell_diagonal: 0.0,
            motion_streak: 0,
            scroll: None,
            uniform_offsets: Vec::new(),
            export: None,
            pipelines: None,
            bind_groups: None,
            export_written: None,
        }
    }

    /// Whether the export texture `image` already holds the current result.
    pub fn export_written(&self, image: &bevy::render::texture::GpuImage) -> bool {
        self.export_written == Some(image.texture.id())
    }

    pub fn mark_export_written(&mut self, image: &bevy::render::texture::GpuImage) {
        self.export_written = Some(image.texture.id());
    }
}

#[expect(clippy::too_many_arguments, reason = "prepares every per-volume GPU input")]
pub(crate) fn prepare_rh_volumes(
    extracted: Res<ExtractedRhVolumes>,
    atlas: Res<RsmAtlas>,
    mut state: ResMut<RhVolumesGpu>,
    pipelines: Res<RhPipelines>,
    mut specialized: ResMut<SpecializedComputePipelines<RhPipelines>>,
    mut specialized_render: ResMut<SpecializedRenderPipelines<RhPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    cameras: Query<&ExtractedDiffuseGi>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    frame: Res<FrameCount>,
    emitters: Option<Res<EmitterSamples>>,
    activity: Res<super::activity::RadianceHintsActivity>,
) {
    let state = &mut *state;
    // The emitter samples, uploaded when they change.
    let emitter_generation = emitters.as_ref().map_or(0, |e| e.generation);
    if state.emitters.is_none() || state.emitters_uploaded != Some(emitter_generation) {
        let samples: &[GpuEmitter] = emitters.as_ref().map_or(&[], |e| e.samples.as_slice());
        let data = if samples.is_empty() { vec![GpuEmitter::default()] } else { samples.to_vec() };
        state.emitters = Some(device.create_buffer_with_data(&BufferInitDescriptor {
            label: Some("diffuse_gi_rh_emitters"),
            contents: bytemuck::cast_slice(&data),
            usage: BufferUsages::STORAGE,
        }));
        state.emitters_uploaded = Some(emitter_generation);
        state.emitter_count = samples.len() as u32;
    }
    // Emitters share the samples of each hint with the GI lights by power.
    let light_power: f32 = atlas.slots.iter().map(|s| s.light_faces.power).sum();
    let emitter_power = emitters.as_ref().map_or(0.0, |e| e.power);
    let emitter_fraction = if state.emitter_count == 0 {
        0.0
    } else if light_power > 0.0 {
        (emitter_power / (emitter_power + light_power)).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let nested = nested_volumes(&extracted.volumes);
    let previous = std::mem::take(&mut state.volumes);
    let mut previous: HashMap<Entity, RhVolumeGpu> = previous.into_iter().map(|v| (v.entity, v)).collect();
    state.uniforms.clear();
    let light_count = atlas.slots.len() as u32;

    for (index, volume) in extracted.volumes.iter().enumerate() {
        let s = &volume.settings;
        let mut gpu = match previous.remove(&volume.entity) {
            Some(gpu) if gpu.allocated_for == (s.resolution, s.sh_order, s.extra_bounces) => gpu,
            _ => RhVolumeGpu::new(&device, volume.entity, s),
        };
        gpu.settings = s.clone();
        gpu.world_from_local = volume.world_from_local;
        gpu.export = volume.export.clone();

        // The voxelised scene, uploaded when it changes. Until the first voxelisation arrives: white
        // albedo, every hint valid, nothing occupied.
        let voxel_generation = volume.voxels.as_ref().map_or(0, |(g, _)| *g);
        if gpu.voxel_generation != Some(voxel_generation) {
            let fitting = volume.voxels.as_ref().filter(|(_, v)| {
                v.albedo_validity.len() == gpu.hints as usize && v.occupancy_resolution == gpu.occupancy_resolution
            });
            let albedo: Vec<[f32; 4]> = match fitting {
                Some((_, v)) => v.albedo_validity.iter().map(|a| a.to_array()).collect(),
                None => vec![[1.0, 1.0, 1.0, 1.0]; gpu.hints as usize],
            };
            queue.write_buffer(&gpu.albedo, 0, bytemuck::cast_slice(&albedo));
            let words = occupancy_words(s.resolution) as usize;
            let occupancy = match fitting {
                Some((_, v)) => v.occupancy.clone(),
                None => vec![0u32; words],
            };
            queue.write_buffer(&gpu.occupancy, 0, bytemuck::cast_slice(&occupancy));
            // The visibility masks: the voxels around what changed after an incremental voxelisation that
            // follows the one the masks were made from, else all (a mask depends on the occupancy between
            // its voxel and its stencil's hints, all within a cell).
            let res = gpu.occupancy_resolution;
            let all = VisibilityRegion::covering(UVec3::ZERO, res - 1, res);
            let follows = gpu.voxel_generation.is_some_and(|g| g + 1 == voxel_generation) && gpu.visibility_pending.is_none();
            let change = fitting.map_or(VoxelChange::All, |(_, v)| v.changed);
            let region = match change {
                VoxelChange::Voxels(lo, hi) if follows => {
                    let margin = UVec3::splat(super::voxelize::OCCUPANCY_FACTOR + 1);
                    Some(VisibilityRegion::covering(lo.saturating_sub(margin), hi + margin, res))
                }
                VoxelChange::Nothing if follows => None,
                // A scroll by whole words along x: shift the masks, recompute only near the faces.
                VoxelChange::Scrolled(shift) if follows && shift.x % 4 == 0 => Some(VisibilityRegion { shift: shift.extend(1), ..all }),
                _ => Some(all),
            };
            if region.is_some_and(|r| r.shift.w != 0) && gpu.visibility_previous.is_none() {
                gpu.visibility_previous = Some(buffer(
                    &device,
                    "diffuse_gi_rh_visibility_previous",
                    gpu.visibility.size(),
                    BufferUsages::STORAGE | BufferUsages::COPY_DST,
                ));
            }
            if let Some(r) = region {
                gpu.last_visibility_update = if r.shift.w != 0 {
                    VisibilityUpdate::Shifted
                } else if r == all {
                    VisibilityUpdate::All
                } else {
                    VisibilityUpdate::Region
                };
            }
            gpu.visibility_pending = region;
            gpu.voxel_generation = Some(voxel_generation);
        }

        let key = BuildKey {
            rsm_version: atlas.version,
            emitter_generation,
            settings: s.clone(),
            transform: volume.world_from_local.to_cols_array().map(f32::to_bits),
            voxel_generation,
        };
        // §8 occlusion depends on the camera: recompute every frame.
        let changed = gpu.built_from.as_ref() != Some(&key) || s.depth_occlusion.is_some();
        // A volume that moved by whole cells keeps its field, scrolled with it (a cascade level following
        // its camera).
        gpu.scroll = gpu.built_from.as_ref().filter(|b| b.settings == key.settings && !gpu.first_update).and_then(|b| {
            let before = Mat4::from_cols_array(&b.transform.map(f32::from_bits));
            super::voxelize::scroll_shift(before, volume.world_from_local, s.resolution)
        });
        // A change to a volume that already shows a field: amortise (see `motion_update`). A new volume
        // or new settings get the full update.
        let same_volume = gpu.built_from.as_ref().is_some_and(|b| b.settings == key.settings && b.transform == key.transform)
            || gpu.scroll.is_some();
        let motion_update = changed && same_volume && !gpu.first_update && s.extra_bounces > 0;
        gpu.motion_streak = if motion_update { gpu.motion_streak.saturating_add(1) } else { 0 };
        // The bounces kept in `delta[1]` are those of the last amortised update: after a full update (its
        // last increment is there) or a scroll (they lie a shift off) every hint recomputes its own.
        // The same holds for the injection kept in `delta[0]`. A volume of more hints than
        // `motion_hints_per_update` injects them in turns too, and its bounces at least as slowly, so that
        // each frame's update is about that many hints' work.
        let amortised = gpu.motion_streak > 1 && gpu.scroll.is_none();
        let inject_period = if amortised { gpu.hints.div_ceil(s.motion_hints_per_update.max(1)).max(1) } else { 1 };
        // A multiple of the injection's period, so that a workgroup's bounce is recomputed on one of its
        // injection turns (the only updates that blend it into the displayed field).
        let motion_period = if amortised { inject_period * s.motion_bounce_period.max(1).div_ceil(inject_period) } else { 1 };
        if changed {
            gpu.updates_left = convergence_updates(s.temporal_blend).max(s.refinement_updates + 1);
            gpu.age = 0;
            gpu.built_from = Some(key);
        }
        gpu.update_this_frame = gpu.updates_left > 0;
        gpu.frames_reused = if gpu.update_this_frame { 0 } else { gpu.frames_reused.saturating_add(1) };
        if gpu.update_this_frame && !gpu.motion_update() {
            // The decide passes count the extra bounces of this update, and the energies of the last two,
            // from zero.
            queue.write_buffer(&gpu.stats, 0, bytemuck::bytes_of(&[0u32; 4]));
        }

        // Uniforms: one for injection/blend/sampling, one per extra bounce.
        let size = (volume.world_from_local * Vec4::new(1.0, 0.0, 0.0, 0.0)).truncate().length();
        let size_y = (volume.world_from_local * Vec4::new(0.0, 1.0, 0.0, 0.0)).truncate().length();
        let size_z = (volume.world_from_local * Vec4::new(0.0, 0.0, 1.0, 0.0)).truncate().length();
        let extent = Vec3::new(size, size_y, size_z);
        let cell = extent / s.resolution.as_vec3();
        gpu.nested = nested[index] != 0;
        gpu.cell_diagonal = cell.length();
        let base_seed = frame.0.wrapping_mul(0x9E37_79B9) ^ (index as u32).wrapping_mul(0x85EB_CA6B);
        let mut uniform = RhVolumeUniform {
            world_from_local: volume.world_from_local,
            local_from_world: volume.world_from_local.inverse(),
            resolution: s.resolution.extend(gpu.hints),
            cell: cell.extend(cell.length()),
            r_max: s.effective_r_max(extent),
            jitter: s.jitter,
            rsm_samples: s.rsm_samples,
            light_count,
            secondary_samples: s.secondary_samples,
            seed: base_seed,
            coverage: s.rsm_coverage,
            temporal_blend: blend_weight(gpu.first_update, gpu.age, s),
            intensity: s.intensity,
            bounce_threshold: s.bounce_threshold,
            albedo_volume: s.albedo_volume as u32,
            depth_occlusion_samples: s.depth_occlusion.map_or(0, |o| o.samples),
            depth_occlusion_strength: s.depth_occlusion.map_or(0.0, |o| o.strength),
            reconstruction_samples: s.reconstruction_samples,
            reconstruction_reach: s.reconstruction_reach,
            bounce_tail: (!gpu.motion_update() && s.extra_bounces > 0) as u32,
            workgroups: gpu.workgroups,
            bounce: 0,
            emitter_count: state.emitter_count,
            emitter_fraction,
            blend_band: if gpu.nested { NESTED_BLEND_CELLS } else { 0.0 },
            blend_faces: nested[index],
            occupancy_resolution: gpu.occupancy_resolution.extend(s.voxel_visibility as u32),
            near_field_range: if s.voxel_visibility { s.near_field_occlusion * cell.length() } else { 0.0 },
            motion_period,
            motion_phase: gpu.motion_streak,
            inject_period,
            scroll: gpu.scroll.unwrap_or(IVec3::ZERO).extend(0),
        };
        gpu.uniform_offsets.clear();
        gpu.uniform_offsets.push(state.uniforms.push(&uniform));
        for k in 1..=s.extra_bounces {
            uniform.bounce = k;
            uniform.seed = base_seed ^ k.wrapping_mul(0xC2B2_AE35);
            gpu.uniform_offsets.push(state.uniforms.push(&uniform));
        }

        if gpu.update_this_frame {
            // The first extra bounce always runs; the decide pass opens or closes the next ones.
            let mut args = vec![0u32; 3 * (s.extra_bounces.max(1) as usize + 1)];
            args[0] = gpu.workgroups;
            for slot in args.chunks_mut(3) {
                slot[1] = 1;
                slot[2] = 1;
            }
            queue.write_buffer(&gpu.args, 0, bytemuck::cast_slice(&args));
        }

        let mut specialize = |pass| specialized.specialize(&pipeline_cache, &pipelines, RhPipelineKey { pass, sh_order: s.sh_order });
        gpu.pipelines = Some(RhVolumePipelines {
            inject: specialize(RhPass::Inject {
                depth_occlusion: s.depth_occlusion.is_some(),
                voxel_visibility: s.voxel_visibility,
            }),
            bounce: specialize(RhPass::Bounce {
                paper: s.secondary == super::settings::SecondaryTransport::Paper,
            }),
            decide: specialize(RhPass::Decide),
            blend: specialize(RhPass::Blend),
            export: specialize(RhPass::Export),
            visibility: specialize(RhPass::Visibility),
            scroll: specialize(RhPass::Scroll),
        });
        if let Some(region) = gpu.visibility_pending {
            let mut data = encase::UniformBuffer::new(Vec::<u8>::new());
            data.write(&region).expect("the region uniform encodes");
            queue.write_buffer(&gpu.visibility_region, 0, data.as_ref());
        }
        state.volumes.push(gpu);
    }
    state.uniforms.write_buffer(&device, &queue);
    activity.publish(
        state
            .volumes
            .iter()
            .map(|v| {
                let a = super::activity::RhVolumeActivity {
                    updating: v.update_this_frame,
                    amortised: v.motion_update(),
                    updates_left: v.updates_left,
                    frames_reused: v.frames_reused,
                    extra_bounces_run: v.bounce_readback.last(),
                    extra_bounces_max: v.settings.extra_bounces,
                    resolution: v.settings.resolution,
                };
                (v.entity, a)
            })
            .collect(),
    );

    state.reconstruct_pipelines.clear();
    for camera in cameras.iter().filter(|c| c.0.method == GiMethod::RadianceHints) {
        for v in &state.volumes {
            let key = reconstruct_key(v, &camera.0);
            let id = specialized_render.specialize(&pipeline_cache, &pipelines, key);
            state.reconstruct_pipelines.insert(key, id);
        }
    }
}

/// The reconstruction pipeline a camera draws `volume` with.
pub fn reconstruct_key(volume: &RhVolumeGpu, camera: &crate::camera::DiffuseGi) -> RhReconstructKey {
    RhReconstructKey {
        sh_order: volume.settings.sh_order,
        half_resolution: camera.half_resolution,
        hint_grid: camera.debug_view == crate::camera::GiDebugView::HintGrid,
        nested: volume.nested,
        nonlinear_irradiance: volume.settings.irradiance == super::settings::IrradianceReconstruction::NonLinear,
    }
}

pub(crate) fn prepare_rh_bind_groups(
    mut state: ResMut<RhVolumesGpu>,
    pipelines: Res<RhPipelines>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
) {
    let state = &mut *state;
    let Some(uniform) = state.uniforms.binding() else {
        return;
    };
    let layout = |l: &BindGroupLayoutDescriptor| pipeline_cache.get_bind_group_layout(l);
    for v in &mut state.volumes {
        let sample = |source: &Buffer| {
            device.create_bind_group(
                "diffuse_gi_rh_sample_bind_group",
                &layout(&pipelines.sample_layout),
                &BindGroupEntries::sequential((
                    uniform.clone(),
                    source.as_entire_binding(),
                    v.distances.as_entire_binding(),
                    v.albedo.as_entire_binding(),
                )),
            )
        };
        let bounce_output = |out: &Buffer| {
            device.create_bind_group(
                "diffuse_gi_rh_bounce_output_bind_group",
                &layout(&pipelines.bounce_output_layout),
                &BindGroupEntries::sequential((
                    out.as_entire_binding(),
                    v.sum.as_entire_binding(),
                    v.partials.as_entire_binding(),
                )),
            )
        };
        v.bind_groups = Some(RhVolumeBindGroups {
            inject_output: device.create_bind_group(
                "diffuse_gi_rh_inject_output_bind_group",
                &layout(&pipelines.inject_output_layout),
                &BindGroupEntries::sequential((
                    uniform.clone(),
                    v.delta[0].as_entire_binding(),
                    v.sum.as_entire_binding(),
                    v.distances.as_entire_binding(),
                    v.albedo.as_entire_binding(),
                )),
            ),
            occupancy: device.create_bind_group(
                "diffuse_gi_rh_occupancy_bind_group",
                &layout(&pipelines.occupancy_layout),
                &BindGroupEntries::single(v.occupancy.as_entire_binding()),
            ),
            bounce_occupancy: device.create_bind_group(
                "diffuse_gi_rh_bounce_occupancy_bind_group",
                &layout(&pipelines.bounce_occupancy_layout),
                &BindGroupEntries::sequential((v.occupancy.as_entire_binding(), v.visibility.as_entire_binding())),
            ),
            sample_result: sample(&v.result),
            // Bounce k writes delta[k % 2] and reads delta[(k − 1) % 2].
            bounce: [
                (bounce_output(&v.delta[0]), sample(&v.delta[1])),
                (bounce_output(&v.delta[1]), sample(&v.delta[0])),
            ],
            decide: device.create_bind_group(
                "diffuse_gi_rh_decide_bind_group",
                &layout(&pipelines.decide_layout),
                &BindGroupEntries::sequential((
                    uniform.clone(),
                    v.partials.as_entire_binding(),
                    v.args.as_entire_binding(),
                    v.stats.as_entire_binding(),
                )),
            ),
            visibility_output: device.create_bind_group(
                "diffuse_gi_rh_visibility_output_bind_group",
                &layout(&pipelines.visibility_output_layout),
                &BindGroupEntries::sequential((
                    v.visibility_region.as_entire_binding(),
                    v.visibility.as_entire_binding(),
                    // Read only after a scroll; until the first, any buffer this pass only reads.
                    v.visibility_previous.as_ref().unwrap_or(&v.occupancy).as_entire_binding(),
                )),
            ),
            lookup: device.create_bind_group(
                "diffuse_gi_rh_lookup_bind_group",
                &layout(&pipelines.lookup_layout),
                &BindGroupEntries::sequential((
                    v.occupancy.as_entire_binding(),
                    v.visibility.as_entire_binding(),
                    v.packed.as_entire_binding(),
                )),
            ),
            blend: device.create_bind_group(
                "diffuse_gi_rh_blend_bind_group",
                &layout(&pipelines.blend_layout),
                &BindGroupEntries::sequential((
                    uniform.clone(),
                    v.sum.as_entire_binding(),
                    v.result.as_entire_binding(),
                    v.packed.as_entire_binding(),
                    v.delta[0].as_entire_binding(),
                    v.delta[1].as_entire_binding(),
                    v.stats.as_entire_binding(),
                )),
            ),
            scroll: device.create_bind_group(
                "diffuse_gi_rh_scroll_bind_group",
                &layout(&pipelines.scroll_layout),
                &BindGroupEntries::sequential((uniform.clone(), v.delta[0].as_entire_binding(), v.result.as_entire_binding())),
            ),
        });
    }
}

#[cfg(test)]
mod tests {

    fn volume(index: u32, centre: Vec3, size: Vec3, hints: u32) -> super::super::extract::ExtractedRhVolume {
        super::super::extract::ExtractedRhVolume {
            entity: Entity::from_raw_u32(index + 1).expect("valid index"),
            settings: RadianceHintsVolume { resolution: UVec3::splat(hints), ..RadianceHintsVolume::MEDIUM },
            world_from_local: Mat4::from_scale_rotation_translation(size, Quat::IDENTITY, centre),
            voxels: None,
            export: None,
        }
    }

    #[test]
    fn finer_volumes_inside_coarser_ones_fade_in_from_their_inner_faces_only() {
        let room = volume(0, Vec3::ZERO, Vec3::splat(2.0), 4);
        // The left half of the room, finer: its +x face lies inside the room, the other five on its walls.
        let half = volume(1, Vec3::new(-0.5, 0.0, 0.0), Vec3::new(1.0, 2.0, 2.0), 12);
        // A volume beside the room, as fine: not nested.
        let beside = volume(2, Vec3::new(2.5, 0.0, 0.0), Vec3::splat(2.0), 12);
        let flags = nested_volumes(&[room, half, beside]);
        assert_eq!(flags[0], 0, "the coarse room is not nested");
        assert_eq!(flags[1], 1 << 6 | 1 << 1, "only the +x face fades in: {:#b}", flags[1]);
        assert_eq!(flags[2], 0);
    }

    use super::*;

    #[test]
    fn visibility_regions_cover_whole_words_inside_the_grid() {
        let res = UVec3::new(64, 20, 36);
        let all = VisibilityRegion::covering(UVec3::ZERO, res - 1, res);
        assert_eq!((all.origin, all.size), (UVec4::ZERO, UVec4::new(16, 20, 36, 0)));
        assert_eq!(all.words(), res.x * res.y * res.z / 4, "one word per four voxels");
        // A box from voxel 5 to 9 along x takes the words of voxels 4..=11; a box past the grid is cut.
        let part = VisibilityRegion::covering(UVec3::new(5, 2, 3), UVec3::new(9, 40, 3), res);
        assert_eq!(part.origin, UVec4::new(4, 2, 3, 0));
        assert_eq!(part.size, UVec4::new(2, 18, 1, 0));
    }

    #[test]
    fn still_updates_average_and_changes_blend() {
        let s = RadianceHintsVolume::MEDIUM;
        assert_eq!(blend_weight(true, 5, &s), 1.0);
        assert_eq!(blend_weight(false, 0, &s), s.temporal_blend);
        // A running mean of the still updates after a change: weights 1, 1/2, 1/3…
        for k in 1..10u32 {
            assert!((blend_weight(false, k, &s) - 1.0 / k as f32).abs() < 1e-6);
        }
        let no_refinement = RadianceHintsVolume { refinement_updates: 0, ..s };
        assert_eq!(blend_weight(false, 7, &no_refinement), s.temporal_blend);
    }

    #[test]
    fn convergence_needs_fewer_updates_with_a_larger_blend() {
        assert_eq!(convergence_updates(1.0), 1);
        let half = convergence_updates(0.5);
        assert!(0.5f32.powi(half as i32 - 1) <= 0.01 && half <= 9, "{half}");
        assert!(convergence_updates(0.1) > half);
    }
}
