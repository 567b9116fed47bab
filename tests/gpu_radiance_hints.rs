//! Radiance Hints rendered on the GPU (lavapipe in CI), asserted on pixels and against the committed
//! path-traced ground truths (`assets/ground_truth/`).
#![cfg(feature = "gpu_tests")]

mod common;


use bevy_diffuse_gi::camera::{GiMethod, GiOutput};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::radiance_hints::{DepthOcclusion, GridSizing, RadianceHintsVolume};
use bevy_diffuse_gi::scenes::StandardScene;
use common::{Region, check, ground_truth, luminance, outliers, render};

fn rh(scene: StandardScene, rh: RadianceHintsVolume) -> HdrImage {
    render(&HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        rh,
        ..Default::default()
    })
    .image
}

/// [`rh`] after 32 frames: a large volume's refinement (17 updates) has converged, as in the report's
/// measurements; after the default 8 frames `open_field` is still 0.2 further off.
///
/// The default volume's images are rendered once per scene and shared by the tests that read them
/// (`cellar`'s by the large scenes, the junction tests and the unlit-room test), which saves a render of
/// 20 s each. The renderer is deterministic for a still scene, so a shared image tests the same thing.
fn rh_converged(scene: StandardScene, rh: RadianceHintsVolume) -> HdrImage {
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock};
    static DEFAULT: OnceLock<Mutex<HashMap<String, HdrImage>>> = OnceLock::new();
    if rh != RadianceHintsVolume::default() {
        return rh_converged_uncached(scene, rh);
    }
    // Held while rendering, so a second test asking for the same scene waits for this render instead
    // of repeating it. `render` takes the render lock after this one, and nothing takes them the other
    // way round. A panicking render leaves the map as it was.
    let mut images = DEFAULT.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner());
    images.entry(scene.name()).or_insert_with(|| rh_converged_uncached(scene, rh)).clone()
}

fn rh_converged_uncached(scene: StandardScene, rh: RadianceHintsVolume) -> HdrImage {
    render(&HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        rh,
        frames: 32,
        ..Default::default()
    })
    .image
}

/// Floor beside the red wall.
const FLOOR_BY_RED: Region = Region::new("floor by the red wall", 12, 228, 40, 246);
/// The small box's side facing the green wall.
const BOX_BY_GREEN: Region = Region::new("small box side facing the green wall", 186, 175, 192, 225);
/// The tall box's side facing the red wall.
const BOX_BY_RED: Region = Region::new("tall box side facing the red wall", 70, 110, 78, 200);
/// The floor in the small box's shadow (no direct light).
const BOX_SHADOW: Region = Region::new("floor in the small box's shadow", 198, 228, 222, 244);
/// The ceiling: lit only indirectly, by white surfaces mostly.
const CEILING: Region = Region::new("ceiling", 60, 8, 196, 30);

#[test]
fn cornell_radiance_hints_bleed_colour_fill_shadows_and_match_the_ground_truth() {
    let test = "cornell_radiance_hints";
    let image = rh(StandardScene::Cornell, RadianceHintsVolume::MEDIUM);
    let truth = ground_truth("cornell.exr");
    check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf in the indirect light".into());

    // Red bleeds onto the white floor and the tall box: far more red than the white albedo's 1.27 : 1.
    for region in [FLOOR_BY_RED, BOX_BY_RED] {
        let c = region.mean(test, &image);
        check(test, c[0] > 3.0 * c[1], &image, Some(&truth), format!("{}: no red bleeding, {c:?}", region.name));
    }
    // Green bleeds onto the small box's side that faces the green wall: greener than the ceiling, which
    // sees mostly white surfaces (ground truth: 1.42×).
    let green = BOX_BY_GREEN.mean(test, &image);
    let neutral = CEILING.mean(test, &image);
    let (g_side, g_ceiling) = (green[1] / green[0], neutral[1] / neutral[0]);
    check(
        test,
        g_side > 1.15 * g_ceiling,
        &image,
        Some(&truth),
        format!("no green bleeding: G/R {g_side:.3} on the box side vs {g_ceiling:.3} on the ceiling"),
    );
    // The spot does not reach the floor behind the small box; bounced light does (truth ≈ 0.22).
    let shadow = luminance(BOX_SHADOW.mean(test, &image));
    check(test, shadow > 0.1, &image, Some(&truth), format!("no indirect light in the shadow: {shadow}"));

    // Against the path-traced indirect light, after 8 frames (the refinement still running). Measured on
    // lavapipe: block relative RMSE 0.123, energy 1.06; the targets are ≤ 0.17 and ±10 %.
    let m = metrics::compare(&image, &truth).expect("comparable images");
    eprintln!("{test}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse <= 0.17 && (0.90..=1.10).contains(&m.energy_ratio),
        &image,
        Some(&truth),
        format!(
            "cornell, medium preset: block relative RMSE {:.4} (want ≤ 0.17), energy {:.4} (want 0.90–1.10)",
            m.block_relative_rmse, m.energy_ratio
        ),
    );
}

