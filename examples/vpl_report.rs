//! Measures the VPL method with screen-space bias compensation against the path-traced ground truths and
//! times it: the numbers of `docs/vpl_ssbc.md`.
//!
//! ```text
//! cargo run --release --features tools --example vpl_report -- [--section NAME]... [--rounds N] [--docs docs/vpl_ssbc.md]
//! ```
//! Sections: `accuracy`, `corners`, `timing` (default: all). Each prints a Markdown table;
//! with `--docs FILE` the table also replaces the text between `<!-- vpl_report:NAME -->` and
//! `<!-- /vpl_report:NAME -->` in FILE. Renders run one after another in this process on whatever Vulkan
//! device wgpu picks (lavapipe on CI machines), at 256² unless a table says otherwise, against the
//! committed EXRs of `assets/ground_truth/`.
//!
//! Timing: lavapipe's timestamps do not bracket compute passes, so pass costs are differences of median
//! frame times between configurations that differ by one pass, measured alternately in `--rounds` rounds;
//! every number is quoted as a ratio to the frame without GI measured in the same rounds.

#[path = "common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use bevy::math::UVec2;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::metrics::{self, ErrorMetrics};
use bevy_diffuse_gi::radiance_hints::RadianceHintsVolume;
use bevy_diffuse_gi::scenes::StandardScene;
use bevy_diffuse_gi::settings::GiSettings;
use bevy_diffuse_gi::vpl::VplSettings;

const SECTIONS: &[&str] = &["accuracy", "corners", "timing"];

/// Frames of an accuracy render (the VPL method has no temporal accumulation; RH refines over these).
const STILL_FRAMES: u32 = 32;
/// Frame intervals at the end of a run that the medians use.
const TIMED_FRAMES: usize = 8;

fn main() -> ExitCode {
    common::report_main("vpl_report", run)
}



fn run() -> Result<(), String> {
    let args = common::start_report("vpl_report", SECTIONS);
    let mut report = Report::new()?;
    for section in &args.sections {
        let started = std::time::Instant::now();
        let table = match section.as_str() {
            "accuracy" => report.accuracy()?,
            "corners" => report.corners()?,
            "timing" => report.timing(args.rounds)?,
            _ => unreachable!("sections are validated"),
        };
        common::publish_section("vpl_report", &args, section, &table, &report.device, started)?;
    }
    Ok(())
}


struct Report {
    truths: BTreeMap<&'static str, HdrImage>,
    device: String,
}



fn vpl_options(scene: StandardScene, vpl: VplSettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::Vpl),
        indirect_only: true,
        vpl,
        frames: STILL_FRAMES,
        ..Default::default()
    }
}

fn rh_options(scene: StandardScene, rh: RadianceHintsVolume) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        rh,
        frames: STILL_FRAMES,
        ..Default::default()
    }
}

fn cells(m: &ErrorMetrics) -> String {
    format!(
        "{:.3} | {:.3} | {:.3} | {:.1} %",
        m.block_relative_rmse,
        m.relative_rmse,
        m.energy_ratio,
        100.0 * m.blocks_over_half_off
    )
}

/// The VPL count of a run, from the same generation on the scene's CPU snapshot (the sidecar does not
/// record it), guided by the scene's camera as the plugin guides it.
fn vpl_count(scene: &StandardScene, settings: &VplSettings) -> usize {
    use bevy_diffuse_gi::scenes::{cellar, cornell, sponza_like};
    use bevy_diffuse_gi::vpl::generate::{EmissionGuide, WalkSettings, generate_vpls, pilot_hits};
    let (snapshot, camera) = match scene {
        StandardScene::Cornell => (bevy_diffuse_gi::scenes::cornell_snapshot(), cornell::CAMERA_POSITION),
        StandardScene::Cellar => (bevy_diffuse_gi::scenes::cellar_snapshot(), cellar::CAMERA_POSITION),
        StandardScene::SponzaLike => (bevy_diffuse_gi::scenes::sponza_like_snapshot(), sponza_like::CAMERA_POSITION),
        StandardScene::Gltf(_)
        | StandardScene::Dynamic
        | StandardScene::EmissivePanel
        | StandardScene::OpenField
        | StandardScene::NearLight
        | StandardScene::SkyRoom
        | StandardScene::Room(_) => return 0,
    };
    let lights: Vec<_> = snapshot.lights.iter().map(|l| l.light).collect();
    let guides: Vec<_> = lights.iter().map(|l| EmissionGuide::from_pilots(&pilot_hits(&snapshot, l), &[camera])).collect();
    let s = settings.sanitized().0;
    generate_vpls(&snapshot, &lights, &[], Some(&guides), WalkSettings { paths: s.light_paths, bounces: s.bounces, seed: s.seed }).len()
}

