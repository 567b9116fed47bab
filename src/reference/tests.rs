//! Analytic checks of the path tracer: a white furnace and a plane under a point light.

use super::*;
use crate::scene::{InputTriangle, SceneSnapshot, SnapshotLight, SnapshotLightEntry, SnapshotMaterial};
use bevy::prelude::Entity;

/// Mean RGB over all pixels of an image.
fn mean_rgb(image: &HdrImage) -> Vec3 {
    let sum = image
        .pixels
        .iter()
        .fold(Vec3::ZERO, |acc, p| acc + Vec3::new(p[0], p[1], p[2]));
    sum / image.pixels.len() as f32
}

fn assert_rel(actual: Vec3, expected: Vec3, tolerance: f32, what: &str) {
    let err = ((actual - expected).abs() / expected.abs().max(Vec3::splat(1e-6))).max_element();
    assert!(
        err <= tolerance,
        "{what}: got {actual}, expected {expected} (relative error {err:.4} > {tolerance})"
    );
}

/// The six faces of the cube `[-1, 1]³` as twelve triangles.
fn cube(material: u32) -> Vec<InputTriangle> {
    let mesh = bevy::mesh::Mesh::from(bevy::math::primitives::Cuboid::new(2.0, 2.0, 2.0));
    crate::scene::mesh_triangles(&mesh, &bevy::prelude::GlobalTransform::IDENTITY, material).unwrap()
}

fn camera_at(position: Vec3, look: Vec3, up: Vec3, fov_y: f32) -> ReferenceCamera {
    let transform = bevy::prelude::Transform::from_translation(position).looking_at(look, up);
    ReferenceCamera {
        position,
        rotation: transform.rotation,
        projection: CameraProjection::Perspective { fov_y },
        exposure: 1.0,
    }
}

#[test]
fn white_furnace_converges_to_le_over_one_minus_rho() {
    let rho = Vec3::new(0.3, 0.5, 0.8);
    let le = Vec3::new(1.0, 2.0, 0.5);
    let material = SnapshotMaterial {
        diffuse: rho,
        emissive: le,
        ..SnapshotMaterial::DEFAULT_GREY
    };
    let scene = SceneSnapshot::build(cube(0), vec![material], vec![], vec![]);
    let camera = camera_at(Vec3::new(0.1, -0.2, 0.3), Vec3::new(1.0, 0.5, -1.0), Vec3::Y, 1.4);
    let settings = ReferenceSettings {
        width: 16,
        height: 16,
        samples_per_pixel: 256,
        seed: 3,
        ..Default::default()
    };
    let images = render(&scene, &camera, &settings);
    assert_eq!(images.dropped_samples, 0);
    // Radiance everywhere in a closed furnace: L = Le + ρ L  ⇒  L = Le / (1 − ρ).
    assert_rel(mean_rgb(&images.full), le / (1.0 - rho), 0.01, "full");
    // No analytic light, so no direct light (Bevy's direct pass renders none here): emission reflected
    // once (ρ Le) is binned with the indirect light, which a GI method must add, as are two or more
    // reflections (ρ² Le / (1 − ρ)).
    assert_eq!(mean_rgb(&images.direct), Vec3::ZERO, "direct light without analytic lights");
    assert_rel(mean_rgb(&images.indirect), rho * le / (1.0 - rho), 0.015, "indirect");
    assert!(images.full.pixels.iter().all(|p| p[3] == 1.0), "every pixel sees the furnace");

    // Per-bounce ground truth: N extra bounces keep ρ Le (1 + ρ + … + ρ^N).
    for (n, expected) in [(1u32, rho * le * (Vec3::ONE + rho)), (2, rho * le * (Vec3::ONE + rho + rho * rho))] {
        let limited = render(&scene, &camera, &ReferenceSettings { max_bounces: Some(n), ..settings.clone() });
        assert_rel(mean_rgb(&limited.indirect), expected, 0.015, &format!("indirect, max {n} bounces"));
        assert_eq!(mean_rgb(&limited.direct), Vec3::ZERO, "direct with a bounce limit");
    }
}

