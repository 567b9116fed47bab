//! The headless renderer: renders a standard scene with no window on whatever Vulkan device exists
//! (lavapipe in CI) and writes a linear float EXR plus a JSON sidecar.
//!
//! `cargo run --release --features tools --example headless -- --scene cornell --method reference --out out/c.exr`
//!
//! The EXR holds linear RGB *after* exposure and *before* tonemapping, and the pixel's geometry coverage in
//! alpha (`shared/METRICS.md`). GPU methods render through a camera with `Hdr`, `Tonemapping::None` and no
//! dithering into an `Rgba32Float` image that is read back after `--frames` frames. The path tracer
//! (`--method reference`) builds the [`SceneSnapshot`] from the same world and also writes its full,
//! direct-only and indirect-only images beside the main one (`FILE.full.exr`, `FILE.direct.exr`,
//! `FILE.indirect.exr`).
//!
//! The sidecar `FILE.json` records the scene, method, settings, the exposure multiplier, every light in
//! Bevy's units, the frame count, the per-pass GPU times where timestamp queries exist, and wall times.

mod options;
pub mod stress;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bevy::app::{ScheduleRunnerPlugin, TerminalCtrlCHandlerPlugin};
use bevy::asset::RenderAssetUsages;
use bevy::camera::{Exposure, Hdr, RenderTarget};
use bevy::core_pipeline::prepass::{DeferredPrepass, DepthPrepass};
use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::diagnostic::DiagnosticsStore;
use bevy::log::LogPlugin;
use bevy::pbr::DefaultOpaqueRendererMethod;
use bevy::prelude::*;
use bevy::render::diagnostic::RenderDiagnosticsPlugin;
use bevy::render::gpu_readback::{Readback, ReadbackComplete};
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat, TextureUsages};
use bevy::render::renderer::RenderAdapterInfo;
use bevy::render::RenderPlugin;
use bevy::window::ExitCondition;
use bevy::winit::WinitPlugin;
use serde_json::{Value, json};

use crate::camera::{DiffuseGi, GiDebugView, GiMethod};
use crate::hdr_image::HdrImage;
use crate::radiance_hints::RadianceHintsVolume;
use crate::scene::SceneSnapshot;
use crate::scenes::{SceneCamera, SceneStatus, StandardScene, StandardScenesPlugin, spawn_standard_scene};

pub use options::{HeadlessArgs, HeadlessCli, HeadlessMethod, HeadlessOptions, parse_args};

/// Frames to wait for a glTF scene to load before giving up.
const MAX_LOADING_FRAMES: u32 = 2000;
/// A fresh app draws nothing for a few frames (mesh uploads, pipeline specialisation, pipelined rendering;
/// more than ten for a glTF scene on lavapipe). `--frames` starts counting once the geometry coverage of
/// the read-back image has been the same, and not empty, for this many readbacks in a row...
pub const SETTLE_READBACKS: usize = 3;
/// ...or after this many frames, whichever comes first (a camera may legitimately see nothing).
pub const MAX_SETTLE_FRAMES: u32 = 600;
/// Longest wait, in seconds, for the CPU methods' background work on the still scene before the
/// measured frames begin.
pub const MAX_BACKGROUND_SECONDS: u64 = 600;

