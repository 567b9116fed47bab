//! The headless renderer: renders a standard scene with no window on whatever Vulkan device exists
//! (lavapipe in CI) and writes a linear float EXR plus a JSON sidecar.
//!
//! `cargo run --release --example headless -- --scene cornell --method reference --out out/c.exr`
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

use crate::hdr_image::HdrImage;
use crate::scene::SceneSnapshot;
use crate::scenes::{SceneCamera, SceneStatus, StandardScene, StandardScenesPlugin, spawn_standard_scene};

pub use options::{HeadlessMethod, HeadlessOptions, USAGE, parse_args};

/// Frames to wait for a glTF scene to load before giving up.
const MAX_LOADING_FRAMES: u32 = 2000;
/// Frames rendered after the scene is ready and before `--frames` starts counting. Bevy needs about three
/// to upload meshes, specialise pipelines and get a frame through pipelined rendering; the first frames
/// come out black on lavapipe without this.
pub const WARM_UP_FRAMES: u32 = 5;

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
    WaitingForScene,
    Rendering,
    ReadingBack,
    Done,
}

#[derive(Resource)]
struct Headless {
    options: HeadlessOptions,
    target: Handle<Image>,
    outcome: Arc<Mutex<Outcome>>,
    phase: Phase,
    frames_waited: u32,
    frames_rendered: u32,
    render_start: Option<Instant>,
    readback_start: Option<Instant>,
}

