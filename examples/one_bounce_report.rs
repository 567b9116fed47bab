//! Measures the one-bounce gathers (RSM gather, Direct Radiance Mapping) against the one-bounce and the
//! full path-traced ground truths and times them beside the other methods: the numbers of
//! `docs/one_bounce.md`.
//!
//! ```text
//! cargo run --release --features tools --example one_bounce_report -- [--section NAME]... [--rounds N] [--docs docs/one_bounce.md]
//! ```
//! Sections: `accuracy`, `near_light`, `flashing`, `timing`, `images` (default: all). Each prints a
//! Markdown table; with `--docs FILE` the table also replaces the text between
//! `<!-- one_bounce_report:NAME -->` and `<!-- /one_bounce_report:NAME -->` in FILE. Renders run one
//! after another in this process on whatever Vulkan device wgpu picks (lavapipe on CI machines), at 256²
//! unless a table says otherwise, against the committed EXRs of `assets/ground_truth/`.
//!
//! Timing: lavapipe's timestamps do not bracket compute passes, so costs are median frame times of
//! configurations measured alternately in `--rounds` rounds, quoted as ratios to the frame without GI
//! measured in the same rounds.

#[path = "common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use bevy::math::UVec2;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::drm::{DrmSettings, DrmSolidAngle};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::metrics::{self, ErrorMetrics};
use bevy_diffuse_gi::rsm_gather::{RsmGatherSettings, RsmSampleWeights};
use bevy_diffuse_gi::scenes::StandardScene;

const SECTIONS: &[&str] = &["accuracy", "near_light", "flashing", "timing", "images"];

/// Frames of a timed render, and the intervals at its end that the medians use.
const TIMING_FRAMES: u32 = 16;
const TIMED_FRAMES: usize = 8;
/// Frames of the flashing runs: each compares its last two frames, at six points of the light's orbit.
const FLASHING_FRAMES: [u32; 6] = [6, 10, 14, 18, 22, 26];

fn main() -> ExitCode {
    common::report_main("one_bounce_report", run)
}

fn run() -> Result<(), String> {
    let args = common::start_report("one_bounce_report", SECTIONS);
    let mut report = Report::new()?;
    for section in &args.sections {
        let started = std::time::Instant::now();
        let table = match section.as_str() {
            "accuracy" => report.accuracy()?,
            "near_light" => report.near_light()?,
            "flashing" => report.flashing()?,
            "timing" => report.timing(args.rounds)?,
            "images" => report.images()?,
            _ => unreachable!("sections are validated"),
        };
        common::publish_section("one_bounce_report", &args, section, &table, &report.device, started)?;
    }
    Ok(())
}

fn rsm(scene: StandardScene, rsm_gather: RsmGatherSettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::RsmGather),
        indirect_only: true,
        rsm_gather,
        frames: 3,
        ..Default::default()
    }
}

fn drm(scene: StandardScene, drm: DrmSettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::Drm),
        indirect_only: true,
        drm,
        frames: 3,
        ..Default::default()
    }
}

fn drm_with(n: u32, solid_angle: DrmSolidAngle) -> DrmSettings {
    DrmSettings { samples_per_axis: n, solid_angle, ..DrmSettings::default() }
}

fn eq(solid_angle: DrmSolidAngle) -> String {
    format!("Eq. {}", solid_angle.equation())
}

/// The configurations of the accuracy table: name and options for a scene.
fn configurations(scene: &StandardScene) -> Vec<(String, HeadlessOptions)> {
    let mut configs = Vec::new();
    for (name, s) in [("low (64)", RsmGatherSettings::LOW), ("medium (144)", RsmGatherSettings::MEDIUM), ("high (400)", RsmGatherSettings::HIGH)]
    {
        configs.push((format!("RSM gather {name}"), rsm(scene.clone(), s)));
    }
    configs.push((
        "RSM gather high, the paper's ξ₁² weights".into(),
        rsm(scene.clone(), RsmGatherSettings { weights: RsmSampleWeights::Paper, ..RsmGatherSettings::HIGH }),
    ));
    for radius in [0.25, 0.5] {
        configs.push((format!("RSM gather medium, r_max {radius}"), rsm(scene.clone(), RsmGatherSettings { radius, ..RsmGatherSettings::MEDIUM })));
    }
    for solid_angle in DrmSolidAngle::ALL {
        for n in [2, 3, 4, 8, 16] {
            configs.push((format!("DRM {}, M = {n}×{n}", eq(solid_angle)), drm(scene.clone(), drm_with(n, solid_angle))));
        }
    }
    for n in [3, 16] {
        configs.push((
            format!("DRM Eq. 14, M = {n}×{n}, centre texels (no mip-map)"),
            drm(scene.clone(), DrmSettings { mip_mapped: false, ..drm_with(n, DrmSolidAngle::TexelArea) }),
        ));
    }
    configs
}

struct Report {
    truths: BTreeMap<&'static str, HdrImage>,
    device: String,
}

