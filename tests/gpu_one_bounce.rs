//! The one-bounce gathers (RSM gather, Direct Radiance Mapping) rendered on the GPU (lavapipe in CI),
//! asserted on pixels and against the committed one-bounce and full path-traced ground truths.
//! Every bound below is the value measured on lavapipe (`docs/one_bounce.md`) plus a margin.
#![cfg(feature = "gpu_tests")]

mod common;

use std::path::PathBuf;

use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::drm::{DrmSettings, DrmSolidAngle};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::rsm_gather::{RsmGatherSettings, RsmSampleWeights};
use bevy_diffuse_gi::scenes::StandardScene;
use common::{Region, check, ground_truth, render, within};

fn rsm_gather(scene: StandardScene, settings: RsmGatherSettings) -> HdrImage {
    render(&HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::RsmGather),
        indirect_only: true,
        rsm_gather: settings,
        frames: 3,
        ..Default::default()
    })
    .image
}

fn drm(scene: StandardScene, settings: DrmSettings) -> HdrImage {
    render(&HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(GiMethod::Drm),
        indirect_only: true,
        drm: settings,
        frames: 3,
        ..Default::default()
    })
    .image
}

/// Floor beside the red wall: lit by the strip of red wall the spot reaches.
const FLOOR_BY_RED: Region = Region::new("floor by the red wall", 12, 228, 40, 246);
/// The small box's side facing the green wall.
const BOX_BY_GREEN: Region = Region::new("small box side facing the green wall", 186, 175, 192, 225);
/// The ceiling: lit by the white floor.
const CEILING: Region = Region::new("ceiling", 60, 8, 196, 30);


/// Asserts the two colour-bleeding regions of `cornell`: red on the floor by the red wall, green on the
/// small box's side facing the green wall.
#[track_caller]
fn bleeds_colour(test: &str, image: &HdrImage, truth: &HdrImage) {
    let floor = FLOOR_BY_RED.mean(test, image);
    check(test, floor[0] > 3.0 * floor[1] && floor[0] > 0.05, image, Some(truth), format!("no red on the floor: {floor:?}"));
    let side = BOX_BY_GREEN.mean(test, image);
    let ceiling = CEILING.mean(test, image);
    let (g_side, g_ceiling) = (side[1] / side[0], ceiling[1] / ceiling[0]);
    check(
        test,
        g_side > g_ceiling + 0.05,
        image,
        Some(truth),
        format!("no green on the box side: G/R {g_side:.3} against {g_ceiling:.3} on the ceiling"),
    );
}

#[test]
fn rsm_gather_bleeds_colour_and_matches_the_one_bounce_truth_of_cornell() {
    let test = "rsm_gather_cornell";
    let truth = ground_truth("cornell_b1.exr");
    let image = rsm_gather(StandardScene::Cornell, RsmGatherSettings::default());
    // Measured: 0.209 / 1.074 (medium); the target for the high preset is ≤ 0.30.
    within(test, &image, &truth, 0.26, (0.85, 1.2));
    bleeds_colour(test, &image, &truth);
    // One bounce is about half the light of the closed box: the gap to the full truth is by design.
    let full = metrics::compare(&image, &ground_truth("cornell.exr")).expect("same size");
    check(test, (0.4..0.75).contains(&full.energy_ratio), &image, None, format!("energy against all bounces {:.3}", full.energy_ratio));

    // The paper's ξ₁² weights lose the light of the texels near the pixel's projection (measured 0.74
    // of the truth's energy at 400 samples against 1.09 with the density weights).
    let paper = rsm_gather(StandardScene::Cornell, RsmGatherSettings { weights: RsmSampleWeights::Paper, ..RsmGatherSettings::HIGH });
    let high = rsm_gather(StandardScene::Cornell, RsmGatherSettings::HIGH);
    let (p, h) = (metrics::compare(&paper, &truth).unwrap(), within("rsm_gather_cornell_high", &high, &truth, 0.24, (0.9, 1.2)));
    check(
        test,
        p.energy_ratio < 0.85 * h.energy_ratio && p.block_relative_rmse > h.block_relative_rmse + 0.1,
        &paper,
        Some(&truth),
        format!("ξ₁² weights: energy {:.3}, RMSE {:.3}; ξ₁: {:.3}, {:.3}", p.energy_ratio, p.block_relative_rmse, h.energy_ratio, h.block_relative_rmse),
    );
}

