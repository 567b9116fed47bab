//! The GI frame: what every method shares, and knows no method.
//!
//! * **Cameras**: [`ExtractedDiffuseGi`] is the render-world copy of a camera's
//!   [`DiffuseGi`](crate::camera::DiffuseGi), present while the camera is active and GI is on.
//! * **The per-view indirect-light target** ([`GiViewTarget`], `Rgba16Float`, full or half resolution):
//!   the camera's method writes `Σ w·E/π` (rgb) and `Σ w` (a) into it during [`GiViewSystems::Produce`]
//!   (after the prepass, before the main pass; the target is cleared first, so a method switched off
//!   leaves nothing behind) and may refine it during [`GiViewSystems::Refine`] (after the opaque pass,
//!   which some refinements read, e.g. screen-space bias compensation).
//! * **The composite**: multiplies by the G-buffer albedo and the exposure and adds the result with
//!   `One + One` blending, between `main_opaque_pass_3d` and `main_transparent_pass_3d` (so transparent
//!   surfaces are drawn over lit opaque ones, not lit themselves). The same depth- and normal-aware filter
//!   upsamples a half-resolution target for every method. Debug views ([`GiDebugView`]) replace the image;
//!   they read the target (or the reflective shadow maps, a shared input) and nothing of any method.
//!
//! Methods import this module's public types; this module imports no method.

use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::core_pipeline::FullscreenShader;
use bevy::core_pipeline::core_3d::{main_opaque_pass_3d, main_transparent_pass_3d};
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::binding_types::{texture_2d, texture_2d_array, texture_depth_2d, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::render_phase::TrackedRenderPass;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::texture::{CachedTexture, TextureCache};
use bevy::render::view::{ViewTarget, ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::shader::{Shader, ShaderDefVal};

use bevy::render::Extract;
use bevy::render::sync_world::RenderEntity;

use crate::camera::{DiffuseGi, GiDebugView, GiOutput, TargetDisplay};
use crate::rsm::RsmAtlas;

/// Format of the per-camera indirect-light target.
pub const GI_TARGET_FORMAT: TextureFormat = TextureFormat::Rgba16Float;

/// The camera's [`DiffuseGi`] in the render world (present only while the camera is active and GI is on).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ExtractedDiffuseGi(pub DiffuseGi);

impl ExtractedDiffuseGi {
    /// Pixels per target texel along each axis: 1 at full resolution, 2 at half.
    pub fn scale(&self) -> u32 {
        if self.0.half_resolution { 2 } else { 1 }
    }
}

/// The camera's indirect-light target for this frame: `Σ w·E/π` (rgb) and `Σ w` (a).
#[derive(Component)]
pub struct GiViewTarget {
    pub texture: CachedTexture,
    /// Pixels per texel along each axis (1 or 2).
    pub scale: u32,
    /// At reduced resolution: the target after the frame's bilateral filter at its own resolution
    /// (`filter.wgsl`), which the composite upsamples, and the filter's pipeline.
    pub filtered: Option<(CachedTexture, CachedRenderPipelineId)>,
}

/// Where a method's per-view passes go in `Core3d`.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GiViewSystems {
    /// After the prepass (depth and G-buffer are ready), before the main pass: write the target.
    Produce,
    /// After the opaque pass (the direct light is in the view's main texture), before the composite.
    Refine,
}

/// What the RSM debug views show: the first GI light's faces.
#[derive(ShaderType, Clone, Copy, Default)]
struct RsmDebugUniform {
    first_layer: u32,
    faces: u32,
    resolution: u32,
    flux_display_scale: f32,
}

/// Key of the composite pipelines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CompositeKey {
    pub format: TextureFormat,
    pub display: TargetDisplay,
    pub half_resolution: bool,
}

/// The composite shader's `DISPLAY` value for a display mode.
fn display_index(display: TargetDisplay) -> u32 {
    match display {
        TargetDisplay::Lit => 0,
        TargetDisplay::Indirect => 1,
        TargetDisplay::Irradiance => 2,
        TargetDisplay::RawIrradiance => 3,
        TargetDisplay::Rsm(k) => 4 + k.min(2),
    }
}

