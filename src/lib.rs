//! # bevy_diffuse_gi
//!
//! Dynamic diffuse global illumination for Bevy: bounced light that updates every frame, with no baking
//! and no ray-tracing hardware, measured against a path-traced ground truth.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_diffuse_gi::prelude::*;
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, DiffuseGiPlugin::default()))
//!     .add_systems(Startup, |mut commands: Commands| {
//!         // Per camera: the method and the debug view (Radiance Hints by default; or
//!         // `DiffuseGi { method: GiMethod::Vpl, .. }`, which needs no volume).
//!         commands.spawn((Camera3d::default(), DiffuseGi::default()));
//!         // Per light: its light bounces.
//!         commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//!         // Where Radiance Hints apply: a 10 m cube.
//!         commands.spawn((RadianceHintsVolume::MEDIUM, Transform::from_scale(Vec3::splat(10.0))));
//!     })
//!     .run();
//! ```
//!
//! Modules: [`composite`] (the GI frame every method shares: the per-view indirect-light target, the
//! composite into the image, debug views, the per-view pass every method draws with), the methods
//! [`radiance_hints`], [`vpl`] (with the screen-space bias compensation of [`ssbc`]), the one-bounce
//! gathers [`rsm_gather`] and [`drm`], and [`radiosity`] (implicit-visibility hierarchical radiosity,
//! which needs no RSM) and [`photon_grid`] (the photon grid and SH field), each of the same shape
//! ([`method`] lists its files); their shared inputs [`rsm`] (reflective shadow maps), [`emitters`]
//! (samples of the emissive surfaces), [`voxels`] (the voxel walk) and [`background`] (the CPU methods'
//! work off the main thread); [`method`] (what every method module shares: the GPU capability check,
//! the settings' registration, the status every method reports), the settings helpers of [`settings`],
//! [`camera`] and [`light`] (the user's components), [`ui`] (the egui panel, feature `egui`). The
//! measuring instruments: [`scene`] (CPU snapshot of the world), [`reference`](mod@reference)
//! (path-traced ground truth), [`metrics`] (errors), [`scenes`] (standard scenes), and with the feature
//! `tools`, `headless` (the headless renderer and its command line).

pub mod background;
pub mod camera;
pub mod composite;
pub mod drm;
pub mod emitters;
pub mod hdr_image;
#[cfg(feature = "tools")]
pub mod headless;
pub mod light;
pub mod method;
pub mod metrics;
pub mod photon_grid;
pub mod radiance_hints;
pub mod radiosity;
#[cfg(feature = "reference")]
pub mod reference;
pub mod rsm;
pub mod rsm_gather;
pub mod sampling;
pub mod scene;
pub mod scenes;
pub mod settings;
pub mod sh;
pub mod ssbc;
#[cfg(feature = "egui")]
pub mod ui;
pub mod vpl;
pub mod voxels;

use bevy::pbr::DefaultOpaqueRendererMethod;
use bevy::prelude::*;
use bevy::shader::Shader;

/// Everything a user needs in scope.
pub mod prelude {
    pub use crate::{DiffuseGiPlugin, GiDeviceTiming, MainThreadCost};
    pub use crate::camera::{DiffuseGi, GiDebugView, GiMethod, GiOutput};
    pub use crate::light::GiLight;
    pub use crate::radiance_hints::{DepthOcclusion, RadianceHintsCascade, RadianceHintsVolume};
    pub use crate::sh::ShOrder;
    pub use crate::vpl::VplSettings;
    pub use crate::rsm_gather::{RsmGatherSettings, RsmSampleWeights};
    pub use crate::drm::{DrmSettings, DrmSolidAngle};
    pub use crate::radiosity::{LinkTransfer, RadiositySettings};
    pub use crate::photon_grid::PhotonGridSettings;
    #[cfg(feature = "egui")]
    pub use crate::ui::{DiffuseGiInspector, DiffuseGiInspectorPlugin};
}

/// The plugin: the GI methods' render passes and the scene snapshot they read. Anything without the
/// crate's components ([`camera::DiffuseGi`], [`light::GiLight`], a method's volume) costs nothing.
///
/// A GPU that lacks what a method needs disables that method with one warning naming the limit; the app
/// runs on.
pub struct DiffuseGiPlugin {
    /// Make deferred rendering the default for `StandardMaterial`s (inserts
    /// `DefaultOpaqueRendererMethod::deferred()`). The per-pixel reconstruction reads albedo from the
    /// G-buffer, which only deferred materials write. Default `true`; forward-rendered apps set `false` and
    /// use [`camera::GiOutput::IrradianceVolume`].
    pub deferred_by_default: bool,
}

impl Default for DiffuseGiPlugin {
    fn default() -> Self {
        Self { deferred_by_default: true }
    }
}

