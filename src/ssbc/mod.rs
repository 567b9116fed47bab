//! Screen-space bias compensation (SSBC; Novák, Engelhardt, Dachsbacher, I3D 2011, §3.2–4.3), a refinement
//! of the frame's indirect-light target for methods that clamp their transport.
//!
//! A method asks for it by putting an [`SsbcRequest`] on a view in the render world (the VPL method does,
//! for its clamped gather); this module knows no method. In the view's [`GiViewSystems::Refine`] pass it
//! returns the light that `G_b = min(G, b)` removed:
//!
//! `L = Σ_{i=0}^{N} T_rⁱ (T L_e + T_b L̂)` (Eq. 3, truncated at `N = steps`), with
//! `(T_r L)(y) ≈ Σ_i f_r(y) G_r(y, z_i) L(y ← z_i) A_i` over the visible pixels `z_i` (§4.1),
//! `G_r = max(G − b, 0)`, no visibility (nearby surfaces are rarely occluded).
//!
//! # Data layout
//! Per view, storage buffers at the target's resolution and every mip level below it (down to the
//! `levels` the request allows): two `vec4` per texel of the G-buffer hierarchy (area-weighted position
//! and the summed area; normal and a discontinuity flag), one `vec4` of outgoing radiance per texel and
//! level (the light of the current step), and at level 0 the albedo, the current step's irradiance and
//! the running sum. Storage buffers rather than textures: the hierarchy has odd sizes at each level and
//! every pass reads and writes it the same way.
//!
//! # Passes (`shaders/ssbc/ssbc.wgsl`)
//! `gbuffer_level` and `reduce` build the hierarchy once per frame; per step, `illuminate` and
//! `reduce_light` build the light's hierarchy (step 0: Bevy's direct light from the main texture plus the
//! clamped light; step k: the previous step's result), and `compensate` walks the hierarchy from the
//! level whose cells are half the bounding radius `r = 1/√b` (projected to screen, §4.1), refining cells
//! by projected solid angle and discontinuities (§4.2). `apply` adds the sum, optionally blurred, to the
//! target. Time span: `diffuse_gi/ssbc`.
//!
//! # Known issues
//! * Only what the camera sees is compensated and compensates (§4.3): energy clamped near off-screen or
//!   hidden surfaces is not returned.
//! * The direct light is read from Bevy's main texture, which also holds emission, ambient light and
//!   specular reflection: those are treated as reflected light (correct for diffuse surfaces only).

use bevy::core_pipeline::Core3d;
use bevy::core_pipeline::FullscreenShader;
use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only_sized, storage_buffer_sized, texture_2d, texture_depth_2d, uniform_buffer,
};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::view::{ViewTarget, ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::render::{Render, RenderApp, RenderStartup, RenderSystems};
use bevy::shader::Shader;

use crate::composite::{ExtractedDiffuseGi, GI_TARGET_FORMAT, GiViewSystems, GiViewTarget};

/// The geometry term `G = cos θ_x cos θ_y / d²` between two surface points with unit normals.
pub fn geometry_term(x: Vec3, nx: Vec3, y: Vec3, ny: Vec3) -> f32 {
    let v = y - x;
    let d2 = v.length_squared();
    if d2 <= 0.0 {
        return 0.0;
    }
    let d = d2.sqrt();
    let cx = nx.dot(v) / d;
    let cy = -ny.dot(v) / d;
    if cx <= 0.0 || cy <= 0.0 { 0.0 } else { cx * cy / d2 }
}

/// The bounded geometry term of §3.1, `G_b = min(G, b)`.
pub fn bounded_geometry_term(g: f32, bound: f32) -> f32 {
    g.min(bound)
}

/// The residual geometry term of §3.2, `G_r = max(G − b, 0)`: what clamping removed, so `G_b + G_r = G`.
pub fn residual_geometry_term(g: f32, bound: f32) -> f32 {
    (g - bound).max(0.0)
}

/// The radius of the region around a shading point where `G_r` can be non-zero (§4.1): both cosines at
/// most 1, so `G ≤ 1/d²` and `G > b` needs `d < 1/√b`. In metres, for `b` in 1/m².
pub fn bounding_radius(bound: f32) -> f32 {
    1.0 / bound.max(1e-12).sqrt()
}

/// That radius in screen space (§4.1, `r_s = r / (tan(δ/2) ‖x − y‖)`), in pixels of an image `height`
/// pixels tall with vertical field of view `fov_y` (radians), for a point at view distance `distance`.
pub fn screen_radius_pixels(radius: f32, fov_y: f32, distance: f32, height: u32) -> f32 {
    let ndc = radius / ((0.5 * fov_y).tan() * distance.max(1e-6));
    ndc * 0.5 * height as f32
}

/// What a method asks of SSBC for one view (a render-world component on the view entity).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct SsbcRequest {
    /// Compensation steps (terms of Eq. 3 after the first), 1–3.
    pub steps: u32,
    /// `b` of the method's clamping, 1/m².
    pub bound: f32,
    /// Refinement threshold, steradians (§4.2).
    pub solid_angle: f32,
    /// Refinement threshold at discontinuities, steradians (§4.2).
    pub discontinuity_solid_angle: f32,
    /// Most levels of the hierarchy.
    pub levels: u32,
    /// Blur the compensation before adding it.
    pub blur: bool,
    /// The method's intensity factor (its target holds light × intensity; the direct light does not).
    pub intensity: f32,
    /// Replace the target with the compensation alone (a debug view) instead of adding it.
    pub replace: bool,
}

