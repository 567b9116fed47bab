//! What the examples share: the headless fallback of the windowed examples, and the command line, the
//! Markdown section replacement and the medians of the report examples.
#![allow(dead_code, reason = "each example uses a different subset")]

use std::path::{Path, PathBuf};

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport, run_and_write};
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

/// The scene a windowed example `tool` is asked to show (`--scene`, default `cornell`). `--help`
/// exits with status 0, bad input with clap's message and status 2.
pub fn example_scene(tool: &'static str, about: &'static str) -> StandardScene {
    use clap::{CommandFactory, FromArgMatches};
    let matches = ExampleCli::command().name(tool).about(about).get_matches();
    ExampleCli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit()).scene
}

/// The command line of a report example.
pub struct ReportArgs {
    pub sections: Vec<String>,
    pub rounds: usize,
    pub docs: Option<PathBuf>,
}

/// The flags every report example takes (clap derive).
#[derive(clap::Parser)]
struct ReportCli {
    /// A section to generate (repeat for several) [default: all]
    #[arg(long = "section", value_name = "NAME")]
    sections: Vec<String>,
    /// Rounds of the alternating timing runs, 1..=20
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=20))]
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

/// Median of the last `timed` frame intervals of a headless run, in milliseconds.
pub fn frame_ms(report: &HeadlessReport, timed: usize) -> f64 {
    let frames: Vec<f64> =
        report.sidecar["frame_ms"].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default();
    median(&frames[frames.len().saturating_sub(timed)..])
}

/// The fixed-frame harness CI runs every windowed example with, in a real window (Xvfb) on lavapipe.
/// Inert unless `DIFFUSE_GI_CAPTURE=OUT.png` is set; then time advances a fixed 1/60 s per frame, a
/// screenshot of the window (3D view and panel) is saved at frame `DIFFUSE_GI_CAPTURE_FRAME` (default
/// 40) and the app exits once it is written. `DIFFUSE_GI_NO_GI=1` keeps every camera's bounced light off,
/// for the test's "unchanged from no GI" comparison.
pub struct CiCapturePlugin;

#[derive(Resource)]
struct CiCapture {
    path: PathBuf,
    frame: u32,
    no_gi: bool,
    count: u32,
}

impl Plugin for CiCapturePlugin {
    fn build(&self, app: &mut App) {
        let Some(path) = std::env::var_os("DIFFUSE_GI_CAPTURE").map(PathBuf::from) else {
            return;
        };
        let frame = std::env::var("DIFFUSE_GI_CAPTURE_FRAME").ok().and_then(|f| f.parse().ok()).unwrap_or(40);
        let no_gi = std::env::var_os("DIFFUSE_GI_NO_GI").is_some();
        app.insert_resource(bevy::time::TimeUpdateStrategy::ManualDuration(std::time::Duration::from_secs_f64(1.0 / 60.0)))
            .insert_resource(CiCapture { path, frame, no_gi, count: 0 })
            .add_systems(Last, ci_capture);
    }
}

fn ci_capture(
    mut commands: Commands,
    mut capture: ResMut<CiCapture>,
    mut cameras: Query<&mut bevy_diffuse_gi::camera::DiffuseGi>,
    mut exit: MessageWriter<AppExit>,
) {
    use bevy::render::view::screenshot::{Screenshot, save_to_disk};
    capture.count += 1;
    if capture.no_gi {
        for mut gi in &mut cameras {
            if gi.enabled {
                gi.enabled = false;
            }
        }
    }
    if capture.count == capture.frame {
        let _ = std::fs::remove_file(&capture.path);
        commands.spawn(Screenshot::primary_window()).observe(save_to_disk(capture.path.clone()));
    }
    // Saving happens a few frames later, on the render thread's readback.
    if capture.count > capture.frame && capture.path.exists() {
        exit.write(AppExit::Success);
    }
    if capture.count > capture.frame + 600 {
        error!("the screenshot for {} never arrived", capture.path.display());
        exit.write(AppExit::error());
    }
}
