//! Measures Radiance Hints against the path-traced ground truths and times its passes: the numbers and
//! images of `docs/radiance_hints.md`.
//!
//! ```text
//! cargo run --release --features tools --example rh_report -- [--section NAME]... [--rounds N] [--docs docs/radiance_hints.md]
//! ```
//! Sections: `presets`, `scale`, `reconstruction`, `bounces`, `ablation`, `cellar`, `tradeoff`, `timing`, `images` (default: all).
//! Each prints a Markdown table; with `--docs FILE` the table also replaces the text between the markers
//! `<!-- rh_report:NAME -->` and `<!-- /rh_report:NAME -->` in FILE. Renders run one after another in this
//! process on whatever Vulkan device wgpu picks (lavapipe on CI machines), at 256² unless a table says
//! otherwise; the ground truths are the committed EXRs of `assets/ground_truth/`.
//!
//! Timing: lavapipe's timestamps of compute passes do not bracket the work (an injection of 1024 samples
//! per hint "takes" 15 ms of GPU time and 350 ms of wall time), so pass costs are differences of median
//! frame times between configurations that differ by one pass, measured alternately in `--rounds` rounds;
//! every number is quoted with its ratio to the frame without GI measured in the same rounds.

#[path = "common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use bevy::math::{UVec2, UVec3};
use bevy_diffuse_gi::camera::{GiDebugView, GiMethod, GiOutput};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::metrics::{self, ErrorMetrics};
use bevy_diffuse_gi::radiance_hints::{DepthOcclusion, GridSizing, RadianceHintsVolume, SecondaryTransport};
use bevy_diffuse_gi::scenes::StandardScene;
use bevy_diffuse_gi::sh::ShOrder;

const SECTIONS: &[&str] = &["presets", "scale", "units", "reconstruction", "bounces", "ablation", "cellar", "tradeoff", "timing", "images"];

/// Static frames rendered before the image is kept: enough for the volume to finish refining, so the last
/// ones time the per-frame cost of a still scene.
const STILL_FRAMES: u32 = 32;
/// Frames of a moving-light run.
const MOVING_FRAMES: u32 = 12;
/// Frame intervals at the end of a run that the medians use.
const TIMED_FRAMES: usize = 8;

fn main() -> ExitCode {
    common::report_main("rh_report", run)
}



fn run() -> Result<(), String> {
    let args = common::start_report("rh_report", SECTIONS);
    let mut report = Report::new()?;
    for section in &args.sections {
        let started = std::time::Instant::now();
        let table = match section.as_str() {
            "presets" => report.presets()?,
            "scale" => report.scale()?,
            "units" => report.units()?,
            "reconstruction" => report.reconstruction(args.rounds)?,
            "bounces" => report.bounces()?,
            "ablation" => report.ablation()?,
            "cellar" => report.cellar()?,
            "tradeoff" => report.tradeoff()?,
            "timing" => report.timing(args.rounds)?,
            "images" => report.images()?,
            _ => unreachable!("sections are validated"),
        };
        common::publish_section("rh_report", &args, section, &table, &report.device, started)?;
    }
    Ok(())
}


struct Report {
    truths: BTreeMap<&'static str, HdrImage>,
    device: String,
}

/// One render's outcome.
struct Measured {
    report: HeadlessReport,
}

impl Measured {
    fn image(&self) -> &HdrImage {
        &self.report.image
    }

    /// Median of the last [`TIMED_FRAMES`] frame intervals, in milliseconds.
    fn frame_ms(&self) -> f64 {
        common::frame_ms(&self.report, TIMED_FRAMES)
    }

    /// The hint grid the volume used (`x×y×z`), fitted to the scene's proportions.
    fn hints(&self) -> String {
        let r = &self.report.sidecar["radiance_hints"]["resolution"];
        format!("{}×{}×{}", r[0], r[1], r[2])
    }

