//! Every windowed example runs in a real window on lavapipe under a virtual X display (Xvfb; `.ci/setup`
//! installs it) with the fixed-frame harness of `examples/common` (`CiCapturePlugin`): a fixed frame
//! time, a screenshot with bounced light held off, then one per method (or, for `showcase`, per slide)
//! ten frames apart, then exit. Fails when an example panics or exits with an error, logs an error,
//! shows an all-black 3D view, shows no more light with a method than without bounced light, or has no
//! tuning panel in a screenshot. Screenshots are left in `target/example-screenshots/`.
#![cfg(all(feature = "gpu_tests", feature = "egui"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// Every method, as the examples label their screenshots.
const METHODS: &[&str] = &["rh", "vpl", "rsm", "drm", "radiosity", "photon-grid"];

/// The windowed examples and the screenshots each takes after the no-GI one; `true`: each shows the scene
/// of the no-GI screenshot (so it must be brighter than it).
const EXAMPLES: &[(&str, &[&str], bool)] = &[
    ("cornell", METHODS, true),
    // The other scene examples step through two methods each in CI (every method is also in its own
    // example, `cornell` and the showcase): the windowed tests were a fifth of the CI run.
    ("cellar", &["vpl", "radiosity"], true),
    ("sponza_like", &["rh", "rsm"], true),
    ("open_field", &["drm", "vpl"], true),
    // Radiosity re-solves in every frame its objects move; tested headless instead.
    ("dynamic", &["rh", "vpl", "rsm", "drm"], true),
    ("radiance_hints", &["rh"], true),
    ("vpl_ssbc", &["vpl"], true),
    ("rsm_gather", &["rsm"], true),
    ("direct_radiance_mapping", &["drm"], true),
    ("implicit_visibility", &["radiosity"], true),
    ("photon_grid", &["photon-grid"], true),
    // The slides: a scene each; only the first shows the no-GI screenshot's scene (cornell).
    (
        "showcase",
        &[
            "cornell_rh",
            "cellar_vpl",
            "sponza_like_rsm",
            "open_field_drm",
            "dynamic_vpl",
            "emissive_panel_radiosity",
            "sky_room_photon-grid",
        ],
        false,
    ),
];

/// The virtual screen; the harness makes the window 800×450 inside it.
const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;

/// `target/<profile>/examples/NAME`, next to this test's own `target/<profile>/deps/` (cargo builds the
/// examples before running the tests).
fn example_binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    exe.parent().and_then(Path::parent).expect("target/<profile>").join("examples").join(name)
}

fn screenshot_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/example-screenshots")
}

/// Runs `example` under `xvfb-run` until it has saved its screenshots (`no_gi`, then `steps`); returns
/// them as RGB images, in that order.
fn run_example(example: &str, steps: &[&str]) -> Vec<(String, image::RgbImage)> {
    let binary = example_binary(example);
    assert!(binary.is_file(), "{} was not built", binary.display());
    std::fs::create_dir_all(screenshot_dir()).unwrap();
    let stem = screenshot_dir().join(example);
    let _guard = common::render_lock();
    let output = Command::new("xvfb-run")
        .args(["-a", "-s", &format!("-screen 0 {WIDTH}x{HEIGHT}x24")])
        .arg("timeout")
        .arg("600")
        .arg(&binary)
        .env("DIFFUSE_GI_CAPTURE", &stem)
        // Ten frames per method instead of the harness's twenty: every method shows bounced light by
        // then (Radiance Hints still refining), and the windowed examples were the largest part of CI.
        .env("DIFFUSE_GI_CAPTURE_INTERVAL", "10")
        .env("WGPU_BACKEND", "vulkan")
        .env("RUST_LOG", "warn")
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap_or_else(|e| panic!("cannot run xvfb-run ({e}); .ci/setup installs Xvfb (Debian/Ubuntu package xvfb)"));
    let log = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{example} exited with {}:\n{log}", output.status);
    let errors: Vec<&str> = log.lines().filter(|l| l.contains(" ERROR ") || l.contains("panicked")).collect();
    assert!(errors.is_empty(), "{example} logged errors:\n{}", errors.join("\n"));
    std::iter::once("no_gi")
        .chain(steps.iter().copied())
        .map(|label| {
            let shot = PathBuf::from(format!("{}_{label}.png", stem.display()));
            let image = image::open(&shot).unwrap_or_else(|e| panic!("{example}: no screenshot {}: {e}", shot.display()));
            (label.to_string(), image.to_rgb8())
        })
        .collect()
}