#[test]
fn drm_bleeds_colour_and_matches_the_one_bounce_truth_of_cornell() {
    let test = "drm_cornell";
    let truth = ground_truth("cornell_b1.exr");
    // The paper's 3 × 3 photons: coarse (0.731 / 0.798 measured); the surfaces next to the boxes get
    // nothing from photons whose mean position lies behind them.
    let default = drm(StandardScene::Cornell, DrmSettings::default());
    within(test, &default, &truth, 0.79, (0.7, 0.95));
    // 16 × 16 photons: 0.382 / 1.078 measured, the issue's ≤ 0.40.
    let image = drm(StandardScene::Cornell, DrmSettings::HIGH);
    within("drm_cornell_high", &image, &truth, 0.43, (0.9, 1.2));
    bleeds_colour("drm_cornell_high", &image, &truth);
}

#[test]
fn eq_11_overexposes_as_an_object_nears_the_light_and_eq_14_does_not() {
    // The paper's Fig. 7: a block hung just below the spot fills most of its map with a small, brightly
    // lit surface. Measured energy against the one-bounce truth: Eq. 11 7.97 on cornell and 91 with the
    // block; Eq. 14 0.80 and 0.75.
    let test = "drm_near_light";
    let energy = |scene: StandardScene, truth: &str, solid_angle| {
        let image = drm(scene, DrmSettings { solid_angle, ..DrmSettings::default() });
        check(test, !image.has_non_finite(), &image, None, "NaN or Inf in the indirect light".into());
        metrics::compare(&image, &ground_truth(truth)).expect("same size").energy_ratio
    };
    let eq11 = (energy(StandardScene::Cornell, "cornell_b1.exr", DrmSolidAngle::Constant), energy(StandardScene::NearLight, "near_light_b1.exr", DrmSolidAngle::Constant));
    let eq14 = (energy(StandardScene::Cornell, "cornell_b1.exr", DrmSolidAngle::TexelArea), energy(StandardScene::NearLight, "near_light_b1.exr", DrmSolidAngle::TexelArea));
    eprintln!("{test}: energy Eq. 11 {eq11:.3?}, Eq. 14 {eq14:.3?} (cornell, near_light)");
    assert!(eq11.1 > 30.0 && eq11.1 > 5.0 * eq11.0, "Eq. 11 does not overexpose near the light: {eq11:?}");
    assert!((0.55..1.3).contains(&eq14.1) && (0.75..1.3).contains(&(eq14.1 / eq14.0)), "Eq. 14 near the light: {eq14:?}");
}

#[test]
fn every_light_kind_bounces_in_the_one_bounce_gathers() {
    // Directional (sponza_like, the sun through the roof) against its one-bounce truth. Measured: RSM
    // gather 0.533 / 1.017; DRM 16 × 16 1.419 / 1.090 (few photons land in the sun patch: worse than a
    // black image's 1.0 block RMSE, so it is the energy bound that fails a method that adds nothing).
    let truth = ground_truth("sponza_like_b1.exr");
    within("rsm_gather_sponza_like", &rsm_gather(StandardScene::SponzaLike, RsmGatherSettings::default()), &truth, 0.58, (0.95, 1.08));
    within("drm_sponza_like", &drm(StandardScene::SponzaLike, DrmSettings::HIGH), &truth, 1.47, (1.0, 1.18));
    // Point light (dynamic: six cube faces) against the full truth, of which one bounce is about half.
    // Measured: RSM gather 0.631 / 0.468, DRM 16 × 16 0.617 / 0.481.
    let truth = ground_truth("dynamic.exr");
    within("rsm_gather_dynamic", &rsm_gather(StandardScene::Dynamic, RsmGatherSettings::default()), &truth, 0.7, (0.35, 0.6));
    within("drm_dynamic", &drm(StandardScene::Dynamic, DrmSettings::HIGH), &truth, 0.7, (0.35, 0.6));
}

/// DRM with one photon per axis (the clamp of 0): its energy against `cornell`'s one-bounce truth,
/// measured 0.353.
const DRM_ONE_BY_ONE: (f64, f64) = (0.3, 0.42);

