//! Run time against error for every method, on every scene with a committed ground truth, in one run:
//! the numbers, tables and Pareto plots of `docs/benchmark.md`, the README's methods table and the
//! cross-method tables of the per-method reports.
//!
//! ```text
//! cargo run --release --features tools --example gi_bench -- [--quick] [--methods rh,vpl,...] [--scenes cornell,room_16,...]
//!     [--presets low,medium,high] [--rounds N] [--resume] [--publish] [--check docs/benchmark.json]
//! ```
//! * **Error**: each method × preset renders the indirect light alone (16 frames, then the wait for its
//!   background work) and is compared with the path-traced truth of all bounces: block relative RMSE,
//!   energy, the share of 4×4 blocks more than 50 % off (`shared/METRICS.md`), and, where a one-bounce
//!   truth exists, the same against it. `near_light` has only a one-bounce truth. At 256² (the generated
//!   rooms at their truths' 64²).
//! * **FLIP** (feature `flip`) of the composited frame against the traced `.full.exr`, from the
//!   still-frame run.
//! * **Cost**: the median of the last [`TIMED_FRAMES`] main-world frame intervals of a still scene
//!   ([`STILL_FRAMES`] frames after the method's background work is done) and of a scene whose GI lights
//!   move every frame ([`MOVING_FRAMES`]), each over the same frame without GI, measured just before the
//!   method's runs (alternating, so a busy machine slows both); 512² for the defaults. The sidecar's
//!   per-pass GPU times where the device has timestamps, main-thread milliseconds, GPU memory (every live
//!   allocation of the allocator, minus the frame without GI's), and the CPU methods' preparation time.
//! * Moving lights and 512² run for the `medium` preset only; the generated rooms measure error only
//!   (their plot takes each preset's cost as its median over the standard scenes).
//!
//! Results go to `docs/benchmark.json` (one record per method, preset and scene, with device and commit;
//! records of other runs are kept, so a run can be split with `--scenes`), and `--publish` regenerates
//! `docs/benchmark.md`, `docs/benchmark/*.svg`, the README's methods table and the per-method reports'
//! cross-method tables from all of it. `--quick` (CI): `cornell` and `cellar`, the defaults, error only;
//! with `--check FILE` it fails when a default's block RMSE is more than 10 % above `FILE`'s.

#[path = "common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use bevy::math::UVec2;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::drm::DrmSettings;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::photon_grid::PhotonGridSettings;
use bevy_diffuse_gi::radiance_hints::RadianceHintsVolume;
use bevy_diffuse_gi::radiosity::RadiositySettings;
use bevy_diffuse_gi::rsm_gather::RsmGatherSettings;
use bevy_diffuse_gi::scenes::{GeneratedRoom, ROOM_HELD_OUT_SEEDS, StandardScene};
use bevy_diffuse_gi::vpl::VplSettings;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// The standard scenes with a committed ground truth.
const STANDARD_SCENES: [&str; 8] =
    ["cornell", "cellar", "sponza_like", "open_field", "dynamic", "emissive_panel", "sky_room", "near_light"];
/// The generated rooms of the full run: four tuning seeds and two held out.
const ROOM_SAMPLE: [u64; 6] = [0, 1, 2, 3, 16, 17];
const PRESETS: [&str; 3] = ["low", "medium", "high"];
/// Frames of the error run before its wait for the background work.
const ERROR_FRAMES: u32 = 16;
/// Frames of a still-scene timing run (Radiance Hints refines its volume over the first dozen).
const STILL_FRAMES: u32 = 32;
/// Frames of a moving-light timing run.
const MOVING_FRAMES: u32 = 16;
/// Frame intervals whose median is a run's frame time (the last ones).
const TIMED_FRAMES: usize = 8;
/// At most this long for a CPU method's background work, seconds.
const WAIT_BACKGROUND: u32 = 300;
/// Where `--stress` keeps its outcomes.
const STRESS_JSON: &str = "docs/benchmark_stress.json";
/// `--check`: a default's block RMSE may rise this much over the committed value.
const CHECK_TOLERANCE: f64 = 0.10;

#[derive(clap::Parser)]
#[command(name = "gi_bench", about = "Run time against error for every method on every scene (docs/benchmark.md).")]
struct Cli {
    /// CI: cornell and cellar, the medium presets, error only
    #[arg(long)]
    quick: bool,
    /// Methods, comma-separated (rh, vpl, rsm, drm, radiosity, photon-grid) [default: all]
    #[arg(long, value_delimiter = ',')]
    methods: Vec<String>,
    /// Scenes, comma-separated (the standard scenes and room_SEED) [default: every standard scene and rooms 0–3, 16, 17]
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Presets, comma-separated (low, medium, high) [default: all]
    #[arg(long, value_delimiter = ',')]
    presets: Vec<String>,
    /// Rounds of the alternating timing runs, 1..=10
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=10))]
    rounds: u32,
    /// Measure error only (no timing runs)
    #[arg(long)]
    no_timing: bool,
    /// The JSON file of every record (records of this run replace those of the same scene, method and preset)
    /// [default: docs/benchmark.json; with --quick, none]
    #[arg(long, value_name = "FILE.json")]
    json: Option<PathBuf>,
    /// Skip the method, preset and scene combinations the JSON file already has
    #[arg(long)]
    resume: bool,
    /// Regenerate docs/benchmark.md, its plots, the README table and the reports' tables from the JSON
    #[arg(long)]
    publish: bool,
    /// Only --publish, measuring nothing
    #[arg(long)]
    publish_only: bool,
    /// Run the stress matrix for every method (`bevy_diffuse_gi::headless::stress`) and publish what each case produced
    #[arg(long)]
    stress: bool,
    /// Fail when a medium preset's block RMSE of this run is more than 10 % above this file's
    #[arg(long, value_name = "FILE.json")]
    check: Option<PathBuf>,
}

