//! Adds a GI method's indirect light into the camera's HDR target after the opaque pass, or replaces the
//! image with a debug view ([`GiDebugView`]).
//!
//! Each GI camera gets a GI target (`Rgba16Float`, full or half resolution) that the method's
//! reconstruction fills with `Σ w·E/π` and `Σ w`; this pass multiplies by the G-buffer albedo and the
//! exposure and adds the result with `One + One` blending, between `main_opaque_pass_3d` and
//! `main_transparent_pass_3d` (so transparent surfaces are drawn over lit opaque ones, not lit themselves).

use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::core_pipeline::FullscreenShader;
use bevy::core_pipeline::core_3d::{main_opaque_pass_3d, main_transparent_pass_3d};
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::binding_types::{texture_2d, texture_2d_array, texture_depth_2d, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::texture::{CachedTexture, TextureCache};
use bevy::render::view::{ViewTarget, ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::shader::{Shader, ShaderDefVal};

use crate::camera::{GiDebugView, GiOutput};
use crate::radiance_hints::extract::ExtractedDiffuseGi;
use crate::radiance_hints::prepare::{GI_TARGET_FORMAT, RhPipelines, RhVolumesGpu};
use crate::rsm::RsmAtlas;
use crate::sh::ShOrder;

/// The camera's GI target for this frame.
#[derive(Component)]
pub struct GiViewTarget {
    pub texture: CachedTexture,
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
    pub debug_view: GiDebugView,
    pub half_resolution: bool,
    /// SH order of the first volume (the hint-grid view reads it).
    pub sh_order: ShOrder,
}

/// The composite pipelines and their layouts.
#[derive(Resource)]
pub struct CompositePipelines {
    view_layout: BindGroupLayoutDescriptor,
    rsm_layout: BindGroupLayoutDescriptor,
    sample_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
    fullscreen: VertexState,
    rsm_debug: UniformBuffer<RsmDebugUniform>,
}

/// The composite shader, kept alive by this resource.
#[derive(Resource, Clone)]
pub struct CompositeShader(pub Handle<Shader>);

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
            sample_layout: world.resource::<RhPipelines>().sample_layout.clone(),
            shader: world.resource::<CompositeShader>().0.clone(),
            fullscreen: world.resource::<FullscreenShader>().to_vertex_state(),
            rsm_debug: UniformBuffer::default(),
        }
    }
}

impl SpecializedRenderPipeline for CompositePipelines {
    type Key = CompositeKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        let view = key.debug_view.shader_index();
        let mut layout = vec![self.view_layout.clone()];
        match key.debug_view {
            GiDebugView::HintGrid => layout.push(self.sample_layout.clone()),
            GiDebugView::RsmFlux | GiDebugView::RsmNormal | GiDebugView::RsmPosition => layout.push(self.rsm_layout.clone()),
            _ => {}
        }
        let blend = (key.debug_view == GiDebugView::None).then_some(BlendState {
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
                    ShaderDefVal::UInt("DEBUG_VIEW".into(), view),
                    ShaderDefVal::Int("GI_SCALE".into(), if key.half_resolution { 2 } else { 1 }),
                    ShaderDefVal::UInt("SH_COEFS".into(), key.sh_order.coefficients() as u32),
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
    pipeline_cache: Res<PipelineCache>,
    volumes: Res<RhVolumesGpu>,
    atlas: Res<RsmAtlas>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let sh_order = volumes.volumes.first().map_or(ShOrder::Two, |v| v.settings.sh_order);
    for (entity, camera, gi, target) in &views {
        let Some(size) = camera.physical_viewport_size else {
            continue;
        };
        let scale = if gi.0.half_resolution { 2 } else { 1 };
        let texture = texture_cache.get(
            &device,
            TextureDescriptor {
                label: Some("diffuse_gi_target"),
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
        );
        let key = CompositeKey {
            format: target.main_texture_format(),
            debug_view: gi.0.debug_view,
            half_resolution: gi.0.half_resolution,
            sh_order,
        };
        let id = specialized.specialize(&pipeline_cache, &pipelines, key);
        commands.entity(entity).insert((GiViewTarget { texture }, CompositePipelineId(id)));
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
    volumes: Res<RhVolumesGpu>,
    atlas: Res<RsmAtlas>,
    mut ctx: RenderContext,
) {
    let (gi, target, view_offset, prepass, gi_target, pipeline_id) = view.into_inner();
    let debug_view = gi.0.debug_view;
    if gi.0.output == GiOutput::IrradianceVolume && debug_view == GiDebugView::None {
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
    let view_group = device.create_bind_group(
        "diffuse_gi_composite_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer, &gi_target.texture.default_view)),
    );
    let extra = match debug_view {
        GiDebugView::HintGrid => {
            let Some((groups, offset)) = volumes
                .volumes
                .first()
                .and_then(|v| v.bind_groups.as_ref().map(|g| (g.sample_result.clone(), v.uniform_offsets[0])))
            else {
                return;
            };
            Some((groups, Some(offset)))
        }
        GiDebugView::RsmFlux | GiDebugView::RsmNormal | GiDebugView::RsmPosition => {
            let Some(debug) = pipelines.rsm_debug.binding() else {
                return;
            };
            let group = device.create_bind_group(
                "diffuse_gi_composite_rsm_bind_group",
                &pipeline_cache.get_bind_group_layout(&pipelines.rsm_layout),
                &BindGroupEntries::sequential((&atlas.position_view, &atlas.normal_view, &atlas.flux_view, debug)),
            );
            Some((group, None))
        }
        _ => None,
    };

    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let span = diagnostics.time_span(ctx.command_encoder(), "diffuse_gi/composite");
    {
        let mut pass = ctx.begin_tracked_render_pass(RenderPassDescriptor {
            label: Some("diffuse_gi_composite"),
            color_attachments: &[Some(RenderPassColorAttachment {
                view: target.main_texture_view(),
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
        });
        pass.set_render_pipeline(pipeline);
        pass.set_bind_group(0, &view_group, &[view_offset.offset]);
        if let Some((group, offset)) = &extra {
            match offset {
                Some(offset) => pass.set_bind_group(1, group, &[*offset]),
                None => pass.set_bind_group(1, group, &[]),
            }
        }
        pass.draw(0..3, 0..1);
    }
    span.end(ctx.command_encoder());
}

/// Registers the composite pass. Added by [`crate::DiffuseGiPlugin`].
pub struct CompositePlugin;

impl Plugin for CompositePlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(
            app,
            "composite/composite.wgsl",
            include_str!("../../shaders/composite/composite.wgsl"),
        );
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(CompositeShader(shader));
        }
    }
}

use bevy::core_pipeline::{Core3d, Core3dSystems};
use bevy::render::{Render, RenderApp, RenderSystems};

/// Adds the composite's render-world systems; called from the crate plugin's `finish`.
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    render_app
        .init_resource::<SpecializedRenderPipelines<CompositePipelines>>()
        .add_systems(
            bevy::render::RenderStartup,
            init_composite_pipelines.after(super::radiance_hints::init_rh_pipelines),
        )
        .add_systems(
            Render,
            prepare_composite
                .in_set(RenderSystems::PrepareResources)
                .after(crate::radiance_hints::prepare::prepare_rh_volumes),
        )
        .add_systems(
            Core3d,
            composite_gi
                .after(main_opaque_pass_3d)
                .before(main_transparent_pass_3d)
                .in_set(Core3dSystems::MainPass),
        );
}

fn init_composite_pipelines(world: &mut World) {
    let pipelines = CompositePipelines::from_world(world);
    world.insert_resource(pipelines);
}