/// What one headless run produced.
#[derive(Clone, Debug)]
pub struct HeadlessReport {
    /// The image `--out` names: the full frame, or only the indirect light with `--indirect-only`.
    pub image: HdrImage,
    /// Extra images to write beside it, with the suffix of their file name (`"direct"` → `FILE.direct.exr`).
    pub extra_images: Vec<(&'static str, HdrImage)>,
    /// The JSON sidecar.
    pub sidecar: Value,
}

#[derive(Default)]
struct Outcome {
    error: Option<String>,
    image: Option<HdrImage>,
    extra_images: Vec<(&'static str, HdrImage)>,
    sidecar: serde_json::Map<String, Value>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Assets loading, the scene camera not yet there.
    WaitingForScene,
    /// GPU methods: frames read back until the geometry coverage stops changing.
    Settling,
    /// GPU methods: `--frames` frames after settling; the path tracer: two frames, then trace.
    Rendering,
    Done,
}

/// What the per-frame readback observer hands to the driver.
#[derive(Default)]
struct Frames {
    /// Readbacks completed so far.
    received: u32,
    /// The newest frame.
    latest: Option<HdrImage>,
    /// The frame before it.
    previous: Option<HdrImage>,
    /// Covered pixel counts of the newest readbacks.
    coverage: Vec<usize>,
    /// Readbacks that contained a NaN or an infinity.
    non_finite: u32,
}

/// Where the headless renderer stands, for systems added through [`run_with`].
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HeadlessClock {
    /// Whether the measured frames have begun (the scene shows and has settled).
    pub rendering: bool,
    /// Frames since rendering began.
    pub frame: u32,
}

#[derive(Resource)]
struct Headless {
    options: HeadlessOptions,
    target: Handle<Image>,
    outcome: Arc<Mutex<Outcome>>,
    frames: Arc<Mutex<Frames>>,
    phase: Phase,
    /// Frames spent in the current phase.
    phase_frames: u32,
    /// Readbacks received when `Rendering` began.
    receipts_at_render: u32,
    render_start: Option<Instant>,
    /// When each frame of the `Rendering` phase began (GPU methods): the frame-time measurements.
    frame_starts: Vec<Instant>,
    /// The Radiance Hints settings of the spawned volume, and its transform.
    spawned_rh: Option<(RadianceHintsVolume, Transform)>,
    /// Main-thread milliseconds of the plugin's CPU work, per rendered frame.
    main_thread_ms: Vec<f32>,
    /// `wait_background`: frames in a row with no background work, and frames rendered after the
    /// `frames` while it caught up.
    background_idle: u32,
    background_wait_frames: u32,
    background_timed_out: bool,
    /// [`HeadlessOptions::scene_scale`]: frames since the scene was scaled (0 before), so that what reads
    /// `GlobalTransform`s waits until the scale has propagated.
    scaled_frames: u32,
}

/// Renders as `options` say and returns the images and the sidecar, without writing anything.
pub fn run(options: &HeadlessOptions) -> Result<HeadlessReport, String> {
    run_with(options, |_| {})
}

/// [`run`] with `customise` applied to the app before it starts: tests and benchmarks add systems that
/// change the world while it renders (reading [`HeadlessClock`] to know when).
pub fn run_with(options: &HeadlessOptions, customise: impl FnOnce(&mut App)) -> Result<HeadlessReport, String> {
    let outcome = Arc::new(Mutex::new(Outcome::default()));
    let started = Instant::now();
    let mut app = build_app(options, outcome.clone());
    customise(&mut app);
    let frames = app.world().resource::<Headless>().frames.clone();
    // `App::run` moves the app out: keep what is read afterwards.
    let pipeline_errors = app.world().get_resource::<crate::GiPipelineErrors>().cloned();
    app.run();
    let non_finite = frames.lock().map_or(0, |f| f.non_finite);
    if non_finite > 0 {
        return Err(format!("{non_finite} frames read back contained NaN or infinite values"));
    }
    let broken = pipeline_errors.map(|e| e.messages()).unwrap_or_default();
    drop(app);
    if !broken.is_empty() {
        return Err(broken.join("\n"));
    }
    let mut outcome = std::mem::take(&mut *outcome.lock().map_err(|_| "the render thread panicked")?);
    if let Some(error) = outcome.error {
        return Err(error);
    }
    let image = outcome.image.take().ok_or("the renderer stopped without producing an image")?;
    if image.has_non_finite() {
        return Err("the image contains NaN or infinite values".into());
    }
    outcome
        .sidecar
        .insert("wall_seconds_total".into(), json!(started.elapsed().as_secs_f64()));
    Ok(HeadlessReport {
        image,
        extra_images: outcome.extra_images,
        sidecar: Value::Object(outcome.sidecar),
    })
}

/// [`run`], then writes `options.out`, its extra images and the sidecar `FILE.json`.
pub fn run_and_write(options: &HeadlessOptions) -> Result<HeadlessReport, String> {
    let mut report = run(options)?;
    let mut outputs = serde_json::Map::new();
    report.image.write_exr(&options.out).map_err(|e| e.to_string())?;
    outputs.insert("image".into(), json!(options.out));
    for (suffix, image) in &report.extra_images {
        let path = sibling(&options.out, suffix, "exr");
        image.write_exr(&path).map_err(|e| e.to_string())?;
        outputs.insert((*suffix).into(), json!(path));
    }
    if let Value::Object(map) = &mut report.sidecar {
        map.insert("outputs".into(), Value::Object(outputs));
    }
    let json_path = options.out.with_extension("json");
    let text = serde_json::to_string_pretty(&report.sidecar).map_err(|e| e.to_string())?;
    std::fs::write(&json_path, text).map_err(|e| format!("{}: {e}", json_path.display()))?;
    Ok(report)
}

/// `dir/name.exr` → `dir/name.suffix.ext`.
pub fn sibling(path: &Path, suffix: &str, ext: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!("{stem}.{suffix}.{ext}"))
}

/// Log and Ctrl-C handlers are process-global: only the first app of a process may install them.
static GLOBAL_PLUGINS_TAKEN: AtomicBool = AtomicBool::new(false);

fn build_app(options: &HeadlessOptions, outcome: Arc<Mutex<Outcome>>) -> App {
    let asset_root = match &options.scene {
        StandardScene::Gltf(path) => std::path::absolute(path)
            .ok()
            .and_then(|p| p.parent().map(Path::to_path_buf))
            .unwrap_or_else(|| PathBuf::from(".")),
        _ => PathBuf::from("assets"),
    };
    let mut plugins = DefaultPlugins
        .set(WindowPlugin {
            primary_window: None,
            exit_condition: ExitCondition::DontExit,
            close_when_requested: false,
            ..default()
        })
        .set(RenderPlugin {
            synchronous_pipeline_compilation: true,
            ..default()
        })
        .set(AssetPlugin {
            file_path: asset_root.to_string_lossy().into_owned(),
            ..default()
        })
        .disable::<WinitPlugin>()
        .disable::<TerminalCtrlCHandlerPlugin>();
    if GLOBAL_PLUGINS_TAKEN.swap(true, Ordering::SeqCst) {
        plugins = plugins.disable::<LogPlugin>();
    }

    let mut app = App::new();
    app.add_plugins(plugins)
        .add_plugins((
            ScheduleRunnerPlugin::run_loop(Duration::ZERO),
            RenderDiagnosticsPlugin,
            crate::DiffuseGiPlugin::default(),
            StandardScenesPlugin,
        ))
        .insert_resource(DefaultOpaqueRendererMethod::deferred())
        .insert_resource(ClearColor(Color::NONE));

    let mut image = Image::new_fill(
        Extent3d {
            width: options.size.x,
            height: options.size.y,
            depth_or_array_layers: 1,
        },
        TextureDimension::D2,
        &[0u8; 16],
        TextureFormat::Rgba32Float,
        RenderAssetUsages::default(),
    );
    image.texture_descriptor.usage |=
        TextureUsages::COPY_SRC | TextureUsages::RENDER_ATTACHMENT | TextureUsages::TEXTURE_BINDING;
    let target = app.world_mut().resource_mut::<Assets<Image>>().add(image);

    if options.method == HeadlessMethod::Reference {
        app.init_resource::<SceneSnapshot>();
    }
    if options.scene == StandardScene::Dynamic {
        // Paused until rendering begins, so the captured pose does not depend on how long loading took.
        app.insert_resource(crate::scenes::DynamicScene {
            frame: options.pose_frame,
            animate_light: options.animate_light,
            moving_meshes: options.animate_meshes as usize,
            stop_at: options.stop_animation_at,
            extra_triangles: options.extra_triangles,
            paused: true,
        });
    }
    if let Some(path) = &options.dump_volume {
        app.insert_resource(crate::radiance_hints::dump::RhVolumeDump { path: path.clone() });
    }
    app.insert_resource(Headless {
        options: options.clone(),
        target,
        outcome,
        frames: Arc::default(),
        phase: Phase::WaitingForScene,
        phase_frames: 0,
        receipts_at_render: 0,
        render_start: None,
        frame_starts: Vec::new(),
        spawned_rh: None,
        main_thread_ms: Vec::new(),
        background_idle: 0,
        background_wait_frames: 0,
        background_timed_out: false,
        scaled_frames: 0,
    })
    .add_systems(Startup, setup)
    .add_systems(Update, (attach_camera, spawn_rh_volume, animate_lights, switch_method, drive).chain())
    .init_resource::<HeadlessClock>()
    .add_systems(Last, (track_dynamic_scene, scale_scene));
    app
}

fn setup(
    mut commands: Commands,
    headless: Res<Headless>,
    asset_server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    let scene = match &headless.options.scene {
        // The asset root is the file's folder (see `build_app`): load it by name.
        StandardScene::Gltf(path) => StandardScene::Gltf(PathBuf::from(path.file_name().unwrap_or_default())),
        other => other.clone(),
    };
    spawn_standard_scene(
        &mut commands,
        &asset_server,
        &mut meshes,
        &mut materials,
        &scene,
        headless.options.ev100,
    );
}

/// Gives the scene's camera the headless render target and what the measurements need.
fn attach_camera(
    mut commands: Commands,
    headless: Res<Headless>,
    mut cameras: Query<(Entity, &mut Projection), Added<SceneCamera>>,
) {
    for (entity, mut projection) in &mut cameras {
        // Bevy recomputes a camera's target size only when the camera is new, its projection changes or
        // its target image changes, not when the `RenderTarget` component is replaced. A glTF camera has
        // already been seen with its default (window) target, so flag the projection to force it.
        projection.set_changed();
        commands.entity(entity).insert((
            RenderTarget::Image(headless.target.clone().into()),
            Hdr,
            Tonemapping::None,
            DebandDither::Disabled,
            Msaa::Off,
            DepthPrepass,
            DeferredPrepass,
        ));
        if let Some(method) = headless.options.method.gi() {
            let o = &headless.options;
            commands.entity(entity).insert(DiffuseGi {
                method,
                debug_view: o.debug_view.unwrap_or(if o.indirect_only { GiDebugView::IndirectOnly } else { GiDebugView::None }),
                half_resolution: o.half_resolution,
                output: o.gi_output,
                ..default()
            });
            // Every method's settings: a camera uses only its method's (and `--switch-method` finds them).
            commands.entity(entity).insert((o.vpl.clone(), o.rsm_gather.clone(), o.drm.clone(), o.radiosity.clone(), o.photon_grid.clone()));
            if let Some((levels, extent)) = o.rh_cascade {
                let rh = RadianceHintsVolume { sizing: crate::radiance_hints::GridSizing::Fixed, ..o.rh.clone() };
                let defaults = crate::radiance_hints::RadianceHintsCascade::default();
                commands.entity(entity).insert(crate::radiance_hints::RadianceHintsCascade {
                    levels,
                    extent,
                    settings: RadianceHintsVolume {
                        resolution: if o.rh_fit_cells { defaults.settings.resolution } else { o.rh.resolution },
                        ..rh
                    },
                    ..defaults
                });
            }
        }
    }
}

/// `--method rh`: once the scene's meshes have bounds, spawns a Radiance Hints volume around them.
fn spawn_rh_volume(
    mut commands: Commands,
    mut headless: ResMut<Headless>,
    status: Res<SceneStatus>,
    volumes: Query<(), With<RadianceHintsVolume>>,
    meshes: Query<(&bevy::camera::primitives::Aabb, &GlobalTransform), With<Mesh3d>>,
) {
    let uses_rh = headless.options.method == HeadlessMethod::Gi(GiMethod::RadianceHints)
        || headless.options.switch_method.is_some_and(|(_, m)| m == GiMethod::RadianceHints);
    if !uses_rh || headless.options.rh_cascade.is_some() || *status != SceneStatus::Ready || !volumes.is_empty() || !scale_propagated(&headless) {
        return;
    }
    let Some((lo, hi)) = crate::scenes::mesh_bounds(meshes) else {
        return;
    };
    // A hair larger than the geometry, and never flat.
    let size = ((hi - lo) * 1.002).max(Vec3::splat(0.05));
    let fixed = headless.options.rh.sizing == crate::radiance_hints::GridSizing::Fixed;
    let settings = if headless.options.rh_fit_cells && fixed {
        headless.options.rh.clone().with_cubic_cells(size)
    } else {
        headless.options.rh.clone()
    };
    let transform = Transform::from_translation((lo + hi) * 0.5).with_scale(size);
    headless.spawned_rh = Some((settings.clone(), transform));
    commands.spawn((settings, transform, Name::new("headless RH volume")));
}

/// [`HeadlessOptions::scene_scale`]: scales the scene once, at the end of the frame it is ready; the Radiance
/// Hints volume is fitted around it once the scale has propagated ([`scale_propagated`]).
fn scale_scene(world: &mut World) {
    let headless = world.resource::<Headless>();
    let scale = scene_scale(&headless.options);
    if headless.scaled_frames > 0 {
        world.resource_mut::<Headless>().scaled_frames += 1;
        return;
    }
    if scale == 1.0 || world.get_resource::<SceneStatus>() != Some(&SceneStatus::Ready) {
        return;
    }
    if scale != headless.options.scene_scale {
        warn!("headless: scene_scale {} is outside 1e-4..=1e6, using {scale}", headless.options.scene_scale);
    }
    scale_world(world, scale);
    world.resource_mut::<Headless>().scaled_frames = 1;
}

/// [`HeadlessOptions::scene_scale`] clamped to its range (1 for a non-finite value).
fn scene_scale(options: &HeadlessOptions) -> f32 {
    let s = options.scene_scale;
    if s.is_finite() { s.clamp(1e-4, 1e6) } else { 1.0 }
}

/// Whether the scene's `GlobalTransform`s are those of its final scale (propagated in the `PostUpdate`
/// after [`scale_scene`] ran in `Last`).
fn scale_propagated(headless: &Headless) -> bool {
    scene_scale(&headless.options) == 1.0 || headless.scaled_frames >= 2
}

/// Scales every root entity's place and size by `s`, and the lights' ranges and shadow near planes and the
/// scene camera's planes with it: the same scene in other units.
pub(crate) fn scale_world(world: &mut World, s: f32) {
    let mut roots = world.query_filtered::<&mut Transform, Without<ChildOf>>();
    for mut transform in roots.iter_mut(world) {
        transform.translation *= s;
        transform.scale *= s;
    }
    // The camera keeps its size (its scale would scale its view): only its place moves.
    let mut cameras = world.query_filtered::<(&mut Transform, &mut Projection), With<crate::scenes::SceneCamera>>();
    for (mut transform, mut projection) in cameras.iter_mut(world) {
        transform.scale = Vec3::ONE;
        if let Projection::Perspective(p) = &mut *projection {
            p.near *= s;
            p.far *= s;
        }
    }
    for mut spot in world.query::<&mut SpotLight>().iter_mut(world) {
        spot.range *= s;
        spot.radius *= s;
        spot.shadow_map_near_z *= s;
    }
    for mut point in world.query::<&mut PointLight>().iter_mut(world) {
        point.range *= s;
        point.radius *= s;
        point.shadow_map_near_z *= s;
    }
    // Lights keep a unit scale too (their scale scales nothing but their children).
    let mut lights = world.query_filtered::<&mut Transform, Or<(With<SpotLight>, With<PointLight>, With<DirectionalLight>)>>();
    for mut transform in lights.iter_mut(world) {
        transform.scale = Vec3::ONE;
    }
}

#[expect(clippy::too_many_arguments, reason = "the driver reads every part of the world it reports on")]
fn drive(
    mut commands: Commands,
    mut headless: ResMut<Headless>,
    status: Res<SceneStatus>,
    mut exit: MessageWriter<AppExit>,
    snapshot: Option<Res<SceneSnapshot>>,
    cameras: Query<(&GlobalTransform, &Projection, Option<&Exposure>), With<SceneCamera>>,
    lights: Query<LightRow>,
    diagnostics: Res<DiagnosticsStore>,
    adapter: Option<Res<RenderAdapterInfo>>,
    dynamic: Option<Res<crate::scenes::DynamicScene>>,
    snapshot_timings: Res<crate::scene::SnapshotTimings>,
    radiosity: Res<crate::radiosity::RadiosityActivity>,
    photon_grid: Res<crate::photon_grid::PhotonGridActivity>,
    (vpls, methods): (Res<crate::vpl::VplSet>, Res<crate::method::GiMethodStatus>),
    (device, warnings, rh_volumes): (
        Option<Res<bevy::render::renderer::RenderDevice>>,
        Option<Res<crate::DiffuseGiWarnings>>,
        Query<(&GlobalTransform, Option<&crate::radiance_hints::RhMeanChord>), With<RadianceHintsVolume>>,
    ),
) {
    // The volume as it runs now (a scene scaled after it spawned moved and resized it).
    let rh_live = rh_volumes.iter().next().map(|(t, c)| (t.compute_transform(), c.and_then(|c| c.metres)));
    let finish = |headless: &mut Headless, exit: &mut MessageWriter<AppExit>, error: Option<String>| {
        let failed = error.is_some();
        headless.outcome.lock().expect("outcome lock").error = error;
        exit.write(if failed { AppExit::error() } else { AppExit::Success });
        headless.phase = Phase::Done;
    };
    headless.phase_frames += 1;
    let is_reference = headless.options.method == HeadlessMethod::Reference;
    match headless.phase {
        Phase::WaitingForScene => match &*status {
            SceneStatus::Ready if !cameras.is_empty() && scale_propagated(&headless) => {
                headless.phase = if is_reference { Phase::Rendering } else { Phase::Settling };
                headless.phase_frames = 0;
                headless.render_start = Some(Instant::now());
                if !is_reference {
                    spawn_readback(&mut commands, &headless);
                }
            }
            SceneStatus::Failed(message) => {
                let message = message.clone();
                finish(&mut headless, &mut exit, Some(message));
            }
            _ if headless.phase_frames > MAX_LOADING_FRAMES => {
                let message = format!(
                    "scene {} did not finish loading within {MAX_LOADING_FRAMES} frames",
                    headless.options.scene.name()
                );
                finish(&mut headless, &mut exit, Some(message));
            }
            _ => {}
        },
        Phase::Settling => {
            let frames = headless.frames.lock().expect("frames lock");
            let recent = &frames.coverage[frames.coverage.len().saturating_sub(SETTLE_READBACKS)..];
            let settled = recent.len() == SETTLE_READBACKS && recent[0] > 0 && recent.iter().all(|c| *c == recent[0]);
            let received = frames.received;
            drop(frames);
            // The CPU methods work in the background: a still frame is measured once their solution of
            // the scene as it is (still) has arrived and been blended in.
            let limit = headless.options.wait_background.map_or(MAX_BACKGROUND_SECONDS, |w| (w as u64).min(MAX_BACKGROUND_SECONDS));
            let waited = headless.render_start.is_some_and(|s| s.elapsed() > Duration::from_secs(limit));
            // Lights that move every frame (`--animate-light`) keep the background busy for good: the
            // frames are measured as they come. (The `dynamic` scene's motion waits until rendering.)
            let lights_move = headless.options.animate_light && headless.options.scene != StandardScene::Dynamic;
            let background_done = !methods.any_busy() || waited || lights_move;
            if (settled || headless.phase_frames > MAX_SETTLE_FRAMES) && background_done {
                headless.phase = Phase::Rendering;
                headless.phase_frames = 0;
                headless.receipts_at_render = received;
            }
        }
        Phase::Rendering => {
            let Ok((transform, projection, exposure)) = cameras.single() else {
                finish(&mut headless, &mut exit, Some("the scene has no camera to render through".into()));
                return;
            };
            let exposure = exposure.copied().unwrap_or_default();
            if is_reference {
                // Two frames let the snapshot and the camera's projection catch up with the spawned scene.
                if headless.phase_frames < 2 {
                    return;
                }
                // Every mesh, material and texture the scene uses must be in the snapshot before tracing.
                if snapshot_timings.waiting > 0 {
                    if headless.phase_frames > MAX_LOADING_FRAMES {
                        let message = format!(
                            "scene {}: {} meshes or textures did not load within {MAX_LOADING_FRAMES} frames",
                            headless.options.scene.name(),
                            snapshot_timings.waiting
                        );
                        finish(&mut headless, &mut exit, Some(message));
                    }
                    return;
                }
                let result = trace_reference(&headless.options, snapshot.as_deref(), transform, projection, &exposure);
                let error = match result {
                    Ok((image, extras, settings)) => {
                        let mut map = sidecar(&headless, &exposure, &lights, &diagnostics, adapter.as_deref(), dynamic.as_deref(), rh_live);
                        map.insert("reference".into(), settings);
                        let mut outcome = headless.outcome.lock().expect("outcome lock");
                        outcome.image = Some(image);
                        outcome.extra_images = extras;
                        outcome.sidecar = map;
                        None
                    }
                    Err(message) => Some(message),
                };
                finish(&mut headless, &mut exit, error);
                return;
            }
            headless.frame_starts.push(Instant::now());
            // With `wait_background`, the CPU methods' work must have caught up too, for as many
            // readbacks as a settled image needs.
            let background_busy = methods.any_busy();
            let received = headless.frames.lock().expect("frames lock").received;
            let counted = received >= headless.receipts_at_render + headless.options.frames;
            if let Some(limit) = headless.options.wait_background.filter(|_| counted) {
                headless.background_idle = if background_busy { 0 } else { headless.background_idle + 1 };
                let waited = headless.render_start.is_some_and(|s| s.elapsed() > Duration::from_secs(limit as u64));
                headless.background_timed_out = waited && background_busy;
                if headless.background_idle <= SETTLE_READBACKS as u32 && !waited {
                    headless.background_wait_frames += 1;
                    return;
                }
            }
            let mut frames = headless.frames.lock().expect("frames lock");
            if !counted {
                drop(frames);
                if headless.render_start.is_some_and(|s| s.elapsed() > Duration::from_secs(600)) {
                    finish(&mut headless, &mut exit, Some("rendering did not finish within 600 s".into()));
                }
                return;
            }
            let mut image = frames.latest.take().expect("a readback arrived");
            let previous = frames.previous.take();
            drop(frames);
            if headless.options.indirect_only && headless.options.method == HeadlessMethod::None {
                // Bevy's direct light adds no indirect light: keep only the coverage.
                for p in &mut image.pixels {
                    p[..3].fill(0.0);
                }
            }
            let frames = headless.phase_frames;
            let seconds = headless.render_start.map_or(0.0, |s| s.elapsed().as_secs_f64());
            let mut map = sidecar(&headless, &exposure, &lights, &diagnostics, adapter.as_deref(), dynamic.as_deref(), rh_live);
            map.insert(
                "wall_seconds".into(),
                json!({ "frames_after_settling": frames, "render_including_settling": seconds,
                        "per_frame": seconds / (frames + headless.receipts_at_render).max(1) as f64 }),
            );
            // Main-world frame intervals while rendering: the frame time in a steady state, readback included.
            let intervals: Vec<f64> =
                headless.frame_starts.windows(2).map(|w| (w[1] - w[0]).as_secs_f64() * 1e3).collect();
            map.insert("frame_ms".into(), json!(intervals));
            map.insert("main_thread_ms".into(), json!(headless.main_thread_ms));
            // Every live GPU allocation, each counted once (the allocator's own report; `null` where the
            // backend keeps none): a method's memory is this minus the same frame's without GI.
            let allocated = device.as_ref().and_then(|d| d.wgpu_device().generate_allocator_report());
            map.insert("gpu_allocated_bytes".into(), json!(allocated.map(|r| r.total_allocated_bytes)));
            map.insert("warnings".into(), json!(warnings.as_ref().map_or(Vec::new(), |w| w.messages.clone())));
            if headless.options.wait_background.is_some() {
                map.insert("background_wait_frames".into(), json!(headless.background_wait_frames));
                map.insert("background_timed_out".into(), json!(headless.background_timed_out));
            }
            if headless.options.method == HeadlessMethod::Gi(crate::camera::GiMethod::Radiosity) {
                let t = &radiosity.times;
                map.insert(
                    "radiosity".into(),
                    json!({ "elements": radiosity.elements, "nodes": radiosity.nodes, "links": t.links,
                            "leaves_pushed": t.leaves_pushed, "leaves_updated": t.leaves_updated, "kept_bins_relinked": t.kept_bins_relinked,
                            "over_budget_mib": radiosity.over_budget_mib, "last_work": format!("{:?}", radiosity.last),
                            "solves": radiosity.solves, "kept_links_derived": radiosity.kept_links_derived,
                            "kept_links_made": radiosity.kept_links_made, "superseded": radiosity.superseded,
                            "bounces_run": t.bounces_run, "busy": radiosity.busy,
                            "update_elements_ms": t.update_elements_ms, "create_links_ms": t.create_links_ms,
                            "refine_push_ms": t.refine_push_ms, "illumination_ms": t.illumination_ms }),
                );
            }
            if headless.options.method == HeadlessMethod::Gi(crate::camera::GiMethod::Vpl) {
                map.insert(
                    "vpl".into(),
                    json!({ "vpls": vpls.vpls.len(), "points": vpls.points.len(), "busy": vpls.busy,
                            "last_walk_ms": vpls.last_walk_ms, "paths_walked": vpls.last_redone.paths,
                            "paths": vpls.last_redone.paths_total, "texels_traced": vpls.last_redone.texels,
                            "texels": vpls.last_redone.texels_total }),
                );
            }
            if headless.options.method == HeadlessMethod::Gi(crate::camera::GiMethod::PhotonGrid) {
                let (a, t) = (&*photon_grid, &photon_grid.times);
                map.insert(
                    "photon_grid".into(),
                    json!({ "dims": [a.dims.x, a.dims.y, a.dims.z], "boundary_sh_cells": a.boundary_sh_cells,
                            "boundary_v_cells": a.boundary_v_cells, "probes": a.probes, "probes_inside": a.inside,
                            "photons_stored": a.photons, "paths": a.stats.paths, "updates": a.updates, "busy": a.busy,
                            "voxelize_ms": t.voxelize_ms, "trace_ms": t.trace_ms, "rgrid_ms": t.rgrid_ms,
                            "field_ms": t.field_ms, "paths_traced": a.paths_traced, "rays": a.rays, "rays_marched": a.rays_marched, "kept_bytes": a.kept_bytes, "field_on_gpu": a.field_on_gpu }),
                );
            }
            let mut outcome = headless.outcome.lock().expect("outcome lock");
            if let Some(mut previous) = previous.filter(|p| p.width == image.width && p.height == image.height) {
                if headless.options.indirect_only && headless.options.method == HeadlessMethod::None {
                    for p in &mut previous.pixels {
                        p[..3].fill(0.0);
                    }
                }
                // The frame before the kept one: frame-to-frame stability.
                outcome.extra_images.push(("previous", previous));
            }
            outcome.image = Some(image);
            outcome.sidecar = map;
            drop(outcome);
            finish(&mut headless, &mut exit, None);
        }
        Phase::Done => {}
    }
}

/// `--switch-method`: changes the camera's method once the given number of rendering frames has passed.
fn switch_method(
    mut commands: Commands,
    headless: Res<Headless>,
    mut cameras: Query<(Entity, &mut DiffuseGi), With<SceneCamera>>,
) {
    let Some((after, method)) = headless.options.switch_method else {
        return;
    };
    if headless.phase != Phase::Rendering || headless.phase_frames + 1 != after {
        return;
    }
    for (entity, mut gi) in &mut cameras {
        gi.method = method;
        let o = &headless.options;
        commands.entity(entity).insert((o.vpl.clone(), o.rsm_gather.clone(), o.drm.clone(), o.radiosity.clone(), o.photon_grid.clone()));
    }
}

/// `--animate-light`: moves every GI light on a 2 cm circle around where it was spawned, one step per
/// frame, so the light's RSM and the GI volume are recomputed every frame as for a moving light. A
/// directional light's position means nothing, so a sun's direction wobbles by half a degree instead
/// (moving it only, the benchmark's "moving sun" changed nothing and timed the volume's first updates).
fn animate_lights(
    headless: Res<Headless>,
    mut lights: Query<(Entity, &mut Transform, Has<DirectionalLight>), With<crate::light::GiLight>>,
    mut origins: Local<std::collections::HashMap<Entity, Transform>>,
    mut step: Local<u32>,
) {
    if !headless.options.animate_light || headless.options.scene == StandardScene::Dynamic {
        return;
    }
    *step += 1;
    let angle = *step as f32 * 0.7;
    let (cos, sin) = (angle.cos(), angle.sin());
    for (entity, mut transform, directional) in &mut lights {
        let origin = *origins.entry(entity).or_insert(*transform);
        if directional {
            let tilt = 0.5_f32.to_radians();
            transform.rotation = origin.rotation * Quat::from_rotation_x(tilt * cos) * Quat::from_rotation_y(tilt * sin);
        } else {
            transform.translation = origin.translation + 0.01 * Vec3::new(cos, 0.0, sin);
        }
    }
}

/// Reads the render target back every frame into `headless.frames`.
fn spawn_readback(commands: &mut Commands, headless: &Headless) {
    let frames = headless.frames.clone();
    let size = headless.options.size;
    commands
        .spawn(Readback::texture(headless.target.clone()))
        .observe(move |event: On<ReadbackComplete>| {
            let image = decode_rgba32f(&event.data, size.x, size.y);
            let covered = image.pixels.iter().filter(|p| p[3] > 0.5).count();
            let mut frames = frames.lock().expect("frames lock");
            frames.received += 1;
            if image.has_non_finite() {
                frames.non_finite += 1;
            }
            frames.coverage.push(covered);
            frames.previous = frames.latest.replace(image);
        });
}

/// Decodes a padded `Rgba32Float` texture readback.
fn decode_rgba32f(data: &[u8], width: u32, height: u32) -> HdrImage {
    let row_bytes = width as usize * 16;
    let padded = data.len() / height.max(1) as usize;
    let mut image = HdrImage::new(width, height);
    for y in 0..height as usize {
        let row = &data[y * padded..y * padded + row_bytes];
        for (x, px) in row.chunks_exact(16).enumerate() {
            let f = |i: usize| f32::from_le_bytes(px[i * 4..i * 4 + 4].try_into().expect("4 bytes"));
            let value = [f(0), f(1), f(2), f(3)];
            // Coverage is binary for the GPU path: alpha is 1 on geometry, 0 on the cleared background.
            image.set(x as u32, y as u32, [value[0], value[1], value[2], if value[3] > 0.5 { 1.0 } else { 0.0 }]);
        }
    }
    image
}

/// `render/<path>/elapsed_gpu` averages, in milliseconds, keyed by `<path>`.
fn gpu_timings(diagnostics: &DiagnosticsStore) -> Value {
    let mut map = serde_json::Map::new();
    for d in diagnostics.iter() {
        let path = d.path().as_str();
        if let Some(pass) = path.strip_prefix("render/").and_then(|p| p.strip_suffix("/elapsed_gpu"))
            && let Some(ms) = d.average()
        {
            map.insert(pass.to_string(), json!(ms));
        }
    }
    Value::Object(map)
}

type LightRow<'a> = (
    Option<&'a Name>,
    Has<crate::light::GiLight>,
    &'a GlobalTransform,
    Option<&'a DirectionalLight>,
    Option<&'a PointLight>,
    Option<&'a SpotLight>,
);

