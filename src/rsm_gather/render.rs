//! Render world: the per-view RSM gather into the frame's indirect-light target.

use bevy::prelude::*;
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, ViewQuery};

use super::prepare::{RsmGatherGpu, RsmGatherPipelines, init_rsm_gather_pipelines, prepare_rsm_gather};
use crate::camera::GiMethod;
use crate::composite::{GiView, GiViewPassParams, add_view_method};
use crate::rsm::RsmAtlas;

/// The gather of one camera into its indirect-light target.
fn gather_rsm(
    view: ViewQuery<GiView>,
    gpu: Res<RsmGatherGpu>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<RsmGatherPipelines>,
    params: GiViewPassParams,
    mut ctx: RenderContext,
) {
    let view = view.into_inner();
    if view.gi.0.method != GiMethod::RsmGather || atlas.slots.is_empty() {
        return;
    }
    let Some(&(offset, key, pipeline_id)) = gpu.views.get(&view.entity) else {
        return;
    };
    let (Some(pipeline), Some(gather_uniforms), Some(pattern), Some(lights), Some(faces)) = (
        params.pipeline_cache.get_render_pipeline(pipeline_id),
        gpu.uniforms.binding(),
        gpu.patterns.get(&key),
        atlas.lights.binding(),
        atlas.faces.binding(),
    ) else {
        return;
    };
    let gather_group = ctx.render_device().create_bind_group(
        "diffuse_gi_rsm_gather_bind_group",
        &params.pipeline_cache.get_bind_group_layout(&pipelines.gather_layout),
        &BindGroupEntries::sequential((
            gather_uniforms,
            pattern.as_entire_binding(),
            &atlas.position_view,
            &atlas.normal_view,
            &atlas.flux_view,
            lights,
            faces,
        )),
    );
    pipelines.pass.draw(
        &mut ctx,
        &params,
        &view,
        GiMethod::RsmGather,
        ("diffuse_gi/rsm_gather", "diffuse_gi_rsm_gather"),
        pipeline,
        &[(&gather_group, &[offset])],
        0..3,
    );
}

/// Adds the gather's render-world systems; called from [`super::RsmGatherPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    super::extract::add_extract_systems(render_app);
    add_view_method::<RsmGatherGpu, RsmGatherPipelines, _, _, _>(
        render_app,
        init_rsm_gather_pipelines,
        prepare_rsm_gather.after(crate::rsm::prepare_rsm),
        gather_rsm,
    );
}
