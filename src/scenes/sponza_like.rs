//! `sponza_like`: a sunlit atrium of 12 × 8 × 6 m with two rows of columns under lintels (the arches of a
//! courtyard, squared), lit only by the sun through a 4 × 3 m opening in the roof. Everything outside the
//! sun's patch on the floor and one column is lit indirectly, and most of that light has bounced twice or
//! more: the large-scene case of the issues (`shared/SCENES.md`).
//!
//! Interior: x ∈ [−6, 6], y ∈ [0, 6], z ∈ [−4, 4] metres; 30 cm walls, floor and roof. Columns 50 cm
//! square at x ∈ {−4.5, −1.5, 1.5, 4.5}, z = ±2.5, up to 4.5 m, joined along x by 50 cm lintels. A red
//! banner hangs on the west wall. The camera stands by the west wall looking down the nave at the sun patch.

use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;


/// Wall and roof reflectance (warm stone).
pub const WALL: Vec3 = Vec3::new(0.7, 0.64, 0.55);
/// Floor reflectance.
pub const FLOOR: Vec3 = Vec3::new(0.45, 0.42, 0.38);
/// Columns and lintels.
pub const COLUMN: Vec3 = Vec3::new(0.8, 0.78, 0.72);
/// The banner on the west wall.
pub const BANNER: Vec3 = Vec3::new(0.65, 0.1, 0.08);
/// Exposure of the scene.
pub const SPONZA_EV100: f32 = 7.0;
/// Sun illuminance on a surface facing it, lux.
pub const SUN_LUX: f32 = 20_000.0;
/// The direction sunlight travels (normalised when used).
pub const SUN_DIRECTION: Vec3 = Vec3::new(0.35, -1.0, 0.2);
pub const CAMERA_POSITION: Vec3 = Vec3::new(-5.6, 1.8, -0.6);
pub const CAMERA_TARGET: Vec3 = Vec3::new(3.0, 1.0, 0.9);
/// Vertical field of view of the camera, in degrees.
pub const FOV_Y_DEGREES: f32 = 70.0;

const T: f32 = 0.3;

/// The boxes of the scene: (min, max corner, material index 0 wall, 1 floor, 2 column, 3 banner).
pub fn sponza_boxes() -> Vec<(Vec3, Vec3, usize)> {
    let (x, y, z) = (6.0, 6.0, 4.0);
    let mut boxes = vec![
        // Floor.
        (Vec3::new(-x - T, -T, -z - T), Vec3::new(x + T, 0.0, z + T), 1),
        // Walls.
        (Vec3::new(-x - T, 0.0, -z - T), Vec3::new(-x, y, z + T), 0),
        (Vec3::new(x, 0.0, -z - T), Vec3::new(x + T, y, z + T), 0),
        (Vec3::new(-x, 0.0, -z - T), Vec3::new(x, y, -z), 0),
        (Vec3::new(-x, 0.0, z), Vec3::new(x, y, z + T), 0),
        // Roof around the opening x ∈ [−2, 2], z ∈ [−1.5, 1.5].
        (Vec3::new(-x - T, y, -z - T), Vec3::new(-2.0, y + T, z + T), 0),
        (Vec3::new(2.0, y, -z - T), Vec3::new(x + T, y + T, z + T), 0),
        (Vec3::new(-2.0, y, -z - T), Vec3::new(2.0, y + T, -1.5), 0),
        (Vec3::new(-2.0, y, 1.5), Vec3::new(2.0, y + T, z + T), 0),
        // The banner.
        (Vec3::new(-x, 1.0, -1.5), Vec3::new(-x + 0.05, 4.0, 1.5), 3),
    ];
    for cz in [-2.5f32, 2.5] {
        for cx in [-4.5f32, -1.5, 1.5, 4.5] {
            boxes.push((Vec3::new(cx - 0.25, 0.0, cz - 0.25), Vec3::new(cx + 0.25, 4.5, cz + 0.25), 2));
        }
        boxes.push((Vec3::new(-4.75, 4.5, cz - 0.25), Vec3::new(4.75, 5.0, cz + 0.25), 2));
    }
    boxes
}

/// Spawns the atrium with its sun (with a [`GiLight`](crate::light::GiLight)) and the [`SceneCamera`](super::SceneCamera).
pub fn spawn_sponza_like(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    super::spawn_boxes(commands, meshes, materials, &sponza_boxes(), &[WALL, FLOOR, COLUMN, BANNER], "atrium");
    super::spawn_sun(
        commands,
        SUN_DIRECTION,
        SUN_LUX,
        // Cascades over the atrium only: sharp shadows of the roof's edges.
        CascadeShadowConfigBuilder {
            num_cascades: 2,
            first_cascade_far_bound: 8.0,
            maximum_distance: 30.0,
            ..default()
        }
        .build(),
    );
    super::spawn_scene_camera(commands, CAMERA_POSITION, CAMERA_TARGET, FOV_Y_DEGREES, ev100, "atrium camera");
}

/// The scene as a [`SceneSnapshot`](crate::scene::SceneSnapshot), built on the CPU from the same boxes,
/// materials and sun as [`spawn_sponza_like`].
pub fn sponza_like_snapshot() -> crate::scene::SceneSnapshot {
    super::boxes_snapshot(&sponza_boxes(), &[WALL, FLOOR, COLUMN, BANNER], vec![super::sun_snapshot(SUN_DIRECTION, SUN_LUX)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sun_enters_only_through_the_roof_opening() {
        let snapshot = sponza_like_snapshot();
        let sun = SUN_DIRECTION.normalize();
        // A ray from the sun through the opening's centre reaches the floor (or a column) inside.
        let start = Vec3::new(0.0, 6.3, 0.0) - sun * 20.0;
        let hit = snapshot.intersect(start, sun, 0.0, f32::INFINITY).expect("the sun reaches inside");
        let p = start + sun * hit.t;
        assert!(p.y < 4.6 && p.x.abs() < 6.0 && p.z.abs() < 4.0, "{p}");
        // One through the roof beside the opening is stopped on the roof.
        let start = Vec3::new(-4.0, 6.3, 0.0) - sun * 20.0;
        let hit = snapshot.intersect(start, sun, 0.0, f32::INFINITY).expect("roof");
        assert!((start + sun * hit.t).y > 5.99);
    }
}