fn sidecar(
    headless: &Headless,
    exposure: &Exposure,
    lights: &Query<LightRow>,
    diagnostics: &DiagnosticsStore,
    adapter: Option<&RenderAdapterInfo>,
    dynamic: Option<&crate::scenes::DynamicScene>,
    rh_live: Option<(Transform, Option<f32>)>,
) -> serde_json::Map<String, Value> {
    let o = &headless.options;
    let lights: Vec<Value> = lights
        .iter()
        .filter_map(|(name, gi, transform, directional, point, spot)| {
            let name = name.map(|n| n.as_str().to_owned());
            let position = transform.translation().to_array();
            let direction = transform.forward().as_vec3().to_array();
            let rgb = |c: Color| c.to_linear().to_f32_array_no_alpha();
            if let Some(d) = directional {
                Some(json!({ "name": name, "kind": "directional", "illuminance_lux": d.illuminance,
                    "color_linear": rgb(d.color), "direction": direction, "shadows": d.shadow_maps_enabled,
                    "gi_light": gi }))
            } else if let Some(s) = spot {
                Some(json!({ "name": name, "kind": "spot", "intensity_lumens": s.intensity,
                    "intensity_candela": s.intensity / (4.0 * std::f32::consts::PI), "color_linear": rgb(s.color),
                    "position": position, "direction": direction, "range": s.range,
                    "inner_angle": s.inner_angle, "outer_angle": s.outer_angle, "shadows": s.shadow_maps_enabled,
                    "gi_light": gi }))
            } else {
                point.map(|p| json!({ "name": name, "kind": "point", "intensity_lumens": p.intensity,
                    "intensity_candela": p.intensity / (4.0 * std::f32::consts::PI), "color_linear": rgb(p.color),
                    "position": position, "range": p.range, "shadows": p.shadow_maps_enabled, "gi_light": gi }))
            }
        })
        .collect();
    let mut map = serde_json::Map::new();
    map.insert("scene".into(), json!(o.scene.name()));
    map.insert("method".into(), json!(o.method.name()));
    map.insert("size".into(), json!([o.size.x, o.size.y]));
    map.insert("indirect_only".into(), json!(o.indirect_only));
    map.insert("frames".into(), json!(headless.phase_frames));
    map.insert("options".into(), serde_json::to_value(o).unwrap_or(Value::Null));
    map.insert(
        "exposure".into(),
        json!({ "ev100": exposure.ev100, "multiplier": exposure.exposure() }),
    );
    map.insert("lights".into(), Value::Array(lights));
    if let Some(scene) = dynamic {
        map.insert("dynamic_pose_frame".into(), json!(scene.frame));
    }
    if let Some((rh, spawned)) = &headless.spawned_rh {
        let (transform, mean_chord) = rh_live.unwrap_or((*spawned, None));
        let rh = rh.effective(transform.to_matrix(), mean_chord);
        map.insert(
            "radiance_hints".into(),
            json!({
                "resolution": rh.resolution.to_array(), "sh_order": rh.sh_order.bands(),
                "rsm_samples": rh.rsm_samples, "rsm_coverage": rh.rsm_coverage, "jitter": rh.jitter,
                "extra_bounces": rh.extra_bounces, "secondary_samples": rh.secondary_samples, "r_max": rh.r_max,
                "bounce_threshold": rh.bounce_threshold, "temporal_blend": rh.temporal_blend,
                "albedo_volume": rh.albedo_volume,
                "depth_occlusion": rh.depth_occlusion.map(|d| json!({"samples": d.samples, "strength": d.strength})),
                "reconstruction_samples": rh.reconstruction_samples, "reconstruction_reach": rh.reconstruction_reach, "intensity": rh.intensity,
                "memory_bytes": rh.memory_bytes(), "half_resolution": o.half_resolution,
                "output": format!("{:?}", o.gi_output),
                "secondary": format!("{:?}", rh.secondary), "voxel_visibility": rh.voxel_visibility,
                "refinement_updates": rh.refinement_updates, "motion_bounce_period": rh.motion_bounce_period, "motion_hints_per_update": rh.motion_hints_per_update,
                "volume_center": transform.translation.to_array(), "volume_size": transform.scale.to_array(),
                "mean_chord": mean_chord,
            }),
        );
    }
    map.insert("gpu_ms".into(), gpu_timings(diagnostics));
    map.insert(
        "device".into(),
        json!(adapter.map(|a| format!("{} ({:?}, {:?})", a.name, a.device_type, a.backend))),
    );
    map
}