/// One method with one preset on one scene.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
struct Record {
    scene: String,
    method: String,
    preset: String,
    /// A generated room of the held-out seeds.
    held_out: bool,
    /// Side of the error image, pixels.
    size: u32,
    block_rmse: f64,
    pixel_rmse: f64,
    energy: f64,
    bad_blocks: f64,
    /// Against the one-bounce truth, where one is committed.
    one_bounce_block_rmse: Option<f64>,
    one_bounce_energy: Option<f64>,
    /// Mean FLIP of the composited frame against the traced full image.
    flip: Option<f64>,
    /// Still scene at 256²: the method's frame, the frame without GI (ms), their ratio.
    still_ms: Option<f64>,
    still_base_ms: Option<f64>,
    still_ratio: Option<f64>,
    /// GI lights moving every frame, 256².
    moving_ms: Option<f64>,
    moving_base_ms: Option<f64>,
    moving_ratio: Option<f64>,
    /// Still scene at 512².
    still_512_ratio: Option<f64>,
    /// The still run's per-pass GPU times (where the device has timestamps), ms.
    gpu_ms: Value,
    /// Median main-thread ms of the still run's frames (the plugin's systems).
    main_thread_ms: Option<f64>,
    /// GPU memory over the frame without GI, bytes.
    gpu_memory_bytes: Option<i64>,
    /// CPU methods: the background preparation of the still scene, ms.
    prep_ms: Option<f64>,
    /// Whether the method's background work finished within the wait.
    background_timed_out: bool,
    device: String,
    commit: String,
    /// The method's settings as the sidecar records them.
    settings: Value,
}

#[derive(Default, Serialize, Deserialize)]
struct Results {
    records: Vec<Record>,
}

/// The stress matrix's last run (`docs/benchmark_stress.json`: a file of its own, so that it and a long
/// benchmark run can be made at the same time).
#[derive(Default, Serialize, Deserialize)]
struct StressResults {
    stress: Vec<StressRecord>,
}

/// What one method made of one stress case.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct StressRecord {
    case: String,
    description: String,
    method: String,
    passed: bool,
    /// Why not, or "ok".
    verdict: String,
    warnings: Vec<String>,
    expected_warnings: usize,
    mean_luminance: f64,
    coverage: f64,
    background_timed_out: bool,
    seconds: f64,
    commit: String,
}

fn main() -> std::process::ExitCode {
    common::report_main("gi_bench", run)
}

