//! The VPL method with screen-space bias compensation rendered on the GPU (lavapipe in CI), asserted on
//! pixels and against the committed path-traced ground truths (`assets/ground_truth/`).
#![cfg(feature = "gpu_tests")]

mod common;


use bevy_diffuse_gi::camera::{GiDebugView, GiMethod};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::scenes::StandardScene;
use bevy_diffuse_gi::vpl::VplSettings;
use common::{Region, check, ground_truth, luminance, render, within};

fn vpl_options(scene: StandardScene, vpl: VplSettings) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::Vpl),
        indirect_only: true,
        vpl,
        frames: 3,
        ..Default::default()
    }
}

fn vpl(scene: StandardScene, vpl: VplSettings) -> HdrImage {
    render(&vpl_options(scene, vpl)).image
}

/// Where the ceiling meets the back wall (a concave edge, unoccluded).
const CEILING_EDGE: Region = Region::new("ceiling–back wall edge", 70, 52, 186, 59);
/// Where the left (red) wall meets the back wall.
const LEFT_EDGE: Region = Region::new("red wall–back wall edge", 52, 70, 60, 150);
/// Where the small box's front stands on the floor.
const BOX_FOOT: Region = Region::new("foot of the small box", 140, 234, 180, 240);
/// The middle of the back wall, far from every edge.
const BACK_WALL: Region = Region::new("middle of the back wall", 110, 90, 146, 130);

#[test]
fn compensation_adds_light_in_corners_never_removes_it_and_moves_energy_towards_the_truth() {
    let test = "vpl_ssbc_steps";
    let truth = ground_truth("cornell.exr");
    let steps: Vec<HdrImage> =
        (0..=3).map(|n| vpl(StandardScene::Cornell, VplSettings { ssbc_steps: n, ..VplSettings::MEDIUM })).collect();
    for image in &steps {
        check(test, !image.has_non_finite(), image, Some(&truth), "NaN or Inf in the indirect light".into());
    }
    let clamped = &steps[0];
    let compensated = &steps[1];

    // Never removes light: every pixel of the compensated image is at least the clamped one (the
    // composite's filter is linear, so a non-negative compensation stays non-negative).
    let peak = clamped.pixels.iter().map(|p| p[0].max(p[1]).max(p[2])).fold(0.0f32, f32::max);
    let removed = clamped
        .pixels
        .iter()
        .zip(&compensated.pixels)
        .filter(|(a, b)| (0..3).any(|c| b[c] < a[c] - 1e-4 * peak))
        .count();
    check(test, removed == 0, compensated, Some(clamped), format!("{removed} pixels lost light to the compensation"));

    // Adds light where clamping removed it: concave edges gain clearly more than a flat wall.
    let gain = |region: Region| {
        let (a, b) = (luminance(region.mean(test, clamped)), luminance(region.mean(test, compensated)));
        (b - a) / a.max(1e-9)
    };
    let flat = gain(BACK_WALL);
    for region in [CEILING_EDGE, LEFT_EDGE, BOX_FOOT] {
        let g = gain(region);
        eprintln!("{test}: {} gains {:.1} % (flat wall {:.1} %)", region.name, 100.0 * g, 100.0 * flat);
        check(
            test,
            g > 0.04 && g > 2.0 * flat,
            compensated,
            Some(clamped),
            format!("{}: the compensation adds {:.1} % (flat wall: {:.1} %)", region.name, 100.0 * g, 100.0 * flat),
        );
    }

    // The energy ratio against the ground truth moves towards 1 with each step, or stays within 1 % of
    // it (measured on lavapipe with traced shadow maps: 0.977, 0.999, 1.002, 1.004 for 0–3 steps).
    let energies: Vec<f64> = steps.iter().map(|i| metrics::compare(i, &truth).expect("comparable").energy_ratio).collect();
    eprintln!("{test}: energy by SSBC steps {energies:?}");
    for k in 1..energies.len() {
        check(
            test,
            (1.0 - energies[k]).abs() <= (1.0 - energies[k - 1]).abs().max(0.01) + 1e-4,
            &steps[k],
            Some(&truth),
            format!("step {k} moved the energy away from 1: {energies:?}"),
        );
    }
    check(test, energies[1] > energies[0] + 0.005, compensated, Some(&truth), format!("no energy returned: {energies:?}"));
    // SSBC's own error against the truth: one step takes the block error from the clamped gather's
    // 0.175 to 0.142 (measured; 0.146 and 0.149 with two and three steps, whose extra light lands a
    // little too evenly). A compensation that adds the wrong light, or none, fails.
    let errors: Vec<f64> = steps.iter().map(|i| metrics::compare(i, &truth).expect("comparable").block_relative_rmse).collect();
    eprintln!("{test}: block relative RMSE by SSBC steps {errors:?}");
    check(
        test,
        errors[1] < errors[0] - 0.02 && errors[1] <= 0.16 && errors[3] <= 0.17,
        compensated,
        Some(&truth),
        format!("block relative RMSE by SSBC steps {errors:?} (measured 0.175, 0.142, 0.146, 0.149)"),
    );
}