#[test]
fn absurd_settings_are_clamped_and_stay_finite() {
    // Clamped to their ranges (a non-finite intensity falls back to 1), the settings still give the
    // one-bounce light of `cornell`: its energy against the one-bounce truth stays where it was measured
    // (RSM gather with the most samples 1.093, 1.07 with the defaults; DRM with one photon per axis 0.353,
    // 0.80 with the default 3 × 3). An image without light fails both.
    let test = "one_bounce_absurd_settings";
    let truth = ground_truth("cornell_b1.exr");
    let energy = |image: &HdrImage| metrics::compare(image, &truth).expect("same size").energy_ratio;
    let rsm = rsm_gather(
        StandardScene::Cornell,
        RsmGatherSettings { samples: u32::MAX, radius: f32::NAN, intensity: f32::INFINITY, ..Default::default() },
    );
    check(test, !rsm.has_non_finite(), &rsm, None, "NaN or Inf from clamped RSM gather settings".into());
    let e = energy(&rsm);
    check(test, (1.0..1.2).contains(&e), &rsm, Some(&truth), format!("clamped RSM gather settings: energy {e:.3}"));
    let d = drm(StandardScene::Cornell, DrmSettings { samples_per_axis: 0, intensity: f32::NAN, ..Default::default() });
    check(test, !d.has_non_finite(), &d, None, "NaN or Inf from clamped DRM settings".into());
    let e = energy(&d);
    check(test, (DRM_ONE_BY_ONE.0..DRM_ONE_BY_ONE.1).contains(&e), &d, Some(&truth), format!("clamped DRM settings: energy {e:.3}"));
}

