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
    /// The new field's weight while it blends in over the previous one (1 once it has): the gather
    /// reads `mix(from_coefficients, coefficients, blend)`.
    pub blend: f32,
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
                storage_buffer_read_only::<Vec4>(false),
            ),
        ),
    );
    world.insert_resource(PhotonGridPipelines {
        pass: GiViewPass::from_world(world),
        field_layout,
        shader: world.resource::<PhotonGridShaders>().gather.clone(),
    });
}

/// The field's buffers: cell → probe, coefficients, V-grid occupancy, the blend's start.
pub(super) struct FieldBuffers {
    pub cell_probe: Buffer,
    pub coefficients: Buffer,
    pub occupancy: Buffer,
    pub from_coefficients: Buffer,
}

/// The field on the GPU and the pipelines of this frame's views.
#[derive(Resource, Default)]
pub struct PhotonGridGpu {
    /// The [`PhotonGridOutput::generation`] and [`PhotonGridOutput::field_generation`] uploaded.
    generation: Option<(u64, u64)>,
    /// The uniform (rewritten for each blend step) and the buffers (uploaded once per field); `None`
    /// while the field is empty.
    pub(super) field: Option<(UniformBuffer<PhotonGridUniform>, FieldBuffers)>,
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
    let uploaded = gpu.generation.replace((output.generation, output.field_generation));
    if uploaded == Some((output.generation, output.field_generation)) {
        return;
    }
    if output.coefficients.is_empty() {
        gpu.field = None;
        return;
    }
    // A blend step or a gather setting: the uniform only.
    if let Some((uniform, _)) = gpu.field.as_mut().filter(|_| uploaded.is_some_and(|(_, f)| f == output.field_generation)) {
        *uniform.get_mut() = output.grid;
        uniform.write_buffer(&device, &queue);
        return;
    }
    let mut uniform = UniformBuffer::from(output.grid);
    uniform.set_label(Some("diffuse_gi_photon_grid_uniform"));
    uniform.write_buffer(&device, &queue);
    let buffer = |label, contents: &[u8]| {
        device.create_buffer_with_data(&BufferInitDescriptor { label: Some(label), contents, usage: BufferUsages::STORAGE })
    };
    // The blend's start has the coefficients' layout; a field shown whole reads its own values there.
    let from: &[Vec4] = if output.from_coefficients.len() == output.coefficients.len() { &output.from_coefficients } else { &output.coefficients };
    gpu.field = Some((
        uniform,
        FieldBuffers {
            cell_probe: buffer("diffuse_gi_photon_grid_cell_probe", bytemuck::cast_slice(&output.cell_probe)),
            coefficients: buffer("diffuse_gi_photon_grid_coefficients", bytemuck::cast_slice(&output.coefficients)),
            occupancy: buffer("diffuse_gi_photon_grid_occupancy", bytemuck::cast_slice(&output.occupancy)),
            from_coefficients: buffer("diffuse_gi_photon_grid_from_coefficients", bytemuck::cast_slice(from)),
        },
    ));
}
