//! Render world: uploads the SH field when it changes and gathers it per pixel into each photon-grid
//! camera's indirect-light target (§4.1–4.2, 4.4).

use bevy::core_pipeline::prepass::ViewPrepassTextures;
use bevy::core_pipeline::{Core3d, FullscreenShader};
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{storage_buffer_read_only, texture_2d, texture_depth_2d, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::view::{ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::render::{Render, RenderStartup, RenderSystems};
use bevy::shader::{Shader, ShaderDefVal};

use super::{PhotonGridOutput, PhotonGridUniform};
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GI_TARGET_FORMAT, GiViewSystems, GiViewTarget, clear_gi_target};

/// The gather shader.
#[derive(Resource, Clone)]
pub struct PhotonGridShader(pub Handle<Shader>);

/// Layouts of the gather; its pipeline is specialised by resolution.
#[derive(Resource)]
pub struct PhotonGridPipelines {
    view_layout: BindGroupLayoutDescriptor,
    field_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
    fullscreen: VertexState,
}

impl SpecializedRenderPipeline for PhotonGridPipelines {
    /// Half resolution.
    type Key = bool;

    fn specialize(&self, half_resolution: bool) -> RenderPipelineDescriptor {
        let mut shader_defs = crate::shared_shader_defs();
        shader_defs.push(ShaderDefVal::Int("GI_SCALE".into(), if half_resolution { 2 } else { 1 }));
        shader_defs.push(ShaderDefVal::Int("V_PER_SH".into(), super::grid::V_PER_SH as i32));
        shader_defs.push(ShaderDefVal::UInt("GATHER_START_OFFSET_PERCENT".into(), (super::grid::GATHER_START_OFFSET * 100.0).round() as u32));
        RenderPipelineDescriptor {
            label: Some("diffuse_gi_photon_gather_pipeline".into()),
            layout: vec![self.view_layout.clone(), self.field_layout.clone()],
            vertex: self.fullscreen.clone(),
            fragment: Some(FragmentState {
                shader: self.shader.clone(),
                shader_defs,
                entry_point: Some("gather".into()),
                targets: vec![Some(ColorTargetState { format: GI_TARGET_FORMAT, blend: None, write_mask: ColorWrites::ALL })],
            }),
            ..default()
        }
    }
}

fn init_photon_grid_pipelines(world: &mut World) {
    let view_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_photon_gather_view_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (uniform_buffer::<ViewUniform>(true), texture_depth_2d(), texture_2d(TextureSampleType::Uint)),
        ),
    );
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
        view_layout,
        field_layout,
        shader: world.resource::<PhotonGridShader>().0.clone(),
        fullscreen: world.resource::<FullscreenShader>().to_vertex_state(),
    });
}

/// The field on the GPU and the pipelines of this frame's views.
#[derive(Resource, Default)]
pub struct PhotonGridGpu {
    /// The [`PhotonGridOutput::generation`] uploaded.
    generation: Option<u64>,
    /// Uniform, cell → probe, coefficients, V-grid occupancy; `None` while the field is empty.
    field: Option<(UniformBuffer<PhotonGridUniform>, Buffer, Buffer, Buffer)>,
    pipelines: [Option<CachedRenderPipelineId>; 2],
}

#[expect(clippy::too_many_arguments, reason = "upload and specialisation")]
fn prepare_photon_grid(
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
    let used: Vec<bool> = views.iter().filter(|gi| gi.0.method == GiMethod::PhotonGrid).map(|gi| gi.0.half_resolution).collect();
    for half in [false, true] {
        if used.contains(&half) && gpu.pipelines[half as usize].is_none() {
            gpu.pipelines[half as usize] = Some(specialized.specialize(&pipeline_cache, &pipelines, half));
        }
    }
    if used.is_empty() {
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

/// The gather of one camera into its indirect-light target.
fn gather_photon_grid(
    view: ViewQuery<(&ExtractedDiffuseGi, &ViewUniformOffset, &ViewPrepassTextures, &GiViewTarget)>,
    gpu: Res<PhotonGridGpu>,
    pipelines: Res<PhotonGridPipelines>,
    pipeline_cache: Res<PipelineCache>,
    view_uniforms: Res<ViewUniforms>,
    mut ctx: RenderContext,
) {
    let (gi, view_offset, prepass, target) = view.into_inner();
    if gi.0.method != GiMethod::PhotonGrid {
        return;
    }
    let (Some((uniform, cell_probe, coefficients, occupancy)), Some(pipeline_id)) = (&gpu.field, gpu.pipelines[gi.0.half_resolution as usize]) else {
        return;
    };
    let (Some(pipeline), Some(uniforms), Some(depth), Some(gbuffer), Some(grid)) = (
        pipeline_cache.get_render_pipeline(pipeline_id),
        view_uniforms.uniforms.binding(),
        prepass.depth_view(),
        prepass.deferred_view(),
        uniform.binding(),
    ) else {
        return;
    };
    let device = ctx.render_device().clone();
    let view_group = device.create_bind_group(
        "diffuse_gi_photon_gather_view_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.view_layout),
        &BindGroupEntries::sequential((uniforms, depth, gbuffer)),
    );
    let field_group = device.create_bind_group(
        "diffuse_gi_photon_gather_field_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.field_layout),
        &BindGroupEntries::sequential((
            grid,
            cell_probe.as_entire_binding(),
            coefficients.as_entire_binding(),
            occupancy.as_entire_binding(),
        )),
    );
    crate::composite::draw_into_target(
        &mut ctx,
        "diffuse_gi/photon_gather",
        "diffuse_gi_photon_gather",
        target,
        pipeline,
        &[(&view_group, &[view_offset.offset]), (&field_group, &[])],
    );
}

/// Adds the photon grid's render-world systems; called from [`super::PhotonGridPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    render_app
        .init_resource::<PhotonGridGpu>()
        .init_resource::<SpecializedRenderPipelines<PhotonGridPipelines>>()
        .add_systems(RenderStartup, init_photon_grid_pipelines)
        .add_systems(Render, prepare_photon_grid.in_set(RenderSystems::PrepareResources))
        .add_systems(Core3d, gather_photon_grid.in_set(GiViewSystems::Produce).after(clear_gi_target));
}
