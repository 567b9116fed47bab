//! Measures implicit-visibility radiosity against the path-traced ground truths and times its stages:
//! the numbers of `docs/radiosity.md`.
//!
//! ```text
//! cargo run --release --features tools --example radiosity_report -- [--section NAME]... [--rounds N] [--docs docs/radiosity.md]
//! ```
//! Sections: `accuracy`, `bounces`, `stages`, `scaling`, `leak`, `timing` (default: all). Each prints a
//! Markdown table; with `--docs FILE` the table also replaces the text between
//! `<!-- radiosity_report:NAME -->` and `<!-- /radiosity_report:NAME -->` in FILE. Renders run one after
//! another in this process on whatever Vulkan device wgpu picks (lavapipe on CI machines), at 256²,
//! against the committed EXRs of `assets/ground_truth/`. The solve runs on the CPU (rayon, every core of
//! the machine): its stage times are wall-clock milliseconds of the main thread's solve.

#[path = "common/mod.rs"]
mod common;

use std::path::PathBuf;
use std::process::ExitCode;

use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::radiosity::RadiositySettings;
use bevy_diffuse_gi::scenes::StandardScene;

const SECTIONS: &[&str] = &["accuracy", "bounces", "stages", "scaling", "leak", "timing"];
/// Frames of a timed render, and the intervals at its end that the medians use.
const TIMING_FRAMES: u32 = 16;
const TIMED_FRAMES: usize = 8;

fn main() -> ExitCode {
    common::report_main("radiosity_report", run)
}

fn run() -> Result<(), String> {
    let args = common::start_report("radiosity_report", SECTIONS);
    let mut device = String::from("an unknown device");
    for section in &args.sections {
        let started = std::time::Instant::now();
        let table = match section.as_str() {
            "accuracy" => accuracy(&mut device)?,
            "bounces" => bounces(&mut device)?,
            "stages" => stages(&mut device)?,
            "scaling" => scaling(&mut device)?,
            "leak" => leak(&mut device)?,
            "timing" => timing(&mut device, args.rounds)?,
            _ => unreachable!("sections are validated"),
        };
        common::publish_section("radiosity_report", &args, section, &table, &device, started)?;
    }
    Ok(())
}

fn options(scene: StandardScene, radiosity: RadiositySettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::Radiosity),
        indirect_only: true,
        radiosity,
        frames: 3,
        ..Default::default()
    }
}


/// The solve's figures from a render's sidecar: elements, links, and the Table 1 stages in ms.
fn solve(report: &HeadlessReport) -> (u64, u64, [f64; 4], u64) {
    let r = &report.sidecar["radiosity"];
    let ms = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
    (
        r["elements"].as_u64().unwrap_or(0),
        r["links"].as_u64().unwrap_or(0),
        [ms("update_elements_ms"), ms("create_links_ms"), ms("refine_push_ms"), ms("illumination_ms")],
        r["bounces_run"].as_u64().unwrap_or(0),
    )
}

/// Each preset and bin resolution on the standard scenes, against the full truth.
fn accuracy(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "Block relative RMSE, per-pixel relative RMSE, energy ratio and the share of 4×4 blocks more than 50 % off,\n\
         against the full path-traced truth (all bounces).\n\n\
         | scene | settings | block RMSE | pixel RMSE | energy | blocks > 50 % off | elements |\n|---|---|---|---|---|---|---|\n",
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
    for (scene, name) in scenes {
        let reference = common::report_truth(name)?;
        let mut configs: Vec<(String, RadiositySettings)> = vec![
            ("low (6×12×12, 4 bounces)".into(), RadiositySettings::LOW),
            ("medium (6×16×16, 8 bounces; default)".into(), RadiositySettings::MEDIUM),
            ("high (6×20×20, 16 bounces)".into(), RadiositySettings::HIGH),
            ("medium, 4 bounces".into(), RadiositySettings { bounces: 4, ..RadiositySettings::MEDIUM }),
        ];
        // Bin resolution and bounce count on the issue's three scenes (the bounces against the full truth:
        // what a bounce count leaves out).
        if ["cornell", "cellar", "sky_room"].contains(&name) {
            for bins in [8, 12] {
                configs.push((format!("medium, 6×{bins}×{bins}"), RadiositySettings { bins, ..RadiositySettings::MEDIUM }));
            }
            for bounces in [1, 2] {
                configs.push((format!("medium, {bounces} bounce{}", if bounces == 1 { "" } else { "s" }), RadiositySettings { bounces, ..RadiositySettings::MEDIUM }));
            }
        }
        if name == "cornell" {
            configs.push((
                "medium, Eq. 5 with the element's area".into(),
                RadiositySettings { transfer: bevy_diffuse_gi::radiosity::LinkTransfer::ElementArea, ..RadiositySettings::MEDIUM },
            ));
        }
        for (label, settings) in configs {
            let report = common::report_render(device, &options(scene.clone(), settings))?;
            let m = common::report_compare(&report.image, &reference)?;
            out += &format!("| {name} | {label} | {} | {} |\n", common::report_cells(&m), solve(&report).0);
        }
    }
    Ok(out)
}

