//! Every windowed example runs in a real window on lavapipe under a virtual X display (Xvfb; `.ci/setup`
//! installs it) with the fixed-frame harness of `examples/common` (`CiCapturePlugin`): a fixed frame
//! time, a screenshot of the window at frame 40, then exit. Fails when an example panics or exits with an
//! error, logs an error, shows an all-black 3D view, shows the same image as without bounced light, or
//! has no tuning panel in its screenshot. Screenshots are left in `target/example-screenshots/`.
#![cfg(all(feature = "gpu_tests", feature = "egui"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// The windowed examples and the method each starts with.
const EXAMPLES: &[&str] = &["radiance_hints", "vpl_ssbc", "dynamic", "rsm_gather", "direct_radiance_mapping"];

/// The virtual screen; Bevy's default window fills it.
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

/// Runs `example` under `xvfb-run` until it has saved its screenshot; returns the RGB image and the log.
fn run_example(example: &str, no_gi: bool) -> (image::RgbImage, String) {
    let binary = example_binary(example);
    assert!(binary.is_file(), "{} was not built", binary.display());
    std::fs::create_dir_all(screenshot_dir()).unwrap();
    let shot = screenshot_dir().join(format!("{example}{}.png", if no_gi { "_no_gi" } else { "" }));
    let _guard = common::render_lock();
    let mut command = Command::new("xvfb-run");
    command
        .args(["-a", "-s", &format!("-screen 0 {WIDTH}x{HEIGHT}x24")])
        .arg("timeout")
        .arg("600")
        .arg(&binary)
        .env("DIFFUSE_GI_CAPTURE", &shot)
        .env("WGPU_BACKEND", "vulkan")
        .env("RUST_LOG", "warn")
        .current_dir(env!("CARGO_MANIFEST_DIR"));
    if no_gi {
        command.env("DIFFUSE_GI_NO_GI", "1");
    } else {
        command.env_remove("DIFFUSE_GI_NO_GI");
    }
    let output = command.output().unwrap_or_else(|e| {
        panic!("cannot run xvfb-run ({e}); .ci/setup installs Xvfb (Debian/Ubuntu package xvfb)")
    });
    let log = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{example} exited with {}:\n{log}", output.status);
    let errors: Vec<&str> = log.lines().filter(|l| l.contains(" ERROR ") || l.contains("panicked")).collect();
    assert!(errors.is_empty(), "{example} logged errors:\n{}", errors.join("\n"));
    let image = image::open(&shot).unwrap_or_else(|e| panic!("{example}: no screenshot {}: {e}", shot.display())).to_rgb8();
    (image, log)
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

#[test]
fn every_windowed_example_runs_with_its_panel_and_adds_bounced_light() {
    for example in EXAMPLES {
        let (lit, _) = run_example(example, false);
        let (unlit, _) = run_example(example, true);
        let brightness = mean(&lit);
        assert!(brightness > 10.0, "{example}: the window is black ({brightness:.1})");
        let panel = panel_share(&lit);
        assert!(panel > 0.1, "{example}: no tuning panel in its screenshot (egui fill on {:.1} % of it)", 100.0 * panel);
        // Bounced light adds light: the screenshot with it is brighter than the one without.
        let gain = brightness - mean(&unlit);
        assert!(gain > 0.5, "{example}: the image with bounced light is not brighter than without ({gain:.2})");
        eprintln!("{example}: mean {brightness:.1}, +{gain:.2} from bounced light, panel {:.1} %", 100.0 * panel);
    }
}