#[test]
fn cellar_light_does_not_leak_through_the_dividing_wall() {
    let test = "cellar_radiance_hints";
    let image = rh(StandardScene::Cellar, RadianceHintsVolume::HIGH);
    let truth = ground_truth("cellar.exr");
    check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf".into());
    // Room B's side of the dividing wall, opposite the flashlight's spot on room A's side.
    for region in [
        Region::new("dividing wall, room B side", 20, 80, 120, 140),
        Region::new("top of the dividing wall", 10, 30, 120, 50),
    ] {
        let (a, t) = (luminance(region.mean(test, &image)), luminance(region.mean(test, &truth)));
        check(
            test,
            a < 1.5 * t,
            &image,
            Some(&truth),
            format!("{}: {a:.3} against {t:.3} in the ground truth: light leaks through the wall", region.name),
        );
    }
    // Specks: where the dividing wall meets the ceiling, single pixels must not pick up the next room's
    // hints (they did, at 10× the truth, through the wall's own voxels). RH has no per-pixel noise, so
    // no pixel there may exceed 3× the truth's mean over the strip.
    let strip = Region::new("junction of the dividing wall and the ceiling", 0, 25, 185, 70);
    let limit = 3.0 * luminance(strip.mean(test, &truth));
    let specks: Vec<(u32, u32)> = (strip.y0..strip.y1)
        .flat_map(|y| (strip.x0..strip.x1).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = image.get(x, y);
            luminance([p[0], p[1], p[2]]) > limit
        })
        .collect();
    check(
        test,
        specks.is_empty(),
        &image,
        Some(&truth),
        format!("{} pixels above {limit:.3} along {}, e.g. {:?}", specks.len(), strip.name, specks.first()),
    );
    // Measured on lavapipe: block relative RMSE 0.290, energy 0.857 (the paper's first bounce without
    // visibility: 2.51 / 2.32).
    let m = metrics::compare(&image, &truth).expect("comparable images");
    eprintln!("{test}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse <= 0.33 && (0.78..=1.0).contains(&m.energy_ratio),
        &image,
        Some(&truth),
        format!("cellar, high preset: block {:.4} (want ≤ 0.33), energy {:.4} (want 0.78–1.0)", m.block_relative_rmse, m.energy_ratio),
    );
}

#[test]
fn absurd_settings_are_clamped_and_still_render_finite_light() {
    let test = "rh_absurd_settings";
    let settings = RadianceHintsVolume {
        resolution: bevy::math::UVec3::new(0, 1_000_000, 4),
        rsm_samples: 0,
        jitter: f32::NAN,
        extra_bounces: 500,
        secondary_samples: 0,
        temporal_blend: -3.0,
        intensity: f32::INFINITY,
        r_max: f32::NAN,
        depth_occlusion: Some(DepthOcclusion { samples: 0, strength: f32::NAN }),
        reconstruction_samples: 0,
        near_field_occlusion: f32::INFINITY,
        sizing: GridSizing::Adaptive { hints: 0, max_cell: f32::NAN, max_hints: u32::MAX },
        ..RadianceHintsVolume::LOW
    };
    let image = render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        rh: settings,
        rh_fit_cells: false,
        frames: 2,
        ..Default::default()
    })
    .image;
    check(test, !image.has_non_finite(), &image, None, "NaN or Inf reached the image".into());
    let ceiling = luminance(CEILING.mean(test, &image));
    check(test, ceiling > 0.05, &image, None, format!("no bounced light with clamped settings: {ceiling}"));
}

#[test]
fn half_resolution_the_default_holds_the_error_of_full_resolution() {
    let test = "rh_half_resolution";
    // Both after the refinement has converged, so that the comparison sees the resolution, not two
    // different stages of the running average (after 8 frames they differed by 0.024–0.054 run to run).
    let full = render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        half_resolution: false,
        frames: 32,
        ..Default::default()
    })
    .image;
    let half = rh_converged(StandardScene::Cornell, RadianceHintsVolume::default());
    assert!(HeadlessOptions::default().half_resolution, "the default camera reconstructs at half resolution");
    let truth = ground_truth("cornell.exr");
    let (m_full, m_half) = (metrics::compare(&full, &truth).expect("full"), metrics::compare(&half, &truth).expect("half"));
    let between = metrics::compare(&half, &full).expect("comparable");
    // Measured on lavapipe: full 0.147, half 0.147 against the truth; 0.03 between the two.
    eprintln!(
        "{test}: against the truth full {:.4} / half {:.4}; between them block {:.4}, energy {:.4}",
        m_full.block_relative_rmse, m_half.block_relative_rmse, between.block_relative_rmse, between.energy_ratio
    );
    check(
        test,
        m_half.block_relative_rmse <= m_full.block_relative_rmse + 0.01
            && between.block_relative_rmse < 0.05
            && (0.97..=1.03).contains(&between.energy_ratio),
        &half,
        Some(&full),
        format!(
            "half resolution {:.4} against full {:.4} (truth); between them block {:.4}, energy {:.4}",
            m_half.block_relative_rmse, m_full.block_relative_rmse, between.block_relative_rmse, between.energy_ratio
        ),
    );
}

#[test]
fn irradiance_volume_output_lights_the_scene_through_bevys_light_probe() {
    let test = "rh_irradiance_volume_output";
    let direct = render(&HeadlessOptions::default()).image;
    let lit = render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        gi_output: GiOutput::IrradianceVolume,
        ..Default::default()
    })
    .image;
    let indirect = lit.subtract(&direct).expect("same size");
    check(test, !indirect.has_non_finite(), &indirect, None, "NaN or Inf".into());
    let truth = ground_truth("cornell.exr");
    // StandardMaterial applies the probe: the ceiling and the box's shadow receive light.
    for region in [CEILING, BOX_SHADOW] {
        let v = luminance(region.mean(test, &indirect));
        check(test, v > 0.05, &indirect, Some(&truth), format!("{}: no light from the probe ({v})", region.name));
    }
    // Six directions per hint (floors and ceilings from the exact vertical irradiance) and no hemisphere
    // sampling, yet close to the per-pixel composite. Measured on lavapipe: block relative RMSE 0.171,
    // energy 1.07 (composite after 8 frames: 0.123, 1.06).
    let m = metrics::compare(&indirect, &truth).expect("comparable");
    eprintln!("{test}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse < 0.21 && (0.90..=1.10).contains(&m.energy_ratio),
        &indirect,
        Some(&truth),
        format!("IrradianceVolume output: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio),
    );
}

