//! `cellar`: two rooms joined by a door, a "flashlight" spot in one, the camera in the other. Tests light
//! leaking through walls: the spot lights room A's side of the dividing wall, so a method without
//! first-bounce occlusion lights room B's side of the same wall (20 cm away) too.
//!
//! Interior: x ∈ [−4, 4], y ∈ [0, 2.5], z ∈ [−2, 2] metres; all walls, floor and ceiling are 20 cm thick
//! boxes. The dividing wall spans x ∈ [−0.1, 0.1] with a door at z ∈ [−1.6, −0.8], up to y = 2. Room A
//! (x < 0) holds a red box and the spot light; room B (x > 0) a blue box and the camera, looking at the
//! dividing wall and the door.

use bevy::camera::Exposure;
use bevy::prelude::*;

use super::SceneCamera;
use crate::light::GiLight;

/// Wall and ceiling reflectance.
pub const WALL: Vec3 = Vec3::new(0.75, 0.73, 0.7);
/// Floor reflectance.
pub const FLOOR: Vec3 = Vec3::new(0.5, 0.47, 0.44);
/// The box in the lit room.
pub const RED: Vec3 = Vec3::new(0.7, 0.12, 0.1);
/// The box in the camera's room.
pub const BLUE: Vec3 = Vec3::new(0.1, 0.2, 0.7);
/// Exposure of the scene (indirect light only reaches the camera's room, so it is dim).
pub const CELLAR_EV100: f32 = -2.0;
/// Spot light ("flashlight") luminous intensity, candela.
pub const LIGHT_CANDELA: f32 = 400.0;
pub const LIGHT_POSITION: Vec3 = Vec3::new(-3.0, 1.6, 0.8);
pub const LIGHT_TARGET: Vec3 = Vec3::new(-0.1, 0.8, 0.7);
pub const CAMERA_POSITION: Vec3 = Vec3::new(3.6, 1.5, 1.6);
pub const CAMERA_TARGET: Vec3 = Vec3::new(0.0, 0.9, -0.4);
/// Vertical field of view of the camera, in degrees.
pub const FOV_Y_DEGREES: f32 = 70.0;

const T: f32 = 0.2;

/// The boxes of the scene: (min, max corner, material index 0 wall, 1 floor, 2 red, 3 blue).
pub fn cellar_boxes() -> Vec<(Vec3, Vec3, usize)> {
    vec![
        // Floor and ceiling.
        (Vec3::new(-4.0 - T, -T, -2.0 - T), Vec3::new(4.0 + T, 0.0, 2.0 + T), 1),
        (Vec3::new(-4.0 - T, 2.5, -2.0 - T), Vec3::new(4.0 + T, 2.5 + T, 2.0 + T), 0),
        // Outer walls.
        (Vec3::new(-4.0 - T, 0.0, -2.0 - T), Vec3::new(-4.0, 2.5, 2.0 + T), 0),
        (Vec3::new(4.0, 0.0, -2.0 - T), Vec3::new(4.0 + T, 2.5, 2.0 + T), 0),
        (Vec3::new(-4.0, 0.0, -2.0 - T), Vec3::new(4.0, 2.5, -2.0), 0),
        (Vec3::new(-4.0, 0.0, 2.0), Vec3::new(4.0, 2.5, 2.0 + T), 0),
        // Dividing wall with the door at z ∈ [−1.6, −0.8], y < 2.
        (Vec3::new(-0.1, 0.0, -2.0), Vec3::new(0.1, 2.5, -1.6), 0),
        (Vec3::new(-0.1, 0.0, -0.8), Vec3::new(0.1, 2.5, 2.0), 0),
        (Vec3::new(-0.1, 2.0, -1.6), Vec3::new(0.1, 2.5, -0.8), 0),
        // Furniture.
        (Vec3::new(-2.6, 0.0, -1.5), Vec3::new(-1.8, 0.9, -0.7), 2),
        (Vec3::new(1.5, 0.0, 0.6), Vec3::new(2.3, 0.7, 1.4), 3),
    ]
}

/// Spawns the cellar with its spot light (with a [`GiLight`]) and the [`SceneCamera`].
pub fn spawn_cellar(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    super::spawn_boxes(commands, meshes, materials, &cellar_boxes(), &[WALL, FLOOR, RED, BLUE], "cellar");
    let cone = 35f32.to_radians();
    commands.spawn((
        SpotLight {
            color: Color::WHITE,
            intensity: 4.0 * std::f32::consts::PI * LIGHT_CANDELA,
            shadow_maps_enabled: true,
            inner_angle: cone * 0.7,
            outer_angle: cone,
            range: 30.0,
            ..default()
        },
        Transform::from_translation(LIGHT_POSITION).looking_at(LIGHT_TARGET, Vec3::Y),
        GiLight::default(),
        Name::new("flashlight"),
    ));
    commands.spawn((
        Camera3d::default(),
        Projection::Perspective(PerspectiveProjection {
            fov: FOV_Y_DEGREES.to_radians(),
            ..default()
        }),
        Transform::from_translation(CAMERA_POSITION).looking_at(CAMERA_TARGET, Vec3::Y),
        Exposure { ev100 },
        SceneCamera,
        Name::new("cellar camera"),
    ));
}

/// The scene as a [`SceneSnapshot`](crate::scene::SceneSnapshot), built on the CPU from the same boxes,
/// materials and light as [`spawn_cellar`].
pub fn cellar_snapshot() -> crate::scene::SceneSnapshot {
    use crate::scene::{SnapshotLight, SnapshotLightEntry};
    let transform = GlobalTransform::from(Transform::from_translation(LIGHT_POSITION).looking_at(LIGHT_TARGET, Vec3::Y));
    let (spot_scale, spot_offset) = SnapshotLight::spot_scale_offset(35f32.to_radians() * 0.7, 35f32.to_radians());
    let light = SnapshotLightEntry {
        entity: Entity::PLACEHOLDER,
        light: SnapshotLight::Spot {
            position: LIGHT_POSITION,
            direction: transform.forward().as_vec3(),
            intensity: Vec3::splat(LIGHT_CANDELA),
            inverse_range_squared: 1.0 / (30.0 * 30.0),
            spot_scale,
            spot_offset,
        },
        shadows_enabled: true,
    };
    super::boxes_snapshot(&cellar_boxes(), &[WALL, FLOOR, RED, BLUE], vec![light])
}
