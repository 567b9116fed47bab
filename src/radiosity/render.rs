//! Render world: uploads the element mesh when the solution changes and draws it into each radiosity
//! camera's indirect-light target.

use bevy::core_pipeline::Core3d;
use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{storage_buffer_read_only, texture_2d, texture_depth_2d, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderDevice, ViewQuery};
use bevy::render::view::{ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::render::{Render, RenderStartup, RenderSystems};
use bevy::shader::{Shader, ShaderDefVal};

use super::{RadiosityOutput, RadiosityVertex};
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GI_TARGET_FORMAT, GiViewSystems, GiViewTarget, clear_gi_target};

/// The display shader.
#[derive(Resource, Clone)]
pub struct RadiosityShader(pub Handle<Shader>);

/// Layouts of the display pass; its pipeline is specialised by resolution.
#[derive(Resource)]
pub struct RadiosityPipelines {
    view_layout: BindGroupLayoutDescriptor,
    mesh_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
}

impl SpecializedRenderPipeline for RadiosityPipelines {
    /// Half resolution.
    type Key = bool;

    fn specialize(&self, half_resolution: Self::Key) -> RenderPipelineDescriptor {
        let shader_defs = vec![ShaderDefVal::Int("GI_SCALE".into(), if half_resolution { 2 } else { 1 })];
        let add = BlendComponent { src_factor: BlendFactor::One, dst_factor: BlendFactor::One, operation: BlendOperation::Add };
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_radiosity_display_pipeline".into()),
            layout: vec![self.view_layout.clone(), self.mesh_layout.clone()],
            vertex: VertexState {
                shader: self.shader.clone(),
                shader_defs: shader_defs.clone(),
                entry_point: Some("vertex".into()),
                buffers: vec![],
            },
            fragment: Some(FragmentState {
                shader: self.shader.clone(),
                shader_defs,
                entry_point: Some("fragment".into()),
                targets: vec![Some(ColorTargetState {
                    format: GI_TARGET_FORMAT,
                    blend: Some(BlendState { color: add, alpha: add }),
                    write_mask: ColorWrites::ALL,
                })],
            }),
            ..default()
        }
    }
}

fn init_radiosity_pipelines(mut commands: Commands, shader: Res<RadiosityShader>) {
    let view_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_radiosity_view_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::VERTEX_FRAGMENT,
            (uniform_buffer::<ViewUniform>(true), texture_depth_2d(), texture_2d(TextureSampleType::Uint)),
        ),
    );
    let mesh_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_radiosity_mesh_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::VERTEX,
            (storage_buffer_read_only::<RadiosityVertex>(false), storage_buffer_read_only::<u32>(false)),
        ),
    );
    commands.insert_resource(RadiosityPipelines { view_layout, mesh_layout, shader: shader.0.clone() });
}

/// The element mesh on the GPU and the pipelines of this frame's views.
#[derive(Resource, Default)]
pub struct RadiosityGpu {
    /// The [`RadiosityOutput::generation`] uploaded.
    generation: Option<u64>,
    mesh: Option<(Buffer, Buffer, u32)>,
    pipelines: [Option<CachedRenderPipelineId>; 2],
}

fn prepare_radiosity(
    mut gpu: ResMut<RadiosityGpu>,
    output: Res<RadiosityOutput>,
    views: Query<&ExtractedDiffuseGi>,
    pipelines: Res<RadiosityPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<RadiosityPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
) {
    let gpu = &mut *gpu;
    let used: Vec<bool> = views.iter().filter(|gi| gi.0.method == GiMethod::Radiosity).map(|gi| gi.0.half_resolution).collect();
    for half in [false, true] {
        if used.contains(&half) && gpu.pipelines[half as usize].is_none() {
            gpu.pipelines[half as usize] = Some(specialized.specialize(&pipeline_cache, &pipelines, half));
        }
    }
    if used.is_empty() {
        gpu.mesh = None;
        gpu.generation = None;
        return;
    }
    if gpu.generation == Some(output.generation) {
        return;
    }
    gpu.generation = Some(output.generation);
    gpu.mesh = (!output.indices.is_empty()).then(|| {
        let buffer = |label, contents: &[u8]| {
            device.create_buffer_with_data(&BufferInitDescriptor { label: Some(label), contents, usage: BufferUsages::STORAGE })
        };
        (
            buffer("diffuse_gi_radiosity_vertices", bytemuck::cast_slice(&output.vertices)),
            buffer("diffuse_gi_radiosity_indices", bytemuck::cast_slice(&output.indices)),
            output.indices.len() as u32,
        )
    });
}

/// Draws the element mesh into one camera's indirect-light target.
fn draw_radiosity(
    view: ViewQuery<(&ExtractedDiffuseGi, &ViewUniformOffset, &ViewPrepassTextures, &GiViewTarget)>,
    gpu: Res<RadiosityGpu>,
    pipelines: Res<RadiosityPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    mut ctx: RenderContext,
) {
    let (gi, view_offset, prepass, target) = view.into_inner();
    if gi.0.method != GiMethod::Radiosity {
        return;
    }
    let (Some((vertices, indices, count)), Some(pipeline_id)) = (&gpu.mesh, gpu.pipelines[gi.0.half_resolution as usize]) else {
        return;
    };
    let (Some(pipeline), Some(uniforms), Some(depth), Some(gbuffer)) = (
        pipeline_cache.get_render_pipeline(pipeline_id),
        view_uniforms.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
    ) else {
        return;
    };
    let device = ctx.render_device().clone();
    let view_group = device.create_bind_group(
        "diffuse_gi_radiosity_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer)),
    );
    let mesh_group = device.create_bind_group(
        "diffuse_gi_radiosity_mesh_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.mesh_layout),
        &BindGroupEntries::sequential((vertices.as_entire_binding(), indices.as_entire_binding())),
    );
    crate::composite::draw_vertices_into_target(
        &mut ctx,
        "diffuse_gi/radiosity_display",
        "diffuse_gi_radiosity_display",
        target,
        pipeline,
        &[(&view_group, &[view_offset.offset]), (&mesh_group, &[])],
        0..*count,
    );
}

/// Adds the radiosity render-world systems; called from [`super::RadiosityPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    render_app
        .init_resource::<RadiosityGpu>()
        .init_resource::<SpecializedRenderPipelines<RadiosityPipelines>>()
        .add_systems(RenderStartup, init_radiosity_pipelines)
        .add_systems(Render, prepare_radiosity.in_set(RenderSystems::PrepareResources))
        .add_systems(Core3d, draw_radiosity.in_set(GiViewSystems::Produce).after(clear_gi_target));
}