/// The composite pipelines and their layouts.
#[derive(Resource)]
pub struct CompositePipelines {
    view_layout: BindGroupLayoutDescriptor,
    rsm_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
    fullscreen: VertexState,
    rsm_debug: UniformBuffer<RsmDebugUniform>,
}

/// The composite shader, the `gi_frame` import library the methods' passes use and the reduced-resolution
/// filter, kept alive by this resource.
#[derive(Resource, Clone)]
pub struct CompositeShader(pub Handle<Shader>, pub Handle<Shader>, pub Handle<Shader>);

impl FromWorld for CompositePipelines {
    fn from_world(world: &mut World) -> Self {
        let unfilterable = TextureSampleType::Float { filterable: false };
        Self {
            view_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_composite_view_layout",
                &BindGroupLayoutEntries::sequential(
                    ShaderStages::FRAGMENT,
                    (
                        uniform_buffer::<ViewUniform>(true),
                        texture_depth_2d(),
                        texture_2d(TextureSampleType::Uint),
                        texture_2d(unfilterable),
                    ),
                ),
            ),
            rsm_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_composite_rsm_layout",
                &BindGroupLayoutEntries::sequential(
                    ShaderStages::FRAGMENT,
                    (
                        texture_2d_array(unfilterable),
                        texture_2d_array(unfilterable),
                        texture_2d_array(unfilterable),
                        uniform_buffer::<RsmDebugUniform>(false),
                    ),
                ),
            ),
            shader: world.resource::<CompositeShader>().0.clone(),
            fullscreen: world.resource::<FullscreenShader>().to_vertex_state(),
            rsm_debug: UniformBuffer::default(),
        }
    }
}

impl SpecializedRenderPipeline for CompositePipelines {
    type Key = CompositeKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let mut layout = vec![self.view_layout.clone()];
        if matches!(key.display, TargetDisplay::Rsm(_)) {
            layout.push(self.rsm_layout.clone());
        }
        let blend = (key.display == TargetDisplay::Lit).then_some(BlendState {
            color: BlendComponent {
                src_factor: BlendFactor::One,
                dst_factor: BlendFactor::One,
                operation: BlendOperation::Add,
            },
            alpha: BlendComponent {
                src_factor: BlendFactor::Zero,
                dst_factor: BlendFactor::One,
                operation: BlendOperation::Add,
            },
        });
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_composite_pipeline".into()),
            layout,
            vertex: self.fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: self.shader.clone(),
                shader_defs: vec![
                    ShaderDefVal::UInt("DISPLAY".into(), display_index(key.display)),
                    ShaderDefVal::Int("GI_SCALE".into(), if key.half_resolution { 2 } else { 1 }),
                ],
                entry_point: Some("composite".into()),
                targets: vec![Some(ColorTargetState {
                    format: key.format,
                    blend,
                    write_mask: ColorWrites::ALL,
                })],
            }),
            ..default()
        }
    }
}

/// Key of the reduced-resolution filter: pixels per target texel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FilterKey(pub u32);

/// The filter of a reduced-resolution target ([`GiViewTarget::filtered`]), with the composite's layout.
#[derive(Resource)]
pub struct FilterPipelines {
    view_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
    fullscreen: VertexState,
}

impl SpecializedRenderPipeline for FilterPipelines {
    type Key = FilterKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_filter_pipeline".into()),
            layout: vec![self.view_layout.clone()],
            vertex: self.fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: self.shader.clone(),
                shader_defs: vec![ShaderDefVal::Int("GI_SCALE".into(), key.0 as i32)],
                entry_point: Some("filter_target".into()),
                targets: vec![Some(ColorTargetState { format: GI_TARGET_FORMAT, blend: None, write_mask: ColorWrites::ALL })],
            }),
            ..default()
        }
    }
}

/// The composite pipeline of a camera this frame.
#[derive(Component)]
pub struct CompositePipelineId(pub CachedRenderPipelineId);

