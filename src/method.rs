//! What the six methods have in common, written once: the GPU capability check, the settings
//! component's registration and validation, the status every method reports to the panel, and the
//! plugin steps every method module takes.
//!
//! Every method module (`radiance_hints`, `vpl`, `rsm_gather`, `drm`, `radiosity`, `photon_grid`) has
//! the same files:
//!
//! | file | what it holds |
//! |---|---|
//! | `mod.rs` | the algorithm's docs (the paper's equations, measured costs, known issues), the plugin, which implements [`GiMethodModule`] |
//! | `settings.rs` | the user's settings component with `LOW`/`MEDIUM`/`HIGH`, every field documented with unit, default, range and cost; its [`GiSettings`] validation |
//! | `extract.rs` | the main-world side: what keeps the method's CPU inputs current (background tasks) and the `ExtractSchedule` systems that copy them and the cameras' settings into the render world |
//! | `prepare.rs` | the render-world resources: shaders, GPU layouts (`ShaderType`), pipelines, buffers, bind groups |
//! | `render.rs` | the passes (`RenderGraph` / `Core3d` systems) and `add_render_systems` |
//!
//! plus the method's own algorithm files (`voxelize.rs`, `generate.rs`, `solver.rs`, `grid.rs`, …). No
//! method imports another (`shared/DESIGN.md`); what two methods need lives below them (`scene`, `rsm`,
//! `emitters`, `voxels`, `background`, this module, and the frame of `composite`).

use std::sync::{Arc, Mutex};

use bevy::app::SubApp;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::DownlevelFlags;
use bevy::render::settings::WgpuLimits;

use crate::camera::GiMethod;
use crate::settings::GiSettings;

/// A GPU capability a method needs and the device lacks: `(name, required, found)`.
pub type Shortfall = (&'static str, u64, u64);

/// What a GPU offers, as a method's requirements read it: the device's limits and the adapter's
/// downlevel flags.
#[derive(Clone, Debug)]
pub struct GpuCapabilities {
    pub limits: WgpuLimits,
    pub flags: DownlevelFlags,
}

impl GpuCapabilities {
    /// wgpu's default limits and every downlevel flag: what a desktop GPU offers at least.
    pub fn desktop() -> Self {
        Self { limits: WgpuLimits::default(), flags: DownlevelFlags::all() }
    }

    /// WebGL2's limits and no downlevel flags: what a browser without WebGPU offers.
    pub fn webgl2() -> Self {
        Self { limits: WgpuLimits::downlevel_webgl2_defaults(), flags: DownlevelFlags::empty() }
    }

    /// Starts a list of requirements checked against these capabilities.
    pub fn require(&self) -> Requirements<'_> {
        Requirements { gpu: self, missing: Vec::new() }
    }
}

/// The requirements of one method, checked as they are listed; [`Requirements::missing`] returns every
/// shortfall.
pub struct Requirements<'a> {
    gpu: &'a GpuCapabilities,
    missing: Vec<Shortfall>,
}

impl Requirements<'_> {
    /// A limit of at least `required`.
    pub fn at_least(mut self, name: &'static str, required: u64, found: u64) -> Self {
        if found < required {
            self.missing.push((name, required, found));
        }
        self
    }

    /// A downlevel feature, named in the warning as `name`.
    pub fn feature(self, name: &'static str, flag: DownlevelFlags) -> Self {
        let found = self.gpu.flags.contains(flag) as u64;
        self.at_least(name, 1, found)
    }

    /// Compute shaders with workgroups of the crate's size ([`crate::WORKGROUP_SIZE`]).
    pub fn compute(self) -> Self {
        let threads = crate::WORKGROUP_SIZE as u64;
        let (x, invocations) = (
            self.gpu.limits.max_compute_workgroup_size_x as u64,
            self.gpu.limits.max_compute_invocations_per_workgroup as u64,
        );
        self.feature("compute shaders (DownlevelFlags::COMPUTE_SHADERS)", DownlevelFlags::COMPUTE_SHADERS)
            .at_least("max_compute_workgroup_size_x", threads, x)
            .at_least("max_compute_invocations_per_workgroup", threads, invocations)
    }

    /// At least `count` storage buffers in one shader stage.
    pub fn storage_buffers(self, count: u64) -> Self {
        let found = self.gpu.limits.max_storage_buffers_per_shader_stage as u64;
        self.at_least("max_storage_buffers_per_shader_stage", count, found)
    }

    /// The shortfalls found, in the order the requirements were listed.
    pub fn missing(self) -> Vec<Shortfall> {
        self.missing
    }
}

