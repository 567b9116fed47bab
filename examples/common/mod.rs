//! What the examples share: the headless fallback of the windowed examples, and the command line, the
//! Markdown section replacement and the medians of the report examples.
#![allow(dead_code, reason = "each example uses a different subset")]

use std::path::{Path, PathBuf};

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport, run_and_write};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::metrics::ErrorMetrics;
use bevy_diffuse_gi::scenes::StandardScene;

/// No display: renders one 512² frame of `scene` with `method` headless on the first Vulkan device and
/// writes `out/{tool}.exr` and a tonemapped `out/{tool}.png`.
pub fn render_headless(tool: &str, scene: StandardScene, method: GiMethod) -> AppExit {
    let out = PathBuf::from(format!("out/{tool}.exr"));
    let options = HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(method),
        size: UVec2::new(512, 512),
        out: out.clone(),
        ..default()
    };
    println!("{tool}: no display found; rendering headless on the first Vulkan device");
    match run_and_write(&options) {
        Ok(report) => {
            let png = out.with_extension("png");
            if let Err(e) = report.image.write_png_tonemapped(&png, 1.0) {
                eprintln!("{tool}: {e}");
                return AppExit::error();
            }
            println!("{tool}: wrote {} (and {}, linear)", png.display(), out.display());
            AppExit::Success
        }
        Err(message) => {
            eprintln!("{tool}: {message}");
            AppExit::error()
        }
    }
}

/// The command line of a windowed example: the scene to show.
#[derive(clap::Parser)]
struct ExampleCli {
    /// cornell, cellar, sponza_like, dynamic, emissive_panel, open_field, near_light, or a glTF 2.0 file
    #[arg(long, value_name = "NAME|PATH.glb", default_value = "cornell", value_parser = StandardScene::parse)]
    scene: StandardScene,
}

/// The scene a windowed example `tool` is asked to show (`--scene`, default `default_scene`). `--help`
/// exits with status 0, bad input with clap's message and status 2.
pub fn example_scene(tool: &'static str, about: &'static str, default_scene: &'static str) -> StandardScene {
    use clap::{CommandFactory, FromArgMatches};
    let matches = ExampleCli::command()
        .name(tool)
        .about(about)
        .mut_arg("scene", |arg| arg.default_value(default_scene))
        .get_matches();
    ExampleCli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit()).scene
}

/// The command line of a report example.
pub struct ReportArgs {
    pub sections: Vec<String>,
    pub rounds: usize,
    pub docs: Option<PathBuf>,
}

/// `--rounds` when not given.
const DEFAULT_ROUNDS: usize = 3;

/// The flags every report example takes (clap derive).
#[derive(clap::Parser)]
struct ReportCli {
    /// A section to generate (repeat for several) [default: all]
    #[arg(long = "section", value_name = "NAME")]
    sections: Vec<String>,
    /// Rounds of the alternating timing runs, 1..=20
    #[arg(long, value_name = "N", default_value_t = DEFAULT_ROUNDS as u64, value_parser = clap::value_parser!(u64).range(1..=20))]
    rounds: u64,
    /// Also replace each section's table between its markers in this Markdown file
    #[arg(long, value_name = "FILE.md")]
    docs: Option<PathBuf>,
}

/// Parses `[--section NAME]... [--rounds N] [--docs FILE.md]` for the report `tool` whose sections are
/// `sections` (default: every one; 3 rounds). `--help` lists them and exits with status 0; bad input
/// prints clap's message and exits with status 2.
pub fn parse_report_args(tool: &'static str, sections: &[&'static str]) -> ReportArgs {
    use clap::{CommandFactory, FromArgMatches};
    let command = ReportCli::command()
        .name(tool)
        .about(format!("Measures and writes the tables of its docs page. Sections: {}.", sections.join(", ")))
        .mut_arg("sections", |arg| arg.value_parser(clap::builder::PossibleValuesParser::new(sections.to_vec())));
    let matches = command.get_matches();
    let cli = ReportCli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    ReportArgs {
        sections: if cli.sections.is_empty() { sections.iter().map(|s| s.to_string()).collect() } else { cli.sections },
        rounds: cli.rounds as usize,
        docs: cli.docs,
    }
}

