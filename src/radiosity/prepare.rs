//! Render world: the element mesh's GPU layout, the display pipelines, and the mesh uploaded when the
//! solution changes.

use bevy::prelude::*;
use bevy::render::render_resource::binding_types::storage_buffer_read_only;
use bevy::render::render_resource::*;
use bevy::render::renderer::RenderDevice;
use bevy::shader::{Shader, ShaderDefVal};

use super::extract::RadiosityOutput;
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GI_TARGET_FORMAT, GiViewPass, PipelinesByResolution};

/// One vertex of the element mesh the frame draws (`RadiosityVertex` in
/// `shaders/radiosity/display.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct RadiosityVertex {
    /// World position (xyz), w = 1.
    pub position: Vec4,
    /// Gathered irradiance over π, `E/π` (rgb, before exposure, times the intensity); w unused.
    pub irradiance: Vec4,
}

/// The method's shaders.
#[derive(Resource, Clone)]
pub struct RadiosityShaders {
    pub display: Handle<Shader>,
}

/// Layouts of the display pass; its pipeline is specialised by resolution.
#[derive(Resource)]
pub struct RadiosityPipelines {
    pub(super) pass: GiViewPass,
    pub(super) mesh_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
}

impl SpecializedRenderPipeline for RadiosityPipelines {
    /// Half resolution.
    type Key = bool;

    fn specialize(&self, half_resolution: Self::Key) -> RenderPipelineDescriptor {
        let shader_defs = vec![ShaderDefVal::Int("GI_SCALE".into(), if half_resolution { 2 } else { 1 })];
        // The element mesh is drawn as it is (its own vertex shader), over the pass's view group.
        let add = BlendComponent { src_factor: BlendFactor::One, dst_factor: BlendFactor::One, operation: BlendOperation::Add };
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_radiosity_display_pipeline".into()),
            layout: vec![self.pass.view_layout.clone(), self.mesh_layout.clone()],
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

pub(super) fn init_radiosity_pipelines(world: &mut World) {
    let mesh_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_radiosity_mesh_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::VERTEX,
            (storage_buffer_read_only::<RadiosityVertex>(false), storage_buffer_read_only::<u32>(false)),
        ),
    );
    let shader = world.resource::<RadiosityShaders>().display.clone();
    world.insert_resource(RadiosityPipelines { pass: GiViewPass::from_world(world), mesh_layout, shader });
}

/// The element mesh on the GPU and the pipelines of this frame's views.
#[derive(Resource, Default)]
pub struct RadiosityGpu {
    /// The [`RadiosityOutput::generation`] uploaded.
    generation: Option<u64>,
    pub(super) mesh: Option<(Buffer, Buffer, u32)>,
    pub(super) pipelines: PipelinesByResolution,
}

pub(super) fn prepare_radiosity(
    mut gpu: ResMut<RadiosityGpu>,
    output: Res<RadiosityOutput>,
    views: Query<&ExtractedDiffuseGi>,
    pipelines: Res<RadiosityPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<RadiosityPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
) {
    let gpu = &mut *gpu;
    if !gpu.pipelines.specialize_for(&views, GiMethod::Radiosity, &mut specialized, &pipeline_cache, &pipelines) {
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