#[test]
fn plane_under_point_light_matches_analytic_irradiance() {
    let rho = 0.8;
    let h = 2.0;
    let intensity = 100.0;
    let s = 50.0;
    let quad = [
        Vec3::new(-s, 0.0, -s),
        Vec3::new(-s, 0.0, s),
        Vec3::new(s, 0.0, s),
        Vec3::new(s, 0.0, -s),
    ];
    let triangles = vec![
        InputTriangle::flat([quad[0], quad[1], quad[2]], 0),
        InputTriangle::flat([quad[0], quad[2], quad[3]], 0),
    ];
    let material = SnapshotMaterial {
        diffuse: Vec3::splat(rho),
        ..SnapshotMaterial::DEFAULT_GREY
    };
    let light = SnapshotLightEntry {
        entity: Entity::PLACEHOLDER,
        light: SnapshotLight::Point {
            position: Vec3::new(0.0, h, 0.0),
            intensity: Vec3::splat(intensity),
            inverse_range_squared: 0.0,
        },
        shadows_enabled: true,
    };
    let scene = SceneSnapshot::build(triangles, vec![material], vec![], vec![light]);
    let camera = camera_at(Vec3::new(0.0, 6.0, 0.0), Vec3::ZERO, Vec3::NEG_Z, 1.2);
    let (w, hgt) = (32, 32);
    let settings = ReferenceSettings {
        width: w,
        height: hgt,
        samples_per_pixel: 16,
        seed: 1,
        ..Default::default()
    };
    let images = render(&scene, &camera, &settings);

    // A lone plane reflects nothing back onto itself: no indirect light at all.
    assert!(images.indirect.pixels.iter().all(|p| p[0] == 0.0 && p[1] == 0.0 && p[2] == 0.0));
    for (x, y) in [(16, 16), (3, 5), (28, 20), (10, 30)] {
        // Analytic radiance at the pixel centre: L = ρ/π · I cos θ / d² = ρ/π · I h / d³.
        let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5, w, hgt);
        let p = o + d * (-o.y / d.y);
        let dist = (Vec3::new(0.0, h, 0.0) - p).length();
        let expected = rho / PI * intensity * h / dist.powi(3);
        let got = images.direct.get(x, y);
        assert_rel(Vec3::new(got[0], got[1], got[2]), Vec3::splat(expected), 0.01, &format!("pixel ({x}, {y})"));
        assert_eq!(images.full.get(x, y), got, "full = direct without emission or bounces");
    }
}

#[test]
fn shadows_block_next_event_estimation() {
    // A plane with a small occluder square between it and the light.
    let quad = |y: f32, s: f32| {
        let q = [
            Vec3::new(-s, y, -s),
            Vec3::new(-s, y, s),
            Vec3::new(s, y, s),
            Vec3::new(s, y, -s),
        ];
        [InputTriangle::flat([q[0], q[1], q[2]], 0), InputTriangle::flat([q[0], q[2], q[3]], 0)]
    };
    let mut tris = quad(0.0, 10.0).to_vec();
    tris.extend(quad(1.0, 0.5));
    let material = SnapshotMaterial {
        diffuse: Vec3::splat(0.5),
        ..SnapshotMaterial::DEFAULT_GREY
    };
    let light = SnapshotLightEntry {
        entity: Entity::PLACEHOLDER,
        light: SnapshotLight::Directional {
            direction: Vec3::NEG_Y,
            illuminance: Vec3::splat(10.0),
        },
        shadows_enabled: true,
    };
    let scene = SceneSnapshot::build(tris, vec![material], vec![], vec![light]);
    // Between the floor and the occluder, looking down: the floor under the occluder is dark...
    let camera = camera_at(Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, 0.0, 0.0), Vec3::Z, 0.2);
    let images = render(
        &scene,
        &camera,
        &ReferenceSettings {
            width: 4,
            height: 4,
            samples_per_pixel: 8,
            ..Default::default()
        },
    );
    assert!(images.direct.pixels.iter().all(|p| p[0] == 0.0), "floor under the occluder is in shadow");

    // ...and the floor beside it is lit by the full 10 lux.
    let camera = camera_at(Vec3::new(3.0, 0.5, 0.0), Vec3::new(3.0, 0.0, 0.0), Vec3::Z, 0.2);
    let images = render(
        &scene,
        &camera,
        &ReferenceSettings {
            width: 4,
            height: 4,
            samples_per_pixel: 8,
            ..Default::default()
        },
    );
    let expected = 0.5 / PI * 10.0;
    assert_rel(mean_rgb(&images.direct), Vec3::splat(expected), 1e-4, "lit floor");
}

#[test]
fn renders_are_deterministic_per_seed() {
    let material = SnapshotMaterial {
        diffuse: Vec3::splat(0.7),
        emissive: Vec3::splat(0.5),
        ..SnapshotMaterial::DEFAULT_GREY
    };
    let scene = SceneSnapshot::build(cube(0), vec![material], vec![], vec![]);
    let camera = camera_at(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, 1.0);
    let settings = ReferenceSettings {
        width: 8,
        height: 8,
        samples_per_pixel: 4,
        seed: 11,
        ..Default::default()
    };
    let a = render(&scene, &camera, &settings);
    let b = render(&scene, &camera, &settings);
    assert_eq!(a.full, b.full);
    let c = render(&scene, &camera, &ReferenceSettings { seed: 12, ..settings });
    assert_ne!(a.full, c.full);
}

#[test]
fn burley_factor_is_one_head_on_and_brighter_at_grazing_light() {
    let n = Vec3::Y;
    assert!((burley_over_lambert(n, n, n, 1.0) - 1.0).abs() < 1e-6);
    let grazing = Vec3::new(1.0, 0.05, 0.0).normalize();
    let f = burley_over_lambert(n, n, grazing, 1.0);
    assert!(f > 1.3 && f < 2.5, "grazing factor {f}");
}