#[test]
fn cornell_vpl_bleeds_colour_and_matches_the_ground_truth() {
    let test = "vpl_cornell";
    let truth = ground_truth("cornell.exr");
    for (name, preset, block_limit, energy) in [
        // Measured on lavapipe with traced shadow maps: medium 0.142 / 0.996 (docs/vpl_ssbc.md).
        ("medium", VplSettings::MEDIUM, 0.17, 0.95..=1.05),
        ("high", VplSettings::HIGH, 0.17, 0.95..=1.05),
    ] {
        let image = vpl(StandardScene::Cornell, preset);
        check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf".into());
        let floor = Region::new("floor by the red wall", 12, 228, 40, 246).mean(test, &image);
        check(test, floor[0] > 3.0 * floor[1], &image, Some(&truth), format!("{name}: no red bleeding, {floor:?}"));
        let m = metrics::compare(&image, &truth).expect("comparable images");
        eprintln!("{test} {name}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
        check(
            test,
            m.block_relative_rmse <= block_limit && energy.contains(&m.energy_ratio),
            &image,
            Some(&truth),
            format!(
                "cornell, {name}: block relative RMSE {:.4} (want ≤ {block_limit}), energy {:.4} (want {energy:?})",
                m.block_relative_rmse, m.energy_ratio
            ),
        );
    }
}

#[test]
fn cellar_vpl_keeps_the_light_in_its_room() {
    let test = "vpl_cellar";
    let truth = ground_truth("cellar.exr");
    let image = vpl(StandardScene::Cellar, VplSettings::MEDIUM);
    check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf".into());
    // Room B's side of the dividing wall matches the truth, and so does the top of the wall where it
    // meets the ceiling (imperfect shadow maps let room A's light through there: 1.9× the truth, 2.2×
    // with traced maps and the imperfect maps' 5 % depth tolerance). A missing visibility test would
    // give several times more.
    for (region, limit) in [
        (Region::new("dividing wall, room B side", 20, 80, 120, 140), 1.3),
        (Region::new("top of the dividing wall", 10, 30, 120, 50), 1.5),
    ] {
        let (a, t) = (luminance(region.mean(test, &image)), luminance(region.mean(test, &truth)));
        check(test, a < limit * t, &image, Some(&truth), format!("{}: {a:.3} against {t:.3}: light leaks", region.name));
    }
    let m = metrics::compare(&image, &truth).expect("comparable images");
    eprintln!("{test}: block {:.4}, energy {:.4}", m.block_relative_rmse, m.energy_ratio);
    check(
        test,
        m.block_relative_rmse <= CELLAR_BLOCK_LIMIT && (0.90..=1.06).contains(&m.energy_ratio),
        &image,
        Some(&truth),
        format!("cellar, medium: block {:.4} (want ≤ {CELLAR_BLOCK_LIMIT}), energy {:.4}", m.block_relative_rmse, m.energy_ratio),
    );
}

#[test]
fn sponza_like_vpl_lights_the_atrium_from_the_sun_patch() {
    let test = "vpl_sponza_like";
    let truth = ground_truth("sponza_like.exr");
    let image = vpl(StandardScene::SponzaLike, VplSettings::MEDIUM);
    check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf".into());
    // The far wall, lit only by light that bounced off the sun patch and the walls.
    let wall = Region::new("far wall", 100, 60, 150, 100);
    let (a, t) = (luminance(wall.mean(test, &image)), luminance(wall.mean(test, &truth)));
    check(test, (0.6..1.5).contains(&(a / t)), &image, Some(&truth), format!("far wall: {a:.3} against {t:.3}"));
    // Measured on lavapipe with traced shadow maps: block 0.209, energy 1.062, 2 % of blocks more than
    // 50 % off.
    let m = metrics::compare(&image, &truth).expect("comparable images");
    eprintln!("{test}: block {:.4}, energy {:.4}, off {:.3}", m.block_relative_rmse, m.energy_ratio, m.blocks_over_half_off);
    check(
        test,
        m.block_relative_rmse <= 0.25 && (0.95..=1.12).contains(&m.energy_ratio) && m.blocks_over_half_off <= 0.05,
        &image,
        Some(&truth),
        format!(
            "sponza_like, medium: block {:.4} (want ≤ 0.25), energy {:.4} (want 0.95–1.12), {:.1} % of blocks off (want ≤ 5 %)",
            m.block_relative_rmse,
            m.energy_ratio,
            100.0 * m.blocks_over_half_off
        ),
    );
}

/// Measured on lavapipe with traced shadow maps: 0.314 (energy 1.001), see `docs/vpl_ssbc.md`.
const CELLAR_BLOCK_LIMIT: f64 = 0.36;

#[test]
fn an_emissive_panel_alone_lights_the_room_in_its_colour() {
    // No GI light: every VPL comes from paths that start on the panel (bounce 0 on the panel itself,
    // carrying its direct light). Measured 0.305 / 0.938 (before emitters started paths: no light at
    // all, 1.561 / 0.000; with second-depth maps behind the panel, which has no back, 0.506 / 1.193).
    let test = "vpl_emissive_panel";
    let truth = ground_truth("emissive_panel.exr");
    let image = vpl(StandardScene::EmissivePanel, VplSettings::MEDIUM);
    within(test, &image, &truth, 0.35, (0.88, 1.0));
    // The warm colour of the panel: R/G and B/G of the back wall within 10 % of the truth's.
    Region::new("back wall", 90, 60, 166, 110).same_colour(test, &image, &truth, 0.1);
}

#[test]
fn switching_the_method_at_run_time_changes_the_image_and_leaves_no_stale_light() {
    let test = "vpl_switch_method";
    let fresh_rh = render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        indirect_only: true,
        frames: 24,
        ..Default::default()
    })
    .image;
    let fresh_vpl = vpl(StandardScene::Cornell, VplSettings::MEDIUM);
    // VPL for a few frames, then Radiance Hints for 24 (past its 17 refinement updates).
    let switched = render(&HeadlessOptions {
        switch_method: Some((3, GiMethod::RadianceHints)),
        frames: 27,
        ..vpl_options(StandardScene::Cornell, VplSettings::MEDIUM)
    })
    .image;
    let to_rh = metrics::compare(&switched, &fresh_rh).expect("comparable");
    let from_vpl = metrics::compare(&fresh_vpl, &fresh_rh).expect("comparable");
    eprintln!(
        "{test}: switched vs fresh RH block {:.4} energy {:.4}; VPL vs RH block {:.4}",
        to_rh.block_relative_rmse, to_rh.energy_ratio, from_vpl.block_relative_rmse
    );
    // Radiance Hints draws fresh random numbers every frame it updates, so two of its renders whose
    // updates fall on other frames differ by its own noise (measured 0.02–0.09 block RMSE on cornell,
    // blotches on the floor), far below the 0.24 between the methods. Light left behind by the VPL method
    // would show in the energy and at the concave edges, where its compensation adds light.
    check(
        test,
        to_rh.block_relative_rmse < 0.1 && (0.98..=1.02).contains(&to_rh.energy_ratio),
        &switched,
        Some(&fresh_rh),
        format!(
            "after the switch the image is not Radiance Hints' own: block {:.4}, energy {:.4}",
            to_rh.block_relative_rmse, to_rh.energy_ratio
        ),
    );
    for region in [CEILING_EDGE, LEFT_EDGE] {
        let (a, b) = (luminance(region.mean(test, &switched)), luminance(region.mean(test, &fresh_rh)));
        check(test, (a / b - 1.0).abs() < 0.04, &switched, Some(&fresh_rh), format!("{}: {a:.4} after the switch, {b:.4} fresh", region.name));
    }
    check(
        test,
        from_vpl.block_relative_rmse > 3.0 * to_rh.block_relative_rmse.max(0.005),
        &fresh_vpl,
        Some(&fresh_rh),
        format!("the two methods render the same image (block {:.4})", from_vpl.block_relative_rmse),
    );
    // And back: Radiance Hints, then VPL. The VPL walks run in the background (issue #30), so the first
    // VPL frames after the switch have no VPLs yet: read back once the walks have caught up.
    let back = render(&HeadlessOptions {
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        switch_method: Some((3, GiMethod::Vpl)),
        frames: 6,
        wait_background: Some(60),
        ..vpl_options(StandardScene::Cornell, VplSettings::MEDIUM)
    })
    .image;
    let m = metrics::compare(&back, &fresh_vpl).expect("comparable");
    eprintln!("{test}: RH then VPL vs fresh VPL block {:.4}", m.block_relative_rmse);
    check(test, m.block_relative_rmse < 0.01, &back, Some(&fresh_vpl), format!("stale light after RH → VPL: block {:.4}", m.block_relative_rmse));
}