/// Allocates GI targets and specialises the composite pipeline of every GI camera.
#[expect(clippy::too_many_arguments, reason = "per-view preparation")]
pub(crate) fn prepare_composite(
    mut commands: Commands,
    views: Query<(Entity, &ExtractedCamera, &ExtractedDiffuseGi, &ViewTarget)>,
    mut texture_cache: ResMut<TextureCache>,
    mut pipelines: ResMut<CompositePipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<CompositePipelines>>,
    filters: Res<FilterPipelines>,
    mut specialized_filters: ResMut<SpecializedRenderPipelines<FilterPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    atlas: Res<RsmAtlas>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    for (entity, camera, gi, target) in &views {
        let Some(size) = camera.physical_viewport_size else {
            continue;
        };
        let scale = gi.scale();
        let mut make_target = |label| {
            texture_cache.get(
                &device,
                TextureDescriptor {
                    label: Some(label),
                    size: Extent3d {
                        width: size.x.div_ceil(scale).max(1),
                        height: size.y.div_ceil(scale).max(1),
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: TextureDimension::D2,
                    format: GI_TARGET_FORMAT,
                    usage: TextureUsages::RENDER_ATTACHMENT | TextureUsages::TEXTURE_BINDING,
                    view_formats: &[],
                },
            )
        };
        let texture = make_target("diffuse_gi_target");
        let filtered = (scale > 1).then(|| {
            (make_target("diffuse_gi_filtered_target"), specialized_filters.specialize(&pipeline_cache, &filters, FilterKey(scale)))
        });
        let key = CompositeKey {
            format: target.main_texture_format(),
            display: gi.0.debug_view.display(),
            half_resolution: gi.0.half_resolution,
        };
        let id = specialized.specialize(&pipeline_cache, &pipelines, key);
        commands.entity(entity).insert((GiViewTarget { texture, scale, filtered }, CompositePipelineId(id)));
    }
    let first = atlas.slots.first();
    pipelines.rsm_debug.set(RsmDebugUniform {
        first_layer: first.map_or(0, |s| s.first_layer),
        faces: first.map_or(1, |s| s.faces),
        resolution: first.map_or(1, |s| s.resolution),
        flux_display_scale: 1.0,
    });
    pipelines.rsm_debug.write_buffer(&device, &queue);
}

/// Adds the indirect light (or draws the debug view) into the camera's main texture.
pub(crate) fn composite_gi(
    view: ViewQuery<(
        &ExtractedDiffuseGi,
        &ViewTarget,
        &ViewUniformOffset,
        &ViewPrepassTextures,
        &GiViewTarget,
        &CompositePipelineId,
    )>,
    pipelines: Res<CompositePipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    atlas: Res<RsmAtlas>,
    mut ctx: RenderContext,
) {
    let (gi, target, view_offset, prepass, gi_target, pipeline_id) = view.into_inner();
    let debug_view = gi.0.debug_view;
    if gi.0.effective_output() == GiOutput::IrradianceVolume && debug_view == GiDebugView::None {
        // StandardMaterial applies the exported IrradianceVolume itself.
        return;
    }
    let (Some(pipeline), Some(uniforms), Some(depth), Some(gbuffer)) = (
        pipeline_cache.get_render_pipeline(pipeline_id.0),
        view_uniforms.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
    ) else {
        return;
    };
    let device = ctx.render_device().clone();
    // The filtered target at reduced resolution; the raw one for the texel-by-texel view.
    let source = match &gi_target.filtered {
        Some((filtered, _)) if debug_view.display() != TargetDisplay::RawIrradiance => &filtered.default_view,
        _ => &gi_target.texture.default_view,
    };
    let view_group = device.create_bind_group(
        "diffuse_gi_composite_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer, source)),
    );
    let rsm_group = match debug_view.display() {
        TargetDisplay::Rsm(_) => {
            let Some(debug) = pipelines.rsm_debug.binding() else {
                return;
            };
            Some(device.create_bind_group(
                "diffuse_gi_composite_rsm_bind_group",
                &pipeline_cache.get_bind_group_layout(&pipelines.rsm_layout),
                &BindGroupEntries::sequential((&atlas.position_view, &atlas.normal_view, &atlas.flux_view, debug)),
            ))
        }
        _ => None,
    };

    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let span = diagnostics.time_span(ctx.command_encoder(), "diffuse_gi/composite");
    {
        let mut pass = begin_target_pass(&mut ctx, "diffuse_gi_composite", target.main_texture_view());
        pass.set_render_pipeline(pipeline);
        pass.set_bind_group(0, &view_group, &[view_offset.offset]);
        if let Some(group) = &rsm_group {
            pass.set_bind_group(1, group, &[]);
        }
        pass.draw(0..3, 0..1);
    }
    span.end(ctx.command_encoder());
}

/// Filters a reduced-resolution target at its own resolution into [`GiViewTarget::filtered`] (after the
/// method has written and refined it, before the composite upsamples it).
pub(crate) fn filter_gi_target(
    view: ViewQuery<(&ExtractedDiffuseGi, &ViewUniformOffset, &ViewPrepassTextures, &GiViewTarget)>,
    pipelines: Res<FilterPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    mut ctx: RenderContext,
) {
    let (gi, view_offset, prepass, gi_target) = view.into_inner();
    if gi.0.effective_output() == GiOutput::IrradianceVolume && gi.0.debug_view == GiDebugView::None {
        return;
    }
    let Some((filtered, pipeline_id)) = &gi_target.filtered else {
        return;
    };
    let (Some(pipeline), Some(uniforms), Some(depth), Some(gbuffer)) = (
        pipeline_cache.get_render_pipeline(*pipeline_id),
        view_uniforms.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
    ) else {
        return;
    };
    let group = ctx.render_device().create_bind_group(
        "diffuse_gi_filter_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer, &gi_target.texture.default_view)),
    );
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let span = diagnostics.time_span(ctx.command_encoder(), "diffuse_gi/filter");
    {
        // The fullscreen triangle writes every texel (no discard), so nothing needs clearing first.
        let mut pass = begin_target_pass(&mut ctx, "diffuse_gi_filter", &filtered.default_view);
        pass.set_render_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[view_offset.offset]);
        pass.draw(0..3, 0..1);
    }
    span.end(ctx.command_encoder());
}