/// The SSBC uniform (`SsbcUniform` in `shaders/ssbc/ssbc.wgsl`), one per (step, level) dispatch.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct SsbcUniform {
    pub size: UVec2,
    pub scale: u32,
    pub levels: u32,
    pub level: u32,
    pub step: u32,
    pub bound: f32,
    pub radius: f32,
    pub solid_angle: f32,
    pub discontinuity_solid_angle: f32,
    pub intensity: f32,
    pub blur: u32,
}

/// Levels of a hierarchy over `size` texels: halving (rounding up) until 1×1, at most `wanted`.
pub fn hierarchy_levels(size: UVec2, wanted: u32) -> u32 {
    let largest = size.x.max(size.y).max(1);
    (32 - largest.leading_zeros()).min(wanted.max(1))
}

/// Size of level `level` over `size` texels (the shader's `level_size`).
pub fn level_size(size: UVec2, level: u32) -> UVec2 {
    ((size + UVec2::splat((1 << level) - 1)) >> level).max(UVec2::ONE)
}

/// Texels in all `levels` levels.
pub fn hierarchy_texels(size: UVec2, levels: u32) -> u64 {
    (0..levels).map(|l| level_size(size, l)).map(|s| s.x as u64 * s.y as u64).sum()
}

/// The SSBC shader, kept alive by this resource.
#[derive(Resource, Clone)]
pub struct SsbcShader(pub Handle<Shader>);

#[derive(Resource)]
struct SsbcPipelines {
    view_layout: BindGroupLayoutDescriptor,
    data_layout: BindGroupLayoutDescriptor,
    apply_layout: BindGroupLayoutDescriptor,
    gbuffer: CachedComputePipelineId,
    reduce: CachedComputePipelineId,
    illuminate: CachedComputePipelineId,
    reduce_light: CachedComputePipelineId,
    compensate: CachedComputePipelineId,
    /// Adding, and replacing (the compensation-only view).
    apply: [CachedRenderPipelineId; 2],
}