impl Report {
    fn new() -> Result<Self, String> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/ground_truth");
        let mut truths = BTreeMap::new();
        for name in ["cornell", "cornell_b1", "cornell_b2", "cellar", "sponza_like"] {
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

    /// Per scene: presets, SSBC steps and VPL bounces, against the all-bounce truth.
    fn accuracy(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| scene | configuration | VPLs | block rel. RMSE | pixel rel. RMSE | energy | blocks > 50 % off |\n\
             |---|---|---|---|---|---|---|\n",
        );
        let medium = VplSettings::MEDIUM;
        for (scene, truth) in
            [(StandardScene::Cornell, "cornell"), (StandardScene::Cellar, "cellar"), (StandardScene::SponzaLike, "sponza_like")]
        {
            let mut variants: Vec<(String, VplSettings)> = vec![
                ("low preset".into(), VplSettings::LOW),
                ("medium preset (default)".into(), medium.clone()),
                ("high preset".into(), VplSettings::HIGH),
            ];
            for steps in [0u32, 2, 3] {
                variants.push((format!("medium, {steps} SSBC steps{}", if steps == 0 { " (clamped only)" } else { "" }), VplSettings { ssbc_steps: steps, ..medium.clone() }));
            }
            for bounces in [1u32, 2, 4] {
                variants.push((format!("medium, at most {bounces} VPL bounce(s)"), VplSettings { bounces, ..medium.clone() }));
            }
            variants.push(("high, 3 SSBC steps".into(), VplSettings { ssbc_steps: 3, ..VplSettings::HIGH }));
            for (name, settings) in variants {
                let measured = self.render(&vpl_options(scene.clone(), settings.clone()))?;
                let m = self.compare(&measured.image, truth)?;
                out += &format!("| {} | {name} | {} | {} |\n", scene.name(), vpl_count(&scene, &settings), cells(&m));
            }
            let rh = self.render(&rh_options(scene.clone(), RadianceHintsVolume::MEDIUM))?;
            out += &format!("| {} | Radiance Hints, medium (for comparison) | – | {} |\n", scene.name(), cells(&self.compare(&rh.image, truth)?));
        }
        // One-bounce VPLs against the one-bounce truth of cornell: the estimator itself.
        let one = VplSettings { bounces: 1, ..medium.clone() };
        for (name, settings) in [
            ("1 bounce, clamped only", VplSettings { ssbc_steps: 0, ..one.clone() }),
            ("1 bounce, unclamped (b = 10⁶), no SSBC", VplSettings { ssbc_steps: 0, geometry_bound: 1e6, ..one.clone() }),
            ("1 bounce, 1 SSBC step", one.clone()),
        ] {
            let measured = self.render(&vpl_options(StandardScene::Cornell, settings.clone()))?;
            let m = self.compare(&measured.image, "cornell_b1")?;
            out += &format!("| cornell vs one-bounce truth | {name} | {} | {} |\n", vpl_count(&StandardScene::Cornell, &settings), cells(&m));
        }
        Ok(out)
    }