/// Renders as `options` say and returns the images and the sidecar, without writing anything.
pub fn run(options: &HeadlessOptions) -> Result<HeadlessReport, String> {
    let outcome = Arc::new(Mutex::new(Outcome::default()));
    let started = Instant::now();
    let mut app = build_app(options, outcome.clone());
    app.run();
    drop(app);
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
            crate::DiffuseGiPlugin,
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
    app.insert_resource(Headless {
        options: options.clone(),
        target,
        outcome,
        phase: Phase::WaitingForScene,
        frames_waited: 0,
        frames_rendered: 0,
        render_start: None,
        readback_start: None,
    })
    .add_systems(Startup, setup)
    .add_systems(Update, (attach_camera, drive).chain());
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
fn attach_camera(mut commands: Commands, headless: Res<Headless>, cameras: Query<Entity, Added<SceneCamera>>) {
    for entity in &cameras {
        commands.entity(entity).insert((
            RenderTarget::Image(headless.target.clone().into()),
            Hdr,
            Tonemapping::None,
            DebandDither::Disabled,
            Msaa::Off,
            DepthPrepass,
            DeferredPrepass,
        ));
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
) {
    let fail = |headless: &Headless, exit: &mut MessageWriter<AppExit>, message: String| {
        headless.outcome.lock().expect("outcome lock").error = Some(message);
        exit.write(AppExit::error());
    };
    match headless.phase {
        Phase::WaitingForScene => match &*status {
            SceneStatus::Ready if !cameras.is_empty() => {
                headless.phase = Phase::Rendering;
                headless.render_start = Some(Instant::now());
            }
            SceneStatus::Failed(message) => {
                fail(&headless, &mut exit, message.clone());
                headless.phase = Phase::Done;
            }
            _ => {
                headless.frames_waited += 1;
                if headless.frames_waited > MAX_LOADING_FRAMES {
                    let message = format!(
                        "scene {} did not finish loading within {MAX_LOADING_FRAMES} frames",
                        headless.options.scene.name()
                    );
                    fail(&headless, &mut exit, message);
                    headless.phase = Phase::Done;
                }
            }
        },
        Phase::Rendering => {
            headless.frames_rendered += 1;
            let Ok((transform, projection, exposure)) = cameras.single() else {
                fail(&headless, &mut exit, "the scene has no camera to render through".into());
                headless.phase = Phase::Done;
                return;
            };
            let exposure = exposure.copied().unwrap_or_default();
            if headless.options.method == HeadlessMethod::Reference {
                // Two frames let the snapshot and the camera's projection catch up with the spawned scene.
                if headless.frames_rendered < 2 {
                    return;
                }
                let result = trace_reference(&headless.options, snapshot.as_deref(), transform, projection, &exposure);
                match result {
                    Ok((image, extras, settings)) => {
                        let mut outcome = headless.outcome.lock().expect("outcome lock");
                        outcome.image = Some(image);
                        outcome.extra_images = extras;
                        outcome.sidecar = sidecar(&headless, &exposure, &lights, &diagnostics, adapter.as_deref());
                        outcome.sidecar.insert("reference".into(), settings);
                    }
                    Err(message) => fail(&headless, &mut exit, message),
                }
                exit.write(AppExit::Success);
                headless.phase = Phase::Done;
                return;
            }
            if headless.frames_rendered >= WARM_UP_FRAMES + headless.options.frames {
                headless.phase = Phase::ReadingBack;
                headless.readback_start = Some(Instant::now());
                let outcome = headless.outcome.clone();
                let size = headless.options.size;
                let indirect_only = headless.options.indirect_only && headless.options.method == HeadlessMethod::None;
                commands.spawn(Readback::texture(headless.target.clone())).observe(
                    move |event: On<ReadbackComplete>, mut commands: Commands| {
                        let mut outcome = outcome.lock().expect("outcome lock");
                        if outcome.image.is_none() {
                            let mut image = decode_rgba32f(&event.data, size.x, size.y);
                            if indirect_only {
                                // Bevy's direct light adds no indirect light: keep only the coverage.
                                for p in &mut image.pixels {
                                    p[..3].fill(0.0);
                                }
                            }
                            outcome.image = Some(image);
                        }
                        commands.entity(event.entity).despawn();
                    },
                );
                let exposure_sidecar = sidecar(&headless, &exposure, &lights, &diagnostics, adapter.as_deref());
                headless.outcome.lock().expect("outcome lock").sidecar = exposure_sidecar;
            }
        }
        Phase::ReadingBack => {
            let done = headless.outcome.lock().expect("outcome lock").image.is_some();
            if done {
                let frames = headless.frames_rendered;
                let seconds = headless.render_start.map_or(0.0, |s| s.elapsed().as_secs_f64());
                let mut outcome = headless.outcome.lock().expect("outcome lock");
                // GPU spans arrive a frame or two late: read them now, at the end.
                outcome.sidecar.insert("gpu_ms".into(), gpu_timings(&diagnostics));
                outcome.sidecar.insert(
                    "wall_seconds".into(),
                    json!({ "frames": frames, "warm_up_frames": WARM_UP_FRAMES, "render": seconds,
                            "per_frame": seconds / frames.max(1) as f64 }),
                );
                drop(outcome);
                exit.write(AppExit::Success);
                headless.phase = Phase::Done;
            } else if headless.readback_start.is_some_and(|s| s.elapsed() > Duration::from_secs(120)) {
                fail(&headless, &mut exit, "the GPU readback did not complete within 120 s".into());
                headless.phase = Phase::Done;
            }
        }
        Phase::Done => {}
    }
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
) -> serde_json::Map<String, Value> {
    let o = &headless.options;
    let lights: Vec<Value> = lights
        .iter()
        .filter_map(|(name, transform, directional, point, spot)| {
            let name = name.map(|n| n.as_str().to_owned());
            let position = transform.translation().to_array();
            let direction = transform.forward().as_vec3().to_array();
            let rgb = |c: Color| c.to_linear().to_f32_array_no_alpha();
            if let Some(d) = directional {
                Some(json!({ "name": name, "kind": "directional", "illuminance_lux": d.illuminance,
                    "color_linear": rgb(d.color), "direction": direction, "shadows": d.shadow_maps_enabled }))
            } else if let Some(s) = spot {
                Some(json!({ "name": name, "kind": "spot", "intensity_lumens": s.intensity,
                    "intensity_candela": s.intensity / (4.0 * std::f32::consts::PI), "color_linear": rgb(s.color),
                    "position": position, "direction": direction, "range": s.range,
                    "inner_angle": s.inner_angle, "outer_angle": s.outer_angle, "shadows": s.shadow_maps_enabled }))
            } else {
                point.map(|p| json!({ "name": name, "kind": "point", "intensity_lumens": p.intensity,
                    "intensity_candela": p.intensity / (4.0 * std::f32::consts::PI), "color_linear": rgb(p.color),
                    "position": position, "range": p.range, "shadows": p.shadow_maps_enabled }))
            }
        })
        .collect();
    let mut map = serde_json::Map::new();
    map.insert("scene".into(), json!(o.scene.name()));
    map.insert("method".into(), json!(o.method.name()));
    map.insert("size".into(), json!([o.size.x, o.size.y]));
    map.insert("indirect_only".into(), json!(o.indirect_only));
    map.insert("frames".into(), json!(headless.frames_rendered));
    map.insert("options".into(), serde_json::to_value(o).unwrap_or(Value::Null));
    map.insert(
        "exposure".into(),
        json!({ "ev100": exposure.ev100, "multiplier": exposure.exposure() }),
    );
    map.insert("lights".into(), Value::Array(lights));
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