fn init_ssbc_pipelines(world: &mut World) {
    let shader = world.resource::<SsbcShader>().0.clone();
    let fullscreen = world.resource::<FullscreenShader>().to_vertex_state();
    let unfilterable = TextureSampleType::Float { filterable: false };
    let rw = || storage_buffer_sized(false, None);
    let view_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_ssbc_view_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer::<ViewUniform>(true),
                texture_depth_2d(),
                texture_2d(TextureSampleType::Uint),
                texture_2d(unfilterable),
                texture_2d(unfilterable),
            ),
        ),
    );
    let data_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_ssbc_data_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (uniform_buffer::<SsbcUniform>(true), rw(), rw(), rw(), rw(), rw()),
        ),
    );
    let apply_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_ssbc_apply_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (
                uniform_buffer::<SsbcUniform>(true),
                storage_buffer_read_only_sized(false, None),
                storage_buffer_read_only_sized(false, None),
            ),
        ),
    );
    let cache = world.resource::<PipelineCache>();
    let compute = |label: &'static str, entry: &'static str| {
        cache.queue_compute_pipeline(ComputePipelineDescriptor {
            label: Some(label.into()),
            layout: vec![view_layout.clone(), data_layout.clone()],
            shader: shader.clone(),
            shader_defs: crate::shared_shader_defs(),
            entry_point: Some(entry.into()),
            ..default()
        })
    };
    let gbuffer = compute("diffuse_gi_ssbc_gbuffer_pipeline", "gbuffer_level");
    let reduce = compute("diffuse_gi_ssbc_reduce_pipeline", "reduce");
    let illuminate = compute("diffuse_gi_ssbc_illuminate_pipeline", "illuminate");
    let reduce_light = compute("diffuse_gi_ssbc_reduce_light_pipeline", "reduce_light");
    let compensate = compute("diffuse_gi_ssbc_compensate_pipeline", "compensate");
    let apply = |replace: bool| {
        let mut shader_defs = crate::shared_shader_defs();
        shader_defs.push("APPLY".into());
        if replace {
            shader_defs.push("REPLACE".into());
        }
        let add = BlendComponent {
            src_factor: BlendFactor::One,
            dst_factor: BlendFactor::One,
            operation: BlendOperation::Add,
        };
        cache.queue_render_pipeline(RenderPipelineDescriptor {
            label: Some("diffuse_gi_ssbc_apply_pipeline".into()),
            layout: vec![apply_layout.clone()],
            vertex: fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: shader.clone(),
                shader_defs,
                entry_point: Some("apply".into()),
                targets: vec![Some(ColorTargetState {
                    format: GI_TARGET_FORMAT,
                    blend: (!replace).then_some(BlendState { color: add, alpha: add }),
                    write_mask: ColorWrites::ALL,
                })],
            }),
            ..default()
        })
    };
    let apply = [apply(false), apply(true)];
    world.insert_resource(SsbcPipelines {
        view_layout,
        data_layout,
        apply_layout,
        gbuffer,
        reduce,
        illuminate,
        reduce_light,
        compensate,
        apply,
    });
}

/// One view's SSBC buffers and its uniform offsets.
struct SsbcView {
    size: UVec2,
    levels: u32,
    geo: Buffer,
    albedo: Buffer,
    light: Buffer,
    step_result: Buffer,
    total: Buffer,
    /// `offsets[step][level]`.
    offsets: Vec<Vec<u32>>,
}

#[derive(Resource, Default)]
struct SsbcState {
    views: HashMap<Entity, SsbcView>,
    uniforms: DynamicUniformBuffer<SsbcUniform>,
}

fn prepare_ssbc(
    views: Query<(Entity, &ExtractedDiffuseGi, &SsbcRequest, &GiViewTarget)>,
    mut state: ResMut<SsbcState>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let state = &mut *state;
    state.uniforms.clear();
    let mut previous = std::mem::take(&mut state.views);
    for (entity, gi, request, target) in &views {
        let size = target.texture.texture.size();
        let size = UVec2::new(size.width, size.height);
        let levels = hierarchy_levels(size, request.levels);
        let mut view = match previous.remove(&entity) {
            Some(v) if v.size == size && v.levels == levels => v,
            _ => {
                let texels = hierarchy_texels(size, levels);
                let base = size.x as u64 * size.y as u64;
                let buffer = |label: &'static str, vec4s: u64| {
                    device.create_buffer(&BufferDescriptor {
                        label: Some(label),
                        size: (vec4s * 16).max(16),
                        usage: BufferUsages::STORAGE,
                        mapped_at_creation: false,
                    })
                };
                SsbcView {
                    size,
                    levels,
                    geo: buffer("diffuse_gi_ssbc_geometry", 2 * texels),
                    albedo: buffer("diffuse_gi_ssbc_albedo", base),
                    light: buffer("diffuse_gi_ssbc_light", texels),
                    step_result: buffer("diffuse_gi_ssbc_step", base),
                    total: buffer("diffuse_gi_ssbc_total", base),
                    offsets: Vec::new(),
                }
            }
        };
        view.offsets.clear();
        for step in 0..request.steps.max(1) {
            let mut row = Vec::new();
            for level in 0..levels {
                row.push(state.uniforms.push(&SsbcUniform {
                    size,
                    scale: gi.scale(),
                    levels,
                    level,
                    step,
                    bound: request.bound,
                    radius: bounding_radius(request.bound),
                    solid_angle: request.solid_angle,
                    discontinuity_solid_angle: request.discontinuity_solid_angle,
                    intensity: request.intensity,
                    blur: request.blur as u32,
                }));
            }
            view.offsets.push(row);
        }
        state.views.insert(entity, view);
    }
    state.uniforms.write_buffer(&device, &queue);
}