/// Begins a render pass that draws into `view` over what it holds (`LoadOp::Load`), with no depth: how
/// the methods write the frame's target and how the composite adds to the main texture.
pub fn begin_target_pass<'a>(ctx: &'a mut RenderContext, label: &'static str, view: &TextureView) -> TrackedRenderPass<'a> {
    ctx.begin_tracked_render_pass(RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: Operations {
                load: LoadOp::Load,
                store: StoreOp::Store,
            },
        })],
        depth_stencil_attachment: None,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// What a camera's view offers a method's per-view pass: the query every pass that writes the frame's
/// target runs on.
#[derive(bevy::ecs::query::QueryData)]
pub struct GiView {
    pub entity: Entity,
    pub gi: &'static ExtractedDiffuseGi,
    pub view_offset: &'static ViewUniformOffset,
    pub prepass: &'static ViewPrepassTextures,
    pub target: &'static GiViewTarget,
}

/// The render-world resources every per-view pass reads: pipelines, the view uniforms and the
/// methods' status (a pass that drew says so).
#[derive(bevy::ecs::system::SystemParam)]
pub struct GiViewPassParams<'w> {
    pub pipeline_cache: Res<'w, PipelineCache>,
    pub view_uniforms: Res<'w, ViewUniforms>,
    pub status: Res<'w, crate::method::GiMethodStatus>,
}

