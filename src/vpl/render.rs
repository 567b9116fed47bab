//! Render world: the imperfect shadow maps (once per frame, before the cameras) and the per-view clamped
//! gather.

use bevy::core_pipeline::schedule::camera_driver;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderContext, RenderGraph, RenderGraphSystems, ViewQuery};

use super::extract::ExtractedVplSet;
use super::prepare::{VplGpu, VplPipelines, init_vpl_pipelines, prepare_vpls};
use crate::camera::GiMethod;
use crate::composite::{GiView, GiViewPassParams, add_view_method};

/// Splats and pull-pushes the imperfect shadow maps, once per frame before the cameras and only after
/// the VPLs or the points changed.
fn build_ism(mut gpu: ResMut<VplGpu>, pipelines: Res<VplPipelines>, pipeline_cache: Res<PipelineCache>, mut ctx: RenderContext) {
    if !gpu.ism_dirty {
        return;
    }
    let (Some(splat), Some(pull_push), Some(vpls), Some(points), Some(ism), Some(uniforms)) = (
        pipeline_cache.get_compute_pipeline(pipelines.splat),
        pipeline_cache.get_compute_pipeline(pipelines.pull_push),
        gpu.vpls.as_ref(),
        gpu.points.as_ref(),
        gpu.ism.as_ref(),
        gpu.uniforms.binding(),
    ) else {
        return;
    };
    let group = ctx.render_device().create_bind_group(
        "diffuse_gi_vpl_ism_bind_group",
        &pipeline_cache.get_bind_group_layout(&pipelines.ism_layout),
        &BindGroupEntries::sequential((uniforms, vpls.as_entire_binding(), points.as_entire_binding(), ism.as_entire_binding())),
    );
    let ism = ism.clone();
    let count = gpu.vpl_count;
    let per_ism = gpu.points_per_ism;
    let offset = gpu.ism_offset;
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let encoder = ctx.command_encoder();
    encoder.clear_buffer(&ism, 0, None);
    {
        let mut pass = encoder.begin_compute_pass(&ComputePassDescriptor {
            label: Some("diffuse_gi_vpl_ism"),
            timestamp_writes: None,
        });
        let span = diagnostics.pass_span(&mut pass, "diffuse_gi/vpl_ism");
        let rows = |n: u32| (n.min(65535), n.div_ceil(65535).max(1));
        let (y, z) = rows(count);
        pass.set_pipeline(splat);
        pass.set_bind_group(0, &group, &[offset]);
        pass.dispatch_workgroups(per_ism.div_ceil(crate::WORKGROUP_SIZE), y, z);
        pass.set_pipeline(pull_push);
        let (x, y) = rows(count);
        pass.dispatch_workgroups(x, y, 1);
        span.end(&mut pass);
    }
    gpu.ism_dirty = false;
}

/// The clamped gather of one VPL camera into its indirect-light target.
fn gather_vpls(view: ViewQuery<GiView>, gpu: Res<VplGpu>, pipelines: Res<VplPipelines>, params: GiViewPassParams, mut ctx: RenderContext) {
    let view = view.into_inner();
    if view.gi.0.method != GiMethod::Vpl || gpu.vpl_count == 0 || gpu.ism_dirty {
        return;
    }
    let (Some(&(offset, pipeline_id)), Some(vpl_uniforms), Some(vpls), Some(ism)) =
        (gpu.views.get(&view.entity), gpu.uniforms.binding(), gpu.vpls.as_ref(), gpu.ism.as_ref())
    else {
        return;
    };
    let Some(pipeline) = params.pipeline_cache.get_render_pipeline(pipeline_id) else {
        return;
    };
    let gather_group = ctx.render_device().create_bind_group(
        "diffuse_gi_vpl_gather_bind_group",
        &params.pipeline_cache.get_bind_group_layout(&pipelines.gather_layout),
        &BindGroupEntries::sequential((vpl_uniforms, vpls.as_entire_binding(), ism.as_entire_binding())),
    );
    pipelines.pass.draw(
        &mut ctx,
        &params,
        &view,
        GiMethod::Vpl,
        ("diffuse_gi/vpl_gather", "diffuse_gi_vpl_gather"),
        pipeline,
        &[(&gather_group, &[offset])],
        0..3,
    );
}

/// Adds the VPL method's render-world systems; called from [`super::VplPlugin::finish`].
pub(crate) fn add_render_systems(render_app: &mut SubApp) {
    super::extract::add_extract_systems(render_app);
    add_view_method::<VplGpu, VplPipelines, _, _, _>(render_app, init_vpl_pipelines, prepare_vpls, gather_vpls);
    render_app
        .init_resource::<ExtractedVplSet>()
        .add_systems(RenderGraph, build_ism.in_set(RenderGraphSystems::Render).before(camera_driver));
}
