//! The generated rooms (`room_SEED`, `docs/unseen_rooms.md`) rendered on the GPU (lavapipe in CI) at 64²
//! and compared with their committed path-traced ground truths (`assets/ground_truth/rooms/`).
//!
//! * A few rooms of the family, every method: the error may not rise above what `unseen_rooms` measured
//!   plus a margin.
//! * The failures issue #32 reported, in rooms of the family's generator: a thin wall between a lit room
//!   and the camera's (`room_136`), a sunlit hall with columns (`room_278`), a lamp-lit furnished room
//!   (`room_281`); and one the family found, a room lit by a glowing box (`room_253`). Radiance Hints and
//!   VPLs must give the camera's room its light within ±15 %, and the VPLs the colour the truth shows on
//!   the walls the camera sees.
#![cfg(feature = "gpu_tests")]

mod common;

use bevy::math::UVec2;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::scenes::{GeneratedRoom, StandardScene};
use common::{check, render};

const SIZE: u32 = 64;

fn room_image(seed: u64, method: GiMethod) -> HdrImage {
    render(&HeadlessOptions {
        scene: StandardScene::Room(seed),
        size: UVec2::splat(SIZE),
        method: HeadlessMethod::Gi(method),
        indirect_only: true,
        frames: 16,
        wait_background: Some(300),
        ..Default::default()
    })
    .image
}

fn room_truth(seed: u64) -> HdrImage {
    common::ground_truth(&format!("rooms/room_{seed}.exr"))
}

/// The camera room's energy (pixels that do not look through a door) of `method` against the truth.
fn camera_room_energy(test: &str, seed: u64, method: GiMethod) -> f64 {
    let room = GeneratedRoom::new(seed);
    let (image, truth) = (room_image(seed, method), room_truth(seed));
    check(test, !image.has_non_finite(), &image, Some(&truth), "NaN or Inf".into());
    let energy = room.camera_room_energy(&image, &truth);
    eprintln!("{test} {}: camera room energy {energy:.3}", method.name());
    check(
        test,
        (0.85..=1.15).contains(&energy),
        &image,
        Some(&truth),
        format!("{}: the camera's room gets {energy:.3} of its light (want 0.85–1.15)", method.name()),
    );
    energy
}

/// Pixels whose camera ray first meets a wall of the camera's room (not the floor, the ceiling, the
/// furniture or anything through a door): traced through the room's CPU snapshot.
fn wall_pixels(room: &GeneratedRoom) -> Vec<bool> {
    let snapshot = room.snapshot();
    let camera = room.reference_camera();
    let (lo, hi) = room.camera_room_bounds();
    let doors = room.through_doors(SIZE, SIZE);
    let mut out = vec![false; (SIZE * SIZE) as usize];
    for y in 0..SIZE {
        for x in 0..SIZE {
            let i = (y * SIZE + x) as usize;
            let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5, SIZE, SIZE);
            let Some(hit) = snapshot.intersect_visible(o, d, 0.0, f32::INFINITY) else { continue };
            let p = o + d * hit.t;
            let on_wall = [(p.x - lo.x).abs(), (p.x - hi.x).abs(), (p.z - lo.z).abs(), (p.z - hi.z).abs()].iter().any(|e| *e < 0.01);
            out[i] = on_wall && !doors[i] && p.y > 0.05 && p.y < hi.y - 0.05;
        }
    }
    out
}

/// Mean colour of `image` over `mask`, as shares of its sum (chromaticity), and the sum.
fn chromaticity(image: &HdrImage, mask: &[bool]) -> ([f64; 3], f64) {
    let mut sum = [0.0f64; 3];
    for (p, _) in image.pixels.iter().zip(mask).filter(|(_, m)| **m) {
        for c in 0..3 {
            sum[c] += p[c] as f64;
        }
    }
    let total = sum.iter().sum::<f64>().max(1e-30);
    (sum.map(|s| s / total), total)
}

/// The rooms and the error each method measured on them with `unseen_rooms` (lavapipe, 64²): block
/// relative RMSE. A method fails when it rises more than 15 % (plus 0.03) above.
const FAMILY_LIMITS: &[(u64, &[(GiMethod, f64)])] = &[
    // A 13.6 × 7.8 m hall lit by the sun through a roof opening, the camera in it.
    (
        1,
        &[
            (GiMethod::RadianceHints, 0.237),
            (GiMethod::Vpl, 0.183),
            (GiMethod::RsmGather, 0.743),
            (GiMethod::Drm, 1.049),
            (GiMethod::Radiosity, 0.099),
            (GiMethod::PhotonGrid, 0.363),
        ],
    ),
    // Two rooms, the sun in one through a roof opening, the camera next door looking through the door.
    (
        2,
        &[
            (GiMethod::RadianceHints, 0.673),
            (GiMethod::Vpl, 0.490),
            (GiMethod::RsmGather, 3.416),
            (GiMethod::Drm, 4.788),
            (GiMethod::Radiosity, 1.398),
            (GiMethod::PhotonGrid, 0.832),
        ],
    ),
];