/// Block RMSE, energy and blocks more than 50 % off of `image` against `truth`, checked against what was
/// measured on lavapipe (`docs/radiance_hints.md`, § game scale) with a margin for the sampling.
fn within_measured(test: &str, image: &HdrImage, truth: &HdrImage, block: f64, energy: f64, off: f64) {
    check(test, !image.has_non_finite(), image, Some(truth), "NaN or Inf in the indirect light".into());
    let m = metrics::compare(image, truth).expect("comparable images");
    eprintln!(
        "{test}: block {:.4}, energy {:.4}, blocks > 50 % off {:.3}",
        m.block_relative_rmse, m.energy_ratio, m.blocks_over_half_off
    );
    check(
        test,
        m.block_relative_rmse <= block + 0.03
            && (m.energy_ratio - energy).abs() <= 0.05
            && m.blocks_over_half_off <= off + 0.03,
        image,
        Some(truth),
        format!(
            "block {:.4} (measured {block}), energy {:.4} (measured {energy}), blocks > 50 % off {:.3} (measured {off})",
            m.block_relative_rmse, m.energy_ratio, m.blocks_over_half_off
        ),
    );
}

#[test]
fn the_default_volume_is_right_in_the_large_standard_scenes() {
    // The default's adaptive grid, fitted to each scene by the headless renderer as a game would place
    // one volume around its level. `sponza_like` is lit by the sun (a directional RSM), `cellar` by a
    // spot light seen from the next room.
    for (scene, truth, block, energy, off) in [
        (StandardScene::SponzaLike, "sponza_like.exr", MEASURED_SPONZA.0, MEASURED_SPONZA.1, MEASURED_SPONZA.2),
        (StandardScene::Cellar, "cellar.exr", MEASURED_CELLAR.0, MEASURED_CELLAR.1, MEASURED_CELLAR.2),
        (StandardScene::OpenField, "open_field.exr", MEASURED_FIELD.0, MEASURED_FIELD.1, MEASURED_FIELD.2),
    ] {
        let test = format!("rh_default_{}", scene.name());
        let image = rh_converged(scene, RadianceHintsVolume::default());
        within_measured(&test, &image, &ground_truth(truth), block, energy, off);
    }
}

/// Measured on lavapipe at the default settings: (block relative RMSE, energy, blocks > 50 % off).
const MEASURED_SPONZA: (f64, f64, f64) = (0.176, 1.006, 0.003);
const MEASURED_CELLAR: (f64, f64, f64) = (0.200, 0.923, 0.004);
/// 0.65 m cells over the 60 m field (the default's budget of 2¹⁷ hints); the target is ≤ 0.30.
/// Measured 0.327 / 0.996 / 0.051 since the volume's first voxels arrive from the background (the
/// benchmark's 16 frames: 0.320 / 0.993 / 0.049; 0.297 / 0.968 / 0.042 before issue #32's changes).
const MEASURED_FIELD: (f64, f64, f64) = (0.327, 0.996, 0.051);
const MEASURED_POINT: (f64, f64, f64) = (0.112, 1.051, 0.003);
const MEASURED_PANEL: (f64, f64, f64) = (0.299, 1.115, 0.118);

#[test]
fn a_point_light_bounces_through_its_cube_rsm() {
    // The `dynamic` scene at pose 0 (nothing moves): a point light, whose RSM is a cube of six faces.
    let test = "rh_point_light";
    let image = rh_converged(StandardScene::Dynamic, RadianceHintsVolume::default());
    within_measured(test, &image, &ground_truth("dynamic.exr"), MEASURED_POINT.0, MEASURED_POINT.1, MEASURED_POINT.2);
}

#[test]
fn an_emissive_panel_alone_lights_the_room_in_its_own_colour() {
    // No analytic light: every lit pixel but the panel is light Radiance Hints injected from the
    // panel's emitter samples and bounced.
    let test = "rh_emissive_panel";
    let image = rh_converged(StandardScene::EmissivePanel, RadianceHintsVolume::default());
    let truth = ground_truth("emissive_panel.exr");
    let floor = luminance(FLOOR_BY_RED.mean(test, &image));
    check(test, floor > 0.05, &image, Some(&truth), format!("no light from the panel on the floor: {floor}"));
    // The panel's warm colour: the image's red : green : blue as in the truth (white surfaces
    // dominate), within 10 %.
    let colour = |i: &HdrImage| {
        let s = i.pixels.iter().filter(|p| p[3] > 0.5).fold([0.0f64; 3], |a, p| [a[0] + p[0] as f64, a[1] + p[1] as f64, a[2] + p[2] as f64]);
        [s[0] / s[1], s[2] / s[1]]
    };
    let (got, want) = (colour(&image), colour(&truth));
    check(
        test,
        (got[0] / want[0] - 1.0).abs() < 0.1 && (got[1] / want[1] - 1.0).abs() < 0.1,
        &image,
        Some(&truth),
        format!("colour R/G, B/G {got:?} against {want:?} in the ground truth"),
    );
    within_measured(test, &image, &truth, MEASURED_PANEL.0, MEASURED_PANEL.1, MEASURED_PANEL.2);
}