impl Plugin for DiffuseGiPlugin {
    fn build(&self, app: &mut App) {
        if self.deferred_by_default {
            app.insert_resource(DefaultOpaqueRendererMethod::deferred());
        }
        app.init_resource::<DiffuseGiWarnings>().init_resource::<MainThreadCost>();
        // Pipelines that fail to compile, seen by the render world and read by tools and tests.
        let pipeline_errors = GiPipelineErrors::default();
        // Each method's status, written by the main world (background work) and by the render world's
        // passes (when they drew), read by the panel, the tools and the tests.
        let status = method::GiMethodStatus::default();
        app.insert_resource(pipeline_errors.clone())
            .insert_resource(status.clone())
            .add_systems(PostUpdate, method::forget_unused_methods);
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(pipeline_errors).insert_resource(status).add_systems(
                bevy::render::Render,
                check_pipelines.in_set(bevy::render::RenderSystems::Cleanup),
            );
        }
        app.register_type::<light::GiLight>().add_plugins((
            scene::SceneSnapshotPlugin,
            rsm::RsmPlugin,
            emitters::EmittersPlugin,
            composite::CompositePlugin,
            radiance_hints::RadianceHintsPlugin,
            vpl::VplPlugin,
            ssbc::SsbcPlugin,
            rsm_gather::RsmGatherPlugin,
            drm::DrmPlugin,
            radiosity::RadiosityPlugin,
            photon_grid::PhotonGridPlugin,
        ));
    }

    fn finish(&self, app: &mut App) {
        use bevy::render::RenderApp;
        use bevy::render::render_resource::WgpuFeatures;
        use wgpu_types::DeviceType;
        use bevy::render::renderer::{RenderAdapterInfo, RenderDevice};
        let Some(render_app) = app.get_sub_app(RenderApp) else {
            return;
        };
        let world = render_app.world();
        let (Some(info), Some(device)) = (world.get_resource::<RenderAdapterInfo>(), world.get_resource::<RenderDevice>())
        else {
            return;
        };
        let timing = GiDeviceTiming {
            device: info.name.clone(),
            per_pass_times: info.device_type != DeviceType::Cpu && device.features().contains(WgpuFeatures::TIMESTAMP_QUERY),
        };
        app.insert_resource(timing);
    }
}

/// What the GPU this app renders on says about timing the plugin's passes, for the panel and the tools.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct GiDeviceTiming {
    /// The adapter's name.
    pub device: String,
    /// Whether per-pass GPU times (Bevy's `RenderDiagnosticsPlugin` time spans) mean anything here:
    /// false without timestamp queries, and on CPU rasterisers (lavapipe), whose timestamps do not
    /// bracket compute work.
    pub per_pass_times: bool,
}

/// Milliseconds of main-thread work the plugin did in the last frame, by part (0 where a part had
/// nothing to do): what a game's frame pays on the CPU for GI. Reports and the headless renderer read it.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct MainThreadCost {
    /// Updating the scene snapshot (moved, added and removed meshes; changed materials and textures).
    pub snapshot_ms: f32,
    /// Radiance Hints volumes' voxels: starting and taking their background updates, and scrolling a
    /// volume moved by whole cells (a full voxelisation and the update after a moved mesh run in the
    /// background).
    pub voxels_ms: f32,
    /// The VPLs' main-thread part: comparing the walks' inputs, drawing the guides, starting a walk.
    /// The walks themselves (random walks over the snapshot, the point set) run in the background.
    pub vpl_ms: f32,
    /// Radiosity's main-thread part: polling its background solve, starting the next (a copy of the
    /// snapshot) and writing the drawn vertices while a solution blends in or a mesh moves. The solve
    /// itself (elements, links, illumination) runs in the background ([`background`]).
    pub radiosity_ms: f32,
    /// The photon grid's main-thread part: polling its background preparation, starting the next and
    /// handing a new field and its blend weight to the render world (the blend itself runs in the
    /// gather). The preparation itself (voxels, photons, R-grid, SH field) runs in the background.
    pub photon_grid_ms: f32,
}

impl MainThreadCost {
    pub fn total_ms(&self) -> f32 {
        self.snapshot_ms + self.voxels_ms + self.vpl_ms + self.radiosity_ms + self.photon_grid_ms
    }
}

/// Threads per workgroup of every 1D compute pass of the crate; the shaders get it as the
/// `WORKGROUP_SIZE` shader def (see [`shared_shader_defs`]).
pub const WORKGROUP_SIZE: u32 = 64;

/// Shader defs every pipeline of the crate gets, so that sizes and enumerations shared between Rust and
/// WGSL are written once, here: `WORKGROUP_SIZE` and the light kinds of [`rsm`]
/// (`LIGHT_KIND_DIRECTIONAL`, `LIGHT_KIND_SPOT`, `LIGHT_KIND_POINT`).
pub fn shared_shader_defs() -> Vec<bevy::shader::ShaderDefVal> {
    use bevy::shader::ShaderDefVal::UInt;
    vec![
        UInt("WORKGROUP_SIZE".into(), WORKGROUP_SIZE),
        UInt("LIGHT_KIND_DIRECTIONAL".into(), rsm::KIND_DIRECTIONAL),
        UInt("LIGHT_KIND_SPOT".into(), rsm::KIND_SPOT),
        UInt("LIGHT_KIND_POINT".into(), rsm::KIND_POINT),
    ]
}

