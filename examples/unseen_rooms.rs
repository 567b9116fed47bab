//! Measures every method on the generated family of rooms ([`GeneratedRoom`]) against the path tracer: the
//! numbers and images of `docs/unseen_rooms.md`.
//!
//! ```text
//! cargo run --release --features tools --example unseen_rooms -- [--seeds 0..24] [--methods rh,vpl,...] [--docs docs/unseen_rooms.md]
//! ```
//! * Ground truths: `assets/ground_truth/rooms/room_SEED.exr` (indirect light only, 64², the average of
//!   4–16 tracer seeds of 2048 samples per pixel, until the estimated block noise is below 1.5 %) and its
//!   `.json` (that noise). Missing ones are traced first; `--retrace` traces them again.
//! * Every method renders every room with its defaults and no other flag (`--method X`), 16 frames plus
//!   the wait for its background work, at 64².
//! * Per method: the distribution (median, 90th percentile, worst) of block relative RMSE, energy and
//!   the share of 4×4 blocks more than 50 % off, for the tuning seeds and the held-out seeds
//!   ([`ROOM_HELD_OUT_SEEDS`]) apart; the energy of the camera's own room (pixels that do not look through
//!   a door); one row per room; images of each method's worst room beside the truth.
//! * `--json FILE` writes every number (the CI test's limits are set from it).

#[path = "common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};

use bevy::math::UVec2;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics::{self, ErrorMetrics};
use bevy_diffuse_gi::scenes::{GeneratedRoom, ROOM_HELD_OUT_SEEDS, StandardScene};
use serde_json::json;

/// Image side, pixels.
const SIZE: u32 = 64;
/// Tracer seeds averaged per ground truth (at least the first, more until the estimated block noise is
/// below [`TRUTH_NOISE`], at most the second), and samples per pixel of each.
const TRUTH_SEEDS: (u64, u64) = (4, 16);
const TRUTH_SPP: u32 = 2048;
/// The block relative RMSE of a ground truth's own noise it is traced to (`shared/METRICS.md`: < 2 %).
const TRUTH_NOISE: f64 = 0.015;
/// Frames each method renders before the image is kept (then it waits for its background work).
const FRAMES: u32 = 16;
/// At most this long for a CPU method's background work, seconds.
const WAIT_BACKGROUND: u32 = 300;

#[derive(clap::Parser)]
#[command(name = "unseen_rooms", about = "Every method on the generated rooms against the path tracer (docs/unseen_rooms.md).")]
struct Cli {
    /// Seeds of the family: ranges START..END, comma-separated
    #[arg(long, value_name = "START..END,...", default_value = "0..24", value_parser = parse_seeds)]
    seeds: Seeds,
    /// Methods, comma-separated (rh, vpl, rsm, drm, radiosity, photon-grid) [default: all]
    #[arg(long, value_delimiter = ',')]
    methods: Vec<String>,
    /// Replace the sections between the `<!-- unseen_rooms:NAME -->` markers of this Markdown file
    #[arg(long, value_name = "FILE.md")]
    docs: Option<PathBuf>,
    /// Write every number to this JSON file
    #[arg(long, value_name = "FILE.json")]
    json: Option<PathBuf>,
    /// Trace the ground truths again even where they exist
    #[arg(long)]
    retrace: bool,
    /// Only trace the missing ground truths
    #[arg(long)]
    truths_only: bool,
    /// Write a strip per room to this folder: the truth, then each method (tonemapped alike, 3× nearest)
    #[arg(long, value_name = "DIR")]
    strips: Option<PathBuf>,
}

/// The seeds of `--seeds`, and how they were written.
#[derive(Clone, Debug)]
struct Seeds(Vec<u64>, String);

fn parse_seeds(text: &str) -> Result<Seeds, String> {
    let mut seeds = Vec::new();
    for range in text.split(',') {
        let (a, b) = range.split_once("..").ok_or("expected START..END")?;
        let (a, b) = (a.parse::<u64>().map_err(|e| e.to_string())?, b.parse::<u64>().map_err(|e| e.to_string())?);
        if a >= b {
            return Err("START must be below END".into());
        }
        seeds.extend(a..b);
    }
    Ok(Seeds(seeds, text.to_string()))
}

