//! Render world: draws the element mesh into each radiosity camera's indirect-light target.

use bevy::prelude::*;
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, ViewQuery};

use super::prepare::{RadiosityGpu, RadiosityPipelines, init_radiosity_pipelines, prepare_radiosity};
use crate::camera::GiMethod;
use crate::composite::{GiView, GiViewPassParams, add_view_method};

/// Draws the element mesh into one camera's indirect-light target.
fn draw_radiosity(
    view: ViewQuery<GiView>,
    gpu: Res<RadiosityGpu>,
    pipelines: Res<RadiosityPipelines>,
    params: GiViewPassParams,
    mut ctx: RenderContext,
) {
    let view = view.into_inner();
    if view.gi.0.method != GiMethod::Radiosity {
        return;
    }
    let (Some((vertices, indices, count)), Some(pipeline_id)) = (&gpu.mesh, gpu.pipelines.get(view.gi.0.half_resolution)) else {
        return;
    };
    let Some(pipeline) = params.pipeline_cache.get_render_pipeline(pipeline_id) else {
        return;
    };
    let mesh_group = ctx.render_device().create_bind_group(
        "diffuse_gi_radiosity_mesh_bind_group",
        &params.pipeline_cache.get_bind_group_layout(&pipelines.mesh_layout),
        &BindGroupEntries::sequential((vertices.as_entire_binding(), indices.as_entire_binding())),
    );
    pipelines.pass.draw(
        &mut ctx,
        &params,
        &view,
        GiMethod::Radiosity,
        ("diffuse_gi/radiosity_display", "diffuse_gi_radiosity_display"),
        pipeline,
        &[(&mesh_group, &[])],
        0..*count,
    );
}

/// Adds the radiosity render-world systems; called from [`super::RadiosityPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    add_view_method::<RadiosityGpu, RadiosityPipelines, _, _, _>(render_app, init_radiosity_pipelines, prepare_radiosity, draw_radiosity);
}
