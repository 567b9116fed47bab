//! Measures the photon grid against the path-traced ground truths, times its stages and sets it beside
//! Radiance Hints: the numbers of `docs/photon_grid.md`.
//!
//! ```text
//! cargo run --release --features tools --example photon_grid_report -- [--section NAME]... [--rounds N] [--docs docs/photon_grid.md]
//! ```
//! Sections: `accuracy`, `stages`, `timing`, `field_device` (default: all). Each prints a Markdown table; with
//! `--docs FILE` the table also replaces the text between `<!-- photon_grid_report:NAME -->` and
//! `<!-- /photon_grid_report:NAME -->` in FILE. Renders run one after another in this process on
//! whatever Vulkan device wgpu picks (lavapipe on CI machines), at 256², against the committed EXRs of
//! `assets/ground_truth/`. The preparation runs on the CPU (rayon, every core of the machine): its stage
//! times are wall-clock milliseconds of the main thread.

#[path = "common/mod.rs"]
mod common;

use std::process::ExitCode;

use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::photon_grid::{FieldDevice, PhotonGridSettings};
use bevy_diffuse_gi::scenes::StandardScene;

const SECTIONS: &[&str] = &["accuracy", "stages", "timing", "field_device"];
/// Frames of a timed render, and the intervals at its end that the medians use.
const TIMING_FRAMES: u32 = 16;
const TIMED_FRAMES: usize = 8;

fn main() -> ExitCode {
    common::report_main("photon_grid_report", run)
}

fn run() -> Result<(), String> {
    let args = common::start_report("photon_grid_report", SECTIONS);
    let mut device = String::from("an unknown device");
    for section in &args.sections {
        let started = std::time::Instant::now();
        let table = match section.as_str() {
            "accuracy" => accuracy(&mut device)?,
            "stages" => stages(&mut device)?,
            "timing" => timing(&mut device, args.rounds)?,
            "field_device" => field_device(&mut device, args.rounds)?,
            _ => unreachable!("sections are validated"),
        };
        common::publish_section("photon_grid_report", &args, section, &table, &device, started)?;
    }
    Ok(())
}

fn options(scene: StandardScene, photon_grid: PhotonGridSettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::PhotonGrid),
        indirect_only: true,
        photon_grid,
        frames: 3,
        ..Default::default()
    }
}


/// The preparation's figures from a render's sidecar: the stage times (ms) and the counts.
struct Preparation {
    ms: [f64; 4],
    dims: String,
    boundary: u64,
    probes: u64,
    stored: u64,
}

fn preparation(report: &HeadlessReport) -> Preparation {
    let r = &report.sidecar["photon_grid"];
    let ms = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
    let dims: Vec<String> = r["dims"].as_array().map(|a| a.iter().map(|v| v.to_string()).collect()).unwrap_or_default();
    Preparation {
        ms: [ms("voxelize_ms"), ms("trace_ms"), ms("rgrid_ms"), ms("field_ms")],
        dims: dims.join("×"),
        boundary: r["boundary_sh_cells"].as_u64().unwrap_or(0),
        probes: r["probes"].as_u64().unwrap_or(0),
        stored: r["photons_stored"].as_u64().unwrap_or(0),
    }
}

const PRESETS: [(&str, PhotonGridSettings); 3] = [
    ("low (16 cells, 65 536 photons, 4 reflections, N_sh 128)", PhotonGridSettings::LOW),
    ("medium (32, 262 144, 8, 256; default)", PhotonGridSettings::MEDIUM),
    ("high (64, 1 048 576, 16, 400)", PhotonGridSettings::HIGH),
];