#[test]
fn a_few_rooms_of_the_family_stay_within_their_measured_error() {
    let test = "unseen_rooms_family";
    assert!(!FAMILY_LIMITS.is_empty());
    for &(seed, limits) in FAMILY_LIMITS {
        let truth = room_truth(seed);
        for &(method, measured) in limits {
            let image = room_image(seed, method);
            let m = metrics::compare(&image, &truth).expect("comparable images");
            let limit = measured * 1.15 + 0.03;
            eprintln!("{test}: room_{seed} {}: block {:.3} (measured {measured:.3}), energy {:.3}", method.name(), m.block_relative_rmse, m.energy_ratio);
            check(
                &format!("{test}_room_{seed}_{}", method.name()),
                !image.has_non_finite() && m.block_relative_rmse <= limit,
                &image,
                Some(&truth),
                format!("room_{seed}, {}: block relative RMSE {:.3} (want ≤ {limit:.3})", method.name(), m.block_relative_rmse),
            );
        }
    }
}

#[test]
fn a_sunlit_hall_with_columns_gets_its_light_with_radiance_hints_and_vpls() {
    // room_278: a 6.5 × 5.9 m hall, 5.6 m high, lit only by the sun through a roof opening, two columns.
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        camera_room_energy("unseen_rooms_sunlit_hall", 278, method);
    }
}

#[test]
fn a_lamp_lit_furnished_room_gets_its_light_with_radiance_hints_and_vpls() {
    // room_281: a 3.6 × 10 m room, 2.7 m high, one point lamp under the ceiling, two tables on thin legs
    // and a cabinet.
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        camera_room_energy("unseen_rooms_furnished_room", 281, method);
    }
}

#[test]
fn a_room_lit_by_a_glowing_box_gets_its_light_with_radiance_hints_and_vpls() {
    // room_253: a 6.4 × 5.1 m room, 4.2 m high, lit only by an emissive box under the ceiling. The box's
    // faces glow on both sides in the tracer, but their insides only light the inside of the box. Radiance
    // Hints' voxels are coarser than the box, so counting both faces let the top face's inside light the
    // room through the box: 2.14 of the light (VPLs 0.99, their visibility is traced). Measured since the
    // emitter samples carry only their open faces: Radiance Hints 1.08, VPLs 1.01.
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        camera_room_energy("unseen_rooms_glowing_box", 253, method);
    }
}

#[test]
#[ignore = "issue #32 is open: the camera's room gets 0.82 of its light with Radiance Hints and 0.70 with VPLs"]
fn the_room_behind_a_thin_wall_gets_its_light_with_radiance_hints_and_vpls() {
    // room_136: two rooms joined by a door through a 7 cm wall, a spot in one, the camera in the other.
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        camera_room_energy("unseen_rooms_thin_wall", 136, method);
    }
}

#[test]
fn vpls_give_the_walls_beside_a_lit_room_the_colour_the_truth_shows() {
    // Rooms lit next door: their walls get light that came through the door and bounced, in the colours
    // of the surfaces it met. VPLs seen through a wall painted the camera's room in the lit room's
    // colours (room_5's floor white where the truth is green, 4.4× the light). Measured with traced
    // shadow maps (lavapipe): room_5 [0.101, 0.818, 0.081] against [0.093, 0.831, 0.076] at 0.86× the
    // light, room_136 [0.509, 0.169, 0.322] against [0.544, 0.139, 0.317] at 0.32× — too little light
    // there (few VPLs reach a room through a door; the ignored thin-wall test holds that target), but
    // none through the wall.
    let test = "unseen_rooms_wall_colour";
    for seed in [5, 136] {
        let room = GeneratedRoom::new(seed);
        let mask = wall_pixels(&room);
        assert!(mask.iter().filter(|m| **m).count() > 200, "room_{seed}: too few wall pixels");
        let (image, truth) = (room_image(seed, GiMethod::Vpl), room_truth(seed));
        let ((a, a_sum), (t, t_sum)) = (chromaticity(&image, &mask), chromaticity(&truth, &mask));
        let shift = (0..3).map(|c| (a[c] - t[c]).abs()).fold(0.0, f64::max);
        eprintln!("{test} room_{seed}: chromaticity {a:.3?} against {t:.3?}, energy {:.3}", a_sum / t_sum);
        check(
            test,
            shift <= 0.05 && a_sum / t_sum <= 1.5,
            &image,
            Some(&truth),
            format!("room_{seed}: the walls' colour {a:.3?} against the truth's {t:.3?} (want each share within 0.05), light {:.3}× (want ≤ 1.5)", a_sum / t_sum),
        );
    }
}