fn manifest(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// `git rev-parse --short HEAD`, with `-dirty` when tracked files differ from it.
fn commit() -> String {
    let git = |args: &[&str]| std::process::Command::new("git").args(args).current_dir(env!("CARGO_MANIFEST_DIR")).output().ok();
    let head = git(&["rev-parse", "--short", "HEAD"])
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    let dirty = git(&["diff", "--quiet", "HEAD", "--", "src", "shaders", "examples", "Cargo.toml"]).is_some_and(|o| !o.status.success());
    if dirty { format!("{head}-dirty") } else { head }
}

fn preset_options(method: GiMethod, preset: &str, base: HeadlessOptions) -> HeadlessOptions {
    fn pick<T>(preset: &str, low: T, medium: T, high: T) -> T {
        match preset {
            "low" => low,
            "high" => high,
            _ => medium,
        }
    }
    let mut o = HeadlessOptions { method: HeadlessMethod::Gi(method), ..base };
    match method {
        GiMethod::RadianceHints => o.rh = pick(preset, RadianceHintsVolume::LOW, RadianceHintsVolume::MEDIUM, RadianceHintsVolume::HIGH),
        GiMethod::Vpl => o.vpl = pick(preset, VplSettings::LOW, VplSettings::MEDIUM, VplSettings::HIGH),
        GiMethod::RsmGather => o.rsm_gather = pick(preset, RsmGatherSettings::LOW, RsmGatherSettings::MEDIUM, RsmGatherSettings::HIGH),
        GiMethod::Drm => o.drm = pick(preset, DrmSettings::LOW, DrmSettings::MEDIUM, DrmSettings::HIGH),
        GiMethod::Radiosity => o.radiosity = pick(preset, RadiositySettings::LOW, RadiositySettings::MEDIUM, RadiositySettings::HIGH),
        GiMethod::PhotonGrid => o.photon_grid = pick(preset, PhotonGridSettings::LOW, PhotonGridSettings::MEDIUM, PhotonGridSettings::HIGH),
    }
    o
}

/// The truths of a scene: all bounces, one bounce (where committed) and the full traced frame.
struct Truths {
    indirect: HdrImage,
    one_bounce: Option<HdrImage>,
    full: Option<HdrImage>,
}

fn truths(scene: &StandardScene) -> Result<Truths, String> {
    let read = |path: PathBuf| HdrImage::read(&path).map_err(|e| format!("{}: {e}", path.display()));
    let optional = |path: PathBuf| path.is_file().then(|| read(path)).transpose();
    if let StandardScene::Room(seed) = scene {
        return Ok(Truths {
            indirect: read(manifest(&format!("assets/ground_truth/rooms/room_{seed}.exr")))?,
            one_bounce: None,
            full: None,
        });
    }
    let name = scene.name();
    let dir = manifest("assets/ground_truth");
    // near_light has only its one-bounce truth (the scene shows one bounce next to a light).
    let all = if name == "near_light" { "near_light_b1".to_string() } else { name.clone() };
    Ok(Truths {
        indirect: read(dir.join(format!("{all}.exr")))?,
        one_bounce: optional(dir.join(format!("{name}_b1.exr")))?,
        full: optional(dir.join(format!("{all}.full.exr")))?,
    })
}

fn timed(report: &HeadlessReport) -> f64 {
    common::frame_ms(report, TIMED_FRAMES)
}

fn allocated(report: &HeadlessReport) -> Option<i64> {
    report.sidecar["gpu_allocated_bytes"].as_u64().map(|b| b as i64)
}

/// The background preparation of a CPU method's still scene, from its sidecar, ms.
fn prep_ms(report: &HeadlessReport) -> Option<f64> {
    let s = &report.sidecar;
    let sum = |object: &Value, keys: &[&str]| keys.iter().map(|k| object[*k].as_f64().unwrap_or(0.0)).sum::<f64>();
    if s["radiosity"].is_object() {
        return Some(sum(&s["radiosity"], &["update_elements_ms", "create_links_ms", "refine_push_ms", "illumination_ms"]));
    }
    if s["photon_grid"].is_object() {
        return Some(sum(&s["photon_grid"], &["voxelize_ms", "trace_ms", "rgrid_ms", "field_ms"]));
    }
    s["vpl"]["last_walk_ms"].as_f64()
}

/// The method's settings: Radiance Hints' as the sidecar records them (with the grid fitted to the scene),
/// the others' as their `Debug` text.
fn method_settings(report: &HeadlessReport, options: &HeadlessOptions, method: GiMethod) -> Value {
    match method {
        GiMethod::RadianceHints => report.sidecar.get("radiance_hints").cloned().unwrap_or(Value::Null),
        GiMethod::Vpl => json!(format!("{:?}", options.vpl)),
        GiMethod::RsmGather => json!(format!("{:?}", options.rsm_gather)),
        GiMethod::Drm => json!(format!("{:?}", options.drm)),
        GiMethod::Radiosity => json!(format!("{:?}", options.radiosity)),
        GiMethod::PhotonGrid => json!(format!("{:?}", options.photon_grid)),
    }
}

struct Bench {
    /// The terminal's progress bar: one step per method and scene.
    bar: indicatif::ProgressBar,
    device: String,
    commit: String,
    rounds: u32,
    timing: bool,
}

impl Bench {
    /// A line above the progress bar (or on stderr where there is no terminal to draw the bar on).
    fn log(&self, line: String) {
        if self.bar.is_hidden() {
            eprintln!("{line}");
        } else {
            self.bar.println(line);
        }
    }

    fn render(&mut self, options: &HeadlessOptions) -> Result<HeadlessReport, String> {
        common::report_render(&mut self.device, options)
    }

    /// Every preset of `method` on `scene`: error, then (standard scenes) the timing runs alternating
    /// with the frame without GI.
    fn measure(&mut self, scene: &StandardScene, method: GiMethod, presets: &[String], truths: &Truths) -> Result<Vec<Record>, String> {
        let room = matches!(scene, StandardScene::Room(_));
        let size = truths.indirect.width;
        let base = HeadlessOptions { scene: scene.clone(), size: UVec2::splat(size), ..Default::default() };
        let mut records = Vec::new();
        // A scene without a GI light (lit by emissive meshes or the sky) has no light to move: its
        // "moving light" runs would time the volume methods' first updates instead (Radiance Hints read
        // 30× the frame without GI in `emissive_panel`, where nothing moved).
        let mut has_gi_light = false;
        for preset in presets {
            let options = preset_options(
                method,
                preset,
                HeadlessOptions { indirect_only: true, frames: ERROR_FRAMES, wait_background: Some(WAIT_BACKGROUND), ..base.clone() },
            );
            let report = self.render(&options)?;
            has_gi_light |= report.sidecar["lights"].as_array().is_some_and(|l| l.iter().any(|l| l["gi_light"] == true));
            let m = common::report_compare(&report.image, &truths.indirect)?;
            let one = truths.one_bounce.as_ref().map(|t| common::report_compare(&report.image, t)).transpose()?;
            records.push(Record {
                scene: scene.name(),
                method: method.name().into(),
                preset: preset.clone(),
                held_out: matches!(scene, StandardScene::Room(seed) if ROOM_HELD_OUT_SEEDS.contains(seed)),
                size,
                block_rmse: m.block_relative_rmse,
                pixel_rmse: m.relative_rmse,
                energy: m.energy_ratio,
                bad_blocks: m.blocks_over_half_off,
                one_bounce_block_rmse: one.map(|o| o.block_relative_rmse),
                one_bounce_energy: one.map(|o| o.energy_ratio),
                background_timed_out: report.sidecar["background_timed_out"].as_bool().unwrap_or(false),
                settings: method_settings(&report, &options, method),
                prep_ms: prep_ms(&report),
                device: self.device.clone(),
                commit: self.commit.clone(),
                ..Default::default()
            });
            self.log(format!(
                "{} {} {preset}: block RMSE {:.3}, energy {:.2}",
                scene.name(),
                method.name(),
                m.block_relative_rmse,
                m.energy_ratio
            ));
        }
        if !self.timing || room {
            return Ok(records);
        }
        let size256 = UVec2::splat(256);
        let still = |o: HeadlessOptions, size: UVec2| HeadlessOptions {
            size,
            frames: STILL_FRAMES,
            wait_background: Some(WAIT_BACKGROUND),
            ..o
        };
        let moving = |o: HeadlessOptions| HeadlessOptions { size: size256, frames: MOVING_FRAMES, animate_light: true, ..o };
        let mut samples: BTreeMap<(usize, &str), Vec<f64>> = BTreeMap::new();
        let mut base_memory = None;
        for _ in 0..self.rounds {
            // The frame without GI just before the method's, each kind of run.
            let none = self.render(&still(base.clone(), size256))?;
            base_memory = allocated(&none).or(base_memory);
            samples.entry((usize::MAX, "still")).or_default().push(timed(&none));
            let medium = presets.iter().any(|p| p == "medium");
            if medium {
                if has_gi_light {
                    samples.entry((usize::MAX, "moving")).or_default().push(timed(&self.render(&moving(base.clone()))?));
                }
                samples.entry((usize::MAX, "still512")).or_default().push(timed(&self.render(&still(base.clone(), UVec2::splat(512)))?));
            }
            for (i, preset) in presets.iter().enumerate() {
                let report = self.render(&preset_options(method, preset, still(base.clone(), size256)))?;
                samples.entry((i, "still")).or_default().push(timed(&report));
                let r = &mut records[i];
                if let (Some(full), true) = (&truths.full, cfg!(feature = "flip")) {
                    r.flip = flip(&report.image, full)?;
                }
                r.gpu_ms = report.sidecar["gpu_ms"].clone();
                let main: Vec<f64> = report.sidecar["main_thread_ms"].as_array().map(|a| a.iter().filter_map(Value::as_f64).collect()).unwrap_or_default();
                r.main_thread_ms = Some(common::median(&main));
                r.gpu_memory_bytes = allocated(&report).zip(base_memory).map(|(a, b)| a - b);
                r.prep_ms = prep_ms(&report).or(r.prep_ms);
                if preset == "medium" {
                    if has_gi_light {
                        samples.entry((i, "moving")).or_default().push(timed(&self.render(&preset_options(method, preset, moving(base.clone())))?));
                    }
                    let big = self.render(&preset_options(method, preset, still(base.clone(), UVec2::splat(512))))?;
                    samples.entry((i, "still512")).or_default().push(timed(&big));
                }
            }
        }
        let median = |key: (usize, &str)| samples.get(&key).map(|v| common::median(v));
        for (i, r) in records.iter_mut().enumerate() {
            r.still_ms = median((i, "still"));
            r.still_base_ms = median((usize::MAX, "still"));
            r.still_ratio = r.still_ms.zip(r.still_base_ms).map(|(a, b)| a / b);
            r.moving_ms = median((i, "moving"));
            r.moving_base_ms = r.moving_ms.and(median((usize::MAX, "moving")));
            r.moving_ratio = r.moving_ms.zip(r.moving_base_ms).map(|(a, b)| a / b);
            r.still_512_ratio = median((i, "still512")).zip(median((usize::MAX, "still512"))).map(|(a, b)| a / b);
        }
        Ok(records)
    }
}

#[cfg(feature = "flip")]
fn flip(image: &HdrImage, full: &HdrImage) -> Result<Option<f64>, String> {
    Ok(bevy_diffuse_gi::metrics::compare_with_flip(image, full, 1.0).map_err(|e| e.to_string())?.flip)
}

#[cfg(not(feature = "flip"))]
fn flip(_: &HdrImage, _: &HdrImage) -> Result<Option<f64>, String> {
    Ok(None)
}

fn read_results(path: &Path) -> Result<Results, String> {
    if !path.is_file() {
        return Ok(Results::default());
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

fn write_results(path: &Path, results: &Results) -> Result<(), String> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    }
    let text = serde_json::to_string_pretty(results).map_err(|e| e.to_string())?;
    std::fs::write(path, text + "\n").map_err(|e| format!("{}: {e}", path.display()))
}

fn key(r: &Record) -> (String, String, String) {
    (r.scene.clone(), r.method.clone(), r.preset.clone())
}

/// The committed defaults this run's must not be more than [`CHECK_TOLERANCE`] worse than.
fn check(run: &[Record], committed: &Path) -> Result<(), String> {
    let committed = read_results(committed)?;
    let mut failures = Vec::new();
    let mut compared = 0;
    for r in run.iter().filter(|r| r.preset == "medium") {
        let Some(c) = committed.records.iter().find(|c| key(c) == key(r)) else {
            failures.push(format!("{} {}: no committed record to compare with", r.scene, r.method));
            continue;
        };
        compared += 1;
        let limit = c.block_rmse * (1.0 + CHECK_TOLERANCE);
        let verdict = if r.block_rmse <= limit { "ok" } else { "WORSE" };
        println!("{:<12} {:<12} block RMSE {:.4} (committed {:.4}, limit {limit:.4}) {verdict}", r.scene, r.method, r.block_rmse, c.block_rmse);
        if r.block_rmse > limit || !r.block_rmse.is_finite() {
            failures.push(format!("{} {}: block RMSE {:.4} > {limit:.4} (committed {:.4} + 10 %)", r.scene, r.method, r.block_rmse, c.block_rmse));
        }
    }
    if compared == 0 {
        failures.push("no default was measured".into());
    }
    if failures.is_empty() { Ok(()) } else { Err(format!("the defaults' error rose:\n  {}", failures.join("\n  "))) }
}

fn run() -> Result<(), String> {
    use clap::Parser;
    let cli = Cli::parse();
    if std::env::var_os("WGPU_BACKEND").is_none() {
        // SAFETY: set before any render thread exists.
        unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    }
    let methods = common::gi_methods(&cli.methods)?;
    let scenes: Vec<StandardScene> = if !cli.scenes.is_empty() {
        cli.scenes.iter().map(|s| StandardScene::parse(s)).collect::<Result<_, _>>()?
    } else if cli.quick {
        vec![StandardScene::Cornell, StandardScene::Cellar]
    } else {
        STANDARD_SCENES.iter().map(|s| StandardScene::parse(s).expect("a standard scene")).chain(ROOM_SAMPLE.map(StandardScene::Room)).collect()
    };
    let presets: Vec<String> = if !cli.presets.is_empty() {
        for p in &cli.presets {
            if !PRESETS.contains(&p.as_str()) {
                return Err(format!("`{p}` is not a preset (low, medium, high)"));
            }
        }
        cli.presets.clone()
    } else if cli.quick {
        vec!["medium".into()]
    } else {
        PRESETS.iter().map(|p| p.to_string()).collect()
    };
    // A quick run replaces the committed records only when asked to (`--json docs/benchmark.json`).
    let write_json = cli.json.is_some() || !cli.quick;
    let json = cli.json.clone().unwrap_or_else(|| PathBuf::from("docs/benchmark.json"));
    let json_path = if json.is_absolute() { json } else { manifest(&json.to_string_lossy()) };
    let mut results = read_results(&json_path)?;
    let bar = indicatif::ProgressBar::new((scenes.len() * methods.len()) as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise}, about {eta} to go]")
            .expect("a valid template"),
    );
    if cli.publish_only {
        bar.finish_and_clear();
    }
    let mut bench = Bench { bar, device: "an unknown device".into(), commit: commit(), rounds: cli.rounds, timing: !(cli.no_timing || cli.quick) };
    let mut run_records = Vec::new();
    if !cli.publish_only {
        for scene in &scenes {
            let truths = truths(scene)?;
            for &method in &methods {
                bench.bar.set_message(format!("{} {}", scene.name(), method.name()));
                let wanted: Vec<String> = presets
                    .iter()
                    .filter(|p| {
                        !cli.resume
                            || !results.records.iter().any(|r| r.scene == scene.name() && r.method == method.name() && &r.preset == *p)
                    })
                    .cloned()
                    .collect();
                if wanted.is_empty() {
                    bench.bar.inc(1);
                    continue;
                }
                // One configuration that fails (a render past its time limit) is reported and left out:
                // the report's list of what was not measured names it.
                let records = match bench.measure(scene, method, &wanted, &truths) {
                    Ok(records) => records,
                    Err(message) => {
                        bench.log(format!("{} {}: not measured: {message}", scene.name(), method.name()));
                        bench.bar.inc(1);
                        continue;
                    }
                };
                bench.bar.inc(1);
                for r in records {
                    results.records.retain(|c| key(c) != key(&r));
                    run_records.push(r.clone());
                    results.records.push(r);
                }
                // Every finished method is saved: a long run that stops loses little.
                if write_json {
                    sort(&mut results.records);
                    write_results(&json_path, &results)?;
                }
            }
        }
    }
    bench.bar.finish();
    if cli.stress {
        use bevy_diffuse_gi::headless::stress::{run_stress, stress_cases};
        let mut results = StressResults::default();
        let mut baselines = std::collections::HashMap::new();
        for case in stress_cases() {
            for method in GiMethod::ALL {
                let outcome = run_stress(&case, method);
                if case.name == "baseline" {
                    baselines.insert(method, outcome.mean_luminance);
                }
                let verdict = outcome.verdict(&case, baselines.get(&method).copied());
                eprintln!(" stress {} {}: {verdict:?} ({:.0} s)", case.name, method.name(), outcome.seconds);
                results.stress.push(StressRecord {
                    case: case.name.into(),
                    description: case.description.into(),
                    method: method.name().into(),
                    passed: verdict.is_ok(),
                    verdict: verdict.err().unwrap_or_else(|| "ok".into()),
                    warnings: outcome.warnings,
                    expected_warnings: case.expected_warnings,
                    mean_luminance: outcome.mean_luminance,
                    coverage: outcome.coverage,
                    background_timed_out: outcome.background_timed_out,
                    seconds: outcome.seconds,
                    commit: bench.commit.clone(),
                });
            }
        }
        let text = serde_json::to_string_pretty(&results).map_err(|e| e.to_string())?;
        let path = manifest(STRESS_JSON);
        std::fs::write(&path, text + "\n").map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if cli.publish || cli.publish_only {
        publish(&results)?;
    }
    if let Some(committed) = &cli.check {
        let committed = if committed.is_absolute() { committed.clone() } else { manifest(&committed.to_string_lossy()) };
        check(&run_records, &committed)?;
    }
    Ok(())
}