/// Each preset on the standard scenes, and the medium preset's parameters one at a time on the
/// issue's three scenes, against the full truth.
fn accuracy(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "Block relative RMSE, per-pixel relative RMSE, energy ratio and the share of 4×4 blocks more than 50 % off,\n\
         against the full path-traced truth (all bounces), and the preparation's time (a background task).\n\n\
         | scene | settings | block RMSE | pixel RMSE | energy | blocks > 50 % off | preparation ms |\n|---|---|---|---|---|---|---|\n",
    );
    let scenes = [
        (StandardScene::Cornell, "cornell"),
        (StandardScene::Cellar, "cellar"),
        (StandardScene::SponzaLike, "sponza_like"),
        (StandardScene::EmissivePanel, "emissive_panel"),
        (StandardScene::Dynamic, "dynamic"),
        (StandardScene::OpenField, "open_field"),
        (StandardScene::SkyRoom, "sky_room"),
    ];
    let medium = PhotonGridSettings::MEDIUM;
    for (scene, name) in scenes {
        let reference = common::report_truth(name)?;
        let mut configs: Vec<(String, PhotonGridSettings)> = PRESETS.iter().map(|(l, s)| (l.to_string(), s.clone())).collect();
        if ["cornell", "cellar", "sponza_like"].contains(&name) {
            for resolution in [16, 64] {
                configs.push((format!("medium, {resolution} cells"), PhotonGridSettings { resolution, ..medium.clone() }));
            }
            for photons in [65_536, 1_048_576] {
                configs.push((format!("medium, {photons} photons"), PhotonGridSettings { photons, ..medium.clone() }));
            }
            configs.push(("medium, 4 reflections (the paper's)".into(), PhotonGridSettings { max_reflections: 4, ..medium.clone() }));
            configs.push(("medium, no radiance filter (level 0)".into(), PhotonGridSettings { filter_levels: 0, ..medium.clone() }));
            configs.push(("medium, unbounded filter (the paper's)".into(), PhotonGridSettings { filter_levels: 5, ..medium.clone() }));
            configs.push(("medium, N_d = 32 (the paper's gather)".into(), PhotonGridSettings { gather_samples: 32, ..medium.clone() }));
        }
        for (label, settings) in configs {
            let report = common::report_render(device, &options(scene.clone(), settings))?;
            let m = common::report_compare(&report.image, &reference)?;
            let total: f64 = preparation(&report).ms.iter().sum();
            out += &format!("| {name} | {label} | {} | {total:.0} |\n", common::report_cells(&m));
        }
    }
    Ok(out)
}

/// The paper's Table 1: the preparation's stages per preset, with the grid and the photon list.
fn stages(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "The stages of one full preparation, ms of wall time on the CPU (share of the preparation), and what they\n\
         made: SH cells, boundary SH cells, probes of the field, stored photons.\n\n\
         | scene | preset | SH cells | boundary | probes | stored photons | voxelisation | photon tracing | R-grid | SH field | total |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (scene, name) in [(StandardScene::Cornell, "cornell"), (StandardScene::Cellar, "cellar"), (StandardScene::SponzaLike, "sponza_like")] {
        for (label, settings) in [("low", PhotonGridSettings::LOW), ("medium", PhotonGridSettings::MEDIUM), ("high", PhotonGridSettings::HIGH)] {
            let report = common::report_render(device, &options(scene.clone(), settings))?;
            let p = preparation(&report);
            let total: f64 = p.ms.iter().sum();
            let pct = |x: f64| format!("{x:.0} ({:.0} %)", 100.0 * x / total);
            out += &format!(
                "| {name} | {label} | {} | {} | {} | {} | {} | {} | {} | {} | {total:.0} |\n",
                p.dims,
                p.boundary,
                p.probes,
                p.stored,
                pct(p.ms[0]),
                pct(p.ms[1]),
                pct(p.ms[2]),
                pct(p.ms[3])
            );
        }
    }
    Ok(out)
}