#[cfg(feature = "reference")]
fn trace_reference(
    options: &HeadlessOptions,
    snapshot: Option<&SceneSnapshot>,
    transform: &GlobalTransform,
    projection: &Projection,
    exposure: &Exposure,
) -> Result<(HdrImage, Vec<(&'static str, HdrImage)>, Value), String> {
    use crate::reference::{DiffuseModel, ReferenceCamera, ReferenceSettings, render};
    let snapshot = snapshot.ok_or("the scene snapshot is missing")?;
    if snapshot.triangle_count() == 0 {
        return Err(format!("scene {} has no triangles to trace", options.scene.name()));
    }
    let camera = ReferenceCamera::from_bevy(transform, projection, Some(exposure))
        .ok_or("the scene camera has a custom projection the path tracer cannot follow")?;
    let settings = ReferenceSettings {
        width: options.size.x,
        height: options.size.y,
        samples_per_pixel: options.spp,
        seed: options.seed,
        max_bounces: options.max_bounces,
        direct_model: if options.burley_direct { DiffuseModel::Burley } else { DiffuseModel::Lambert },
        pixel_centers: options.pixel_centers,
        ..default()
    };
    let images = render(snapshot, &camera, &settings);
    let main = if options.indirect_only { images.indirect.clone() } else { images.full.clone() };
    let info = json!({
        "settings": settings,
        "seconds": images.seconds,
        "dropped_samples": images.dropped_samples,
        "triangles": snapshot.triangle_count(),
        "threads": rayon::current_num_threads(),
    });
    Ok((
        main,
        vec![("full", images.full), ("direct", images.direct), ("indirect", images.indirect)],
        info,
    ))
}

#[cfg(not(feature = "reference"))]
fn trace_reference(
    _: &HeadlessOptions,
    _: Option<&SceneSnapshot>,
    _: &GlobalTransform,
    _: &Projection,
    _: &Exposure,
) -> Result<(HdrImage, Vec<(&'static str, HdrImage)>, Value), String> {
    Err("--method reference needs the `reference` feature".into())
}

/// Starts the `dynamic` scene's clock when rendering begins, and records the plugin's main-thread cost.
fn track_dynamic_scene(
    mut headless: ResMut<Headless>,
    scene: Option<ResMut<crate::scenes::DynamicScene>>,
    cost: Res<crate::MainThreadCost>,
    mut clock: ResMut<HeadlessClock>,
) {
    if headless.phase != Phase::Rendering {
        return;
    }
    *clock = HeadlessClock { rendering: true, frame: clock.frame + clock.rendering as u32 };
    if let Some(mut scene) = scene
        && scene.paused
    {
        scene.paused = false;
    }
    let ms = cost.total_ms();
    if ms > 1.0 {
        debug!("frame {}: the plugin's main-thread work took {ms:.2} ms: {:?}", clock.frame, *cost);
    }
    headless.main_thread_ms.push(ms);
}