fn scene_order(name: &str) -> (usize, u64) {
    match STANDARD_SCENES.iter().position(|s| *s == name) {
        Some(i) => (i, 0),
        None => (STANDARD_SCENES.len(), name.trim_start_matches("room_").parse().unwrap_or(u64::MAX)),
    }
}

fn method_order(name: &str) -> usize {
    GiMethod::ALL.iter().position(|m| m.name() == name).unwrap_or(usize::MAX)
}

fn preset_order(name: &str) -> usize {
    PRESETS.iter().position(|p| *p == name).unwrap_or(usize::MAX)
}

fn sort(records: &mut [Record]) {
    records.sort_by_key(|r| (scene_order(&r.scene), method_order(&r.method), preset_order(&r.preset)));
}

// ---------------------------------------------------------------------------------------------------
// The report.

fn method_label(name: &str) -> &'static str {
    match name {
        "rh" => "Radiance Hints",
        "vpl" => "VPL + SSBC",
        "rsm" => "RSM gather",
        "drm" => "DRM",
        "radiosity" => "Radiosity",
        "photon-grid" => "Photon grid",
        _ => "?",
    }
}

fn colour(name: &str) -> plotters::style::RGBColor {
    use plotters::style::RGBColor;
    match name {
        "rh" => RGBColor(214, 96, 40),
        "vpl" => RGBColor(40, 110, 200),
        "rsm" => RGBColor(60, 160, 70),
        "drm" => RGBColor(150, 80, 180),
        "radiosity" => RGBColor(200, 40, 90),
        _ => RGBColor(120, 120, 120),
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.filter(|x| x.is_finite()).map_or_else(|| "—".into(), |x| format!("{x:.digits$}"))
}

fn mib(bytes: Option<i64>) -> String {
    bytes.map_or_else(|| "—".into(), |b| format!("{:.1}", b as f64 / (1024.0 * 1024.0)))
}

/// The points of a scene's plot: (method, preset, cost, block RMSE).
type Point = (String, String, f64, f64);

/// The points not dominated by another (at most its cost and at most its error, one strictly less).
fn pareto(points: &[Point]) -> Vec<usize> {
    (0..points.len())
        .filter(|&i| {
            let (_, _, c, e) = &points[i];
            !points.iter().any(|(_, _, c2, e2)| c2 <= c && e2 <= e && (c2 < c || e2 < e))
        })
        .collect()
}

fn plot(path: &Path, title: &str, x_label: &str, points: &[Point]) -> Result<(), Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    let root = SVGBackend::new(path, (720, 460)).into_drawing_area();
    root.fill(&WHITE)?;
    let (c_min, c_max, e_min, e_max) = points
        .iter()
        .fold((1.0f64, 1.0f64, f64::INFINITY, 0.0f64), |(c0, c1, lo, hi), p| (c0.min(p.2), c1.max(p.2), lo.min(p.3), hi.max(p.3)));
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((c_min * 0.9..c_max * 1.1).log_scale(), ((e_min * 0.8).max(1e-3)..e_max * 1.25).log_scale())?;
    chart
        .configure_mesh()
        .x_desc(format!("{x_label} (log)"))
        .y_desc("block relative RMSE (log)")
        .x_label_formatter(&|v| format!("{v:.1}"))
        .y_label_formatter(&|v| format!("{v:.2}"))
        .draw()?;
    let front = pareto(points);
    let mut front_points: Vec<(f64, f64)> = front.iter().map(|&i| (points[i].2, points[i].3)).collect();
    front_points.sort_by(|a, b| a.0.total_cmp(&b.0));
    // The front as a staircase: from each point, right at its error, then down to the next.
    let mut stairs = Vec::new();
    for (k, p) in front_points.iter().enumerate() {
        stairs.push(*p);
        if let Some(next) = front_points.get(k + 1) {
            stairs.push((next.0, p.1));
        }
    }
    if let Some(last) = front_points.last() {
        stairs.push((c_max * 1.1, last.1));
    }
    chart
        .draw_series(LineSeries::new(stairs, BLACK.mix(0.35).stroke_width(1)))?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.mix(0.35)));
    for method in GiMethod::ALL.map(GiMethod::name) {
        let mut series: Vec<&Point> = points.iter().filter(|p| p.0 == method).collect();
        if series.is_empty() {
            continue;
        }
        series.sort_by_key(|p| preset_order(&p.1));
        let c = colour(method);
        chart
            .draw_series(LineSeries::new(series.iter().map(|p| (p.2, p.3)), c.stroke_width(2)))?
            .label(method_label(method))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
        chart.draw_series(series.iter().map(|p| Circle::new((p.2, p.3), 4, c.filled())))?;
        chart.draw_series(series.iter().map(|p| {
            Text::new(p.1[..1].to_uppercase(), (p.2, p.3), ("sans-serif", 12).into_font().color(&c))
        }))?;
    }
    chart.draw_series(front.iter().map(|&i| Circle::new((points[i].2, points[i].3), 8, BLACK.stroke_width(1))))?;
    chart.configure_series_labels().background_style(WHITE.mix(0.9)).border_style(BLACK).position(SeriesLabelPosition::UpperRight).draw()?;
    root.present()?;
    Ok(())
}