/// The GI methods named in a `--methods` list (every method for an empty list).
pub fn gi_methods(names: &[String]) -> Result<Vec<GiMethod>, String> {
    if names.is_empty() {
        return Ok(GiMethod::ALL.to_vec());
    }
    names
        .iter()
        .map(|m| match HeadlessMethod::parse(m)? {
            HeadlessMethod::Gi(g) => Ok(g),
            _ => Err(format!("`{m}` is not a GI method")),
        })
        .collect()
}

/// The `main` of a report (or any tool) `tool`: status 0 when `run` succeeds, otherwise its message on
/// stderr and status 1.
pub fn report_main(tool: &str, run: impl FnOnce() -> Result<(), String>) -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("{tool}: {message}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// [`parse_report_args`], then `WGPU_BACKEND=vulkan` unless the caller chose a backend (lavapipe, whose
/// Vulkan driver every report's numbers come from). Call it first, before any render thread exists.
pub fn start_report(tool: &'static str, sections: &[&'static str]) -> ReportArgs {
    let args = parse_report_args(tool, sections);
    if std::env::var_os("WGPU_BACKEND").is_none() {
        // SAFETY: set before any render thread exists.
        unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    }
    args
}

/// Prints section `section`'s `table` of the report `tool` with the line that says how it was generated
/// (the command, `--rounds` where not the default, the device, the time since `started`), and with
/// `--docs` writes it between the section's markers.
pub fn publish_section(
    tool: &str,
    args: &ReportArgs,
    section: &str,
    table: &str,
    device: &str,
    started: std::time::Instant,
) -> Result<(), String> {
    let rounds = if args.rounds == DEFAULT_ROUNDS { String::new() } else { format!(" --rounds {}", args.rounds) };
    let table = format!(
        "{table}\n_Generated by `cargo run --release --features tools --example {tool} -- --section {section}{rounds}` on {device}, in {:.0} s._\n",
        started.elapsed().as_secs_f64()
    );
    println!("\n## {section}\n\n{table}");
    match &args.docs {
        Some(docs) => replace_section(docs, tool, section, &table),
        None => Ok(()),
    }
}

/// Replaces the text between `<!-- {tool}:{name} -->` and `<!-- /{tool}:{name} -->` in `path`.
pub fn replace_section(path: &Path, tool: &str, name: &str, body: &str) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (open, close) = (format!("<!-- {tool}:{name} -->"), format!("<!-- /{tool}:{name} -->"));
    let (Some(start), Some(end)) = (text.find(&open), text.find(&close)) else {
        return Err(format!("{}: no {open} … {close} markers", path.display()));
    };
    let updated = format!("{}{open}\n{body}{}", &text[..start], &text[end..]);
    std::fs::write(path, updated).map_err(|e| format!("{}: {e}", path.display()))
}

pub fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// One headless render of a report, a dot on stderr for progress; keeps the device's name from the
/// sidecar in `device`.
pub fn report_render(device: &mut String, options: &HeadlessOptions) -> Result<HeadlessReport, String> {
    eprint!(".");
    let report = bevy_diffuse_gi::headless::run(options)?;
    if let Some(name) = report.sidecar["device"].as_str() {
        *device = name.to_string();
    }
    Ok(report)
}

/// The committed ground truth `assets/ground_truth/{name}.exr`.
pub fn report_truth(name: &str) -> Result<HdrImage, String> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/ground_truth").join(format!("{name}.exr"));
    HdrImage::read(&path).map_err(|e| format!("{}: {e}", path.display()))
}

pub fn report_compare(image: &HdrImage, truth: &HdrImage) -> Result<ErrorMetrics, String> {
    bevy_diffuse_gi::metrics::compare(image, truth).map_err(|e| e.to_string())
}

/// `block RMSE | pixel RMSE | energy | blocks > 50 % off` cells of a Markdown row.
pub fn report_cells(m: &ErrorMetrics) -> String {
    format!("{:.3} | {:.3} | {:.3} | {:.1} %", m.block_relative_rmse, m.relative_rmse, m.energy_ratio, 100.0 * m.blocks_over_half_off)
}