/// Mean brightness (0–255) of the whole screenshot.
fn mean(image: &image::RgbImage) -> f64 {
    let sum: f64 = image.pixels().map(|p| (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0).sum();
    sum / (image.width() * image.height()).max(1) as f64
}

/// The share of the screenshot covered by egui's window fill (the dark theme's flat grey, 27 ± 6 in every
/// channel): the "Diffuse GI" panel and the examples' key window cover a fifth or more of it; a 3D view
/// alone has almost none of it.
fn panel_share(image: &image::RgbImage) -> f64 {
    let fill = image
        .pixels()
        .filter(|p| (21..=33).contains(&p[0]) && p[0].abs_diff(p[1]) <= 2 && p[1].abs_diff(p[2]) <= 2)
        .count();
    fill as f64 / (image.width() * image.height()).max(1) as f64
}

/// The brightness (0–255, the whole 1280×720 screen) each method's bounced light added to its example's
/// screenshot on lavapipe (2026-12-06); the test asks for at least half of it. `showcase`'s slides after
/// the first show other scenes than its screenshot without bounced light, so only its first is compared.
const MEASURED_GAIN: &[(&str, &str, f64)] = &[
    ("cornell", "rh", 19.63),
    ("cornell", "vpl", 19.70),
    ("cornell", "rsm", 16.38),
    ("cornell", "drm", 15.78),
    ("cornell", "radiosity", 20.49),
    ("cornell", "photon-grid", 19.42),
    ("cellar", "vpl", 40.74),
    ("cellar", "radiosity", 35.22),
    ("sponza_like", "rh", 55.55),
    ("sponza_like", "rsm", 35.32),
    ("open_field", "drm", 4.30),
    ("open_field", "vpl", 10.12),
    ("dynamic", "rh", 9.84),
    ("dynamic", "vpl", 9.93),
    ("dynamic", "rsm", 5.83),
    ("dynamic", "drm", 4.57),
    ("radiance_hints", "rh", 17.10),
    ("vpl_ssbc", "vpl", 18.82),
    ("rsm_gather", "rsm", 16.21),
    ("direct_radiance_mapping", "drm", 15.70),
    ("implicit_visibility", "radiosity", 17.79),
    ("photon_grid", "photon-grid", 35.02),
    ("showcase", "cornell_rh", 12.12),
];

#[test]
fn every_windowed_example_runs_with_its_panel_and_adds_bounced_light() {
    for (example, steps, same_scene) in EXAMPLES {
        let shots = run_example(example, steps);
        let unlit = mean(&shots[0].1);
        assert!(unlit > 5.0, "{example}: the window without bounced light is black ({unlit:.1})");
        for (label, image) in &shots[1..] {
            let brightness = mean(image);
            assert!(brightness > 10.0, "{example} {label}: the window is black ({brightness:.1})");
            let panel = panel_share(image);
            assert!(panel > 0.1, "{example} {label}: no tuning panel in its screenshot (egui fill on {:.1} % of it)", 100.0 * panel);
            // Bounced light adds light: the screenshot with it is brighter than the one without, by at
            // least half of what was measured (a method that adds a trace of light fails).
            let gain = brightness - unlit;
            let measured = MEASURED_GAIN.iter().find(|(e, l, _)| e == example && l == label).map(|m| m.2);
            if *same_scene || measured.is_some() {
                let measured = measured.unwrap_or_else(|| panic!("{example} {label}: no measured gain in MEASURED_GAIN"));
                assert!(
                    gain > 0.5 * measured,
                    "{example} {label}: bounced light adds {gain:.2} to the screenshot's brightness, under half the {measured} measured"
                );
            }
            eprintln!("{example} {label}: mean {brightness:.1}, {gain:+.2} from bounced light, panel {:.1} %", 100.0 * panel);
        }
    }
}