fn publish(results: &Results) -> Result<(), String> {
    let records = &results.records;
    let doc = manifest("docs/benchmark.md");
    let plots = manifest("docs/benchmark");
    std::fs::create_dir_all(&plots).map_err(|e| format!("{}: {e}", plots.display()))?;
    let distinct = |field: fn(&Record) -> &String| {
        let mut values: Vec<String> = records.iter().map(|r| field(r).clone()).collect();
        values.sort();
        values.dedup();
        values
    };
    let (devices, commits) = (distinct(|r| &r.device), distinct(|r| &r.commit));
    let generated = format!(
        "_Generated by `cargo run --release --features tools --example gi_bench -- --publish` from `docs/benchmark.json` ({} records; device: {}; commits: {})._\n",
        records.len(),
        devices.join(", "),
        commits.join(", ")
    );

    // Per scene: a table and a plot.
    let mut scenes: Vec<String> = records.iter().map(|r| r.scene.clone()).collect();
    scenes.sort_by_key(|s| scene_order(s));
    scenes.dedup();
    let mut body = String::new();
    // Each preset's cost as its median over the standard scenes (the rooms' plot uses it).
    let median_cost = |method: &str, preset: &str| {
        let v: Vec<f64> = records.iter().filter(|r| r.method == method && r.preset == preset).filter_map(|r| r.still_ratio).collect();
        (!v.is_empty()).then(|| common::median(&v))
    };
    for scene in scenes.iter().filter(|s| !s.starts_with("room_")) {
        let rows: Vec<&Record> = records.iter().filter(|r| &r.scene == scene).collect();
        // A scene whose cost was not measured (an error-only run) is plotted at each preset's median cost
        // over the scenes that were, and says so.
        let timed = rows.iter().any(|r| r.still_ratio.is_some());
        let points: Vec<Point> = rows
            .iter()
            .filter_map(|r| {
                let cost = r.still_ratio.or_else(|| median_cost(&r.method, &r.preset))?;
                Some((r.method.clone(), r.preset.clone(), cost, r.block_rmse))
            })
            .collect();
        let front = pareto(&points);
        let on_front = |r: &Record| front.iter().any(|&i| points[i].0 == r.method && points[i].1 == r.preset);
        let one_bounce = rows.iter().any(|r| r.one_bounce_block_rmse.is_some());
        let truth_note = if scene == "near_light" { " (against its one-bounce truth, the only one committed)" } else { "" };
        body += &format!("### `{scene}`{truth_note}\n\n");
        if !timed {
            body += "Cost not measured on this scene in this run: the plot places each preset at its median still-frame cost over\nthe scenes that were timed.\n\n";
        } else if rows.iter().any(|r| r.still_ratio.is_none()) {
            body += "Rows without a cost were measured for error only; the plot places them at their preset's median still-frame\ncost over the timed scenes.\n\n";
        }
        body += &format!(
            "| method | preset | block rel. RMSE | energy | blocks > 50 % off |{} FLIP | still × no GI (256²) | moving light × | still × (512²) | GPU memory MiB | main thread ms | preparation ms | front |\n|---|---|---|---|---|{}---|---|---|---|---|---|---|---|\n",
            if one_bounce { " one bounce: RMSE / energy |" } else { "" },
            if one_bounce { "---|" } else { "" },
        );
        for r in &rows {
            body += &format!(
                "| {} | {} | {:.3} | {:.2} | {:.1} % |{} {} | {} | {} | {} | {} | {} | {} | {} |\n",
                method_label(&r.method),
                r.preset,
                r.block_rmse,
                r.energy,
                100.0 * r.bad_blocks,
                if one_bounce { format!(" {} / {} |", opt(r.one_bounce_block_rmse, 3), opt(r.one_bounce_energy, 2)) } else { String::new() },
                opt(r.flip, 3),
                opt(r.still_ratio, 2),
                opt(r.moving_ratio, 2),
                opt(r.still_512_ratio, 2),
                mib(r.gpu_memory_bytes),
                opt(r.main_thread_ms, 2),
                opt(r.prep_ms, 0),
                if on_front(r) { "◆" } else { "" },
            );
        }
        if !points.is_empty() {
            let file = format!("{scene}.svg");
            let x_label = if timed { "still frame × frame without GI" } else { "still frame × no GI (median over the timed scenes)" };
            plot(&plots.join(&file), &format!("{scene}: error against cost, 256² on {}", short_device(&devices)), x_label, &points)
                .map_err(|e| format!("{file}: {e}"))?;
            body += &format!("\n![{scene}: block RMSE against still-frame cost](benchmark/{file})\n");
        }
        body += "\n";
    }
    common::replace_section(&doc, "gi_bench", "scenes", &body)?;

    // The rooms: per room, then the distribution, tuning and held-out apart.
    let rooms: Vec<&String> = scenes.iter().filter(|s| s.starts_with("room_")).collect();
    let mut body = String::new();
    if !rooms.is_empty() {
        body += "| room | seeds | description |";
        for m in GiMethod::ALL {
            body += &format!(" {} low / medium / high |", method_label(m.name()));
        }
        body += "\n|---|---|---|";
        body += &"---|".repeat(GiMethod::ALL.len());
        body += "\n";
        for scene in &rooms {
            let seed: u64 = scene.trim_start_matches("room_").parse().unwrap_or(0);
            body += &format!(
                "| {scene} | {} | {} |",
                if ROOM_HELD_OUT_SEEDS.contains(&seed) { "held out" } else { "tuning" },
                GeneratedRoom::new(seed).describe()
            );
            for m in GiMethod::ALL {
                let cells: Vec<String> = PRESETS
                    .iter()
                    .map(|p| {
                        records
                            .iter()
                            .find(|r| &&r.scene == scene && r.method == m.name() && r.preset == *p)
                            .map_or("—".into(), |r| format!("{:.2}", r.block_rmse))
                    })
                    .collect();
                body += &format!(" {} |", cells.join(" / "));
            }
            body += "\n";
        }
        body += "\nMedians of the block relative RMSE (energy) over the rooms:\n\n| method | preset | tuning rooms | held-out rooms |\n|---|---|---|---|\n";
        let mut points = Vec::new();
        for m in GiMethod::ALL {
            for p in PRESETS {
                let pick = |held: bool| {
                    let rows: Vec<&Record> = records.iter().filter(|r| r.scene.starts_with("room_") && r.method == m.name() && r.preset == p && r.held_out == held).collect();
                    let rmse: Vec<f64> = rows.iter().map(|r| r.block_rmse).collect();
                    let energy: Vec<f64> = rows.iter().map(|r| r.energy).collect();
                    (!rows.is_empty()).then(|| (common::median(&rmse), common::median(&energy), rows.len()))
                };
                let (tuning, held) = (pick(false), pick(true));
                if tuning.is_none() && held.is_none() {
                    continue;
                }
                let cell = |v: Option<(f64, f64, usize)>| v.map_or("—".into(), |(r, e, n)| format!("{r:.3} ({e:.2}), {n} rooms"));
                body += &format!("| {} | {p} | {} | {} |\n", method_label(m.name()), cell(tuning), cell(held));
                if let (Some((r, ..)), Some(cost)) = (held.or(tuning), median_cost(m.name(), p)) {
                    points.push((m.name().to_string(), p.to_string(), cost, r));
                }
            }
        }
        if !points.is_empty() {
            plot(&plots.join("rooms.svg"), "generated rooms (held out): median error against median cost", "still frame × no GI (median over the standard scenes)", &points)
                .map_err(|e| format!("rooms.svg: {e}"))?;
            body += "\n![rooms: median block RMSE of the held-out rooms against median cost](benchmark/rooms.svg)\n";
        }
    }
    common::replace_section(&doc, "gi_bench", "rooms", &body)?;

    let stress: StressResults = match std::fs::read_to_string(manifest(STRESS_JSON)) {
        Ok(text) => serde_json::from_str(&text).map_err(|e| format!("{STRESS_JSON}: {e}"))?,
        Err(_) => StressResults::default(),
    };
    common::replace_section(&doc, "gi_bench", "stress", &stress_table(&stress.stress))?;

    // What the full run measures and these records lack.
    let mut missing = Vec::new();
    let all_scenes: Vec<String> = STANDARD_SCENES.iter().map(|s| s.to_string()).chain(ROOM_SAMPLE.iter().map(|s| format!("room_{s}"))).collect();
    for scene in &all_scenes {
        for m in GiMethod::ALL {
            let absent: Vec<&str> = PRESETS
                .iter()
                .copied()
                .filter(|p| !records.iter().any(|r| &r.scene == scene && r.method == m.name() && r.preset == *p))
                .collect();
            if !absent.is_empty() {
                missing.push(format!("`{scene}` {} ({})", method_label(m.name()), absent.join(", ")));
            }
        }
    }
    let missing = if missing.is_empty() {
        "Every method and preset was measured on every scene of the full run.\n".to_string()
    } else {
        format!("Not measured in these records (the full run measures them): {}.\n", missing.join("; "))
    };
    common::replace_section(&doc, "gi_bench", "missing", &missing)?;

    // The summary: every method's default over the standard scenes.
    let summary = defaults_table(records);
    common::replace_section(&doc, "gi_bench", "summary", &format!("{summary}\n{generated}"))?;
    common::replace_section(&manifest("README.md"), "gi_bench", "readme", &format!("{summary}\n{generated}"))?;
    let cross = cross_method_table(records);
    for report in ["docs/radiance_hints.md", "docs/vpl_ssbc.md", "docs/one_bounce.md", "docs/radiosity.md", "docs/photon_grid.md"] {
        common::replace_section(&manifest(report), "gi_bench", "methods", &format!("{cross}\n{generated}"))?;
    }
    println!("{summary}");
    Ok(())
}