impl Report {
    fn new() -> Result<Self, String> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/ground_truth");
        let mut truths = BTreeMap::new();
        for name in ["cornell", "cornell_b1", "cellar", "cellar_b1", "sponza_like", "sponza_like_b1", "near_light_b1"] {
            let path = dir.join(format!("{name}.exr"));
            truths.insert(name, HdrImage::read(&path).map_err(|e| format!("{}: {e}", path.display()))?);
        }
        Ok(Self { truths, device: String::from("an unknown device") })
    }

    fn render(&mut self, options: &HeadlessOptions) -> Result<HeadlessReport, String> {
        eprint!(".");
        let report = headless::run(options)?;
        if let Some(name) = report.sidecar["device"].as_str() {
            self.device = name.to_string();
        }
        Ok(report)
    }

    fn compare(&self, image: &HdrImage, truth: &str) -> Result<ErrorMetrics, String> {
        metrics::compare(image, &self.truths[truth]).map_err(|e| e.to_string())
    }

    /// Every configuration on `cornell`, `cellar` and `sponza_like`, against the one-bounce truth and
    /// the full one.
    fn accuracy(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| scene | configuration | one bounce: block rel. RMSE | energy | blocks > 50 % off | all bounces: block rel. RMSE | energy |\n\
             |---|---|---|---|---|---|---|\n",
        );
        for (scene, name) in [(StandardScene::Cornell, "cornell"), (StandardScene::Cellar, "cellar"), (StandardScene::SponzaLike, "sponza_like")] {
            for (label, options) in configurations(&scene) {
                let image = self.render(&options)?.image;
                let one = self.compare(&image, &format!("{name}_b1"))?;
                let all = self.compare(&image, name)?;
                out += &format!(
                    "| {name} | {label} | {:.3} | {:.3} | {:.1} % | {:.3} | {:.3} |\n",
                    one.block_relative_rmse,
                    one.energy_ratio,
                    100.0 * one.blocks_over_half_off,
                    all.block_relative_rmse,
                    all.energy_ratio
                );
            }
        }
        Ok(out)
    }

    /// The paper's Fig. 7: energy against the one-bounce truth of `cornell` and of `near_light` (a block
    /// hung below the spot), per solid-angle approximation.
    fn near_light(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| configuration | cornell: energy | block rel. RMSE | near_light: energy | block rel. RMSE | energy near / far |\n\
             |---|---|---|---|---|---|\n",
        );
        let mut configs: Vec<(String, DrmSettings, Option<RsmGatherSettings>)> = Vec::new();
        for solid_angle in DrmSolidAngle::ALL {
            configs.push((format!("DRM {}, M = 3×3", eq(solid_angle)), drm_with(3, solid_angle), None));
        }
        configs.push(("DRM Eq. 14, M = 16×16".into(), drm_with(16, DrmSolidAngle::TexelArea), None));
        configs.push(("RSM gather medium".into(), DrmSettings::default(), Some(RsmGatherSettings::MEDIUM)));
        for (label, d, r) in configs {
            let mut row = Vec::new();
            for (scene, truth) in [(StandardScene::Cornell, "cornell_b1"), (StandardScene::NearLight, "near_light_b1")] {
                let options = match &r {
                    Some(r) => rsm(scene, r.clone()),
                    None => drm(scene, d.clone()),
                };
                let image = self.render(&options)?.image;
                row.push(self.compare(&image, truth)?);
            }
            out += &format!(
                "| {label} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} |\n",
                row[0].energy_ratio,
                row[0].block_relative_rmse,
                row[1].energy_ratio,
                row[1].block_relative_rmse,
                row[1].energy_ratio / row[0].energy_ratio
            );
        }
        Ok(out)
    }

    /// The paper's flashing (§5): how much the image changes from one frame to the next while `dynamic`'s
    /// light orbits the room (one step per frame), with mip-mapped photons and with centre texels, over
    /// several frames of the orbit.
    fn flashing(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| configuration | frame-to-frame change, block rel. RMSE: mean | largest | energy ratio, mean |\n|---|---|---|---|\n",
        );
        let mut configs: Vec<(String, HeadlessOptions)> = Vec::new();
        for n in [3, 16] {
            for mip_mapped in [true, false] {
                let what = if mip_mapped { "mip-mapped" } else { "centre texels" };
                configs.push((
                    format!("DRM Eq. 14, {n}×{n}, {what}"),
                    drm(StandardScene::Dynamic, DrmSettings { mip_mapped, ..drm_with(n, DrmSolidAngle::TexelArea) }),
                ));
            }
        }
        configs.push(("RSM gather medium".into(), rsm(StandardScene::Dynamic, RsmGatherSettings::MEDIUM)));
        for (label, options) in configs {
            let (mut changes, mut energies) = (Vec::new(), Vec::new());
            for frames in FLASHING_FRAMES {
                let report = self.render(&HeadlessOptions { animate_light: true, frames, ..options.clone() })?;
                let previous = report
                    .extra_images
                    .iter()
                    .find(|(name, _)| *name == "previous")
                    .map(|(_, image)| image)
                    .ok_or("no previous frame")?;
                let m = metrics::compare(&report.image, previous).map_err(|e| e.to_string())?;
                changes.push(m.block_relative_rmse);
                energies.push(m.energy_ratio);
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            out += &format!(
                "| {label} | {:.3} | {:.3} | {:.3} |\n",
                mean(&changes),
                changes.iter().copied().fold(0.0, f64::max),
                mean(&energies)
            );
        }
        Ok(out)
    }

    /// Frame-time ratios to the frame without GI on `cornell` at 256² and 512², alternating.
    fn timing(&mut self, rounds: usize) -> Result<String, String> {
        let mut out = String::from("| size | configuration | frame (median ms) | × frame without GI |\n|---|---|---|---|\n");
        let configs: Vec<(String, Option<HeadlessOptions>)> = vec![
            ("no GI".into(), None),
            ("RSM gather low (64)".into(), Some(rsm(StandardScene::Cornell, RsmGatherSettings::LOW))),
            ("RSM gather medium (144)".into(), Some(rsm(StandardScene::Cornell, RsmGatherSettings::MEDIUM))),
            ("RSM gather high (400)".into(), Some(rsm(StandardScene::Cornell, RsmGatherSettings::HIGH))),
            ("DRM Eq. 14, 2×2".into(), Some(drm(StandardScene::Cornell, DrmSettings::LOW))),
            ("DRM Eq. 14, 3×3 (medium)".into(), Some(drm(StandardScene::Cornell, DrmSettings::MEDIUM))),
            ("DRM Eq. 11, 3×3".into(), Some(drm(StandardScene::Cornell, drm_with(3, DrmSolidAngle::Constant)))),
            ("DRM Eq. 15, 3×3".into(), Some(drm(StandardScene::Cornell, drm_with(3, DrmSolidAngle::SceneDiagonal)))),
            ("DRM Eq. 14, 8×8".into(), Some(drm(StandardScene::Cornell, drm_with(8, DrmSolidAngle::TexelArea)))),
            ("DRM Eq. 14, 16×16 (high)".into(), Some(drm(StandardScene::Cornell, DrmSettings::HIGH))),
        ];
        for size in [256u32, 512] {
            let mut times: Vec<Vec<f64>> = vec![Vec::new(); configs.len()];
            for _ in 0..rounds {
                for (i, (_, options)) in configs.iter().enumerate() {
                    let base = options.clone().unwrap_or_default();
                    let options =
                        HeadlessOptions { indirect_only: false, frames: TIMING_FRAMES, size: UVec2::splat(size), ..base };
                    times[i].push(common::frame_ms(&self.render(&options)?, TIMED_FRAMES));
                }
            }
            let base = common::median(&times[0]);
            for (i, (name, _)) in configs.iter().enumerate() {
                let t = common::median(&times[i]);
                out += &format!("| {size}² | {name} | {t:.1} | {:.2} |\n", t / base);
            }
        }
        Ok(out)
    }


    /// Images for the docs page (`docs/images/one_bounce_*.png`, indirect light ×4, tonemapped).
    fn images(&mut self) -> Result<String, String> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/images");
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let mut rows = Vec::new();
        let cases: Vec<(&str, &str, Option<HeadlessOptions>)> = vec![
            ("one_bounce_cornell_truth", "cornell, one-bounce path-traced truth", None),
            ("one_bounce_cornell_rsm", "RSM gather medium", Some(rsm(StandardScene::Cornell, RsmGatherSettings::MEDIUM))),
            ("one_bounce_cornell_drm3", "DRM Eq. 14, 3×3 (medium)", Some(drm(StandardScene::Cornell, DrmSettings::MEDIUM))),
            ("one_bounce_cornell_drm16", "DRM Eq. 14, 16×16 (high)", Some(drm(StandardScene::Cornell, DrmSettings::HIGH))),
            ("one_bounce_near_light_truth", "near_light, one-bounce path-traced truth", None),
            ("one_bounce_near_light_eq11", "DRM Eq. 11, 3×3 (×1/50)", Some(drm(StandardScene::NearLight, drm_with(3, DrmSolidAngle::Constant)))),
            ("one_bounce_near_light_eq14", "DRM Eq. 14, 3×3", Some(drm(StandardScene::NearLight, drm_with(3, DrmSolidAngle::TexelArea)))),
        ];
        for (file, label, options) in cases {
            let image = match options {
                Some(o) => self.render(&o)?.image,
                None => self.truths[if file.contains("near_light") { "near_light_b1" } else { "cornell_b1" }].clone(),
            };
            let scale = if file.ends_with("eq11") { 4.0 / 50.0 } else { 4.0 };
            let path = dir.join(format!("{file}.png"));
            image.write_png_tonemapped(&path, scale).map_err(|e| e.to_string())?;
            rows.push(format!("| {label} | ![{label}](images/{file}.png) |"));
        }
        Ok(format!("| image | indirect light only, ×4 |\n|---|---|\n{}\n", rows.join("\n")))
    }
}