    /// Bevy's GPU-time average of a pass (`diffuse_gi/rh_reconstruct`, …), in milliseconds.
    fn gpu_ms(&self, pass: &str) -> Option<f64> {
        self.report.sidecar["gpu_ms"][pass].as_f64()
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

fn cornell(rh: RadianceHintsVolume) -> HeadlessOptions {
    rh_options(StandardScene::Cornell, rh)
}

fn metrics_cells(m: &ErrorMetrics) -> String {
    format!("{:.3} | {:.3} | {:.3}", m.block_relative_rmse, m.relative_rmse, m.energy_ratio)
}

fn mib(bytes: u64) -> String {
    format!("{:.2} MiB", bytes as f64 / (1024.0 * 1024.0))
}

/// The pixels of the 256² cellar view that look through the door into room A (the doorway and its frame).
const CELLAR_DOORWAY: (u32, u32, u32, u32) = (144, 78, 172, 150);

/// Σ image / Σ truth over the pixels of `metrics::mask` (the mask of the energy ratio) inside (`inside`
/// true) or outside the rectangle.
fn energy_ratio_in(image: &HdrImage, truth: &HdrImage, rect: (u32, u32, u32, u32), inside: bool) -> f64 {
    let Ok(mask) = metrics::mask(image, truth) else {
        return f64::NAN;
    };
    let (mut a, mut r) = (0.0f64, 0.0f64);
    for y in 0..truth.height {
        for x in 0..truth.width {
            let i = truth.index(x, y);
            let in_rect = x >= rect.0 && y >= rect.1 && x < rect.2 && y < rect.3;
            if in_rect == inside && mask[i] {
                let (p, q) = (image.pixels[i], truth.pixels[i]);
                a += (p[0] + p[1] + p[2]) as f64;
                r += (q[0] + q[1] + q[2]) as f64;
            }
        }
    }
    if r > 0.0 { a / r } else { f64::NAN }
}

fn luminance(c: [f32; 3]) -> f64 {
    (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]) as f64
}

impl Report {
    fn new() -> Result<Self, String> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/ground_truth");
        let mut truths = BTreeMap::new();
        for name in ["cornell", "cornell_b1", "cornell_b2", "cellar", "sponza_like", "open_field", "emissive_panel", "dynamic"] {
            let path = dir.join(format!("{name}.exr"));
            truths.insert(name, HdrImage::read(&path).map_err(|e| format!("{}: {e}", path.display()))?);
        }
        Ok(Self { truths, device: String::from("an unknown device") })
    }

    fn render(&mut self, options: &HeadlessOptions) -> Result<Measured, String> {
        eprint!(".");
        let report = headless::run(options)?;
        if let Some(name) = report.sidecar["device"].as_str() {
            self.device = name.to_string();
        }
        Ok(Measured { report })
    }

    fn compare(&self, image: &HdrImage, truth: &str) -> Result<ErrorMetrics, String> {
        metrics::compare(image, &self.truths[truth]).map_err(|e| e.to_string())
    }