/// One row per case: what it does, the warnings it must log, and per method the outcome.
fn stress_table(stress: &[StressRecord]) -> String {
    if stress.is_empty() {
        return "Not run yet (`gi_bench --stress --publish`).\n".into();
    }
    let mut out = String::from(
        "Each case on `cornell`, each method's `LOW` preset, 32², six frames plus at most 20 s for the CPU methods' background work, indirect light only\n\
         (`tests/gpu_stress.rs` runs the same matrix). A cell reads ✓ when the run finished, no frame read back held NaN\n\
         or infinity, the plugin logged exactly the expected warnings and the bounced light is what the case leaves of it\n\
         (against the same method's on the unchanged scene: within a factor of two of the inverse-square value for a scaled\n\
         scene, of the unchanged value for odd geometry on the floor), then the mean luminance of the bounced light (cd/m²\n\
         after exposure) and, for CPU methods whose work outlasted the wait, \"still solving\".\n\n| case | expected warnings |",
    );
    for m in GiMethod::ALL {
        out += &format!(" {} |", method_label(m.name()));
    }
    out += "\n|---|---|";
    out += &"---|".repeat(GiMethod::ALL.len());
    out += "\n";
    let mut cases: Vec<(&str, &str, usize)> = stress.iter().map(|s| (s.case.as_str(), s.description.as_str(), s.expected_warnings)).collect();
    cases.dedup();
    for (case, description, expected) in cases {
        out += &format!("| `{case}`: {description} | {expected} |");
        for m in GiMethod::ALL {
            let cell = stress.iter().find(|s| s.case == case && s.method == m.name()).map_or("—".into(), |s| {
                let mark = if s.passed { "✓".to_string() } else { format!("✗ {}", s.verdict.replace('|', "/")) };
                format!("{mark} {:.2e}{}", s.mean_luminance, if s.background_timed_out { ", still solving" } else { "" })
            });
            out += &format!(" {cell} |");
        }
        out += "\n";
    }
    let failed = stress.iter().filter(|s| !s.passed).count();
    out += &format!("\n{} runs, {failed} failed; commit {}.\n", stress.len(), stress.first().map_or("?", |s| s.commit.as_str()));
    out
}