/// Median of the last `timed` frame intervals of a headless run, in milliseconds.
pub fn frame_ms(report: &HeadlessReport, timed: usize) -> f64 {
    let frames = frame_intervals(report);
    median(&frames[frames.len().saturating_sub(timed)..])
}

/// Every main-world frame interval of a headless run since the scene showed, in milliseconds.
pub fn frame_intervals(report: &HeadlessReport) -> Vec<f64> {
    report.sidecar["frame_ms"].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default()
}

/// The fixed-frame harness CI runs every windowed example with, in a real window (Xvfb) on lavapipe.
/// Inert unless `DIFFUSE_GI_CAPTURE=DIR/NAME` is set; then time advances a fixed 1/60 s per frame and
/// screenshots of the window (3D view and panel) are saved:
/// * `DIR/NAME_no_gi.png` at frame `DIFFUSE_GI_CAPTURE_FRAME` (default 30), with every camera's bounced
///   light held off until then;
/// * then, with bounced light on, one `DIR/NAME_{label}.png` every `DIFFUSE_GI_CAPTURE_INTERVAL` frames
///   (default 20) per label of the example's [`CiSteps`] (one step, `gi`, without it). Before step `i`
///   the harness sends [`CiStep`]`(i)`, which the example answers by showing what the label says (a method,
///   a scene). `DIFFUSE_GI_CAPTURE_STEPS=N` keeps the first `N` steps (the README's pictures take one).
///
/// Frames count only while every pipeline the renderer asked for is compiled (lavapipe compiles them in
/// the background for seconds, and a frame drawn before that shows nothing of what it waits for), so the
/// screenshots do not depend on how fast the machine compiles shaders.
///
/// The app exits once every screenshot is written.
pub struct CiCapturePlugin;

/// Whether the render world's pipeline cache has no pipeline waiting to compile (written by the render
/// world each frame, read by [`ci_capture`]).
#[derive(Resource, Clone, Default)]
struct CiPipelinesReady(std::sync::Arc<std::sync::atomic::AtomicBool>);

fn ci_pipelines_ready(cache: Res<bevy::render::render_resource::PipelineCache>, ready: Res<CiPipelinesReady>) {
    let settled = cache.waiting_pipelines().next().is_none() && cache.pipelines().next().is_some();
    ready.0.store(settled, std::sync::atomic::Ordering::Relaxed);
}

/// The labels of the example's CI screenshots after the no-GI one (see [`CiCapturePlugin`]).
#[derive(Resource, Clone, Debug)]
pub struct CiSteps(pub Vec<String>);

/// Sent by the CI harness before its screenshot of step `.0`.
#[derive(Message, Clone, Copy, Debug)]
pub struct CiStep(pub usize);

#[derive(Resource)]
struct CiCapture {
    stem: PathBuf,
    first: u32,
    interval: u32,
    /// `DIFFUSE_GI_CAPTURE_STEPS`: the most steps to take.
    max_steps: usize,
    count: u32,
    /// Frames in a row that did not count (a pipeline still compiling).
    waited: u32,
    written: Vec<PathBuf>,
}

impl Plugin for CiCapturePlugin {
    fn build(&self, app: &mut App) {
        app.add_message::<CiStep>();
        let Some(stem) = std::env::var_os("DIFFUSE_GI_CAPTURE").map(PathBuf::from) else {
            return;
        };
        let number = |name: &str, default: u32| std::env::var(name).ok().and_then(|f| f.parse().ok()).unwrap_or(default);
        let first = number("DIFFUSE_GI_CAPTURE_FRAME", 30).max(2);
        let interval = number("DIFFUSE_GI_CAPTURE_INTERVAL", 20).max(2);
        let max_steps = number("DIFFUSE_GI_CAPTURE_STEPS", u32::MAX).max(1) as usize;
        let ready = CiPipelinesReady::default();
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app
                .insert_resource(ready.clone())
                .add_systems(bevy::render::Render, ci_pipelines_ready.in_set(bevy::render::RenderSystems::Cleanup));
        }
        app.insert_resource(ready)
            .insert_resource(bevy::time::TimeUpdateStrategy::ManualDuration(std::time::Duration::from_secs_f64(1.0 / 60.0)))
            .insert_resource(CiCapture { stem, first, interval, max_steps, count: 0, waited: 0, written: Vec::new() })
            .add_systems(Startup, ci_window_size)
            .add_systems(Last, ci_capture);
    }
}