#[test]
fn the_same_scene_in_other_units_gets_the_same_hints_and_the_same_light() {
    // emissive_panel at 1× and at 250× (about Bevy's 557 m CornellBox.glb): an emissive scene's image does
    // not depend on its scale, and the adaptive grid follows the surfaces' mean chord, not metres. With
    // `max_cell` in metres alone the large box got 51×51×51 hints and a frame 38× slower
    // (`docs/radiance_hints.md`, § the same scene in other units).
    let test = "rh_scene_units";
    let run = |scene_scale| {
        render(&HeadlessOptions {
            scene: StandardScene::EmissivePanel,
            method: HeadlessMethod::Gi(GiMethod::RadianceHints),
            indirect_only: true,
            size: bevy::math::UVec2::splat(64),
            frames: 8,
            scene_scale,
            ..Default::default()
        })
    };
    let (one, large) = (run(1.0), run(250.0));
    let (a, b) = (&one.sidecar["radiance_hints"], &large.sidecar["radiance_hints"]);
    let chord = |r: &serde_json::Value| r["mean_chord"].as_f64().unwrap_or(f64::NAN);
    check(
        test,
        a["resolution"] == b["resolution"] && a["resolution"] == serde_json::json!([16, 16, 16]) && (chord(b) / chord(a) / 250.0 - 1.0).abs() < 0.01,
        &large.image,
        Some(&one.image),
        format!("hints {} at 1× and {} at 250×, mean chord {:.3} m and {:.1} m", a["resolution"], b["resolution"], chord(a), chord(b)),
    );
    let m = metrics::compare(&large.image, &one.image).expect("same size");
    check(
        test,
        m.block_relative_rmse < 0.05 && (m.energy_ratio - 1.0).abs() < 0.02,
        &large.image,
        Some(&one.image),
        format!("250× against 1×: block rel. RMSE {:.3}, energy {:.3}", m.block_relative_rmse, m.energy_ratio),
    );
}

/// Luminance along a row band of `image`, one value per column in `x0..x1`.
fn row_profile(image: &HdrImage, rows: std::ops::Range<u32>, x0: u32, x1: u32) -> Vec<f32> {
    (x0..x1)
        .map(|x| {
            let n = rows.len() as f32;
            rows.clone().map(|y| { let p = image.get(x, y); luminance([p[0], p[1], p[2]]) }).sum::<f32>() / n
        })
        .collect()
}

#[test]
fn a_volume_nested_in_a_coarser_one_takes_over_without_a_seam() {
    use bevy::prelude::*;
    let test = "rh_nested_volumes";
    // A coarse volume around the Cornell box (4³ hints of 50 cm) and, in its left part, a fine one
    // (12 × 24 × 24 hints of 11 cm) whose light is made 3× brighter so that a seam cannot hide: its
    // field must fade in over its blend band (2 cells, x = 0.08 … 0.3 m on the back wall, pixel columns
    // ≈ 134–150), not switch on at its face.
    let coarse = RadianceHintsVolume { sizing: GridSizing::Fixed, resolution: UVec3::splat(4), ..RadianceHintsVolume::MEDIUM };
    let options = HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        rh: coarse.clone(),
        rh_fit_cells: false,
        frames: 24,
        ..Default::default()
    };
    // The volumes are spawned here, so the renderer does not fit its own.
    let render_volumes = |volumes: Vec<(RadianceHintsVolume, Transform)>| {
        let _guard = common::render_lock();
        bevy_diffuse_gi::headless::run_with(&options, move |app| {
            app.add_systems(Startup, move |mut commands: Commands| {
                for v in &volumes {
                    commands.spawn(v.clone());
                }
            });
        })
        .unwrap_or_else(|e| panic!("headless render failed: {e}"))
        .image
    };
    let around_the_box = (coarse.clone(), Transform::from_scale(Vec3::splat(2.02)));
    let with_fine = |intensity: f32| {
        let fine = RadianceHintsVolume { resolution: UVec3::new(12, 24, 24), intensity, ..coarse.clone() };
        render_volumes(vec![
            around_the_box.clone(),
            (fine, Transform::from_xyz(-0.355, 0.0, 0.0).with_scale(Vec3::new(1.31, 2.02, 2.02))),
        ])
    };
    let plain = with_fine(1.0);
    let nested = with_fine(3.0);
    check(test, !nested.has_non_finite(), &nested, Some(&plain), "NaN or Inf".into());
    // The back wall above the boxes, columns 100..190 (x ≈ −0.4 … +0.85 m).
    let rows = 92..100;
    let p = row_profile(&nested, rows.clone(), 100, 190);
    let c = row_profile(&plain, rows, 100, 190);
    let ratio = |range: std::ops::Range<usize>| range.clone().map(|i| p[i] / c[i]).sum::<f32>() / range.len() as f32;
    // The fine volume (its light 3× in `nested`) rules left of the band, the coarse one right of its
    // face.
    let (inside, outside) = (ratio(10..30), ratio(55..85));
    check(
        test,
        inside > 2.5 && (outside - 1.0).abs() < 0.1,
        &nested,
        Some(&plain),
        format!("brightened / plain fine volume: {inside:.3} inside it (want ≈ 3), {outside:.3} beyond it (want 1)"),
    );
    // No seam: across the band (columns 125..160) no pixel-to-pixel step is more than 3× the largest
    // step 4–8 pixels further on either side. A switch at the face (measured by making the band 0.01
    // cells: this check then fails), spread over the composite's 3×3 filter, is a few steps of tens of
    // percent of the light among steps of a few percent; the fade spreads the change over ~16 pixels.
    let d: Vec<f32> = (0..p.len() - 1).map(|i| (p[i + 1] - p[i]).abs()).collect();
    let mean = p.iter().sum::<f32>() / p.len() as f32;
    for i in 25..60 {
        let further = (i - 8..=i - 4).chain(i + 4..=i + 8).map(|j| d[j]).fold(0.0f32, f32::max);
        check(
            test,
            d[i] <= 3.0 * further + 0.002 * mean,
            &nested,
            Some(&plain),
            format!("seam at column {}: a step of {:.4} where steps 4–8 pixels away are at most {further:.4}", 100 + i, d[i]),
        );
    }
}


