//! Render world: gathers the SH field per pixel into each photon-grid camera's indirect-light target
//! (§4.1–4.2, 4.4).

use bevy::prelude::*;
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, ViewQuery};

use super::prepare::{PhotonGridGpu, PhotonGridPipelines, init_photon_grid_pipelines, prepare_photon_grid};
use crate::camera::GiMethod;
use crate::composite::{GiView, GiViewPassParams, add_view_method};

/// The gather of one camera into its indirect-light target.
fn gather_photon_grid(
    view: ViewQuery<GiView>,
    gpu: Res<PhotonGridGpu>,
    pipelines: Res<PhotonGridPipelines>,
    params: GiViewPassParams,
    mut ctx: RenderContext,
) {
    let view = view.into_inner();
    if view.gi.0.method != GiMethod::PhotonGrid {
        return;
    }
    let (Some((uniform, buffers)), Some(pipeline_id)) =
        (&gpu.field, gpu.pipelines.get(view.gi.0.half_resolution))
    else {
        return;
    };
    let (Some(pipeline), Some(grid)) = (params.pipeline_cache.get_render_pipeline(pipeline_id), uniform.binding()) else {
        return;
    };
    let field_group = ctx.render_device().create_bind_group(
        "diffuse_gi_photon_gather_field_bind_group",
        &params.pipeline_cache.get_bind_group_layout(&pipelines.field_layout),
        &BindGroupEntries::sequential((
            grid,
            buffers.cell_probe.as_entire_binding(),
            buffers.coefficients.as_entire_binding(),
            buffers.occupancy.as_entire_binding(),
            buffers.from_coefficients.as_entire_binding(),
        )),
    );
    pipelines.pass.draw(
        &mut ctx,
        &params,
        &view,
        GiMethod::PhotonGrid,
        ("diffuse_gi/photon_gather", "diffuse_gi_photon_gather"),
        pipeline,
        &[(&field_group, &[])],
        0..3,
    );
}

/// Adds the photon grid's render-world systems; called from [`super::PhotonGridPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    add_view_method::<PhotonGridGpu, PhotonGridPipelines, _, _, _>(render_app, init_photon_grid_pipelines, prepare_photon_grid, gather_photon_grid);
}