/// Still-frame cost against the frame without GI, alternating in `rounds` rounds.
fn timing(device: &mut String, rounds: usize) -> Result<String, String> {
    let mut out = String::from(
        "Median frame time of a still frame (the field reused, only the gather runs) over the frame without GI,\n\
         measured alternately; the preparation is in `stages`.\n\n| scene | size | no GI ms | photon grid ms | ratio |\n|---|---|---|---|---|\n",
    );
    for (scene, name) in [(StandardScene::Cornell, "cornell"), (StandardScene::SponzaLike, "sponza_like")] {
        for size in [256u32, 512] {
            let (mut none, mut with) = (Vec::new(), Vec::new());
            for _ in 0..rounds.max(1) {
                let base = HeadlessOptions {
                    scene: scene.clone(),
                    size: bevy::math::UVec2::splat(size),
                    frames: TIMING_FRAMES,
                    ..Default::default()
                };
                none.push(common::frame_ms(&common::report_render(device, &base)?, TIMED_FRAMES));
                let gi = HeadlessOptions { method: HeadlessMethod::Gi(GiMethod::PhotonGrid), ..base };
                with.push(common::frame_ms(&common::report_render(device, &gi)?, TIMED_FRAMES));
            }
            let (a, b) = (common::median(&none), common::median(&with));
            out += &format!("| {name} | {size}² | {a:.1} | {b:.1} | {:.2} |\n", b / a);
        }
    }
    Ok(out)
}

/// The SH field built on the CPU and on the GPU the frame renders with (`FieldDevice`), alternating in
/// `rounds` rounds: the field's milliseconds in the background task, its probes, and how far apart the
/// two images are.
fn field_device(device: &mut String, rounds: usize) -> Result<String, String> {
    let mut out = String::from(
        "The SH field of one full preparation at the default preset, built on the CPU (rayon) and on the GPU the\n\
         frame renders with (`--photon-field cpu|gpu`), alternating; ms of wall time in the background task while\n\
         frames render (min–max over the rounds), the probes kept, and the GPU's image against the CPU's.\n\n\
         | scene | CPU field ms | GPU field ms | GPU / CPU | probes CPU / GPU | block RMSE between the images | energy GPU / CPU |\n\
         |---|---|---|---|---|---|---|\n",
    );
    let range = |v: &[f64]| format!("{:.0}–{:.0}", v.iter().copied().fold(f64::INFINITY, f64::min), v.iter().copied().fold(0.0, f64::max));
    for (scene, name) in [
        (StandardScene::Cornell, "cornell"),
        (StandardScene::Cellar, "cellar"),
        (StandardScene::SponzaLike, "sponza_like"),
        (StandardScene::Dynamic, "dynamic"),
    ] {
        let (mut cpu_ms, mut gpu_ms) = (Vec::new(), Vec::new());
        let mut last = None;
        for _ in 0..rounds.max(1) {
            let run = |device: &mut String, field_device| {
                common::report_render(device, &options(scene.clone(), PhotonGridSettings { field_device, ..PhotonGridSettings::MEDIUM }))
            };
            let cpu = run(device, FieldDevice::Cpu)?;
            let gpu = run(device, FieldDevice::Gpu)?;
            if gpu.sidecar["photon_grid"]["field_on_gpu"].as_bool() != Some(true) {
                return Err(format!("{name}: the GPU did not build the field (see the log)"));
            }
            cpu_ms.push(preparation(&cpu).ms[3]);
            gpu_ms.push(preparation(&gpu).ms[3]);
            last = Some((cpu, gpu));
        }
        let (cpu, gpu) = last.expect("one round at least");
        let m = common::report_compare(&gpu.image, &cpu.image)?;
        out += &format!(
            "| {name} | {} | {} | {:.2} | {} / {} | {:.4} | {:.4} |\n",
            range(&cpu_ms),
            range(&gpu_ms),
            common::median(&gpu_ms) / common::median(&cpu_ms),
            preparation(&cpu).probes,
            preparation(&gpu).probes,
            m.block_relative_rmse,
            m.energy_ratio
        );
    }
    Ok(out)
}