    /// Energy near cornell's concave edges and box feet: clamped, compensated, truth.
    fn corners(&mut self) -> Result<String, String> {
        let regions: [(&str, (u32, u32, u32, u32)); 4] = [
            ("ceiling–back wall edge", (70, 52, 186, 59)),
            ("red wall–back wall edge", (52, 70, 60, 150)),
            ("foot of the small box", (140, 234, 180, 240)),
            ("middle of the back wall (flat, for reference)", (110, 90, 146, 130)),
        ];
        let truth = self.truths["cornell"].clone();
        let mut images = Vec::new();
        for steps in 0..=3u32 {
            let measured = self.render(&vpl_options(StandardScene::Cornell, VplSettings { ssbc_steps: steps, ..VplSettings::MEDIUM }))?;
            images.push(measured.image);
        }
        let mean = |image: &HdrImage, (x0, y0, x1, y1): (u32, u32, u32, u32)| {
            let m = image.region_mean(x0, y0, x1, y1).unwrap_or([0.0; 3]);
            (0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]) as f64
        };
        let mut out = String::from(
            "| region | clamped / truth | 1 SSBC step / truth | 2 steps / truth | 3 steps / truth |\n|---|---|---|---|---|\n",
        );
        for (name, rect) in regions {
            let t = mean(&truth, rect);
            let ratios: Vec<String> = images.iter().map(|i| format!("{:.3}", mean(i, rect) / t)).collect();
            out += &format!("| {name} | {} |\n", ratios.join(" | "));
        }
        Ok(out)
    }

    /// Frame-time ratios to the frame without GI at 256² and 512², alternating configurations.
    fn timing(&mut self, rounds: usize) -> Result<String, String> {
        let mut out = String::from(
            "| size | configuration | VPLs | frame (median ms) | × frame without GI |\n|---|---|---|---|---|\n",
        );
        let medium = VplSettings::MEDIUM;
        let configs: Vec<(String, Option<VplSettings>)> = vec![
            ("no GI".into(), None),
            ("low".into(), Some(VplSettings::LOW)),
            ("medium, clamped only (0 SSBC steps)".into(), Some(VplSettings { ssbc_steps: 0, ..medium.clone() })),
            ("medium (1 SSBC step)".into(), Some(medium.clone())),
            ("medium, 2 SSBC steps".into(), Some(VplSettings { ssbc_steps: 2, ..medium.clone() })),
            ("medium, 3 SSBC steps".into(), Some(VplSettings { ssbc_steps: 3, ..medium.clone() })),
            ("medium, 80 light paths".into(), Some(VplSettings { light_paths: 80, ..medium.clone() })),
            ("medium, 320 light paths".into(), Some(VplSettings { light_paths: 320, ..medium.clone() })),
            ("high".into(), Some(VplSettings::HIGH)),
            ("medium, half resolution".into(), Some(medium.clone())),
        ];
        for size in [256u32, 512] {
            let mut times: Vec<Vec<f64>> = vec![Vec::new(); configs.len()];
            for _ in 0..rounds {
                for (i, (name, settings)) in configs.iter().enumerate() {
                    let options = match settings {
                        None => HeadlessOptions { indirect_only: false, frames: 16, size: UVec2::splat(size), ..Default::default() },
                        Some(s) => HeadlessOptions {
                            indirect_only: false,
                            frames: 16,
                            size: UVec2::splat(size),
                            half_resolution: name.contains("half"),
                            ..vpl_options(StandardScene::Cornell, s.clone())
                        },
                    };
                    times[i].push(common::frame_ms(&self.render(&options)?, TIMED_FRAMES));
                }
            }
            let base = common::median(&times[0]);
            for (i, (name, settings)) in configs.iter().enumerate() {
                let t = common::median(&times[i]);
                let vpls = settings.as_ref().map_or("–".to_string(), |s| vpl_count(&StandardScene::Cornell, s).to_string());
                out += &format!("| {size}² | {name} | {vpls} | {t:.1} | {:.2} |\n", t / base);
            }
        }
        Ok(out)
    }

}