/// The compensation of one view, after its opaque pass.
fn ssbc(
    view: ViewQuery<(
        Entity,
        &SsbcRequest,
        &ViewTarget,
        &ViewUniformOffset,
        &ViewPrepassTextures,
        &GiViewTarget,
    ), With<ExtractedDiffuseGi>>,
    state: Res<SsbcState>,
    pipelines: Res<SsbcPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    mut ctx: RenderContext,
) {
    let (entity, request, view_target, view_offset, prepass, target) = view.into_inner();
    let ids = [pipelines.gbuffer, pipelines.reduce, pipelines.illuminate, pipelines.reduce_light, pipelines.compensate];
    let compute: Vec<_> = ids.iter().filter_map(|id| pipeline_cache.get_compute_pipeline(*id)).collect();
    let apply_id = pipelines.apply[request.replace as usize];
    let (Some(data), [gbuffer, reduce, illuminate, reduce_light, compensate], Some(apply), Some(uniforms), Some(ssbc_uniforms), Some(depth), Some(g)) = (
        state.views.get(&entity),
        compute.as_slice(),
        pipeline_cache.get_render_pipeline(apply_id),
        view_uniforms.uniforms.binding(),
        state.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
    ) else {
        return;
    };
    let device = ctx.render_device().clone();
    let view_group = device.create_bind_group(
        "diffuse_gi_ssbc_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, g, &target.texture.default_view, view_target.main_texture_view())),
    );
    let data_group = device.create_bind_group(
        "diffuse_gi_ssbc_data_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.data_layout),
        &BindGroupEntries::sequential((
            ssbc_uniforms.clone(),
            data.geo.as_entire_binding(),
            data.albedo.as_entire_binding(),
            data.light.as_entire_binding(),
            data.step_result.as_entire_binding(),
            data.total.as_entire_binding(),
        )),
    );
    let apply_group = device.create_bind_group(
        "diffuse_gi_ssbc_apply_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.apply_layout),
        &BindGroupEntries::sequential((ssbc_uniforms, data.geo.as_entire_binding(), data.total.as_entire_binding())),
    );
    let groups = |size: UVec2| (size.x.div_ceil(8), size.y.div_ceil(8));
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    {
        let mut pass = ctx.command_encoder().begin_compute_pass(&ComputePassDescriptor {
            label: Some("diffuse_gi_ssbc"),
            timestamp_writes: None,
        });
        let span = diagnostics.pass_span(&mut pass, "diffuse_gi/ssbc");
        let mut dispatch = |pipeline: &ComputePipeline, offset: u32, level: u32| {
            let (x, y) = groups(level_size(data.size, level));
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &view_group, &[view_offset.offset]);
            pass.set_bind_group(1, &data_group, &[offset]);
            pass.dispatch_workgroups(x, y, 1);
        };
        dispatch(gbuffer, data.offsets[0][0], 0);
        for level in 1..data.levels {
            dispatch(reduce, data.offsets[0][level as usize], level);
        }
        for row in &data.offsets {
            dispatch(illuminate, row[0], 0);
            for level in 1..data.levels {
                dispatch(reduce_light, row[level as usize], level);
            }
            dispatch(compensate, row[0], 0);
        }
        span.end(&mut pass);
    }
    let mut pass = crate::composite::begin_target_pass(&mut ctx, "diffuse_gi_ssbc_apply", &target.texture.default_view);
    pass.set_render_pipeline(apply);
    pass.set_bind_group(0, &apply_group, &[data.offsets[0][0]]);
    pass.draw(0..3, 0..1);
}

/// Registers the SSBC pass. Added by [`crate::DiffuseGiPlugin`].
pub struct SsbcPlugin;