/// Registers the render-world side every per-view method shares: its GPU state `G`, the cache of its
/// specialised view pipelines `P` (made at `RenderStartup` by `init`), its per-frame preparation (in
/// `PrepareResources`) and its per-view pass (in [`GiViewSystems::Produce`], after the target is
/// cleared).
pub fn add_view_method<G, P, M1, M2, M3>(
    render_app: &mut bevy::app::SubApp,
    init: impl IntoScheduleConfigs<bevy::ecs::system::ScheduleSystem, M1>,
    prepare: impl IntoScheduleConfigs<bevy::ecs::system::ScheduleSystem, M2>,
    pass: impl IntoScheduleConfigs<bevy::ecs::system::ScheduleSystem, M3>,
) where
    G: Resource + Default,
    P: SpecializedRenderPipeline + Resource,
    P::Key: Send + Sync,
{
    render_app
        .init_resource::<G>()
        .init_resource::<SpecializedRenderPipelines<P>>()
        .add_systems(bevy::render::RenderStartup, init)
        .add_systems(bevy::render::Render, prepare.in_set(bevy::render::RenderSystems::PrepareResources))
        .add_systems(bevy::core_pipeline::Core3d, pass.in_set(GiViewSystems::Produce).after(clear_gi_target));
}

/// A method's view pipelines by resolution (full, half), specialised the first frame a view of the
/// method needs one: for the methods whose per-view pipeline varies by nothing else.
#[derive(Default)]
pub struct PipelinesByResolution([Option<CachedRenderPipelineId>; 2]);

impl PipelinesByResolution {
    /// Specialises the pipelines the views using `method` need. Returns whether any view uses it.
    pub fn specialize_for<P: SpecializedRenderPipeline<Key = bool>>(
        &mut self,
        views: &Query<&ExtractedDiffuseGi>,
        method: crate::camera::GiMethod,
        specialized: &mut SpecializedRenderPipelines<P>,
        pipeline_cache: &PipelineCache,
        pipelines: &P,
    ) -> bool {
        let mut used = false;
        for gi in views.iter().filter(|gi| gi.0.method == method) {
            used = true;
            let half = gi.0.half_resolution;
            if self.0[half as usize].is_none() {
                self.0[half as usize] = Some(specialized.specialize(pipeline_cache, pipelines, half));
            }
        }
        used
    }

    /// The pipeline of a view at full or half resolution, once specialised.
    pub fn get(&self, half_resolution: bool) -> Option<CachedRenderPipelineId> {
        self.0[half_resolution as usize]
    }
}

/// What every method's per-view pass shares, written once: the view's bind group (group 0: the view
/// uniform, the prepass depth and the deferred G-buffer), the fullscreen triangle, the pipeline that
/// writes the frame's target at the view's resolution, and the draw itself.
#[derive(Clone)]
pub struct GiViewPass {
    pub view_layout: BindGroupLayoutDescriptor,
    fullscreen: VertexState,
}

impl GiViewPass {
    /// Built at `RenderStartup` (needs Bevy's [`FullscreenShader`]).
    pub fn from_world(world: &World) -> Self {
        Self {
            view_layout: BindGroupLayoutDescriptor::new(
                "diffuse_gi_view_layout",
                &BindGroupLayoutEntries::sequential(
                    ShaderStages::VERTEX_FRAGMENT,
                    (uniform_buffer::<ViewUniform>(true), texture_depth_2d(), texture_2d(TextureSampleType::Uint)),
                ),
            ),
            fullscreen: world.resource::<FullscreenShader>().to_vertex_state(),
        }
    }

