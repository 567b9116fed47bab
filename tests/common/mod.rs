//! Shared helpers of the GPU tests: serialised headless renders, region checks, and failure images.
#![allow(dead_code, reason = "each test binary uses a different subset")]

use std::path::PathBuf;
use std::sync::Mutex;

use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessOptions};
use bevy_diffuse_gi::metrics;

/// One Bevy app at a time: lavapipe shares two cores, and each app owns a Vulkan device.
static GPU: Mutex<()> = Mutex::new(());

/// Holds the GPU for one render (and selects Vulkan unless `WGPU_BACKEND` says otherwise).
pub fn render_lock() -> std::sync::MutexGuard<'static, ()> {
    let guard = GPU.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if std::env::var_os("WGPU_BACKEND").is_none() {
        // Lavapipe is a Vulkan driver; do not let wgpu wander to GL.
        // SAFETY: set while holding the lock, before this test starts a render thread.
        unsafe { std::env::set_var("WGPU_BACKEND", "vulkan") };
    }
    guard
}

/// Renders `options` in this process and returns the report. Panics with the renderer's message.
pub fn render(options: &HeadlessOptions) -> headless::HeadlessReport {
    let _guard = render_lock();
    headless::run(options).unwrap_or_else(|e| panic!("headless render failed: {e}"))
}

/// Where failing tests leave their images: `target/test-failures/<test>/`.
pub fn failure_dir(test: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-failures").join(test)
}

/// Saves `actual` (EXR and PNG), and, with a reference, the reference PNG and a false-colour difference.
pub fn save_failure(test: &str, actual: &HdrImage, reference: Option<&HdrImage>) -> PathBuf {
    let dir = failure_dir(test);
    std::fs::create_dir_all(&dir).ok();
    actual.write_exr(dir.join("actual.exr")).ok();
    actual.write_png_tonemapped(dir.join("actual.png"), 1.0).ok();
    if let Some(reference) = reference {
        reference.write_png_tonemapped(dir.join("reference.png"), 1.0).ok();
        if let Ok(diff) = metrics::difference_image(actual, reference, 1.0) {
            diff.save(dir.join("difference.png")).ok();
        }
    }
    dir
}

/// A named rectangle `[x0, x1) × [y0, y1)` of a 256² cornell image.
#[derive(Clone, Copy, Debug)]
pub struct Region {
    pub name: &'static str,
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Region {
    pub const fn new(name: &'static str, x0: u32, y0: u32, x1: u32, y1: u32) -> Self {
        Self { name, x0, y0, x1, y1 }
    }

    /// Mean RGB of the covered pixels; panics (saving the image) when none is covered.
    pub fn mean(&self, test: &str, image: &HdrImage) -> [f32; 3] {
        image.region_mean(self.x0, self.y0, self.x1, self.y1).unwrap_or_else(|| {
            let dir = save_failure(test, image, None);
            panic!("region {} sees no geometry; image saved in {}", self.name, dir.display())
        })
    }

    /// Asserts that the region's colour in `image` is the truth's: its R/G and B/G ratios each within
    /// `tolerance` (a fraction) of the truth's there.
    #[track_caller]
    pub fn same_colour(&self, test: &str, image: &HdrImage, truth: &HdrImage, tolerance: f32) {
        let (a, r) = (self.mean(test, image), self.mean(test, truth));
        for (c, name) in [(0, "R/G"), (2, "B/G")] {
            let (ours, theirs) = (a[c] / a[1], r[c] / r[1]);
            check(
                test,
                (ours / theirs - 1.0).abs() < tolerance,
                image,
                Some(truth),
                format!("{}: {name} {ours:.3} against the truth's {theirs:.3}", self.name),
            );
        }
    }
}

pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Asserts `condition`, saving the images first when it fails.
#[track_caller]
pub fn check(test: &str, condition: bool, actual: &HdrImage, reference: Option<&HdrImage>, message: String) {
    if !condition {
        let dir = save_failure(test, actual, reference);
        panic!("{message}\n(images saved in {})", dir.display());
    }
}

/// The path tracer's direct light of `scene` the way Bevy shades it (Burley lobe, one ray through each
/// pixel centre: noise-free), for comparing with Bevy's own direct light.
pub fn traced_direct(scene: bevy_diffuse_gi::scenes::StandardScene) -> HdrImage {
    let report = render(&HeadlessOptions {
        scene,
        method: bevy_diffuse_gi::headless::HeadlessMethod::Reference,
        spp: 1,
        max_bounces: Some(1),
        burley_direct: true,
        pixel_centers: true,
        ..Default::default()
    });
    report.extra_images.into_iter().find(|(n, _)| *n == "direct").map(|(_, i)| i).expect("direct image")
}

/// Asserts the error and energy of `image` against `truth` are within the bounds, and nothing is
/// non-finite; returns the metrics.
#[track_caller]
pub fn within(test: &str, image: &HdrImage, truth: &HdrImage, max_block_rmse: f64, energy: (f64, f64)) -> metrics::ErrorMetrics {
    check(test, !image.has_non_finite(), image, Some(truth), "NaN or Inf in the indirect light".into());
    let m = metrics::compare(image, truth).expect("same size");
    eprintln!("{test}: block rel. RMSE {:.3}, energy {:.3}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse <= max_block_rmse && (energy.0..=energy.1).contains(&m.energy_ratio),
        image,
        Some(truth),
        format!(
            "block rel. RMSE {:.3} (at most {max_block_rmse}), energy {:.3} (in {energy:?})",
            m.block_relative_rmse, m.energy_ratio
        ),
    );
    m
}

/// A committed ground truth of `assets/ground_truth/`.
pub fn ground_truth(name: &str) -> HdrImage {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/ground_truth").join(name);
    HdrImage::read(&path).unwrap_or_else(|e| panic!("ground truth {}: {e}", path.display()))
}

/// Pixels of `image` off by more than `factor` either way from the truth around them: from the truth's
/// mean over every 3×3 window within a pixel of them (the truth's per-pixel noise averaged away; Radiance
/// Hints has none of its own). A pixel on a silhouette agrees with the windows on its own side of the
/// edge; a speck or a dotted row agrees with none.
pub fn outliers(image: &HdrImage, truth: &HdrImage, factor: f32) -> Vec<(u32, u32, f32, f32)> {
    let (w, h) = (image.width, image.height);
    let mean_all = {
        let lit: Vec<f32> = truth.pixels.iter().filter(|p| p[3] > 0.5).map(|p| luminance([p[0], p[1], p[2]])).collect();
        lit.iter().sum::<f32>() / lit.len().max(1) as f32
    };
    let mut found = Vec::new();
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            let p = image.get(x, y);
            if p[3] < 0.5 {
                continue;
            }
            let a = luminance([p[0], p[1], p[2]]);
            let windows: Vec<f32> = (0..9)
                .filter_map(|k| {
                    let (cx, cy) = (x + k % 3 - 1, y + k / 3 - 1);
                    truth.region_mean(cx - 1, cy - 1, cx + 2, cy + 2).map(luminance)
                })
                .collect();
            let Some(&t) = windows.iter().max_by(|a, b| a.total_cmp(b)) else {
                continue;
            };
            let too_bright = windows.iter().all(|&t| a > factor * t);
            let too_dark = windows.iter().all(|&t| a < t / factor);
            if t > 0.01 * mean_all && (too_bright || too_dark) {
                found.push((x, y, a, t));
            }
        }
    }
    found
}