/// A method module's plugin: what the shared steps of [`build_method`] and [`finish_method`] need to
/// know of it.
pub trait GiMethodModule: Plugin {
    /// The method, as a camera picks it.
    const METHOD: GiMethod;
    /// Its name in warnings ("Radiance Hints").
    const NAME: &'static str;
    /// Its settings component.
    type Settings: GiSettings + Default + PartialEq + Reflect + bevy::reflect::TypePath + bevy::reflect::GetTypeRegistration;

    /// The GPU capabilities the method needs that `gpu` lacks, as `(name, required, found)`.
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall>;

    /// Adds the method's render-world systems (only on a GPU with what it needs).
    fn add_render_systems(render_app: &mut SubApp);
}

/// The steps every method's `Plugin::build` takes: registers its settings component for reflection,
/// validates it (clamped, one warning per entity and field) and makes its status known to the panel.
pub(crate) fn build_method<M: GiMethodModule>(app: &mut App) {
    app.register_type::<M::Settings>()
        .init_resource::<GiMethodStatus>()
        .add_systems(PostUpdate, crate::settings::validate_settings::<M::Settings>);
}

/// The step every method's `Plugin::finish` takes: checks the GPU (one warning naming the limit when it
/// falls short, and the method stays off) and adds the render-world systems.
pub(crate) fn finish_method<M: GiMethodModule>(app: &mut App) {
    if !crate::gpu_supports(app, M::NAME, M::missing_capabilities) {
        return;
    }
    if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
        M::add_render_systems(render_app);
    }
}

/// A camera's settings of one method in the render world, sanitised, on the cameras that use the method
/// (removed from those that switch to another).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ExtractedSettings<S: GiSettings>(pub S);

/// Copies each camera's settings of method `M` into the render world ([`ExtractedSettings`]); a camera
/// without the component gets the defaults.
pub(crate) fn extract_camera_settings<M: GiMethodModule>(
    mut commands: Commands,
    cameras: bevy::render::Extract<Query<(bevy::render::sync_world::RenderEntity, &crate::camera::DiffuseGi, Option<&M::Settings>)>>,
) {
    for (entity, gi, settings) in &cameras {
        let Ok(mut entity) = commands.get_entity(entity) else {
            continue;
        };
        if gi.method == M::METHOD {
            entity.insert(ExtractedSettings(settings.cloned().unwrap_or_default().sanitized().0));
        } else {
            entity.remove::<ExtractedSettings<M::Settings>>();
        }
    }
}

/// What a method reports of itself every frame, one shape for the six: the panel shows it, the tools
/// and tests read it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MethodStatus {
    /// Whether the method draws light: false from its activation until its first result (a CPU
    /// method's first background solve, a GPU method's pipelines compiling).
    pub ready: bool,
    /// Whether what is drawn is not yet the scene as it is now: background work running or due, or a
    /// new result still being blended in. Always false for the per-frame GPU methods.
    pub busy: bool,
    /// Frames since the last background update started from the scene (0 for per-frame methods).
    pub frames_since_start: u32,
    /// Background updates finished so far (0 for the per-frame GPU methods).
    pub updates: u64,
    /// Views the method drew into so far (one per camera and frame).
    pub views_drawn: u64,
}

/// Every active method's [`MethodStatus`], in the main world (and, shared, in the render world, whose
/// passes say when they drew).
#[derive(Resource, Clone, Default, Debug)]
pub struct GiMethodStatus(Arc<Mutex<HashMap<GiMethod, MethodStatus>>>);