impl Plugin for SsbcPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "ssbc/ssbc.wgsl", include_str!("../../shaders/ssbc/ssbc.wgsl"));
        let Some(render_app) = app.get_sub_app_mut(RenderApp) else {
            return;
        };
        render_app
            .insert_resource(SsbcShader(shader))
            .init_resource::<SsbcState>()
            .add_systems(RenderStartup, init_ssbc_pipelines)
            .add_systems(
                Render,
                prepare_ssbc
                    .in_set(RenderSystems::PrepareResources)
                    .after(crate::composite::prepare_composite),
            )
            .add_systems(Core3d, ssbc.in_set(GiViewSystems::Refine));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `a ≈ b` within `rel` of `b`'s magnitude (plus a tiny absolute floor).
    fn close(a: f32, b: f32, rel: f32) -> bool {
        (a - b).abs() <= rel * b.abs().max(1e-12) + 1e-9
    }

    #[test]
    fn bounded_and_residual_geometry_terms_add_up_to_the_full_term() {
        let mut state = 0x1234_5678u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32
        };
        for _ in 0..1000 {
            let x = Vec3::new(next(), next(), next()) * 4.0 - 2.0;
            let y = Vec3::new(next(), next(), next()) * 4.0 - 2.0;
            let nx = (Vec3::new(next(), next(), next()) - 0.5).normalize_or(Vec3::Y);
            let ny = (Vec3::new(next(), next(), next()) - 0.5).normalize_or(Vec3::Y);
            let g = geometry_term(x, nx, y, ny);
            let b = 10f32.powf(next() * 4.0 - 2.0);
            let (gb, gr) = (bounded_geometry_term(g, b), residual_geometry_term(g, b));
            assert!(gb >= 0.0 && gr >= 0.0 && gb <= b, "{g} {b} {gb} {gr}");
            assert!(close(gb + gr, g, 1e-6), "G_b + G_r = {} ≠ G = {g} (b = {b})", gb + gr);
        }
        // Facing unit patches 0.1 m apart: G = 100 m⁻²; with b = 25, G_b = 25 and G_r = 75.
        let g = geometry_term(Vec3::ZERO, Vec3::Z, Vec3::new(0.0, 0.0, 0.1), Vec3::NEG_Z);
        assert!(close(g, 100.0, 1e-5));
        assert_eq!((bounded_geometry_term(g, 25.0), residual_geometry_term(g, 25.0).round()), (25.0, 75.0));
    }

    #[test]
    fn the_residual_vanishes_beyond_the_bounding_radius_and_its_screen_size_follows_the_paper() {
        let b = 4.0;
        let r = bounding_radius(b);
        assert!(close(r, 0.5, 1e-6));
        // The largest G at distance d (both cosines 1) is 1/d²: zero residual just beyond r, positive inside.
        for d in [0.51f32, 0.6, 2.0] {
            assert_eq!(residual_geometry_term(geometry_term(Vec3::ZERO, Vec3::Z, Vec3::Z * d, Vec3::NEG_Z), b), 0.0);
        }
        assert!(residual_geometry_term(geometry_term(Vec3::ZERO, Vec3::Z, Vec3::Z * 0.49, Vec3::NEG_Z), b) > 0.0);
        // r_s = r / (tan(δ/2) · ‖x − y‖) in NDC; with δ = 90° at 2 m, r = 0.5 m is a quarter of the half
        // screen: 64 px of a 512 px tall image.
        let px = screen_radius_pixels(0.5, std::f32::consts::FRAC_PI_2, 2.0, 512);
        assert!(close(px, 64.0, 1e-5), "{px}");
        // Twice as far: half the pixels.
        assert!(close(screen_radius_pixels(0.5, std::f32::consts::FRAC_PI_2, 4.0, 512), 32.0, 1e-5));
    }


    #[test]
    fn the_hierarchy_halves_each_level_rounding_up() {
        let size = UVec2::new(256, 100);
        assert_eq!(hierarchy_levels(size, 20), 9);
        assert_eq!(hierarchy_levels(size, 6), 6);
        assert_eq!(level_size(size, 1), UVec2::new(128, 50));
        assert_eq!(level_size(size, 3), UVec2::new(32, 13));
        assert_eq!(level_size(size, 8), UVec2::new(1, 1));
        assert_eq!(hierarchy_texels(UVec2::new(4, 4), 3), 16 + 4 + 1);
    }
}