/// The outliers of the default volume's `cellar` image in rows `rows`, leaving out the door opening
/// (columns 140..176, rows 75..165: what shows through it is room A, and its 20 cm jambs, thinner than a
/// cell, are a thin-wall case of their own) and the blue box in front (columns 44..160, rows 158..256: an
/// object, whose silhouette is an edge of the truth's pixel filter and whose contact with the floor is
/// near-field occlusion; both known issues).
/// Fails the test when there are any.
fn assert_no_cellar_junction_outliers(test: &str, rows: std::ops::Range<u32>) {
    let image = rh_converged(StandardScene::Cellar, RadianceHintsVolume::default());
    let truth = ground_truth("cellar.exr");
    let found: Vec<_> = outliers(&image, &truth, 3.0)
        .into_iter()
        .filter(|&(x, y, _, _)| !((140..176).contains(&x) && (75..165).contains(&y)))
        .filter(|&(x, y, _, _)| !((44..160).contains(&x) && (158..256).contains(&y)))
        .filter(|&(_, y, _, _)| rows.contains(&y))
        .collect();
    eprintln!("{test}: {} outlier pixels, e.g. {:?}", found.len(), &found[..found.len().min(8)]);
    check(
        test,
        found.is_empty(),
        &image,
        Some(&truth),
        format!("{} pixels more than 3× off the truth around them, e.g. {:?}", found.len(), &found[..found.len().min(8)]),
    );
}

#[test]
fn cellar_ceiling_junctions_hold_no_outlier_pixels() {
    // Where the dividing wall and the side walls meet the ceiling, and the corner line below it (rows
    // 0..120: the upper half of the view), single pixels must not read the next room's hints or a hint
    // inside the wall (thin walls, both faces in adjacent voxels): no pixel may be 3× brighter or darker
    // than the truth around it.
    assert_no_cellar_junction_outliers("rh_cellar_ceiling_junctions", 0..120);
}

#[test]
fn cellar_floor_junctions_hold_no_outlier_pixels() {
    // The same below the middle of the view: where the dividing wall, the back wall and the floor meet
    // beside the door (the corner read 3.2× the truth while the reconstruction's first sample stood one
    // and a half cell diagonals off the wall, in the door's light), and the light patch at the back wall's
    // foot.
    assert_no_cellar_junction_outliers("rh_cellar_floor_junctions", 120..256);
}

#[test]
fn a_sunlit_floor_reads_only_the_light_from_above() {
    // The field above a sunlit floor holds mostly the floor's own light, arriving from below and around
    // the horizon; SH of order 2 gave a surface facing up a third to a half of it (17× the truth on
    // `open_field`'s ground near the camera, Hazel's form; 2× with Eq. 7's). The exact vertical
    // irradiance per hint reads only what comes from above: the buildings' and the wall's light.
    let test = "rh_sunlit_floor";
    let image = rh_converged(StandardScene::OpenField, RadianceHintsVolume::default());
    let truth = ground_truth("open_field.exr");
    for region in [Region::new("ground near the camera", 10, 200, 246, 250), Region::new("ground further off", 10, 180, 246, 200)] {
        let (a, t) = (luminance(region.mean(test, &image)), luminance(region.mean(test, &truth)));
        eprintln!("{test}: {}: {a:.4} against {t:.4} in the ground truth", region.name);
        check(
            test,
            (0.6 * t..=1.6 * t).contains(&a),
            &image,
            Some(&truth),
            format!("{}: {a:.4} against {t:.4} in the ground truth (want 0.6–1.6×)", region.name),
        );
    }
}

#[test]
fn the_unlit_room_gets_the_light_of_every_bounce() {
    // Most of what reaches `cellar`'s room B has bounced many times; eight extra bounces left it at 0.83
    // of its path-traced light. The blend adds the geometric tail of the bounces not run (blend.wgsl).
    let test = "rh_cellar_room_b";
    let image = rh_converged(StandardScene::Cellar, RadianceHintsVolume::default());
    let truth = ground_truth("cellar.exr");
    let in_room_b = |x: u32, y: u32| !((140..176).contains(&x) && (75..165).contains(&y));
    let sum = |i: &HdrImage| -> f64 {
        let mut s = 0.0;
        for y in 0..i.height {
            for x in 0..i.width {
                let p = i.get(x, y);
                if truth.get(x, y)[3] > 0.5 && in_room_b(x, y) {
                    s += (p[0] + p[1] + p[2]) as f64;
                }
            }
        }
        s
    };
    let energy = sum(&image) / sum(&truth);
    eprintln!("{test}: room B holds {energy:.3} of its path-traced light (measured 0.90)");
    check(test, energy >= 0.86, &image, Some(&truth), format!("room B holds {energy:.3} of its path-traced light (want ≥ 0.86)"));
}