/// Bounce counts on `cornell` against the per-bounce truths.
fn bounces(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "`cornell`, medium preset, against the truth with the same number of bounces (`cornell_b1`, `_b2`; all for 4, 8 and 16), no early stop.\n\n\
         | bounces | truth | block RMSE | pixel RMSE | energy | blocks > 50 % off | bounces run |\n|---|---|---|---|---|---|---|\n",
    );
    for (bounces, name) in [(1, "cornell_b1"), (2, "cornell_b2"), (4, "cornell"), (8, "cornell"), (16, "cornell")] {
        let settings = RadiositySettings { bounces, stop_threshold: 0.0, ..RadiositySettings::MEDIUM };
        let report = common::report_render(device, &options(StandardScene::Cornell, settings))?;
        let m = common::report_compare(&report.image, &common::report_truth(name)?)?;
        out += &format!("| {bounces} | {name} | {} | {} |\n", common::report_cells(&m), solve(&report).3);
    }
    Ok(out)
}

/// The paper's Table 1: the solve's stages for 6×8×8, 6×12×12 and 6×16×16 bins.
fn stages(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "The stages of one full solve (one bounce, as the paper's Table 1), ms of wall time on the CPU.\n\n\
         | scene | bins | elements | links | update elements | create links | refine & push | illumination | total |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for (scene, name) in [(StandardScene::Cornell, "cornell"), (StandardScene::SponzaLike, "sponza_like")] {
        for bins in [8, 12, 16] {
            let settings = RadiositySettings { bins, bounces: 1, ..RadiositySettings::MEDIUM };
            let report = common::report_render(device, &options(scene.clone(), settings))?;
            let (elements, links, t, _) = solve(&report);
            let total: f64 = t.iter().sum();
            let pct = |x: f64| format!("{x:.0} ({:.0} %)", 100.0 * x / total);
            out += &format!(
                "| {name} | 6×{bins}×{bins} | {elements} | {links} | {} | {} | {} | {} | {total:.0} |\n",
                pct(t[0]),
                pct(t[1]),
                pct(t[2]),
                pct(t[3])
            );
        }
    }
    Ok(out)
}

/// Time per stage against the element count (element size from 1/8 to 1/64 of the scene), with the
/// slope of a least-squares line through log(time) against log(elements): about 1 for O(N log N). Also
/// draws the points on a log-log plot, `docs/images/radiosity_scaling.svg`.
fn scaling(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "`cornell`, 6×12×12 bins, one bounce, element size from 1/8 to 1/64 of the scene's diagonal.\n\n\
         | element size | elements | update elements ms | create links ms | refine & push ms | illumination ms |\n|---|---|---|---|---|---|\n",
    );
    let mut points: Vec<(f64, [f64; 4])> = Vec::new();
    for divisions in [8.0f32, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0] {
        let settings = RadiositySettings { bins: 12, bounces: 1, element_size: 1.0 / divisions, ..RadiositySettings::MEDIUM };
        let report = common::report_render(device, &options(StandardScene::Cornell, settings))?;
        let (elements, _, t, _) = solve(&report);
        out += &format!("| 1/{divisions} | {elements} | {:.1} | {:.1} | {:.1} | {:.1} |\n", t[0], t[1], t[2], t[3]);
        points.push((elements as f64, t));
    }
    let slope = |stage: usize| {
        let pts: Vec<(f64, f64)> = points.iter().filter(|p| p.1[stage] > 0.0).map(|p| (p.0.ln(), p.1[stage].ln())).collect();
        let n = pts.len() as f64;
        let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>()
    };
    out += &format!(
        "\nLog-log slopes (time ∝ elements^s; O(N log N) over this range is about 1.1): update elements {:.2}, create links {:.2}, \
         refine & push {:.2}, illumination {:.2}.\n",
        slope(0),
        slope(1),
        slope(2),
        slope(3)
    );
    let plot = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/images/radiosity_scaling.svg");
    plot_scaling(&plot, &points).map_err(|e| format!("{}: {e}", plot.display()))?;
    out += "\n![Time per stage against elements, log-log](images/radiosity_scaling.svg)\n";
    Ok(out)
}