#[test]
fn debug_views_show_the_parts_and_absurd_settings_stay_finite() {
    let test = "vpl_debug_views";
    let view = |debug_view: GiDebugView| {
        render(&HeadlessOptions { debug_view: Some(debug_view), ..vpl_options(StandardScene::Cornell, VplSettings::LOW) }).image
    };
    let clamped = view(GiDebugView::VplClampedOnly);
    let compensation = view(GiDebugView::VplCompensationOnly);
    let full = vpl(StandardScene::Cornell, VplSettings::LOW);
    // Clamped + compensation = the full indirect light (the composite is linear in the target).
    let sum = clamped.pixels.iter().zip(&compensation.pixels).map(|(a, b)| luminance([a[0] + b[0], a[1] + b[1], a[2] + b[2]])).sum::<f32>();
    let total = full.pixels.iter().map(|p| luminance([p[0], p[1], p[2]])).sum::<f32>();
    check(test, (sum / total - 1.0).abs() < 0.01, &full, Some(&clamped), format!("clamped + compensation = {sum}, full = {total}"));
    // The positions view is the clamped light with a dot on every visible VPL: some pixels (a dot is 5
    // pixels across; measured 13 % of them), far brighter than the light around them, and the rest as in
    // the clamped view. Without the dots none.
    let positions = view(GiDebugView::VplPositions);
    check(test, !positions.has_non_finite(), &positions, None, "NaN in the VPL view".into());
    let dots = positions
        .pixels
        .iter()
        .zip(&clamped.pixels)
        .filter(|(p, c)| luminance([p[0], p[1], p[2]]) > 4.0 * luminance([c[0], c[1], c[2]]) + 1e-3)
        .count();
    let share = dots as f32 / positions.pixels.len() as f32;
    check(test, (0.05..0.25).contains(&share), &positions, Some(&clamped), format!("{dots} dot pixels ({:.1} %)", share * 100.0));

    let absurd = VplSettings {
        light_paths: 0,
        bounces: 1000,
        geometry_bound: f32::NAN,
        ism_resolution: 1,
        ism_points: 0,
        ism_bias: f32::INFINITY,
        ssbc_steps: 50,
        ssbc_solid_angle: -1.0,
        ssbc_levels: 0,
        intensity: f32::NAN,
        ..VplSettings::LOW
    };
    let image = vpl(StandardScene::Cornell, absurd);
    check(test, !image.has_non_finite(), &image, None, "NaN or Inf with clamped settings".into());
    // Clamped (one path, the intensity back at 1), they still bounce light (measured: 87 % of the pixels
    // lit).
    let lit = image.pixels.iter().filter(|p| luminance([p[0], p[1], p[2]]) > 1e-3).count();
    check(test, lit > image.pixels.len() * 6 / 10, &image, None, format!("clamped settings light {lit} pixels"));
}