/// The window CI renders: 800×450 (`DIFFUSE_GI_CAPTURE_SIZE=WxH` sets another), a third of the
/// default's pixels, because lavapipe's frame time grows with them.
fn ci_window_size(mut windows: Query<&mut Window, With<bevy::window::PrimaryWindow>>) {
    let size = std::env::var("DIFFUSE_GI_CAPTURE_SIZE")
        .ok()
        .and_then(|s| s.split_once('x').and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?))))
        .unwrap_or((800u32, 450u32));
    for mut window in &mut windows {
        window.resolution.set(size.0 as f32, size.1 as f32);
    }
}

/// Whether a frame shows what it should: no pipeline waiting to compile, and no method waiting for its
/// first background result (a CPU method's solve, the VPL walks: it draws no bounced light until then).
/// Later results do not count: an example that moves something keeps them running.
#[derive(bevy::ecs::system::SystemParam)]
struct CiFrameReady<'w> {
    pipelines: Res<'w, CiPipelinesReady>,
    methods: Option<Res<'w, bevy_diffuse_gi::method::GiMethodStatus>>,
}

impl CiFrameReady<'_> {
    fn get(&self) -> bool {
        let first_result_pending = self.methods.as_ref().is_some_and(|m| m.any_awaiting_first_result());
        self.pipelines.0.load(std::sync::atomic::Ordering::Relaxed) && !first_result_pending
    }
}

fn ci_capture(
    mut commands: Commands,
    mut capture: ResMut<CiCapture>,
    ready: CiFrameReady,
    steps: Option<Res<CiSteps>>,
    mut cameras: Query<&mut bevy_diffuse_gi::camera::DiffuseGi>,
    mut step: MessageWriter<CiStep>,
    mut exit: MessageWriter<AppExit>,
) {
    use bevy::render::view::screenshot::{Screenshot, save_to_disk};
    let mut labels = steps.map_or_else(|| vec!["gi".to_string()], |s| s.0.clone());
    labels.truncate(capture.max_steps);
    if !ready.get() {
        // A pipeline still compiling or a first solve pending: this frame does not count (at most 6000
        // in a row).
        capture.waited += 1;
        if capture.waited > 6000 {
            error!("pipelines still compiling or a first background solve pending after {} frames", capture.waited);
            exit.write(AppExit::error());
        }
        return;
    }
    capture.waited = 0;
    capture.count += 1;
    let (count, first, interval) = (capture.count, capture.first, capture.interval);
    let shoot = |commands: &mut Commands, capture: &mut CiCapture, label: &str| {
        let path = PathBuf::from(format!("{}_{label}.png", capture.stem.display()));
        let _ = std::fs::remove_file(&path);
        commands.spawn(Screenshot::primary_window()).observe(save_to_disk(path.clone()));
        capture.written.push(path);
    };
    if count <= first {
        for mut gi in &mut cameras {
            if gi.enabled {
                gi.enabled = false;
            }
        }
        if count == first {
            shoot(&mut commands, &mut capture, "no_gi");
        }
        return;
    }
    let since = count - first;
    if since == 1 {
        for mut gi in &mut cameras {
            gi.enabled = true;
        }
    }
    // Step i: announced one frame after the previous screenshot, shot `interval` frames after it.
    let i = ((since - 1) / interval) as usize;
    if (since - 1) % interval == 0 && i < labels.len() {
        step.write(CiStep(i));
    }
    if since % interval == 0 && (since / interval) as usize <= labels.len() {
        let label = labels[(since / interval) as usize - 1].clone();
        shoot(&mut commands, &mut capture, &label);
    }
    // Saving happens a few frames later, on the render thread's readback.
    let last = first + interval * labels.len() as u32;
    if count > last && capture.written.iter().all(|p| p.exists()) {
        exit.write(AppExit::Success);
    }
    if count > last + 600 {
        error!("the screenshots {:?} never all arrived", capture.written);
        exit.write(AppExit::error());
    }
}
