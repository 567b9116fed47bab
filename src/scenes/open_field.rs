//! `open_field`: a 60 × 60 m sunlit field with five buildings of different sizes and colours and one thin
//! free-standing wall (`shared/SCENES.md`): a large, sparse, open scene. Light escapes upwards (no sky is
//! modelled, in the game or the tracer), so the indirect light is the sun's bounce off the ground onto the
//! buildings' shaded sides, and off the sunlit walls onto the ground between them. It tests volumes far
//! larger than a room (sparse grids, several volumes, camera-centred cascades).
//!
//! Ground: y ∈ [−0.3, 0] over x, z ∈ [−30, 30]. The camera stands at eye height near one corner and looks
//! across the field towards the centre.

use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;


/// Ground reflectance (dry earth).
pub const GROUND: Vec3 = Vec3::new(0.4, 0.36, 0.3);
/// The buildings' reflectances: plaster, brick, slate, ochre.
pub const PALETTE: [Vec3; 5] = [
    GROUND,
    Vec3::new(0.75, 0.72, 0.68),
    Vec3::new(0.55, 0.2, 0.15),
    Vec3::new(0.35, 0.4, 0.55),
    Vec3::new(0.7, 0.55, 0.25),
];
/// Exposure of the scene (sunlight).
pub const OPEN_FIELD_EV100: f32 = 10.0;
/// Sun illuminance on a surface facing it, lux.
pub const SUN_LUX: f32 = 20_000.0;
/// The direction sunlight travels (normalised when used).
pub const SUN_DIRECTION: Vec3 = Vec3::new(0.5, -0.8, 0.35);
pub const CAMERA_POSITION: Vec3 = Vec3::new(-22.0, 1.7, 21.0);
pub const CAMERA_TARGET: Vec3 = Vec3::new(2.0, 2.5, -4.0);
/// Vertical field of view of the camera, in degrees.
pub const FOV_Y_DEGREES: f32 = 60.0;

/// The boxes of the scene: (min, max corner, index into [`PALETTE`]).
pub fn open_field_boxes() -> Vec<(Vec3, Vec3, usize)> {
    vec![
        (Vec3::new(-30.0, -0.3, -30.0), Vec3::new(30.0, 0.0, 30.0), 0),
        (Vec3::new(-14.0, 0.0, -10.0), Vec3::new(-6.0, 6.0, -2.0), 1),
        (Vec3::new(4.0, 0.0, -16.0), Vec3::new(10.0, 9.0, -10.0), 2),
        (Vec3::new(-4.0, 0.0, 8.0), Vec3::new(2.0, 3.5, 14.0), 3),
        (Vec3::new(12.0, 0.0, 4.0), Vec3::new(20.0, 5.0, 12.0), 4),
        (Vec3::new(-2.0, 0.0, -4.0), Vec3::new(3.0, 4.0, 1.0), 1),
        // A free-standing wall, 30 cm thick.
        (Vec3::new(-20.0, 0.0, 11.7), Vec3::new(-8.0, 2.5, 12.0), 1),
    ]
}

/// Spawns the field with its sun (with a [`GiLight`](crate::light::GiLight)) and the [`SceneCamera`](super::SceneCamera).
pub fn spawn_open_field(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    super::spawn_boxes(commands, meshes, materials, &open_field_boxes(), &PALETTE, "field");
    super::spawn_sun(
        commands,
        SUN_DIRECTION,
        SUN_LUX,
        CascadeShadowConfigBuilder {
            num_cascades: 3,
            first_cascade_far_bound: 12.0,
            maximum_distance: 90.0,
            ..default()
        }
        .build(),
    );
    super::spawn_scene_camera(commands, CAMERA_POSITION, CAMERA_TARGET, FOV_Y_DEGREES, ev100, "field camera");
}

/// The scene as a [`SceneSnapshot`](crate::scene::SceneSnapshot), built on the CPU from the same boxes,
/// materials and sun as [`spawn_open_field`].
pub fn open_field_snapshot() -> crate::scene::SceneSnapshot {
    super::boxes_snapshot(&open_field_boxes(), &PALETTE, vec![super::sun_snapshot(SUN_DIRECTION, SUN_LUX)])
}
