//! Render world: the gather's GPU layout, its pipelines, and the field uploaded when it changes.

use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{storage_buffer_read_only, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::shader::{Shader, ShaderDefVal};

use super::extract::PhotonGridOutput;
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GiViewPass, PipelinesByResolution};

/// The grid the gather reads (`PhotonGridUniform` in `shaders/photon_grid/gather.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct PhotonGridUniform {
    /// World position of the grid's minimum corner.
    pub origin: Vec3,
    /// SH-grid cell side, metres.
    pub cell_size: f32,
    /// SH-grid cells per axis.
    pub dims: UVec3,
    /// `w_sh`'s extent, metres.
    pub r_max: f32,
    pub intensity: f32,
    /// `N_d`; 0: the exact integral.
    pub gather_samples: u32,
    /// Obscurance distance, metres; 0: off.
    pub obscurance_distance: f32,
    pub probes: u32,
}

/// The method's shaders.
#[derive(Resource, Clone)]
pub struct PhotonGridShaders {
    pub gather: Handle<Shader>,
}

/// Layouts of the gather; its pipeline is specialised by resolution.
#[derive(Resource)]
pub struct PhotonGridPipelines {
    pub(super) pass: GiViewPass,
    pub(super) field_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
}

impl SpecializedRenderPipeline for PhotonGridPipelines {
    /// Half resolution.
    type Key = bool;

    fn specialize(&self, half_resolution: bool) -> RenderPipelineDescriptor {
        let defs = vec![
            ShaderDefVal::Int("V_PER_SH".into(), super::grid::V_PER_SH as i32),
            ShaderDefVal::UInt("GATHER_START_OFFSET_PERCENT".into(), (super::grid::GATHER_START_OFFSET * 100.0).round() as u32),
        ];
        let layouts = [&self.field_layout];
        self.pass.pipeline("diffuse_gi_photon_gather_pipeline", &self.shader, "gather", half_resolution, &layouts, defs, None)
    }
}

pub(super) fn init_photon_grid_pipelines(world: &mut World) {
    let field_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_photon_gather_field_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (
                uniform_buffer::<PhotonGridUniform>(false),
                storage_buffer_read_only::<u32>(false),
                storage_buffer_read_only::<Vec4>(false),
                storage_buffer_read_only::<u32>(false),
            ),
        ),
    );
    world.insert_resource(PhotonGridPipelines {
        pass: GiViewPass::from_world(world),
        field_layout,
        shader: world.resource::<PhotonGridShaders>().gather.clone(),
    });
}

/// The field on the GPU and the pipelines of this frame's views.
#[derive(Resource, Default)]
pub struct PhotonGridGpu {
    /// The [`PhotonGridOutput::generation`] uploaded.
    generation: Option<u64>,
    /// Uniform, cell → probe, coefficients, V-grid occupancy; `None` while the field is empty.
    pub(super) field: Option<(UniformBuffer<PhotonGridUniform>, Buffer, Buffer, Buffer)>,
    pub(super) pipelines: PipelinesByResolution,
}

#[expect(clippy::too_many_arguments, reason = "upload and specialisation")]
pub(super) fn prepare_photon_grid(
    mut gpu: ResMut<PhotonGridGpu>,
    output: Res<PhotonGridOutput>,
    views: Query<&ExtractedDiffuseGi>,
    pipelines: Res<PhotonGridPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<PhotonGridPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let gpu = &mut *gpu;
    if !gpu.pipelines.specialize_for(&views, GiMethod::PhotonGrid, &mut specialized, &pipeline_cache, &pipelines) {
        gpu.field = None;
        gpu.generation = None;
        return;
    }
    if gpu.generation == Some(output.generation) {
        return;
    }
    gpu.generation = Some(output.generation);
    gpu.field = (!output.coefficients.is_empty()).then(|| {
        let mut uniform = UniformBuffer::from(output.grid);
        uniform.set_label(Some("diffuse_gi_photon_grid_uniform"));
        uniform.write_buffer(&device, &queue);
        let buffer = |label, contents: &[u8]| {
            device.create_buffer_with_data(&BufferInitDescriptor { label: Some(label), contents, usage: BufferUsages::STORAGE })
        };
        (
            uniform,
            buffer("diffuse_gi_photon_grid_cell_probe", bytemuck::cast_slice(&output.cell_probe)),
            buffer("diffuse_gi_photon_grid_coefficients", bytemuck::cast_slice(&output.coefficients)),
            buffer("diffuse_gi_photon_grid_occupancy", bytemuck::cast_slice(&output.occupancy)),
        )
    });
}