#[test]
fn two_lights_of_a_gltf_room_bounce_as_the_path_tracer_says() {
    // tests/assets/test_room.gltf: a spot and a point light (six cube faces), both GI lights, in a room
    // the methods were never tuned on. The one-bounce truth is traced here, at 256 samples (≈ 4 s).
    // Measured: RSM gather medium 0.095 / 1.016, DRM high 0.137 / 1.033, DRM medium 0.376 / 0.795.
    let scene = StandardScene::Gltf(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/assets/test_room.gltf"));
    let size = bevy::math::UVec2::splat(128);
    let truth = render(&HeadlessOptions {
        scene: scene.clone(),
        method: HeadlessMethod::Reference,
        indirect_only: true,
        max_bounces: Some(1),
        spp: 256,
        size,
        ..Default::default()
    })
    .image;
    let gi = |method, rsm_gather, drm| {
        render(&HeadlessOptions {
            scene: scene.clone(),
            method: HeadlessMethod::Gi(method),
            indirect_only: true,
            rsm_gather,
            drm,
            size,
            frames: 3,
            ..Default::default()
        })
        .image
    };
    let rsm = gi(GiMethod::RsmGather, RsmGatherSettings::MEDIUM, DrmSettings::default());
    within("rsm_gather_two_lights", &rsm, &truth, 0.17, (0.88, 1.15));
    let drm_high = gi(GiMethod::Drm, RsmGatherSettings::default(), DrmSettings::HIGH);
    within("drm_two_lights", &drm_high, &truth, 0.21, (0.88, 1.18));
}

#[test]
fn drm_photons_follow_a_moving_light_every_frame() {
    // The photons are remade whenever an RSM face was redrawn: with `dynamic`'s light orbiting one step
    // per frame, every frame differs from the one before (measured 0.012 block RMSE; photons kept one
    // frame too long made every other frame identical to the previous one).
    let test = "drm_moving_light";
    for frames in [8, 9] {
        let report = render(&HeadlessOptions {
            scene: StandardScene::Dynamic,
            method: HeadlessMethod::Gi(GiMethod::Drm),
            indirect_only: true,
            animate_light: true,
            frames,
            ..Default::default()
        });
        let previous = &report.extra_images.iter().find(|(name, _)| *name == "previous").expect("the frame before").1;
        let change = metrics::compare(&report.image, previous).expect("same size").block_relative_rmse;
        check(test, change > 0.004, &report.image, Some(previous), format!("frame {frames}: the image did not follow the light ({change:.4})"));
    }
}

#[test]
fn a_scene_lit_by_emissive_surfaces_alone_warns_once_that_the_gathers_bounce_only_gi_lights() {
    // emissive_panel has no GiLight: the RSM gather and DRM have nothing to gather and say so, once;
    // cornell (a GiLight spot) gets no such warning.
    let warnings = |scene, method| {
        let report = render(&HeadlessOptions {
            scene,
            method: HeadlessMethod::Gi(method),
            indirect_only: true,
            size: bevy::math::UVec2::splat(32),
            frames: 6,
            ..Default::default()
        });
        let all: Vec<String> =
            report.sidecar["warnings"].as_array().expect("warnings").iter().map(|w| w.as_str().unwrap_or_default().to_owned()).collect();
        (report.image, all.into_iter().filter(|w| w.contains("emissive surfaces alone")).collect::<Vec<_>>())
    };
    for method in [GiMethod::RsmGather, GiMethod::Drm] {
        let test = format!("one_bounce_emissive_only_{method:?}");
        let (image, found) = warnings(StandardScene::EmissivePanel, method);
        check(
            &test,
            found.len() == 1 && found[0].contains(&format!("GiMethod::{method:?}")) && found[0].contains("add a GiLight"),
            &image,
            None,
            format!("warnings about emissive-only lighting: {found:?}"),
        );
        let (image, found) = warnings(StandardScene::Cornell, method);
        check(&test, found.is_empty(), &image, None, format!("cornell has a GiLight, yet: {found:?}"));
    }
}

#[test]
fn asking_a_per_pixel_method_for_the_irradiance_volume_output_composites_instead() {
    // Only Radiance Hints has a volume to export. A camera that asks the RSM gather for
    // `GiOutput::IrradianceVolume` gets the composited light (and one warning), not an image without
    // bounced light.
    use bevy_diffuse_gi::camera::GiOutput;
    let lit = |gi_output, method| {
        render(&HeadlessOptions {
            scene: StandardScene::Cornell,
            method,
            gi_output,
            size: bevy::math::UVec2::splat(64),
            frames: 3,
            ..Default::default()
        })
        .image
    };
    let gi = HeadlessMethod::Gi(GiMethod::RsmGather);
    let asked = lit(GiOutput::IrradianceVolume, gi);
    let composite = lit(GiOutput::Composite, gi);
    let none = lit(GiOutput::Composite, HeadlessMethod::None);
    let total = |i: &HdrImage| i.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>();
    let (a, c, n) = (total(&asked), total(&composite), total(&none));
    check(
        "one_bounce_irradiance_volume_fallback",
        (a - c).abs() <= 1e-3 * c && a > 1.05 * n,
        &asked,
        Some(&composite),
        format!("IrradianceVolume asked of the RSM gather: {a:.1}, composited {c:.1}, no GI {n:.1}"),
    );
}

#[test]
fn a_plugin_pipeline_that_fails_to_compile_fails_the_headless_run() {
    // A `diffuse_gi…` pipeline whose shader naga rejects, queued on the fourth frame, after the plugin's
    // own pipelines settled (the check then looks only at pipelines newer than those): the run must
    // fail and name it, not render on with the pass silently missing.
    use bevy::prelude::*;
    use bevy::render::render_resource::{ComputePipelineDescriptor, PipelineCache};
    use bevy::render::{Render, RenderApp};
    #[derive(Resource, Clone)]
    struct Broken(Handle<Shader>);
    let options = HeadlessOptions {
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(GiMethod::RsmGather),
        indirect_only: true,
        frames: 8,
        ..Default::default()
    };
    let _guard = common::render_lock();
    let result = bevy_diffuse_gi::headless::run_with(&options, |app| {
        let shader = app.world_mut().resource_mut::<Assets<Shader>>().add(Shader::from_wgsl(
            "@compute @workgroup_size(1) fn main() { let x: f32 = 1u; }",
            "broken_for_test.wgsl",
        ));
        app.sub_app_mut(RenderApp).insert_resource(Broken(shader)).add_systems(
            Render,
            |cache: Res<PipelineCache>, broken: Res<Broken>, mut frame: Local<u32>| {
                *frame += 1;
                if *frame == 4 {
                    cache.queue_compute_pipeline(ComputePipelineDescriptor {
                        label: Some("diffuse_gi_test_broken".into()),
                        shader: broken.0.clone(),
                        entry_point: Some("main".into()),
                        ..default()
                    });
                }
            },
        );
    });
    let error = result.expect_err("a run with a broken plugin pipeline must fail");
    assert!(error.contains("diffuse_gi_test_broken"), "the error must name the pipeline: {error}");
}
