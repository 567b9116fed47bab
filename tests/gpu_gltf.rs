//! glTF scenes through Bevy's loader: lights get shadows and a `GiLight`, Bevy and the path tracer agree
//! on the direct light, and unloadable files fail with a message instead of a panic.
#![cfg(feature = "gpu_tests")]

mod common;

use std::path::PathBuf;

use bevy_diffuse_gi::headless::{self, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::scenes::StandardScene;
use common::{check, render};

fn asset(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/assets").join(name)
}

fn room() -> StandardScene {
    StandardScene::Gltf(asset("test_room.gltf"))
}

/// The least share of the glTF room's direct light its GI lights' bounce must add (the RSM gather,
/// measured 0.332).
const BOUNCED_SHARE: f64 = 0.25;

#[test]
fn gltf_lights_cast_shadows_and_bounce() {
    let report = render(&HeadlessOptions {
        scene: room(),
        frames: 1,
        ..Default::default()
    });
    let lights = report.sidecar["lights"].as_array().expect("lights in the sidecar");
    assert_eq!(lights.len(), 2, "{lights:?}");
    for light in lights {
        assert_eq!(light["shadows"], true, "{light}");
        assert_eq!(light["gi_light"], true, "{light}");
    }
    // KHR_lights_punctual gives candela; Bevy stores 4π × cd lumens.
    let spot = lights.iter().find(|l| l["kind"] == "spot").expect("a spot light");
    assert!((spot["intensity_candela"].as_f64().unwrap() - 60.0).abs() < 1e-3);
    let test = "gltf_lights_cast_shadows_and_bounce";
    let image = &report.image;
    let covered = (0..image.pixels.len()).filter(|&i| image.covered(i)).count();
    check(test, covered > image.pixels.len() / 2, image, None, format!("only {covered} pixels see the room"));
    let floor = image.region_mean(60, 200, 120, 240).expect("floor in view");
    check(test, floor[0] > 0.5, image, None, format!("lit floor is dark: {floor:?}"));
    // And their light bounces: the glTF's lights are GI lights, so a GI method adds indirect light (the
    // RSM gather, the cheapest; its values against a traced truth of this room are checked in
    // tests/gpu_one_bounce.rs). An image without bounced light fails.
    let indirect = render(&HeadlessOptions {
        scene: room(),
        method: headless::HeadlessMethod::Gi(bevy_diffuse_gi::camera::GiMethod::RsmGather),
        indirect_only: true,
        frames: 3,
        ..Default::default()
    })
    .image;
    let total = |i: &bevy_diffuse_gi::hdr_image::HdrImage| i.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>();
    let share = total(&indirect) / total(image).max(1e-12);
    check(test, share > BOUNCED_SHARE, &indirect, Some(image), format!("the glTF's lights bounce {share:.4} of their direct light"));
}

#[test]
fn gltf_direct_light_matches_the_path_tracer() {
    let test = "gltf_direct_light_matches_the_path_tracer";
    let bevy = render(&HeadlessOptions {
        scene: room(),
        frames: 1,
        ..Default::default()
    })
    .image;
    let traced = common::traced_direct(room());
    let m = metrics::compare(&bevy, &traced).expect("comparable");
    // Measured on lavapipe: block relative RMSE 0.047, energy ratio 1.026 (a spot and a point light).
    check(
        test,
        (0.95..=1.05).contains(&m.energy_ratio) && m.block_relative_rmse <= 0.12,
        &bevy,
        Some(&traced),
        format!("energy ratio {:.4}, block rel. RMSE {:.4}", m.energy_ratio, m.block_relative_rmse),
    );
}

#[test]
fn unloadable_gltf_is_an_error_not_a_panic() {
    let options = HeadlessOptions {
        scene: StandardScene::Gltf(asset("corrupt.glb")),
        ..Default::default()
    };
    let _guard = common::render_lock();
    let error = headless::run(&options).expect_err("a corrupt file must not render");
    assert!(error.contains("cannot load glTF") && error.contains("corrupt.glb"), "{error}");
}

#[test]
fn textured_partly_metallic_gltf_has_the_same_colours_in_the_tracer_as_in_bevy() {
    // tests/assets/textured_chair.gltf (make_textured_chair.py): base-colour textures through
    // KHR_texture_transform and TEXCOORD_1, legs with metallicFactor 1 and a metallic-roughness texture
    // that leaves seven eighths of them dielectric. A tracer that missed any of these would show a white
    // chair, a white floor or black legs where Bevy shows colour.
    let test = "textured_partly_metallic_gltf_colours";
    let scene = StandardScene::Gltf(asset("textured_chair.gltf"));
    let bevy = render(&HeadlessOptions { scene: scene.clone(), frames: 1, ..Default::default() }).image;
    let traced = common::traced_direct(scene);
    let sums = |image: &bevy_diffuse_gi::hdr_image::HdrImage| {
        let mut s = [0.0f64; 3];
        for (i, p) in image.pixels.iter().enumerate() {
            if bevy.covered(i) && traced.covered(i) {
                for c in 0..3 {
                    s[c] += p[c] as f64;
                }
            }
        }
        s
    };
    let (b, t) = (sums(&bevy), sums(&traced));
    let ratios: Vec<f64> = (0..3).map(|c| t[c] / b[c].max(1e-12)).collect();
    // Measured on lavapipe: 0.984, 0.969, 0.957 (Bevy adds a little specular the diffuse tracer does not).
    check(
        test,
        ratios.iter().all(|r| (0.95..=1.05).contains(r)),
        &traced,
        Some(&bevy),
        format!("traced / Bevy direct light per channel: {ratios:.4?} (Bevy {b:.1?}, traced {t:.1?})"),
    );
    // And the chair is orange, not white, in the traced image.
    let seat = traced.region_mean(100, 120, 160, 140).expect("the seat is in view");
    check(test, seat[0] > 2.0 * seat[2], &traced, Some(&bevy), format!("the traced seat is not orange: {seat:?}"));
}

#[test]
fn gltf_textures_in_jpeg_webp_and_ktx2_load_and_colour_the_scene() {
    // tests/assets/textured_chair_{jpeg,webp,ktx2}.gltf (make_image_format_variants.py): the chair of
    // textured_chair.gltf with its textures as external JPEG, WebP and KTX2 files, the formats glTF files
    // ship. Each must load and show the orange seat in Bevy and in the tracer.
    for file in ["textured_chair_jpeg.gltf", "textured_chair_webp.gltf", "textured_chair_ktx2.gltf"] {
        let test = format!("gltf_textures_{file}");
        let scene = StandardScene::Gltf(asset(file));
        let bevy = render(&HeadlessOptions { scene: scene.clone(), frames: 1, ..Default::default() }).image;
        let traced = common::traced_direct(scene);
        for (who, image) in [("Bevy", &bevy), ("the tracer", &traced)] {
            let seat = image.region_mean(100, 120, 160, 140).expect("the seat is in view");
            check(&test, seat[0] > 2.0 * seat[2], image, None, format!("{file}: the seat is not orange in {who}: {seat:?}"));
        }
    }
}

#[test]
fn a_missing_texture_ends_the_run_at_once_naming_the_file() {
    // tests/assets/missing_texture.gltf points its first texture at a file that does not exist. The run
    // must fail while loading, with a message naming the glTF and the missing file, not wait for frames.
    let options = HeadlessOptions { scene: StandardScene::Gltf(asset("missing_texture.gltf")), ..Default::default() };
    let _guard = common::render_lock();
    let started = std::time::Instant::now();
    let error = headless::run(&options).expect_err("a glTF with a missing texture must not render");
    assert!(error.contains("missing_texture.gltf") && error.contains("does_not_exist.png"), "{error}");
    // Measured: well under a second; waiting out the loading frames took minutes on lavapipe.
    assert!(started.elapsed().as_secs() < 60, "took {:?}: {error}", started.elapsed());
}