    /// A fullscreen pipeline writing the target with `shader`'s fragment `entry`: the view's group, then
    /// `layouts`; the crate's shared shader defs, `GI_SCALE` (1, or 2 at half resolution) and `defs`.
    /// `blend: None` replaces the target (the camera's one method); volumes that add up pass a blend.
    #[expect(clippy::too_many_arguments, reason = "what differs between the methods' view pipelines, named")]
    pub fn pipeline(
        &self,
        label: &'static str,
        shader: &Handle<Shader>,
        entry: &'static str,
        half_resolution: bool,
        layouts: &[&BindGroupLayoutDescriptor],
        defs: Vec<ShaderDefVal>,
        blend: Option<BlendState>,
    ) -> RenderPipelineDescriptor {
        let mut shader_defs = crate::shared_shader_defs();
        shader_defs.push(ShaderDefVal::Int("GI_SCALE".into(), if half_resolution { 2 } else { 1 }));
        shader_defs.extend(defs);
        let mut layout = vec![self.view_layout.clone()];
        layout.extend(layouts.iter().map(|l| (*l).clone()));
        RenderPipelineDescriptor {
            label: Some(label.into()),
            layout,
            vertex: self.fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: shader.clone(),
                shader_defs,
                entry_point: Some(entry.into()),
                targets: vec![Some(ColorTargetState { format: GI_TARGET_FORMAT, blend, write_mask: ColorWrites::ALL })],
            }),
            ..default()
        }
    }

    /// Draws `vertices` with `pipeline` into the view's target inside the GPU time span `span`: the
    /// view's group first, then `groups`; records that `method` drew. Draws nothing (and returns false)
    /// while the view's uniforms or prepass textures are not there yet.
    #[expect(clippy::too_many_arguments, reason = "one draw, named once for every method")]
    pub fn draw(
        &self,
        ctx: &mut RenderContext,
        params: &GiViewPassParams,
        view: &GiViewItem,
        method: crate::camera::GiMethod,
        (span, label): (&'static str, &'static str),
        pipeline: &RenderPipeline,
        groups: &[(&BindGroup, &[u32])],
        vertices: std::ops::Range<u32>,
    ) -> bool {
        let Some(view_group) = self.view_group(ctx.render_device(), params, view) else {
            return false;
        };
        let offsets = [view.view_offset.offset];
        let mut all = vec![(&view_group, &offsets[..])];
        all.extend_from_slice(groups);
        draw_vertices_into_target(ctx, span, label, view.target, pipeline, &all, vertices);
        params.status.drew(method);
        true
    }

    /// The view's bind group (group 0 of every view pipeline), bound with the view's uniform offset;
    /// `None` while the view's uniforms or prepass textures are not there yet.
    pub fn view_group(&self, device: &RenderDevice, params: &GiViewPassParams, view: &GiViewItem) -> Option<BindGroup> {
        let (Some(uniforms), Some(depth), Some(gbuffer)) =
            (params.view_uniforms.uniforms.binding(), view.prepass.depth_view(), view.prepass.deferred_view())
        else {
            return None;
        };
        Some(device.create_bind_group(
            "diffuse_gi_view_bind_group",
            &params.pipeline_cache.get_bind_group_layout(&self.view_layout),
            &BindGroupEntries::sequential((uniforms, depth, gbuffer)),
        ))
    }
}

/// Draws `vertices` non-indexed vertices with `pipeline` into the camera's indirect-light target,
/// inside the GPU time span `span`, `groups` bound in order (3 for a fullscreen triangle; a method that
/// draws a mesh pulls its vertices from storage buffers). [`GiViewPass::draw`] is how methods call it.
fn draw_vertices_into_target(
    ctx: &mut RenderContext,
    span: &'static str,
    label: &'static str,
    target: &GiViewTarget,
    pipeline: &RenderPipeline,
    groups: &[(&BindGroup, &[u32])],
    vertices: std::ops::Range<u32>,
) {
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let time = diagnostics.time_span(ctx.command_encoder(), span);
    {
        let mut pass = begin_target_pass(ctx, label, &target.texture.default_view);
        pass.set_render_pipeline(pipeline);
        for (index, (group, offsets)) in groups.iter().enumerate() {
            pass.set_bind_group(index, group, offsets);
        }
        pass.draw(vertices, 0..1);
    }
    time.end(ctx.command_encoder());
}