#[test]
fn hints_beside_a_lit_wall_hold_its_light() {
    // A hint a few centimetres from a lit surface receives most of its light from the texels right behind
    // it, at 1/d²: drawn uniformly from the RSM they were hit once in hundreds of updates, receivers in the
    // wall's own voxel layer had their paths blocked by its neighbouring voxels, and the extra bounces met
    // phantom walls there. Such hints read a tenth to a half of their light. Here: the hints 5 cm from the
    // spot-lit face of `cellar`'s dividing wall, against the path tracer.
    use bevy::math::{Mat4, UVec3, Vec3};
    use bevy_diffuse_gi::reference::{ReferenceSettings, incident_radiance};
    use bevy_diffuse_gi::sampling::{SobolStream, fibonacci_sphere};
    use bevy_diffuse_gi::sh;
    let test = "rh_hints_beside_a_lit_wall";
    let dir = common::failure_dir(test);
    std::fs::create_dir_all(&dir).expect("a directory for the dump");
    let path = dir.join("volume.json");
    // A dump left by an earlier run must not pass for this one's.
    let _ = std::fs::remove_file(&path);
    render(&HeadlessOptions {
        scene: StandardScene::Cellar,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        frames: 32,
        dump_volume: Some(path.clone()),
        ..Default::default()
    });
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).expect("the dump")).expect("JSON");
    let floats = |k: &str| -> Vec<f32> { v[k].as_array().expect(k).iter().map(|x| x.as_f64().unwrap() as f32).collect() };
    let res = UVec3::from_array(serde_json::from_value(v["resolution"].clone()).expect("resolution"));
    let terms = v["field_terms"].as_u64().expect("field terms") as usize;
    let world_from_local = Mat4::from_cols_slice(&floats("world_from_local"));
    let (field, validity) = (floats("sh"), floats("albedo_validity"));
    let scene = bevy_diffuse_gi::scenes::cellar_snapshot();
    let settings = ReferenceSettings { seed: 3, ..Default::default() };
    let (mut gpu, mut traced, mut hints) = (0.0f32, 0.0f32, 0);
    for index in 0..(res.x * res.y * res.z) as usize {
        let c = UVec3::new(index as u32 % res.x, (index as u32 / res.x) % res.y, index as u32 / (res.x * res.y));
        let local = (c.as_vec3() + 0.5) / res.as_vec3() - 0.5;
        let p = world_from_local.transform_point3(local);
        // Room A's side of the dividing wall (its lit face at x = −0.1), beside the wall, not the door.
        if !(-0.2..-0.1).contains(&p.x) || p.z < -0.6 || !(0.4..2.1).contains(&p.y) || validity[index * 4 + 3] < 0.5 {
            continue;
        }
        // Band 0 of the traced field: a = ∫L dω / 4 = π × the mean radiance over the sphere, from origins
        // jittered over the free part of the cell as the injection's receivers are.
        let stream = SobolStream::new(5, index as u64);
        let (mut sum, mut used) = (Vec3::ZERO, 0);
        for k in 0..512u32 {
            let u = stream.vertex_4d(k, 0);
            let origin = world_from_local.transform_point3(local + (Vec3::new(u[0], u[1], u[2]) - 0.5) * 0.5 / res.as_vec3());
            let to = origin - p;
            if to.length() > 1e-6 && scene.occluded(p, to.normalize(), 0.0, to.length()) {
                continue;
            }
            let [e, direct, indirect] = incident_radiance(&scene, origin, fibonacci_sphere(k, 512), &settings, 1, index as u64 * 512 + k as u64);
            sum += e + direct + indirect;
            used += 1;
        }
        traced += luminance((sum / used.max(1) as f32).to_array()) * std::f32::consts::PI;
        let b = index * 3 * terms;
        // The irradiance's band 0, π Y₀₀ L₀₀ (`rh_packed.wgsl`).
        gpu += luminance([field[b], field[b + 1], field[b + 2]]) * sh::COSINE_LOBE[0] * sh::Y00;
        hints += 1;
    }
    let ratio = gpu / traced;
    eprintln!("{test}: {hints} hints, band-0 irradiance GPU / path traced {ratio:.3}");
    assert!(hints >= 20, "only {hints} hints beside the wall");
    assert!((0.8..=1.25).contains(&ratio), "{hints} hints 5 cm from the lit wall hold {ratio:.3} of their path-traced light (want 0.8–1.25)");
}

/// Places `cornell`'s volume at 1.5× the box it was fitted to (so that moving it a cell keeps the box
/// inside), `cells` of its cells along x. `home` keeps the first placement seen.
/// The transform is written only when it changes (no change detection otherwise).
fn place_volume(home: &mut Option<bevy::prelude::Transform>, volume: &RadianceHintsVolume, transform: &mut bevy::prelude::Mut<bevy::prelude::Transform>, cells: f32) {
    use bevy::prelude::*;
    let home = *home.get_or_insert_with(|| Transform { scale: transform.scale * 1.5, ..**transform });
    let cell = home.scale.x / volume.effective(home.to_matrix(), None).resolution.x as f32;
    let next = Transform { translation: home.translation + Vec3::X * (cells * cell), ..home };
    if **transform != next {
        **transform = next;
    }
}

