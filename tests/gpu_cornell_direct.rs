//! Bevy's own direct lighting of `cornell` on the GPU (lavapipe in CI), checked on pixels and against the
//! path tracer's direct-only image.
#![cfg(feature = "gpu_tests")]

mod common;

use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use common::{Region, check, luminance, render};

/// Floor inside the spot, left of the small box.
const LIT_FLOOR: Region = Region::new("lit floor", 48, 226, 112, 240);
/// Top of the small box, under the spot.
const SMALL_BOX_TOP: Region = Region::new("small box top", 140, 162, 180, 172);
/// Floor right of the small box, in its shadow.
const BOX_SHADOW: Region = Region::new("floor in the small box's shadow", 198, 228, 222, 244);

fn bevy_direct() -> bevy_diffuse_gi::hdr_image::HdrImage {
    render(&HeadlessOptions {
        method: HeadlessMethod::None,
        frames: 3,
        ..Default::default()
    })
    .image
}

#[test]
fn cornell_is_lit_under_the_spot_and_dark_in_the_box_shadow() {
    let test = "cornell_is_lit_under_the_spot_and_dark_in_the_box_shadow";
    let image = bevy_direct();
    check(test, !image.has_non_finite(), &image, None, "NaN or Inf in the image".into());
    let lit = luminance(LIT_FLOOR.mean(test, &image));
    let top = luminance(SMALL_BOX_TOP.mean(test, &image));
    let shadow = luminance(BOX_SHADOW.mean(test, &image));
    // The spot delivers 100 cd / 1.98² m ≈ 25.5 lux to the floor: ρ/π · E · exposure ≈ 5 on the white floor.
    check(test, lit > 3.0, &image, None, format!("lit floor luminance {lit} (expected ≈ 4.5)"));
    check(test, top > 3.0, &image, None, format!("small box top luminance {top} (expected ≈ 4)"));
    check(test, shadow < 0.01 * lit, &image, None, format!("shadowed floor {shadow} vs lit floor {lit}"));
    // The box is open towards the camera: the image corners see no geometry.
    check(test, !image.covered(0), &image, None, "top-left corner should be background".into());
    check(test, image.covered(image.index(128, 128)), &image, None, "image centre should see the back wall".into());
}

/// Bevy's direct lighting against the path tracer's direct-only image with Bevy's Burley lobe, sampled at
/// pixel centres (both noise-free). Measured on lavapipe: block relative RMSE 0.092, energy ratio 0.997;
/// what remains is shadow-map filtering along shadow edges and the 8-bit gamma albedo of the G-buffer.
#[test]
fn bevy_direct_light_matches_the_path_tracer() {
    let test = "bevy_direct_light_matches_the_path_tracer";
    let bevy = bevy_direct();
    let traced = render(&HeadlessOptions {
        method: HeadlessMethod::Reference,
        spp: 1,
        max_bounces: Some(1),
        burley_direct: true,
        pixel_centers: true,
        ..Default::default()
    });
    let (_, traced) = traced
        .extra_images
        .into_iter()
        .find(|(name, _)| *name == "direct")
        .expect("the tracer writes a direct image");
    let m = metrics::compare(&bevy, &traced).expect("comparable images");
    check(
        test,
        (0.97..=1.03).contains(&m.energy_ratio) && m.block_relative_rmse <= 0.12,
        &bevy,
        Some(&traced),
        format!(
            "direct light disagrees: energy ratio {:.4} (want 0.97–1.03), block rel. RMSE {:.4} (want ≤ 0.12)",
            m.energy_ratio, m.block_relative_rmse
        ),
    );
    for region in [LIT_FLOOR, SMALL_BOX_TOP] {
        let (b, t) = (region.mean(test, &bevy), region.mean(test, &traced));
        for c in 0..3 {
            let rel = (b[c] - t[c]).abs() / t[c].max(1e-6);
            check(
                test,
                rel <= 0.03,
                &bevy,
                Some(&traced),
                format!("{}: Bevy {b:?} vs traced {t:?} (channel {c} off by {:.1} %)", region.name, rel * 100.0),
            );
        }
    }
}