/// Clears the camera's indirect-light target before its method writes it, so that a method switched
/// off (or one whose pipelines are still compiling) leaves no stale light. Methods order their
/// [`GiViewSystems::Produce`] passes `.after(clear_gi_target)` and draw with `LoadOp::Load`.
pub fn clear_gi_target(view: ViewQuery<&GiViewTarget, With<ExtractedDiffuseGi>>, mut ctx: RenderContext) {
    let target = view.into_inner();
    let pass = ctx.command_encoder().begin_render_pass(&RenderPassDescriptor {
        label: Some("diffuse_gi_clear_target"),
        color_attachments: &[Some(RenderPassColorAttachment {
            view: &target.texture.default_view,
            depth_slice: None,
            resolve_target: None,
            ops: Operations {
                load: LoadOp::Clear(default()),
                store: StoreOp::Store,
            },
        })],
        depth_stencil_attachment: None,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    drop(pass);
}

/// Copies each camera's [`DiffuseGi`] into the render world (removing it from cameras that lost it or
/// turned it off).
pub(crate) fn extract_cameras(
    mut commands: Commands,
    cameras: Extract<Query<(RenderEntity, &Camera, &DiffuseGi)>>,
    without: Extract<Query<RenderEntity, (With<Camera>, Without<DiffuseGi>)>>,
) {
    for entity in &without {
        if let Ok(mut entity) = commands.get_entity(entity) {
            entity.remove::<(ExtractedDiffuseGi, GiViewTarget)>();
        }
    }
    for (entity, camera, gi) in &cameras {
        let Ok(mut entity) = commands.get_entity(entity) else {
            continue;
        };
        if camera.is_active && gi.enabled {
            entity.insert(ExtractedDiffuseGi(gi.clone()));
        } else {
            entity.remove::<(ExtractedDiffuseGi, GiViewTarget)>();
        }
    }
}

/// The GI frame: camera extraction, the per-view target, the composite and the frame's debug views.
/// Added by [`crate::DiffuseGiPlugin`].
pub struct CompositePlugin;

impl Plugin for CompositePlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(
            app,
            "composite/composite.wgsl",
            include_str!("../../shaders/composite/composite.wgsl"),
        );
        let library = crate::add_shader(app, "composite/gi_frame.wgsl", include_str!("../../shaders/composite/gi_frame.wgsl"));
        let filter = crate::add_shader(app, "composite/filter.wgsl", include_str!("../../shaders/composite/filter.wgsl"));
        app.add_systems(PostUpdate, crate::camera::warn_unsupported_output);
        let Some(render_app) = app.get_sub_app_mut(RenderApp) else {
            return;
        };
        render_app
            .insert_resource(CompositeShader(shader, library, filter))
            .init_resource::<SpecializedRenderPipelines<CompositePipelines>>()
            .init_resource::<SpecializedRenderPipelines<FilterPipelines>>()
            .add_systems(RenderStartup, init_composite_pipelines)
            .add_systems(ExtractSchedule, extract_cameras)
            .add_systems(Render, prepare_composite.in_set(RenderSystems::PrepareResources))
            .configure_sets(
                Core3d,
                (
                    GiViewSystems::Produce.after(Core3dSystems::Prepass).before(Core3dSystems::MainPass),
                    GiViewSystems::Refine
                        .after(main_opaque_pass_3d)
                        .before(main_transparent_pass_3d)
                        .in_set(Core3dSystems::MainPass),
                ),
            )
            .add_systems(
                Core3d,
                (
                    clear_gi_target.in_set(GiViewSystems::Produce),
                    filter_gi_target
                        .after(GiViewSystems::Refine)
                        .before(composite_gi)
                        .in_set(Core3dSystems::MainPass),
                    composite_gi
                        .after(GiViewSystems::Refine)
                        .before(main_transparent_pass_3d)
                        .in_set(Core3dSystems::MainPass),
                ),
            );
    }
}

use bevy::core_pipeline::{Core3d, Core3dSystems};
use bevy::render::{ExtractSchedule, Render, RenderApp, RenderStartup, RenderSystems};

fn init_composite_pipelines(world: &mut World) {
    let pipelines = CompositePipelines::from_world(world);
    let filters = FilterPipelines {
        view_layout: pipelines.view_layout.clone(),
        shader: world.resource::<CompositeShader>().2.clone(),
        fullscreen: pipelines.fullscreen.clone(),
    };
    world.insert_resource(pipelines);
    world.insert_resource(filters);
}