fn main() -> std::process::ExitCode {
    common::report_main("unseen_rooms", run)
}

fn truth_path(seed: u64) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("assets/ground_truth/rooms/room_{seed}.exr"))
}

/// Traces the ground truth of `seed` as the average of [`TRUTH_SEEDS`] tracer seeds; writes its EXR and a
/// JSON with the estimated block noise (half the block RMSE of the even seeds' average against the odd's).
fn trace_truth(seed: u64, device: &mut String) -> Result<(), String> {
    let path = truth_path(seed);
    std::fs::create_dir_all(path.parent().expect("a folder")).map_err(|e| e.to_string())?;
    let mut images = Vec::new();
    let started = std::time::Instant::now();
    let average = |images: &[HdrImage], pick: &dyn Fn(usize) -> bool| {
        let chosen: Vec<&HdrImage> = images.iter().enumerate().filter(|(i, _)| pick(*i)).map(|(_, im)| im).collect();
        HdrImage::average(&chosen).map_err(|e| e.to_string())
    };
    let mut noise = f64::INFINITY;
    for k in 0..TRUTH_SEEDS.1 {
        let options = HeadlessOptions {
            scene: StandardScene::Room(seed),
            size: UVec2::splat(SIZE),
            method: HeadlessMethod::Reference,
            indirect_only: true,
            spp: TRUTH_SPP,
            seed: 1 + k,
            ..Default::default()
        };
        images.push(common::report_render(device, &options)?.image);
        if images.len() as u64 >= TRUTH_SEEDS.0 && images.len() % 2 == 0 {
            let half = common::report_compare(&average(&images, &|i| i % 2 == 0)?, &average(&images, &|i| i % 2 == 1)?)?;
            noise = half.block_relative_rmse / 2.0;
            if noise <= TRUTH_NOISE {
                break;
            }
        }
    }
    let all = average(&images, &|_| true)?;
    all.write_exr(&path).map_err(|e| e.to_string())?;
    let room = GeneratedRoom::new(seed);
    let sidecar = json!({
        "scene": room.name(),
        "description": room.describe(),
        "size": [SIZE, SIZE],
        "spp_per_seed": TRUTH_SPP,
        "seeds": images.len(),
        "seconds": started.elapsed().as_secs_f64(),
        "estimated_block_noise_of_average": noise,
    });
    std::fs::write(path.with_extension("json"), serde_json::to_string_pretty(&sidecar).expect("JSON")).map_err(|e| e.to_string())
}

/// One method on one room.
struct Row {
    seed: u64,
    method: GiMethod,
    metrics: ErrorMetrics,
    room_energy: f64,
    image: HdrImage,
}

fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let position = q * (v.len() - 1) as f64;
    let (i, f) = (position.floor() as usize, position.fract());
    if i + 1 < v.len() { v[i] * (1.0 - f) + v[i + 1] * f } else { v[i] }
}

/// `| method | rooms | block RMSE median / p90 / worst | energy median | rooms within ±10 % | bad blocks median / worst | camera room energy median / worst |`
fn summary_row(method: GiMethod, rows: &[&Row]) -> String {
    let rmse: Vec<f64> = rows.iter().map(|r| r.metrics.block_relative_rmse).collect();
    let energy: Vec<f64> = rows.iter().map(|r| r.metrics.energy_ratio).collect();
    let bad: Vec<f64> = rows.iter().map(|r| r.metrics.blocks_over_half_off).collect();
    let room: Vec<f64> = rows.iter().map(|r| r.room_energy).collect();
    let within = energy.iter().filter(|e| (**e - 1.0).abs() <= 0.1).count();
    let room_worst = room.iter().copied().filter(|e| e.is_finite()).max_by(|a, b| (a - 1.0).abs().total_cmp(&(b - 1.0).abs())).unwrap_or(f64::NAN);
    format!(
        "| {} | {} | {:.3} / {:.3} / {:.3} | {:.2} | {} of {} | {:.1} % / {:.1} % | {:.2} / {:.2} |\n",
        method.name(),
        rows.len(),
        quantile(&rmse, 0.5),
        quantile(&rmse, 0.9),
        quantile(&rmse, 1.0),
        quantile(&energy, 0.5),
        within,
        rows.len(),
        100.0 * quantile(&bad, 0.5),
        100.0 * quantile(&bad, 1.0),
        quantile(&room, 0.5),
        room_worst,
    )
}