/// `cornell` with its volume 1.5× the box (see [`place_volume`]), 256 RSM and 64 secondary samples and no
/// jitter. With a positive `step` the volume jumps `step` cells along x and back every frame; with a
/// negative one it stays and the light's intensity changes by 0.01 % every frame instead (inputs that
/// change every frame, as a moving light's do, without moving anything). Returns the image and the activity
/// the panel shows, frame by frame.
fn moving_volume(step: f32) -> (HdrImage, Vec<bevy_diffuse_gi::radiance_hints::RhVolumeActivity>) {
    use bevy::prelude::*;
    use bevy_diffuse_gi::radiance_hints::RadianceHintsActivity;
    use std::sync::{Arc, Mutex};
    let seen = Arc::new(Mutex::new(Vec::new()));
    let record = seen.clone();
    let options = HeadlessOptions {
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        frames: 32,
        // Low-noise updates: each run's field is then (nearly) the same whatever frame the readback lands
        // on, so what is left is the scroll's own error.
        rh: RadianceHintsVolume { rsm_samples: 256, secondary_samples: 64, jitter: 0.0, ..Default::default() },
        ..Default::default()
    };
    let _guard = common::render_lock();
    let report = bevy_diffuse_gi::headless::run_with(&options, move |app| {
        app.add_systems(
            Update,
            move |mut frame: Local<u32>,
                  mut home: Local<Option<Transform>>,
                  activity: Res<RadianceHintsActivity>,
                  mut lights: Query<&mut SpotLight>,
                  mut volumes: Query<(Entity, &RadianceHintsVolume, &mut Transform)>| {
                let Ok((entity, volume, mut transform)) = volumes.single_mut() else {
                    return;
                };
                *frame += 1;
                if let Some(a) = activity.get(entity) {
                    record.lock().unwrap().push(a);
                }
                let cells = if step > 0.0 && *frame > 3 && frame.is_multiple_of(2) { step } else { 0.0 };
                if step < 0.0 && *frame > 3 {
                    for mut light in &mut lights {
                        light.intensity *= if frame.is_multiple_of(2) { 1.0001 } else { 1.0 / 1.0001 };
                    }
                }
                place_volume(&mut home, volume, &mut transform, cells);
            },
        );
    })
    .expect("render");
    let seen = seen.lock().unwrap().clone();
    (report.image, seen)
}

/// `cornell` with its volume one cell further along x (see [`place_volume`]): placed there from the start, or
/// (`moved`) moved there on the eighth frame. Returns the volume as [`RhVolumeDump`] writes it after the
/// last frame.
///
/// [`RhVolumeDump`]: bevy_diffuse_gi::radiance_hints::dump::RhVolumeDump
fn volume_one_cell_along(moved: bool, name: &str) -> serde_json::Value {
    use bevy::prelude::*;
    let dir = common::failure_dir(name);
    std::fs::create_dir_all(&dir).expect("the test output folder");
    let path = dir.join("volume.json");
    // A dump left by an earlier run must not pass for this one's.
    let _ = std::fs::remove_file(&path);
    let options = HeadlessOptions {
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        frames: 16,
        ..Default::default()
    };
    let _guard = common::render_lock();
    bevy_diffuse_gi::headless::run_with(&options, |app| {
        app.insert_resource(bevy_diffuse_gi::radiance_hints::dump::RhVolumeDump { path: path.clone() });
        app.add_systems(
            Update,
            move |mut frame: Local<u32>,
                  mut home: Local<Option<Transform>>,
                  mut volumes: Query<(&RadianceHintsVolume, &mut Transform)>| {
                let Ok((volume, mut transform)) = volumes.single_mut() else {
                    return;
                };
                *frame += 1;
                place_volume(&mut home, volume, &mut transform, if !moved || *frame >= 8 { 1.0 } else { 0.0 });
            },
        );
    })
    .expect("render");
    serde_json::from_str(&std::fs::read_to_string(&path).expect("the volume dump")).expect("dump JSON")
}

#[test]
fn a_scrolled_volume_shifts_its_visibility_masks_to_what_a_fresh_volume_computes() {
    // After a scroll the reconstruction's per-voxel hint masks are shifted with the volume and recomputed
    // only within a cell of the faces the move crossed (`visibility.wgsl`), not redone for the whole grid.
    // They must equal the masks of a volume that stood there from the start (a full computation).
    let scrolled = volume_one_cell_along(true, "rh_masks_scrolled");
    let fresh = volume_one_cell_along(false, "rh_masks_fresh");
    assert_eq!(scrolled["last_visibility_update"], "Shifted", "the scrolled volume must shift its masks");
    assert_eq!(fresh["last_visibility_update"], "All");
    assert_eq!(scrolled["world_from_local"], fresh["world_from_local"], "both volumes end at the same place");
    let words = |v: &serde_json::Value| -> Vec<u32> {
        v["visibility"].as_array().expect("masks").iter().map(|w| w.as_u64().expect("word") as u32).collect()
    };
    let res: Vec<u64> = fresh["occupancy_resolution"].as_array().unwrap().iter().map(|r| r.as_u64().unwrap()).collect();
    let voxels = (res[0] * res[1] * res[2]) as usize;
    let (a, b) = (words(&scrolled), words(&fresh));
    let byte = |w: &[u32], i: usize| (w[i / 4] >> (8 * (i % 4))) & 0xff;
    let differing = (0..voxels).filter(|&i| byte(&a, i) != byte(&b, i)).count();
    let used = (0..voxels).filter(|&i| byte(&b, i) != 0).count();
    eprintln!("rh_scrolled_masks: {differing} of {voxels} voxel masks differ ({used} non-empty)");
    assert!(used > voxels / 2, "the fresh volume's masks must be computed: {used} of {voxels} non-empty");
    assert_eq!(differing, 0, "{differing} of {voxels} shifted masks differ from a fresh volume's");
}