fn short_device(devices: &[String]) -> String {
    devices.first().map_or("?".into(), |d| d.split(" (").next().unwrap_or(d).to_string())
}

/// `| method | settings | cornell | cellar | median of the standard scenes | rooms | still × | moving × | memory | needs |`
fn defaults_table(records: &[Record]) -> String {
    let mut out = String::from(
        "| method | settings | `cornell` block RMSE / energy | `cellar` | median of the standard scenes measured | generated rooms, tuning / held out (median) | still frame × no GI, 256² / 512² (median of the timed scenes) | moving light × no GI (median) | GPU memory (cornell) | needs |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    for m in GiMethod::ALL {
        let name = m.name();
        let rows: Vec<&Record> = records.iter().filter(|r| r.method == name && r.preset == "medium").collect();
        if rows.is_empty() {
            continue;
        }
        let at = |scene: &str| rows.iter().find(|r| r.scene == scene).map_or("—".into(), |r| format!("{:.3} / {:.2}", r.block_rmse, r.energy));
        let standard: Vec<&&Record> = rows.iter().filter(|r| !r.scene.starts_with("room_")).collect();
        let med = |f: &dyn Fn(&Record) -> Option<f64>, list: &[&&Record]| {
            let v: Vec<f64> = list.iter().filter_map(|r| f(r)).filter(|x| x.is_finite()).collect();
            (!v.is_empty()).then(|| common::median(&v))
        };
        let rooms = |held: bool| {
            let list: Vec<&&Record> = rows.iter().filter(|r| r.scene.starts_with("room_") && r.held_out == held).collect();
            med(&|r| Some(r.block_rmse), &list)
        };
        let cornell_memory = rows.iter().find(|r| r.scene == "cornell").and_then(|r| r.gpu_memory_bytes);
        let (settings, needs) = match m {
            GiMethod::RadianceHints => ("`RadianceHintsVolume`", "a volume around the scene"),
            GiMethod::Vpl => ("`VplSettings`", "CPU cores in the background for its walks and shadow-map rays"),
            GiMethod::RsmGather => ("`RsmGatherSettings`", "— (one bounce)"),
            GiMethod::Drm => ("`DrmSettings`", "— (one bounce)"),
            GiMethod::Radiosity => ("`RadiositySettings`", "CPU cores in the background: its light lags a change by one solve"),
            GiMethod::PhotonGrid => ("`PhotonGridSettings`", "CPU cores in the background: its light lags a change by one preparation"),
        };
        out += &format!(
            "| `{m:?}` ({name}) | {settings} | {} | {} | {} | {} / {} | {} / {} | {} | {} MiB | {needs} |\n",
            at("cornell"),
            at("cellar"),
            opt(med(&|r| Some(r.block_rmse), &standard), 3),
            opt(rooms(false), 3),
            opt(rooms(true), 3),
            opt(med(&|r| r.still_ratio, &standard), 2),
            opt(med(&|r| r.still_512_ratio, &standard), 2),
            opt(med(&|r| r.moving_ratio, &standard), 2),
            mib(cornell_memory),
        );
    }
    out
}

/// Every method's default on the three scenes every report uses, for the per-method reports.
fn cross_method_table(records: &[Record]) -> String {
    let mut out = String::from(
        "Every method with its default settings (`MEDIUM`), 256², against the path-traced truth of all bounces (and of one\n\
         bounce, the one-bounce methods' target), from the benchmark (`docs/benchmark.md`):\n\n\
         | scene | method | block rel. RMSE | energy | one bounce: RMSE / energy | still frame × no GI | moving light × no GI |\n|---|---|---|---|---|---|---|\n",
    );
    for scene in ["cornell", "cellar", "sponza_like"] {
        for m in GiMethod::ALL {
            if let Some(r) = records.iter().find(|r| r.scene == scene && r.method == m.name() && r.preset == "medium") {
                out += &format!(
                    "| `{scene}` | {} | {:.3} | {:.2} | {} / {} | {} | {} |\n",
                    method_label(m.name()),
                    r.block_rmse,
                    r.energy,
                    opt(r.one_bounce_block_rmse, 3),
                    opt(r.one_bounce_energy, 2),
                    opt(r.still_ratio, 2),
                    opt(r.moving_ratio, 2)
                );
            }
        }
    }
    out
}