/// The stage times against the element count on log-log axes, with an `N log N` guide through the
/// first point of the slowest stage.
fn plot_scaling(path: &std::path::Path, points: &[(f64, [f64; 4])]) -> Result<(), Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    let root = SVGBackend::new(path, (720, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let positive = || points.iter().flat_map(|p| p.1).filter(|t| *t > 0.0);
    let (t_min, t_max) = (positive().fold(f64::INFINITY, f64::min), positive().fold(0.0, f64::max));
    let (n_min, n_max) = (points.iter().map(|p| p.0).fold(f64::INFINITY, f64::min), points.iter().map(|p| p.0).fold(0.0, f64::max));
    let mut chart = ChartBuilder::on(&root)
        .caption("Radiosity solve on cornell: time per stage (6×12×12 bins)", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((n_min * 0.8..n_max * 1.25).log_scale(), (t_min * 0.5..t_max * 2.0).log_scale())?;
    chart.configure_mesh().x_desc("elements").y_desc("ms (wall clock, CPU)").draw()?;
    let stages = ["update elements", "create links", "refine & push", "illumination"];
    let colours = [RGBColor(80, 80, 80), RGBColor(200, 60, 40), RGBColor(40, 110, 200), RGBColor(40, 160, 70)];
    for (stage, (name, colour)) in stages.iter().zip(colours).enumerate() {
        let series: Vec<(f64, f64)> = points.iter().filter(|p| p.1[stage] > 0.0).map(|p| (p.0, p.1[stage])).collect();
        chart
            .draw_series(LineSeries::new(series.clone(), colour.stroke_width(2)))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
        chart.draw_series(series.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
    }
    // N log N through the first point of create links (the dominant stage).
    if let Some(first) = points.iter().find(|p| p.1[1] > 0.0) {
        let (n0, t0) = (first.0, first.1[1]);
        let guide: Vec<(f64, f64)> =
            points.iter().map(|p| (p.0, t0 * (p.0 * p.0.ln()) / (n0 * n0.ln()))).collect();
        chart
            .draw_series(LineSeries::new(guide, BLACK.mix(0.4).stroke_width(1)))?
            .label("N log N")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.mix(0.4)));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.9)).border_style(BLACK).position(SeriesLabelPosition::UpperLeft).draw()?;
    root.present()?;
    Ok(())
}

/// The leak of coarse tessellation (the paper's Fig. 10d): the meshes' own vertices against cut
/// elements, and what the subdivision threshold does.
fn leak(device: &mut String) -> Result<String, String> {
    let mut out = String::from(
        "Element size 0 keeps the meshes' own vertices (the paper's elements: four per wall of `cornell`, the cellar's\n\
         walls are boxes of eight). Against the full truth.\n\n\
         | scene | elements | subdivision threshold | block RMSE | pixel RMSE | energy | blocks > 50 % off | elements |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for (scene, name) in [(StandardScene::Cornell, "cornell"), (StandardScene::Cellar, "cellar")] {
        let reference = common::report_truth(name)?;
        for (size, label) in [(0.0, "mesh vertices"), (1.0 / 16.0, "1/16"), (1.0 / 32.0, "1/32 (default)")] {
            for threshold in [1.0, 0.25] {
                let settings = RadiositySettings { element_size: size, subdivision_threshold: threshold, ..RadiositySettings::MEDIUM };
                let report = common::report_render(device, &options(scene.clone(), settings))?;
                let m = common::report_compare(&report.image, &reference)?;
                out += &format!("| {name} | {label} | {threshold} | {} | {} |\n", common::report_cells(&m), solve(&report).0);
            }
        }
    }
    Ok(out)
}

/// Still-frame cost against the frame without GI, alternating in `rounds` rounds.
fn timing(device: &mut String, rounds: usize) -> Result<String, String> {
    let mut out = String::from(
        "Median frame time of a still frame (the solution reused, only the display pass runs) over the frame without GI,\n\
         measured alternately; the solve itself is in `stages`.\n\n| scene | size | no GI ms | radiosity ms | ratio |\n|---|---|---|---|---|\n",
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
                let gi = HeadlessOptions { method: HeadlessMethod::Gi(GiMethod::Radiosity), ..base };
                with.push(common::frame_ms(&common::report_render(device, &gi)?, TIMED_FRAMES));
            }
            let (a, b) = (common::median(&none), common::median(&with));
            out += &format!("| {name} | {size}² | {a:.1} | {b:.1} | {:.2} |\n", b / a);
        }
    }
    Ok(out)
}