impl GiMethodStatus {
    /// The status of `method`, or `None` while no camera uses it.
    pub fn get(&self, method: GiMethod) -> Option<MethodStatus> {
        self.0.lock().ok()?.get(&method).copied()
    }

    /// Changes the status of `method` (made when absent).
    fn update(&self, method: GiMethod, change: impl FnOnce(&mut MethodStatus)) {
        if let Ok(mut map) = self.0.lock() {
            change(map.entry(method).or_default());
        }
    }

    /// Sets what a method with background work says of it (from its main-world update): everything
    /// but [`MethodStatus::views_drawn`], which the render world counts.
    pub fn set_background(&self, method: GiMethod, ready: bool, busy: bool, frames_since_start: u32, updates: u64) {
        self.update(method, |s| *s = MethodStatus { ready, busy, frames_since_start, updates, views_drawn: s.views_drawn });
    }

    /// Sets whether a GPU method's background work (Radiance Hints' voxelisations) runs, keeping what
    /// the render world said (ready, views drawn).
    pub fn set_busy(&self, method: GiMethod, busy: bool, frames_since_start: u32, updates: u64) {
        self.update(method, |s| (s.busy, s.frames_since_start, s.updates) = (busy, frames_since_start, updates));
    }

    /// Forgets every method but those in `used` (no camera uses the others any more).
    pub fn keep_only(&self, used: &[GiMethod]) {
        if let Ok(mut map) = self.0.lock() {
            map.retain(|method, _| used.contains(method));
        }
    }

    /// Whether any method's light is not yet that of the scene as it is (background work running or due,
    /// or a new result blending in).
    pub fn any_busy(&self) -> bool {
        self.0.lock().is_ok_and(|map| map.values().any(|s| s.busy))
    }

    /// Whether any method in use still waits for its first result (draws no light yet) while its
    /// background work runs.
    pub fn any_awaiting_first_result(&self) -> bool {
        self.0.lock().is_ok_and(|map| map.values().any(|s| s.busy && !s.ready))
    }

    /// Records that `method` drew into a view's target (from the render world's per-view pass).
    pub fn drew(&self, method: GiMethod) {
        self.update(method, |s| (s.ready, s.views_drawn) = (true, s.views_drawn + 1));
    }
}

/// Forgets the status of methods no active camera uses, so that the panel and the tools do not show a
/// method that is off as ready.
pub(crate) fn forget_unused_methods(cameras: Query<(&Camera, &crate::camera::DiffuseGi)>, status: Res<GiMethodStatus>) {
    let used: Vec<GiMethod> = cameras.iter().filter(|(c, gi)| c.is_active && gi.enabled).map(|(_, gi)| gi.method).collect();
    status.keep_only(&used);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requirements_list_every_shortfall_in_order() {
        let gpu = GpuCapabilities::webgl2();
        let missing = gpu.require().compute().storage_buffers(4).missing();
        let names: Vec<_> = missing.iter().map(|m| m.0).collect();
        assert_eq!(names[0], "compute shaders (DownlevelFlags::COMPUTE_SHADERS)");
        assert!(names.contains(&"max_storage_buffers_per_shader_stage"), "{names:?}");
        assert!(GpuCapabilities::desktop().require().compute().storage_buffers(4).missing().is_empty());
    }

    #[test]
    fn a_drawn_method_is_ready_and_counts_its_frames() {
        let status = GiMethodStatus::default();
        assert_eq!(status.get(GiMethod::RsmGather), None);
        status.drew(GiMethod::RsmGather);
        status.drew(GiMethod::RsmGather);
        let s = status.get(GiMethod::RsmGather).expect("recorded");
        assert!(s.ready && !s.busy);
        assert_eq!((s.updates, s.views_drawn), (0, 2));
        status.set_background(GiMethod::RsmGather, true, true, 3, 1);
        let s = status.get(GiMethod::RsmGather).expect("recorded");
        assert_eq!((s.busy, s.frames_since_start, s.updates, s.views_drawn), (true, 3, 1, 2), "the drawn views are kept");
        status.keep_only(&[GiMethod::Vpl]);
        assert_eq!(status.get(GiMethod::RsmGather), None);
    }
}