#[test]
fn a_floor_under_a_sky_reflects_rho_times_the_sky_as_indirect_light() {
    use crate::scene::Environment;
    let rho = Vec3::new(0.2, 0.5, 0.7);
    let sky = Vec3::new(3.0, 2.0, 1.0);
    let material = SnapshotMaterial { diffuse: rho, ..SnapshotMaterial::DEFAULT_GREY };
    // A large floor, seen from just above its middle: every path that leaves it escapes.
    let s = 1000.0;
    let floor = vec![
        InputTriangle::flat([Vec3::new(-s, 0.0, -s), Vec3::new(-s, 0.0, s), Vec3::new(s, 0.0, s)], 0),
        InputTriangle::flat([Vec3::new(-s, 0.0, -s), Vec3::new(s, 0.0, s), Vec3::new(s, 0.0, -s)], 0),
    ];
    let mut scene = SceneSnapshot::build(floor, vec![material], vec![], vec![]);
    let settings = ReferenceSettings { width: 8, height: 8, samples_per_pixel: 64, seed: 1, ..Default::default() };
    let camera = camera_at(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 0.0, -0.01), Vec3::NEG_Z, 0.5);
    let dark = render(&scene, &camera, &settings);
    assert_eq!(mean_rgb(&dark.full), Vec3::ZERO, "no environment, no light");

    scene.environment = Some(std::sync::Arc::new(Environment::uniform(sky)));
    let lit = render(&scene, &camera, &settings);
    // L = ρ/π · π L_sky, reflected once: the GI's light, so in the indirect image, not the direct one.
    assert_rel(mean_rgb(&lit.indirect), rho * sky, 0.01, "sky reflected by the floor");
    assert_eq!(mean_rgb(&lit.direct), Vec3::ZERO);
    // A probe looking up sees the sky itself (no reflection).
    let [emission, direct, indirect] = incident_radiance(&scene, Vec3::Y, Vec3::Y, &settings, 4, 0);
    assert_rel(emission, sky, 1e-6, "the sky seen by a probe");
    assert_eq!(direct + indirect, Vec3::ZERO);
}

#[test]
fn floor_under_an_emissive_panel_matches_the_closed_form_form_factor() {
    // A black 1 × 0.6 m panel of radiance Le, 0.8 m over a 40 m floor of albedo ρ: the floor reflects
    // ρ/π · E with E the closed form (`crate::emitters::parallel_rectangle_irradiance`), all of it
    // indirect light (emission reflected once; Bevy draws no light from emissive materials).
    let le = Vec3::new(30.0, 20.0, 10.0);
    let rho = 0.5;
    let y = 0.8;
    let glow = SnapshotMaterial { emissive: le, diffuse: Vec3::ZERO, ..SnapshotMaterial::DEFAULT_GREY };
    let floor = SnapshotMaterial { diffuse: Vec3::splat(rho), ..SnapshotMaterial::DEFAULT_GREY };
    let (a, b, c, d) = (Vec3::new(-0.5, y, -0.3), Vec3::new(0.5, y, -0.3), Vec3::new(0.5, y, 0.3), Vec3::new(-0.5, y, 0.3));
    let s = 20.0;
    let f = [Vec3::new(-s, 0.0, -s), Vec3::new(-s, 0.0, s), Vec3::new(s, 0.0, s), Vec3::new(s, 0.0, -s)];
    let triangles = vec![
        InputTriangle::flat([a, b, c], 1),
        InputTriangle::flat([a, c, d], 1),
        InputTriangle::flat([f[0], f[1], f[2]], 0),
        InputTriangle::flat([f[0], f[2], f[3]], 0),
    ];
    let scene = SceneSnapshot::build(triangles, vec![floor, glow], vec![], vec![]);
    // Low and to the side, under the panel's height: the camera sees the floor around and under it.
    let camera = camera_at(Vec3::new(1.5, 0.6, 0.3), Vec3::new(0.0, 0.0, 0.1), Vec3::Y, 0.4);
    let (w, h) = (8, 8);
    let settings = ReferenceSettings {
        width: w,
        height: h,
        samples_per_pixel: 4096,
        seed: 2,
        pixel_centers: true,
        ..Default::default()
    };
    let images = render(&scene, &camera, &settings);
    assert_eq!(mean_rgb(&images.direct), Vec3::ZERO, "no analytic light, no direct light");
    let (mut got_sum, mut want_sum) = (Vec3::ZERO, Vec3::ZERO);
    for (x, yy) in (0..h).flat_map(|yy| (0..w).map(move |x| (x, yy))) {
        let (o, dir) = camera.ray(x as f32 + 0.5, yy as f32 + 0.5, w, h);
        let p = o + dir * (-o.y / dir.y);
        let e = le.to_array().map(|l| crate::emitters::parallel_rectangle_irradiance(l, y, [-0.5 - p.x, 0.5 - p.x], [-0.3 - p.z, 0.3 - p.z]));
        let want = Vec3::from_array(e) * rho / PI;
        let got = images.indirect.get(x, yy);
        let got = Vec3::new(got[0], got[1], got[2]);
        assert_rel(got, want, 0.06, &format!("pixel ({x}, {yy}) at {p}"));
        got_sum += got;
        want_sum += want;
    }
    assert_rel(got_sum, want_sum, 0.015, "mean over the pixels");
}