#[test]
fn a_volume_moving_by_whole_cells_scrolls_its_field_with_it() {
    // A cascade level moves a whole cell at a time as its camera walks. Its field is scrolled with it
    // (`scroll.wgsl`; only the slab that came in is voxelised), so every hint keeps its place in the
    // world and the update is the amortised one of inputs that change every frame. Here the volume jumps
    // a cell and back every frame: the image must be that of the still volume whose inputs change every
    // frame (the same amortised updates, nothing moving). With the default samples two runs of either
    // differed by up to 0.098 (the seed follows the frame count, and the readback's frame varies), as much
    // as the scroll's error: `moving_volume` raises the samples and drops the jitter. Measured on lavapipe
    // then: block 0.029, energy 0.998 (two moving runs differ by up to 0.036; two still ones not at all);
    // without the scroll (the field shown a cell off, then recomputed) 0.238, energy 0.868.
    let test = "rh_scrolled_volume";
    let (reference, _) = moving_volume(-1.0);
    let (moving, activity) = moving_volume(1.0);
    let moved: Vec<_> = activity.iter().skip(8).collect();
    assert!(
        !moved.is_empty() && moved.iter().all(|a| a.updating && a.amortised),
        "a volume moving by whole cells must update as moving inputs do (scrolled), not start afresh: {moved:?}"
    );
    let m = metrics::compare(&moving, &reference).expect("same size");
    eprintln!("{test}: moving vs still volume: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse < 0.08 && (m.energy_ratio - 1.0).abs() < 0.03,
        &moving,
        Some(&reference),
        format!("the moving volume's light differs from the still one's: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio),
    );
}

/// `cornell`'s indirect light at 64² after its light moved every frame for 24 frames, with `volume`.
fn cornell_light_moving(volume: RadianceHintsVolume) -> HdrImage {
    render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        animate_light: true,
        frames: 24,
        size: bevy::math::UVec2::splat(64),
        rh: volume,
        ..Default::default()
    })
    .image
}

/// Fails `test` unless `turns` is within 0.1 block RMSE and 4 % of the energy of `every`.
fn holds_the_light(test: &str, turns: &HdrImage, every: &HdrImage, what: &str) {
    let m = metrics::compare(turns, every).expect("same size");
    check(
        test,
        m.block_relative_rmse < 0.1 && (m.energy_ratio - 1.0).abs() < 0.04,
        turns,
        Some(every),
        format!("{what}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio),
    );
}

#[test]
fn a_moving_lights_bounces_recomputed_in_turns_hold_the_light_of_every_hint_every_frame() {
    // While a light moves, each update gathers one bounce from the displayed field; with
    // `motion_bounce_period` 4 one workgroup of hints in four recomputes it and the others add the one
    // they kept. The kept bounces must be added (not dropped, not added twice): the image of a light
    // that moved every frame for 24 frames must hold the light of every hint recomputing every frame.
    // Without any extra bounce the same run has half its light (0.50 on lavapipe), so a period that
    // dropped the kept bounces (three quarters of the bounce light) would miss the energy bound below by
    // far. Measured on lavapipe: block 0.061, energy 0.999.
    let test = "rh_motion_bounce_period";
    let every = cornell_light_moving(RadianceHintsVolume { motion_bounce_period: 1, ..Default::default() });
    let turns = cornell_light_moving(RadianceHintsVolume::default());
    let unbounced = cornell_light_moving(RadianceHintsVolume { extra_bounces: 0, ..Default::default() });
    let m = metrics::compare(&turns, &every).expect("same size");
    let control = metrics::compare(&unbounced, &every).expect("same size");
    eprintln!(
        "{test}: period 4 vs 1: block {:.4}, energy {:.4}; no extra bounce vs 1: energy {:.4}",
        m.block_relative_rmse, m.energy_ratio, control.energy_ratio
    );
    assert!(control.energy_ratio < 0.9, "the extra bounces must carry light here: {:.4}", control.energy_ratio);
    holds_the_light(test, &turns, &every, "bounces recomputed in turns differ from every hint's every frame");
}

#[test]
fn a_moving_light_over_more_hints_than_the_budget_injects_them_in_turns_and_holds_every_hints_light() {
    // `motion_hints_per_update` 512 on `cornell`'s 4 096 hints: while the light moves, one workgroup of
    // hints in eight injects (and gathers its bounce) per update, and the others keep their displayed
    // field until their turn. The image must hold the light of a volume injecting every hint every
    // frame. Measured on lavapipe: block 0.051, energy 1.008 (at 128², 0.0585 / 1.0003 from the still
    // image against 0.0591 / 1.0009 for every hint, at half the moving frame's time: 64 against 122 ms).
    // Blending the skipped hints towards the running sum this update did not compute for them (it keeps
    // growing by their kept bounce) measured 127 / 76.
    let test = "rh_motion_hints_per_update";
    let every = cornell_light_moving(RadianceHintsVolume { motion_hints_per_update: RadianceHintsVolume::MAX_HINTS, ..Default::default() });
    let turns = cornell_light_moving(RadianceHintsVolume { motion_hints_per_update: 512, ..Default::default() });
    let m = metrics::compare(&turns, &every).expect("same size");
    eprintln!("{test}: 512 hints per update vs every hint: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(test, !turns.has_non_finite(), &turns, None, "NaN or Inf in the image".into());
    holds_the_light(test, &turns, &every, "hints injected in turns differ from every hint injected every frame");
}