fn run() -> Result<(), String> {
    use clap::Parser;
    let cli = Cli::parse();
    if std::env::var_os("WGPU_BACKEND").is_none() {
        // SAFETY: set before any render thread exists.
        unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    }
    let started = std::time::Instant::now();
    let mut device = String::from("an unknown device");
    let methods = common::gi_methods(&cli.methods)?;

    let mut truths = Vec::new();
    for &seed in &cli.seeds.0 {
        if cli.retrace || !truth_path(seed).is_file() {
            eprintln!("tracing the ground truth of room_{seed}");
            trace_truth(seed, &mut device)?;
        }
        truths.push((seed, HdrImage::read(truth_path(seed)).map_err(|e| format!("{}: {e}", truth_path(seed).display()))?));
    }
    if cli.truths_only {
        return Ok(());
    }

    let mut rows = Vec::new();
    for (seed, truth) in &truths {
        let room = GeneratedRoom::new(*seed);
        for &method in &methods {
            let options = HeadlessOptions {
                scene: StandardScene::Room(*seed),
                size: UVec2::splat(SIZE),
                method: HeadlessMethod::Gi(method),
                indirect_only: true,
                frames: FRAMES,
                wait_background: Some(WAIT_BACKGROUND),
                ..Default::default()
            };
            let image = common::report_render(&mut device, &options)?.image;
            let metrics = common::report_compare(&image, truth)?;
            let room_energy = room.camera_room_energy(&image, truth);
            eprintln!(
                " room_{seed} {}: {:.3} / energy {:.2} / room {:.2} / {:.0} % bad",
                method.name(),
                metrics.block_relative_rmse,
                metrics.energy_ratio,
                room_energy,
                100.0 * metrics.blocks_over_half_off
            );
            rows.push(Row { seed: *seed, method, metrics, room_energy, image });
        }
    }

    if let Some(dir) = &cli.strips {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        for (seed, truth) in &truths {
            let mut images = vec![truth];
            images.extend(rows.iter().filter(|r| r.seed == *seed).map(|r| &r.image));
            let path = dir.join(format!("room_{seed}.png"));
            strip(&images, display_scale(truth), 3).save(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        }
    }

    let held_out = |seed: u64| ROOM_HELD_OUT_SEEDS.contains(&seed);
    let header = "| method | rooms | block rel. RMSE median / p90 / worst | energy median | energy within ±10 % | blocks > 50 % off median / worst | camera room energy median / worst |\n\
                  |---|---|---|---|---|---|---|\n";
    let mut summary = String::new();
    for (title, pick) in [("Tuning seeds", false), ("Held-out seeds", true)] {
        let seeds: Vec<u64> = truths.iter().map(|(s, _)| *s).filter(|s| held_out(*s) == pick).collect();
        if seeds.is_empty() {
            continue;
        }
        summary += &format!("**{title}** ({}–{}):\n\n{header}", seeds[0], seeds[seeds.len() - 1]);
        for &method in &methods {
            let subset: Vec<&Row> = rows.iter().filter(|r| r.method == method && held_out(r.seed) == pick).collect();
            summary += &summary_row(method, &subset);
        }
        summary += "\n";
    }

    let mut per_room = String::from("| room | scene | noise of the truth |");
    for m in &methods {
        per_room += &format!(" {} |", m.name());
    }
    per_room += "\n|---|---|---|";
    per_room += &"---|".repeat(methods.len());
    per_room += "\n";
    for (seed, _) in &truths {
        let room = GeneratedRoom::new(*seed);
        let noise: f64 = std::fs::read_to_string(truth_path(*seed).with_extension("json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["estimated_block_noise_of_average"].as_f64())
            .unwrap_or(f64::NAN);
        per_room += &format!("| {}{} | {} | {:.3} |", room.name(), if held_out(*seed) { " (held out)" } else { "" }, room.describe(), noise);
        for &m in &methods {
            let r = rows.iter().find(|r| r.seed == *seed && r.method == m).expect("measured");
            per_room += &format!(" {:.3} / {:.2} / {:.2} |", r.metrics.block_relative_rmse, r.metrics.energy_ratio, r.room_energy);
        }
        per_room += "\n";
    }

    // Images: each method's worst room (by block RMSE) beside its truth.
    let image_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/images/unseen_rooms");
    std::fs::create_dir_all(&image_dir).map_err(|e| e.to_string())?;
    let mut images = String::from("| method | worst room | method | truth | difference |\n|---|---|---|---|---|\n");
    for &m in &methods {
        let Some(worst) = rows.iter().filter(|r| r.method == m).max_by(|a, b| a.metrics.block_relative_rmse.total_cmp(&b.metrics.block_relative_rmse)) else {
            continue;
        };
        let truth = &truths.iter().find(|(s, _)| *s == worst.seed).expect("truth").1;
        let scale = display_scale(truth);
        let stem = format!("{}_room_{}", m.name(), worst.seed);
        write_png(&worst.image, &image_dir.join(format!("{stem}.png")), scale)?;
        write_png(truth, &image_dir.join(format!("truth_room_{}.png", worst.seed)), scale)?;
        let diff = metrics::difference_image(&worst.image, truth, 1.0).map_err(|e| e.to_string())?;
        diff.save(image_dir.join(format!("{stem}.diff.png"))).map_err(|e| e.to_string())?;
        images += &format!(
            "| {} | room_{} ({:.3}) | <img src=\"images/unseen_rooms/{stem}.png\" width=\"192\"> | <img src=\"images/unseen_rooms/truth_room_{}.png\" width=\"192\"> | <img src=\"images/unseen_rooms/{stem}.diff.png\" width=\"192\"> |\n",
            m.name(),
            worst.seed,
            worst.metrics.block_relative_rmse,
            worst.seed
        );
    }

    let footer = format!(
        "\n_Generated by `cargo run --release --features tools --example unseen_rooms -- --seeds {}` on {device}, in {:.0} s._\n",
        cli.seeds.1,
        started.elapsed().as_secs_f64()
    );
    for (name, body) in [("summary", &summary), ("rooms", &per_room), ("images", &images)] {
        println!("\n## {name}\n\n{body}");
        if let Some(docs) = &cli.docs {
            common::replace_section(docs, "unseen_rooms", name, &format!("{body}{footer}"))?;
        }
    }
    if let Some(path) = &cli.json {
        let out: Vec<_> = rows
            .iter()
            .map(|r| {
                json!({
                    "seed": r.seed,
                    "method": r.method.name(),
                    "block_relative_rmse": r.metrics.block_relative_rmse,
                    "energy_ratio": r.metrics.energy_ratio,
                    "blocks_over_half_off": r.metrics.blocks_over_half_off,
                    "camera_room_energy": r.room_energy,
                })
            })
            .collect();
        std::fs::write(path, serde_json::to_string_pretty(&out).expect("JSON")).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

/// A tonemapping scale that shows the truth's 95th-percentile pixel near 0.8.
fn display_scale(truth: &HdrImage) -> f32 {
    let mut values: Vec<f32> = truth.pixels.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).filter(|v| *v > 0.0).collect();
    if values.is_empty() {
        return 1.0;
    }
    values.sort_by(f32::total_cmp);
    let p95 = values[(values.len() as f32 * 0.95) as usize];
    4.0 / p95.max(1e-6)
}

fn write_png(image: &HdrImage, path: &Path, scale: f32) -> Result<(), String> {
    image.write_png_tonemapped(path, scale).map_err(|e| format!("{}: {e}", path.display()))
}

/// `images` side by side, tonemapped alike ([`HdrImage::tonemapped`]), each pixel `zoom`² pixels.
fn strip(images: &[&HdrImage], scale: f32, zoom: u32) -> image::RgbImage {
    let (w, h) = (images[0].width * zoom, images[0].height * zoom);
    let mut out = image::RgbImage::new(w * images.len() as u32, h);
    for (k, im) in images.iter().enumerate() {
        let zoomed = image::imageops::resize(&im.tonemapped(scale), w, h, image::imageops::FilterType::Nearest);
        image::imageops::replace(&mut out, &zoomed, (k as u32 * w) as i64, 0);
    }
    out
}