/// The plugin's render pipelines that failed to compile (a shader the driver or naga rejects): one line
/// each, naming the pipeline and the error, in order. Bevy logs the error and the pass does not run; the
/// headless renderer fails a run that has any, so tests see a broken shader as a failure.
#[derive(Resource, Clone, Default)]
pub struct GiPipelineErrors(std::sync::Arc<std::sync::Mutex<Vec<String>>>);

impl GiPipelineErrors {
    pub fn messages(&self) -> Vec<String> {
        self.0.lock().map(|m| m.clone()).unwrap_or_default()
    }
}

/// Records the plugin's pipelines (labels `diffuse_gi…`) in the error state into [`GiPipelineErrors`].
/// Pipelines are only appended to the cache and settle once (compiled or failed): each frame looks only
/// at those from the first one not settled yet, so a frame whose pipelines are all ready costs nothing.
fn check_pipelines(
    cache: Res<bevy::render::render_resource::PipelineCache>,
    errors: Res<GiPipelineErrors>,
    mut settled: Local<usize>,
) {
    use bevy::render::render_resource::{CachedPipelineState, PipelineDescriptor};
    use bevy::shader::ShaderCacheError;
    let mut all_settled = true;
    for pipeline in cache.pipelines().skip(*settled) {
        // A shader (or import) not loaded yet is retried by the cache: neither settled nor an error.
        let waiting = matches!(
            pipeline.state,
            CachedPipelineState::Queued
                | CachedPipelineState::Creating(_)
                | CachedPipelineState::Err(ShaderCacheError::ShaderNotLoaded(_) | ShaderCacheError::ShaderImportNotYetAvailable)
        );
        all_settled &= !waiting;
        if all_settled {
            *settled += 1;
        }
        let (false, CachedPipelineState::Err(error)) = (waiting, &pipeline.state) else {
            continue;
        };
        let label = match &pipeline.descriptor {
            PipelineDescriptor::RenderPipelineDescriptor(d) => d.label.as_deref(),
            PipelineDescriptor::ComputePipelineDescriptor(d) => d.label.as_deref(),
        };
        let Some(label) = label.filter(|l| l.starts_with("diffuse_gi")) else {
            continue;
        };
        let Ok(mut messages) = errors.0.lock() else {
            return;
        };
        let message = format!("pipeline {label} failed to compile: {error}");
        if !messages.contains(&message) {
            messages.push(message);
        }
    }
}

/// Every warning the plugin has logged about the app's settings or the GPU, in order (each is logged
/// once, not every frame). For tests, tools and the tuning panel.
#[derive(Resource, Default, Clone, Debug)]
pub struct DiffuseGiWarnings {
    pub messages: Vec<String>,
}

pub use method::Shortfall;

/// The GPU check of a method's `finish`: `missing` lists what the device lacks, given its limits and
/// downlevel flags (all flags when the adapter is unknown). On a shortfall, logs one warning naming the
/// method, the limit and the value found, and returns `false`: the method stays disabled and the app
/// runs on. `false` too in apps without a renderer.
pub(crate) fn gpu_supports(
    app: &mut App,
    method: &str,
    missing: impl FnOnce(&crate::method::GpuCapabilities) -> Vec<Shortfall>,
) -> bool {
    use bevy::render::RenderApp;
    use bevy::render::render_resource::DownlevelFlags;
    use bevy::render::renderer::{RenderAdapter, RenderDevice};
    let Some(render_app) = app.get_sub_app(RenderApp) else {
        return false;
    };
    let Some(device) = render_app.world().get_resource::<RenderDevice>() else {
        return false;
    };
    let flags = render_app
        .world()
        .get_resource::<RenderAdapter>()
        .map_or(DownlevelFlags::all(), |a| a.get_downlevel_capabilities().flags);
    let gpu = crate::method::GpuCapabilities { limits: device.limits(), flags };
    let Some((name, required, found)) = missing(&gpu).into_iter().next() else {
        return true;
    };
    let message = format!(
        "bevy_diffuse_gi: {method} disabled: the GPU lacks {name} (needs {required}, has {found}). \
         The app runs on without its bounced light."
    );
    gi_warning(&mut app.world_mut().resource_mut::<DiffuseGiWarnings>(), message);
    false
}

/// Logs `message` as a warning and records it in [`DiffuseGiWarnings`].
pub(crate) fn gi_warning(warnings: &mut DiffuseGiWarnings, message: String) {
    warn!("{message}");
    warnings.messages.push(message);
}

/// Registers a WGSL file of `shaders/` as a [`Shader`] asset (import libraries become importable by their
/// `#define_import_path`). Returns a default handle in apps without a renderer.
pub(crate) fn add_shader(app: &mut App, path: &'static str, source: &'static str) -> Handle<Shader> {
    let Some(mut shaders) = app.world_mut().get_resource_mut::<Assets<Shader>>() else {
        return Handle::default();
    };
    shaders.add(Shader::from_wgsl(source, format!("bevy_diffuse_gi/{path}")))
}