    /// Quality presets on cornell.
    fn presets(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| preset | hints | RSM samples N_s | extra bounces × samples | volume memory | block rel. RMSE | pixel rel. RMSE | energy |\n\
             |---|---|---|---|---|---|---|---|\n",
        );
        for (name, preset) in
            [("low", RadianceHintsVolume::LOW), ("medium (default)", RadianceHintsVolume::MEDIUM), ("high", RadianceHintsVolume::HIGH)]
        {
            let measured = self.render(&cornell(preset.clone()))?;
            let m = self.compare(measured.image(), "cornell")?;
            out += &format!(
                "| {name} | {} | {} | {} × {} | {} | {} |\n",
                measured.hints(),
                preset.rsm_samples,
                preset.extra_bounces,
                preset.secondary_samples,
                mib(preset.memory_bytes()),
                metrics_cells(&m)
            );
        }
        Ok(out)
    }

    /// The presets and the old fixed grid on rooms of 2 m to a 60 m field, plus the other light kinds.
    fn scale(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| scene | setting | hints | volume memory | block rel. RMSE | pixel rel. RMSE | energy | blocks > 50 % off | still frame × frame without GI |\n\
             |---|---|---|---|---|---|---|---|---|\n",
        );
        let fixed16 = RadianceHintsVolume { sizing: GridSizing::Fixed, resolution: UVec3::splat(16), extra_bounces: 4, ..RadianceHintsVolume::MEDIUM };
        let settings = [
            ("before: 16 along the longest side, 4 bounces", fixed16),
            ("low", RadianceHintsVolume::LOW),
            ("**default** (medium)", RadianceHintsVolume::MEDIUM),
            ("high", RadianceHintsVolume::HIGH),
        ];
        let scenes = [
            (StandardScene::Cornell, "cornell", "cornell (2 m, spot)"),
            (StandardScene::Cellar, "cellar", "cellar (8 m, two rooms, spot)"),
            (StandardScene::SponzaLike, "sponza_like", "sponza_like (12 m, sun)"),
            (StandardScene::OpenField, "open_field", "open_field (60 m, sun)"),
        ];
        let row = |report: &mut Self, truth: &str, label: &str, name: &str, options: HeadlessOptions, plain_ms: f64| -> Result<String, String> {
            let measured = report.render(&options)?;
            let m = report.compare(measured.image(), truth)?;
            let memory = measured.report.sidecar["radiance_hints"]["memory_bytes"].as_u64();
            Ok(format!(
                "| {label} | {name} | {} | {} | {} | {:.3} | {:.2} |\n",
                if options.rh_cascade.is_some() { "3 levels × 24×12×24".to_string() } else { measured.hints() },
                memory.map_or("–".into(), mib),
                metrics_cells(&m),
                m.blocks_over_half_off,
                measured.frame_ms() / plain_ms
            ))
        };
        for (scene, truth, label) in scenes {
            let plain = self.render(&HeadlessOptions { scene: scene.clone(), frames: STILL_FRAMES, ..Default::default() })?;
            let plain_ms = plain.frame_ms();
            for (name, rh) in &settings {
                let mut options = rh_options(scene.clone(), rh.clone());
                options.rh_fit_cells = true;
                out += &row(self, truth, label, name, options, plain_ms)?;
            }
            if scene == StandardScene::OpenField {
                let options = HeadlessOptions { rh_cascade: Some((3, bevy::math::Vec3::new(12.0, 6.0, 12.0))), ..rh_options(scene.clone(), RadianceHintsVolume::MEDIUM) };
                out += &row(self, truth, label, "camera-centred cascade, 3 levels (0.5, 1, 2 m cells)", options, plain_ms)?;
            }
        }
        for (scene, truth, label) in [
            (StandardScene::Dynamic, "dynamic", "dynamic at rest (6 m, point light: cube RSM)"),
            (StandardScene::EmissivePanel, "emissive_panel", "emissive_panel (2 m, emissive panel only)"),
        ] {
            let plain = self.render(&HeadlessOptions { scene: scene.clone(), frames: STILL_FRAMES, ..Default::default() })?;
            let plain_ms = plain.frame_ms();
            out += &row(self, truth, label, "**default** (medium)", rh_options(scene.clone(), RadianceHintsVolume::MEDIUM), plain_ms)?;
        }
        Ok(out)
    }

    /// The same scene in other units: `emissive_panel` (its image does not depend on its scale) at 1×,
    /// 100×, 250× (about Bevy's 557 m `CornellBox.glb`) and 1000×, with the default, and at 250× with the
    /// grid the `max_cell` rule alone gave. Eight frames each (the old grid's take about half a minute
    /// each on lavapipe): the frame time is that of a volume still refining, what a moving light or mesh
    /// pays every frame.
    fn units(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| scale | box | setting | mean chord | hints | volume memory | block rel. RMSE | pixel rel. RMSE | energy | frame while the volume refines | × the default at 1× |\n\
             |---|---|---|---|---|---|---|---|---|---|---|\n",
        );
        let scaled = |scale: f32, rh: RadianceHintsVolume, frames: u32| HeadlessOptions {
            scene_scale: scale,
            frames,
            ..rh_options(StandardScene::EmissivePanel, rh)
        };
        let mut at_one = None;
        let mut row = |report: &mut Self, scale: f32, name: &str, options: HeadlessOptions| -> Result<String, String> {
            let measured = report.render(&options)?;
            let m = report.compare(measured.image(), "emissive_panel")?;
            let rh = &measured.report.sidecar["radiance_hints"];
            let ms = measured.frame_ms();
            let one = *at_one.get_or_insert(ms);
            Ok(format!(
                "| {scale}× | {:.0} m | {name} | {} | {} | {} | {} | {:.0} ms | {:.2} |\n",
                rh["volume_size"][0].as_f64().unwrap_or(0.0),
                rh["mean_chord"].as_f64().map_or("–".into(), |c| format!("{c:.2} m")),
                measured.hints(),
                rh["memory_bytes"].as_u64().map_or("–".into(), mib),
                metrics_cells(&m),
                ms,
                ms / one
            ))
        };
        for scale in [1.0, 100.0, 250.0, 1000.0] {
            out += &row(self, scale, "**default** (medium)", scaled(scale, RadianceHintsVolume::MEDIUM, 8))?;
        }
        // The grid `max_cell` alone gives the 250× box (2.004 × 2.014 × 2.004 m at 1×).
        let before = GridSizing::MEDIUM.resolution_for(UVec3::ZERO, bevy::math::Vec3::new(2.004, 2.014, 2.004) * 250.0, None);
        let fixed = RadianceHintsVolume { sizing: GridSizing::Fixed, resolution: before, ..RadianceHintsVolume::MEDIUM };
        out += &row(self, 250.0, "before: `max_cell` in metres alone", scaled(250.0, fixed, 8))?;
        Ok(out)
    }

    /// The per-pixel reconstruction: its error with the linear and the non-linear irradiance at full and
    /// half resolution, at three reaches, and with the near-field occlusion, on six scenes (256²), and what a still frame
    /// costs at 512² (rounds alternating).
    fn reconstruction(&mut self, rounds: usize) -> Result<String, String> {
        use bevy_diffuse_gi::radiance_hints::IrradianceReconstruction::{Linear, NonLinear};
        // (name, irradiance, half resolution, near-field occlusion in cell diagonals, reach in cell
        // diagonals, timed at 512²: the reach changes where the samples are, not what they cost)
        let variants = [
            ("linear (Eq. 7), full resolution", Linear, false, 0.0, 0.5, true),
            ("non-linear, full resolution", NonLinear, false, 0.0, 0.5, true),
            ("linear, half resolution", Linear, true, 0.0, 0.5, true),
            ("**default**: non-linear, half resolution, reach 0.5", NonLinear, true, 0.0, 0.5, true),
            ("default, reach 1 (§5: the hemisphere one cell diagonal out)", NonLinear, true, 0.0, 1.0, false),
            ("default, reach 0.25", NonLinear, true, 0.0, 0.25, false),
            ("default + near-field occlusion 0.5", NonLinear, true, 0.5, 0.5, true),
        ];
        let scenes = [
            (StandardScene::Cornell, "cornell"),
            (StandardScene::Cellar, "cellar"),
            (StandardScene::SponzaLike, "sponza_like"),
            (StandardScene::OpenField, "open_field"),
            (StandardScene::Dynamic, "dynamic"),
            (StandardScene::EmissivePanel, "emissive_panel"),
        ];
        let options = |scene: StandardScene, irradiance, half: bool, near_field_occlusion: f32, reconstruction_reach: f32| HeadlessOptions {
            half_resolution: half,
            ..rh_options(scene, RadianceHintsVolume { irradiance, near_field_occlusion, reconstruction_reach, ..RadianceHintsVolume::MEDIUM })
        };
        let mut out = String::from("| reconstruction | ");
        out += &scenes.iter().map(|(_, n)| format!("`{n}`: block / energy / > 50 % off")).collect::<Vec<_>>().join(" | ");
        out += &format!(" |\n|---|{}\n", "---|".repeat(scenes.len()));
        for (name, irradiance, half, near, reach, _) in variants {
            let mut cells = Vec::new();
            for (scene, truth) in &scenes {
                let measured = self.render(&options(scene.clone(), irradiance, half, near, reach))?;
                let m = self.compare(measured.image(), truth)?;
                cells.push(format!("{:.3} / {:.3} / {:.3}", m.block_relative_rmse, m.energy_ratio, m.blocks_over_half_off));
            }
            out += &format!("| {name} | {} |\n", cells.join(" | "));
        }

        // Cost of a still frame at 512² on cornell, the configurations alternating in each round.
        let size = UVec2::splat(512);
        let mut configs = vec![("frame without GI", HeadlessOptions { frames: STILL_FRAMES, size, ..Default::default() })];
        for (name, irradiance, half, near, reach, _) in variants.into_iter().filter(|v| v.5) {
            configs.push((name, HeadlessOptions { indirect_only: false, size, ..options(StandardScene::Cornell, irradiance, half, near, reach) }));
        }
        let mut frames: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
        let mut passes: BTreeMap<(&str, &str), Vec<f64>> = BTreeMap::new();
        for _ in 0..rounds {
            for (name, options) in &configs {
                let measured = self.render(options)?;
                frames.entry(name).or_default().push(measured.frame_ms());
                for pass in ["rh_reconstruct", "filter", "composite"] {
                    if let Some(ms) = measured.gpu_ms(&format!("diffuse_gi/{pass}")) {
                        passes.entry((name, pass)).or_default().push(ms);
                    }
                }
            }
        }
        let none = common::median(&frames["frame without GI"]);
        out += "\nA still frame of `cornell` at 512² (volume reused), medians of alternating runs; the passes are GPU \
                timestamps (reliable on lavapipe for these render passes):\n\n\
                | configuration | frame (ms) | × frame without GI | `rh_reconstruct` (ms) | `filter` (ms) | `composite` (ms) |\n\
                |---|---|---|---|---|---|\n";
        for (name, _) in &configs {
            let frame = common::median(&frames[name]);
            let pass = |p: &str| passes.get(&(*name, p)).map_or("–".to_string(), |v| format!("{:.1}", common::median(v)));
            out += &format!(
                "| {name} | {frame:.0} | {:.2} | {} | {} | {} |\n",
                frame / none,
                pass("rh_reconstruct"),
                pass("filter"),
                pass("composite")
            );
        }
        Ok(out)
    }

    /// Extra bounces 0–12 with SH order 2 and 3 (medium otherwise), against the all-bounce truth and, for
    /// 0 and 1 extra bounces, the truths with the same number of bounces.
    fn bounces(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| extra bounces | SH order 2: block / pixel / energy | SH order 3: block / pixel / energy | order 2 vs the truth with as many bounces |\n\
             |---|---|---|---|\n",
        );
        let default = RadianceHintsVolume::MEDIUM.extra_bounces;
        for bounces in [0u32, 1, 2, 4, 8, 12] {
            let mut cells = Vec::new();
            let mut partial = String::from("–");
            for order in [ShOrder::Two, ShOrder::Three] {
                let rh = RadianceHintsVolume { extra_bounces: bounces, sh_order: order, ..RadianceHintsVolume::MEDIUM };
                let measured = self.render(&cornell(rh))?;
                let m = self.compare(measured.image(), "cornell")?;
                cells.push(format!("{:.3} / {:.3} / {:.3}", m.block_relative_rmse, m.relative_rmse, m.energy_ratio));
                if order == ShOrder::Two && bounces <= 1 {
                    let truth = if bounces == 0 { "cornell_b1" } else { "cornell_b2" };
                    let p = self.compare(measured.image(), truth)?;
                    partial = format!("{} bounce(s): {:.3} / {:.3} / {:.3}", bounces + 1, p.block_relative_rmse, p.relative_rmse, p.energy_ratio);
                }
            }
            out += &format!("| {bounces}{} | {} | {} | {partial} |\n", if bounces == default { " (default)" } else { "" }, cells[0], cells[1]);
        }
        Ok(out)
    }

    /// What each part of the design contributes on cornell (medium preset, one change at a time).
    fn ablation(&mut self) -> Result<String, String> {
        let medium = RadianceHintsVolume::MEDIUM;
        let variants: Vec<(&str, HeadlessOptions)> = vec![
            ("medium preset (default: non-linear irradiance, half resolution)", cornell(medium.clone())),
            ("white secondary reflectance (no §6 albedo volume, Eq. 10 as printed)", cornell(RadianceHintsVolume { albedo_volume: false, ..medium.clone() })),
            (
                "paper's secondary transport (Eq. 8–11), r_max automatic",
                cornell(RadianceHintsVolume { secondary: SecondaryTransport::Paper, ..medium.clone() }),
            ),
            (
                "paper's secondary transport, r_max = 0.5 m, 1 extra bounce",
                cornell(RadianceHintsVolume { secondary: SecondaryTransport::Paper, r_max: 0.5, extra_bounces: 1, ..medium.clone() }),
            ),
            ("no voxel visibility in the injection", cornell(RadianceHintsVolume { voxel_visibility: false, ..medium.clone() })),
            (
                "§8 camera-depth occlusion (8 steps) instead of voxel visibility",
                cornell(RadianceHintsVolume {
                    voxel_visibility: false,
                    depth_occlusion: Some(DepthOcclusion { samples: 8, strength: 0.5 }),
                    ..medium.clone()
                }),
            ),
            ("receiver jitter over the whole cell (1.0)", cornell(RadianceHintsVolume { jitter: 1.0, ..medium.clone() })),
            ("no refinement (temporal blend only)", cornell(RadianceHintsVolume { refinement_updates: 0, ..medium.clone() })),
            ("1 reconstruction sample (normal only)", cornell(RadianceHintsVolume { reconstruction_samples: 1, ..medium.clone() })),
            ("8 reconstruction samples", cornell(RadianceHintsVolume { reconstruction_samples: 8, ..medium.clone() })),
            ("full-resolution reconstruction", HeadlessOptions { half_resolution: false, ..cornell(medium.clone()) }),
            (
                "linear irradiance (Eq. 7 as printed)",
                cornell(RadianceHintsVolume { irradiance: bevy_diffuse_gi::radiance_hints::IrradianceReconstruction::Linear, ..medium.clone() }),
            ),
        ];
        let mut out = String::from("| variant | block rel. RMSE | pixel rel. RMSE | energy |\n|---|---|---|---|\n");
        for (name, options) in variants {
            let measured = self.render(&options)?;
            let m = self.compare(measured.image(), "cornell")?;
            out += &format!("| {name} | {} |\n", metrics_cells(&m));
        }
        // Forward path: Bevy's IrradianceVolume lit by the exported hints; its bounced light is the lit
        // image minus Bevy's direct image.
        let direct = self.render(&HeadlessOptions { frames: STILL_FRAMES, ..Default::default() })?;
        let lit = self.render(&HeadlessOptions {
            indirect_only: false,
            gi_output: GiOutput::IrradianceVolume,
            ..cornell(medium)
        })?;
        let indirect = lit.image().subtract(direct.image()).map_err(|e| e.to_string())?;
        let m = self.compare(&indirect, "cornell")?;
        out += &format!("| `GiOutput::IrradianceVolume` (Bevy's light probe, forward and deferred) | {} |\n", metrics_cells(&m));
        Ok(out)
    }

    /// The two-room cellar: error, indirect energy in the camera's room and light on the dividing wall.
    fn cellar(&mut self) -> Result<String, String> {
        let truth = self.truths["cellar"].clone();
        // Room B's side of the dividing wall, opposite the flashlight's spot on room A's side.
        let wall = |image: &HdrImage| image.region_mean(20, 80, 120, 140).map(luminance).unwrap_or(f64::NAN);
        let wall_truth = wall(&truth);
        let occlusion = Some(DepthOcclusion { samples: 8, strength: 0.5 });
        let mut out = String::from(
            "| preset (hints) | first-bounce visibility | extra bounces | block rel. RMSE | pixel rel. RMSE | energy | energy in room B | energy seen through the door | dividing wall (truth = 1) |\n\
             |---|---|---|---|---|---|---|---|---|\n",
        );
        for (preset_name, preset) in [("high", RadianceHintsVolume::HIGH), ("medium", RadianceHintsVolume::MEDIUM)] {
            let variants = [
                ("voxels (default)", "voxel march", RadianceHintsVolume { ..preset.clone() }),
                ("none (paper §4)", "voxel march", RadianceHintsVolume { voxel_visibility: false, ..preset.clone() }),
                (
                    "§8 camera depth, 8 steps",
                    "voxel march",
                    RadianceHintsVolume { voxel_visibility: false, depth_occlusion: occlusion, ..preset.clone() },
                ),
                ("voxels + §8", "voxel march", RadianceHintsVolume { depth_occlusion: occlusion, ..preset.clone() }),
                (
                    "none (paper §4)",
                    "paper Eq. 8–11",
                    RadianceHintsVolume { voxel_visibility: false, secondary: SecondaryTransport::Paper, ..preset.clone() },
                ),
                (
                    "§8 camera depth, 8 steps",
                    "paper Eq. 8–11",
                    RadianceHintsVolume {
                        voxel_visibility: false,
                        depth_occlusion: occlusion,
                        secondary: SecondaryTransport::Paper,
                        ..preset.clone()
                    },
                ),
            ];
            for (visibility, transport, rh) in variants {
                let measured = self.render(&rh_options(StandardScene::Cellar, rh))?;
                let m = self.compare(measured.image(), "cellar")?;
                out += &format!(
                    "| {preset_name} ({}) | {visibility} | {transport} | {} | {:.3} | {:.3} | {:.2} |\n",
                    measured.hints(),
                    metrics_cells(&m),
                    energy_ratio_in(measured.image(), &truth, CELLAR_DOORWAY, false),
                    energy_ratio_in(measured.image(), &truth, CELLAR_DOORWAY, true),
                    wall(measured.image()) / wall_truth
                );
            }
        }
        Ok(out)
    }

    /// Grid resolution × RSM samples: error and the cost of one volume update (moving light).
    fn tradeoff(&mut self) -> Result<String, String> {
        let mut out = String::from(
            "| hints | N_s | block rel. RMSE | energy | frame, still (ms) | frame, light moving (ms) | update cost (ms) |\n\
             |---|---|---|---|---|---|---|\n",
        );
        let mut configs: Vec<(u32, u32)> = Vec::new();
        for res in [8u32, 16, 24] {
            for samples in [16u32, 64, 256] {
                configs.push((res, samples));
            }
        }
        configs.push((32, 64));
        for (res, samples) in configs {
            // A fixed grid: the default's adaptive sizing would ignore `resolution`.
            let rh = RadianceHintsVolume {
                sizing: GridSizing::Fixed,
                resolution: UVec3::splat(res),
                rsm_samples: samples,
                ..RadianceHintsVolume::MEDIUM
            };
            let still = self.render(&HeadlessOptions { rh_fit_cells: false, ..cornell(rh.clone()) })?;
            let m = self.compare(still.image(), "cornell")?;
            let moving = self.render(&HeadlessOptions {
                rh_fit_cells: false,
                animate_light: true,
                frames: MOVING_FRAMES,
                ..cornell(rh)
            })?;
            let (s, mv) = (still.frame_ms(), moving.frame_ms());
            out += &format!(
                "| {res}³ | {samples} | {:.3} | {:.3} | {s:.0} | {mv:.0} | {:.0} |\n",
                m.block_relative_rmse,
                m.energy_ratio,
                mv - s
            );
        }
        Ok(out)
    }

    /// Per-pass cost from frame-time differences, at 256² and 512², alternating configurations.
    fn timing(&mut self, rounds: usize) -> Result<String, String> {
        let medium = RadianceHintsVolume::MEDIUM;
        let configs: Vec<(&str, HeadlessOptions)> = vec![
            ("none", HeadlessOptions { frames: STILL_FRAMES, ..Default::default() }),
            ("still", HeadlessOptions { indirect_only: false, half_resolution: false, ..cornell(medium.clone()) }),
            ("still_half", HeadlessOptions { indirect_only: false, half_resolution: true, ..cornell(medium.clone()) }),
            (
                "moving",
                HeadlessOptions { indirect_only: false, animate_light: true, frames: MOVING_FRAMES, ..cornell(medium.clone()) },
            ),
            (
                "moving_p1",
                HeadlessOptions {
                    indirect_only: false,
                    animate_light: true,
                    frames: MOVING_FRAMES,
                    ..cornell(RadianceHintsVolume { motion_bounce_period: 1, ..medium.clone() })
                },
            ),
            (
                "moving_b0",
                HeadlessOptions {
                    indirect_only: false,
                    animate_light: true,
                    frames: MOVING_FRAMES,
                    ..cornell(RadianceHintsVolume { extra_bounces: 0, ..medium.clone() })
                },
            ),
            (
                "moving_b0_ns1",
                HeadlessOptions {
                    indirect_only: false,
                    animate_light: true,
                    frames: MOVING_FRAMES,
                    ..cornell(RadianceHintsVolume { extra_bounces: 0, rsm_samples: 1, ..medium.clone() })
                },
            ),
        ];
        let mut out = String::from(
            "| pass (medium preset, cornell) | 256²: ms | 256²: × frame without GI | 512²: ms | 512²: × frame without GI |\n\
             |---|---|---|---|---|\n",
        );
        let mut columns: Vec<BTreeMap<&str, f64>> = Vec::new();
        let mut stamps: Vec<BTreeMap<&str, f64>> = Vec::new();
        for size in [256u32, 512] {
            let mut samples: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
            let mut gpu: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
            for _ in 0..rounds {
                for (name, options) in &configs {
                    let measured = self.render(&HeadlessOptions { size: UVec2::splat(size), ..options.clone() })?;
                    samples.entry(name).or_default().push(measured.frame_ms());
                    if *name == "still" {
                        for pass in ["rh_reconstruct", "composite"] {
                            if let Some(ms) = measured.gpu_ms(&format!("diffuse_gi/{pass}")) {
                                gpu.entry(pass).or_default().push(ms);
                            }
                        }
                    }
                    if *name == "moving"
                        && let Some(ms) = measured.gpu_ms("diffuse_gi/rsm")
                    {
                        gpu.entry("rsm").or_default().push(ms);
                    }
                }
            }
            columns.push(samples.iter().map(|(k, v)| (*k, common::median(v))).collect());
            stamps.push(gpu.iter().map(|(k, v)| (*k, common::median(v))).collect());
        }
        let period = medium.motion_bounce_period;
        let moving_label = format!("frame with RH, light moving (injection every frame, the bounce of one hint in {period})");
        let bounce_label = format!("extra bounces while moving (amortised, `rh_bounce`, one hint in {period} per frame)");
        let rows: [(&str, Box<dyn Fn(&BTreeMap<&str, f64>) -> f64>); 10] = [
            ("frame without GI (Bevy's deferred direct light, readback included)", Box::new(|c| c["none"])),
            ("frame with RH, scene still (volume reused)", Box::new(|c| c["still"])),
            (&moving_label, Box::new(|c| c["moving"])),
            ("frame with RH, light moving, every hint's bounce every frame (`motion_bounce_period` 1)", Box::new(|c| c["moving_p1"])),
            ("reconstruction + composite, full resolution", Box::new(|c| c["still"] - c["none"])),
            ("reconstruction + composite, half resolution", Box::new(|c| c["still_half"] - c["none"])),
            ("RSM, 1-sample injection, blend, decide (an update with N_s = 1, no extra bounce)", Box::new(|c| c["moving_b0_ns1"] - c["still"])),
            ("injection, 64 RSM samples per hint (`rh_inject`)", Box::new(|c| c["moving_b0"] - c["moving_b0_ns1"])),
            (&bounce_label, Box::new(|c| c["moving"] - c["moving_b0"])),
            ("extra bounces while moving, every hint every frame", Box::new(|c| c["moving_p1"] - c["moving_b0"])),
        ];
        for (name, f) in rows {
            // A difference of frame times below zero is smaller than the run-to-run noise.
            let cells = |ms: f64, none: f64| {
                if ms < 0.0 { "≤ noise | –".to_string() } else { format!("{ms:.0} | {:.2}", ms / none) }
            };
            out += &format!(
                "| {name} | {} | {} |\n",
                cells(f(&columns[0]), columns[0]["none"]),
                cells(f(&columns[1]), columns[1]["none"])
            );
        }
        out += "\nGPU timestamps of the render passes (reliable on lavapipe, unlike its compute passes), medians:\n\n\
                | pass | 256² (ms) | 512² (ms) |\n|---|---|---|\n";
        for pass in ["rsm", "rh_reconstruct", "composite"] {
            let get = |c: &BTreeMap<&str, f64>| c.get(pass).map_or("–".to_string(), |v| format!("{v:.1}"));
            out += &format!("| `diffuse_gi/{pass}` | {} | {} |\n", get(&stamps[0]), get(&stamps[1]));
        }
        let memory: Vec<String> = [("low", RadianceHintsVolume::LOW), ("medium", RadianceHintsVolume::MEDIUM), ("high", RadianceHintsVolume::HIGH)]
            .iter()
            .map(|(n, p)| format!("{n} {}", mib(p.memory_bytes())))
            .collect();
        let order3 = RadianceHintsVolume { sh_order: ShOrder::Three, ..RadianceHintsVolume::MEDIUM };
        out += &format!(
            "\nVolume memory (SH buffers, distances, albedo, packed irradiance, occupancy bits, visibility masks): {}; medium with SH order 3 {}. \
             The RSM atlas adds 36 B per texel and face (position, normal, flux, depth): 2.25 MiB for a spot \
             light at the default 256², 13.5 MiB for a point light's cube.\n",
            memory.join(", "),
            mib(order3.memory_bytes())
        );
        Ok(out)
    }

    /// Images for the docs page (`docs/images/rh_*.png`, tonemapped; indirect light ×4 as for the truths).
    fn images(&mut self) -> Result<String, String> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/images");
        let save = |image: &HdrImage, name: &str, scale: f32| -> Result<String, String> {
            let path = dir.join(format!("{name}.png"));
            image.write_png_tonemapped(&path, scale).map_err(|e| e.to_string())?;
            Ok(format!("images/{name}.png"))
        };
        let mut rows = Vec::new();
        let medium = self.render(&cornell(RadianceHintsVolume::MEDIUM))?;
        let full = self.render(&HeadlessOptions { indirect_only: false, ..cornell(RadianceHintsVolume::MEDIUM) })?;
        let direct = self.render(&HeadlessOptions::default())?;
        rows.push((
            "cornell, direct light only (Bevy)",
            save(direct.image(), "rh_cornell_direct", 1.0)?,
        ));
        rows.push(("cornell, direct + Radiance Hints (medium)", save(full.image(), "rh_cornell_full", 1.0)?));
        rows.push(("path-traced indirect light ×4 (ground truth)", save(&self.truths["cornell"], "rh_cornell_truth_x4", 4.0)?));
        rows.push(("Radiance Hints indirect light ×4 (medium)", save(medium.image(), "rh_cornell_medium_x4", 4.0)?));
        let diff = metrics::difference_image(medium.image(), &self.truths["cornell"], 1.0).map_err(|e| e.to_string())?;
        let diff_path = dir.join("rh_cornell_medium_diff.png");
        diff.save(&diff_path).map_err(|e| e.to_string())?;
        rows.push(("|RH − truth| / truth, false colour (black 0, white ≥ 1)", "images/rh_cornell_medium_diff.png".into()));
        for (view, name, label) in [
            (GiDebugView::HintGrid, "rh_cornell_hint_grid", "debug view: hint grid (nearest hint, cell borders)"),
            (GiDebugView::RsmFlux, "rh_cornell_rsm_flux", "debug view: the spot light's RSM flux"),
        ] {
            let m = self.render(&HeadlessOptions { debug_view: Some(view), ..cornell(RadianceHintsVolume::MEDIUM) })?;
            rows.push((label, save(m.image(), name, 4.0)?));
        }
        let cellar = self.render(&rh_options(StandardScene::Cellar, RadianceHintsVolume::HIGH))?;
        let leaky = self.render(&rh_options(
            StandardScene::Cellar,
            RadianceHintsVolume { voxel_visibility: false, ..RadianceHintsVolume::HIGH },
        ))?;
        rows.push(("cellar: path-traced indirect light ×4", save(&self.truths["cellar"], "rh_cellar_truth_x4", 4.0)?));
        rows.push(("cellar: Radiance Hints (high) ×4", save(cellar.image(), "rh_cellar_high_x4", 4.0)?));
        rows.push(("cellar: without voxel visibility (the paper's unoccluded first bounce) ×4", save(leaky.image(), "rh_cellar_no_visibility_x4", 4.0)?));
        let depth = self.render(&rh_options(
            StandardScene::Cellar,
            RadianceHintsVolume {
                voxel_visibility: false,
                depth_occlusion: Some(DepthOcclusion { samples: 8, strength: 0.5 }),
                ..RadianceHintsVolume::HIGH
            },
        ))?;
        rows.push(("cellar: §8 camera-depth occlusion instead of voxels ×4", save(depth.image(), "rh_cellar_depth_occlusion_x4", 4.0)?));
        let medium_cellar = self.render(&rh_options(StandardScene::Cellar, RadianceHintsVolume::MEDIUM))?;
        rows.push(("cellar: Radiance Hints (default, 0.3 m cells) ×4", save(medium_cellar.image(), "rh_cellar_medium_x4", 4.0)?));
        let mut out = String::from("| | |\n|---|---|\n");
        for pair in rows.chunks(2) {
            let cell = |r: &(&str, String)| format!("![{0}]({1})<br>{0}", r.0, r.1);
            out += &format!("| {} | {} |\n", cell(&pair[0]), pair.get(1).map(cell).unwrap_or_default());
        }
        Ok(out)
    }
}
