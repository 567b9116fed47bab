//! `sky_room`: an 8 × 6 × 3 m room with 0.2 m walls, lit only by the sky, an environment map on the camera
//! (no analytic light, no emission). The sky comes in through a 2 × 2 m roof opening and a door in the
//! east wall; a red and a blue block stand inside. Outside, a 14 × 12 m ground reflects the sky into the
//! door.
//!
//! The environment is a procedural cube map ([`sky_radiance`]): a zenith-blue to horizon-white gradient
//! with a broad warm glow towards the south-east and a dark brown ground below the horizon, so that the
//! light inside depends on the map's orientation (a face or axis mix-up shows). The camera's
//! `EnvironmentMapLight` has a black diffuse map ([`crate::scene::environment::occluded_environment`]): Bevy
//! shows only the sky's reflections, and the sky's diffuse light inside is the GI's to add, with
//! occlusion. The ground truth bins sky light reflected once with the indirect light for that reason
//! ([`crate::reference`]).

use bevy::asset::RenderAssetUsages;
use bevy::light::EnvironmentMapLight;
use bevy::prelude::*;

use super::cellar::{BLUE, FLOOR, RED, WALL};

/// Exposure of the scene: the floor under the opening is about 0.5 after it.
pub const SKY_ROOM_EV100: f32 = 9.0;
/// Texels per side of each face of the sky's cube map.
pub const SKY_FACE: u32 = 32;
pub const CAMERA_POSITION: Vec3 = Vec3::new(-3.4, 1.6, 2.4);
pub const CAMERA_TARGET: Vec3 = Vec3::new(1.0, 0.7, -1.0);

const T: f32 = 0.2;
const H: f32 = 3.0;

/// The room's boxes: (min, max, palette index into `[WALL, FLOOR, RED, BLUE]`).
pub fn sky_room_boxes() -> Vec<(Vec3, Vec3, usize)> {
    vec![
        // Ground, under the room and around it.
        (Vec3::new(-7.0, -T, -6.0), Vec3::new(7.0, 0.0, 6.0), 1),
        // Roof around the opening x ∈ [0.5, 2.5], z ∈ [−1.5, 0.5].
        (Vec3::new(-4.0 - T, H, -3.0 - T), Vec3::new(0.5, H + T, 3.0 + T), 0),
        (Vec3::new(2.5, H, -3.0 - T), Vec3::new(4.0 + T, H + T, 3.0 + T), 0),
        (Vec3::new(0.5, H, -3.0 - T), Vec3::new(2.5, H + T, -1.5), 0),
        (Vec3::new(0.5, H, 0.5), Vec3::new(2.5, H + T, 3.0 + T), 0),
        // West, north and south walls.
        (Vec3::new(-4.0 - T, 0.0, -3.0 - T), Vec3::new(-4.0, H, 3.0 + T), 0),
        (Vec3::new(-4.0, 0.0, -3.0 - T), Vec3::new(4.0, H, -3.0), 0),
        (Vec3::new(-4.0, 0.0, 3.0), Vec3::new(4.0, H, 3.0 + T), 0),
        // East wall with a 1.2 × 2.2 m door at z ∈ [0.6, 1.8].
        (Vec3::new(4.0, 0.0, -3.0 - T), Vec3::new(4.0 + T, H, 0.6), 0),
        (Vec3::new(4.0, 0.0, 1.8), Vec3::new(4.0 + T, H, 3.0 + T), 0),
        (Vec3::new(4.0, 2.2, 0.6), Vec3::new(4.0 + T, H, 1.8), 0),
        // Two blocks.
        (Vec3::new(-1.5, 0.0, -2.2), Vec3::new(-0.5, 1.2, -1.2), 2),
        (Vec3::new(1.8, 0.0, 1.2), Vec3::new(2.6, 0.8, 2.0), 3),
    ]
}

/// The sky's radiance in cd/m² towards world direction `d` (unit).
pub fn sky_radiance(d: Vec3) -> Vec3 {
    let d = d.normalize_or_zero();
    if d.y < 0.0 {
        // The ground below the horizon, darker towards the nadir.
        return Vec3::new(600.0, 480.0, 360.0) * (1.0 + d.y * 0.5);
    }
    let horizon = Vec3::new(4000.0, 4000.0, 4200.0);
    let zenith = Vec3::new(1200.0, 1800.0, 3600.0);
    let glow_direction = Vec3::new(0.55, 0.55, 0.63).normalize();
    let glow = Vec3::new(9000.0, 7000.0, 4500.0) * d.dot(glow_direction).max(0.0).powi(8);
    horizon.lerp(zenith, d.y.sqrt()) + glow
}

/// The sky as a cube-map image (`Rgba32Float`, [`SKY_FACE`]² per face, CPU data kept so that the GI and
/// the tracer can read it), in the face and texel order Bevy samples (see [`crate::scene::Environment`]).
pub fn sky_image() -> Image {
    crate::scene::environment::cube_image(SKY_FACE, RenderAssetUsages::default(), sky_radiance)
}

/// Spawns the room and the [`SceneCamera`](super::SceneCamera) with the sky's `EnvironmentMapLight`.
pub fn spawn_sky_room(commands: &mut Commands, meshes: &mut Assets<Mesh>, materials: &mut Assets<StandardMaterial>, ev100: f32) {
    super::spawn_boxes(commands, meshes, materials, &sky_room_boxes(), &[WALL, FLOOR, RED, BLUE], "sky room");
    super::spawn_scene_camera(commands, CAMERA_POSITION, CAMERA_TARGET, 70.0, ev100, "sky room camera");
    // The environment needs the image assets, which the scene builders are not given: add it when the
    // commands apply, to the camera just spawned.
    commands.queue(|world: &mut World| {
        let sky = world.resource_mut::<Assets<Image>>().add(sky_image());
        let light = EnvironmentMapLight { diffuse_map: sky.clone(), specular_map: sky, intensity: 1.0, ..default() };
        let light = crate::scene::environment::occluded_environment(&light, &mut world.resource_mut::<Assets<Image>>());
        let mut cameras = world.query_filtered::<Entity, With<super::SceneCamera>>();
        let cameras: Vec<Entity> = cameras.iter(world).collect();
        for camera in cameras {
            world.entity_mut(camera).insert(light.clone());
        }
    });
}

/// The room as a CPU snapshot, with its sky.
pub fn sky_room_snapshot() -> crate::scene::SceneSnapshot {
    let mut snapshot = super::boxes_snapshot(&sky_room_boxes(), &[WALL, FLOOR, RED, BLUE], vec![]);
    let environment = crate::scene::Environment::from_image(&sky_image(), 1.0, Quat::IDENTITY).expect("the sky is readable");
    snapshot.environment = Some(std::sync::Arc::new(environment));
    snapshot
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sky_image_reads_back_as_the_sky_in_every_direction() {
        let environment = crate::scene::Environment::from_image(&sky_image(), 1.0, Quat::IDENTITY).unwrap();
        let mut worst = 0.0f32;
        for i in 0..500 {
            // Directions spread over the sphere (a Fibonacci lattice), away from the horizon's kink.
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / 500.0;
            let phi = i as f32 * 2.399_963;
            let r = (1.0 - y * y).sqrt();
            let d = Vec3::new(r * phi.cos(), y, r * phi.sin());
            if y.abs() < 0.1 {
                continue;
            }
            let (got, want) = (environment.radiance(d), sky_radiance(d));
            worst = worst.max(((got - want).abs() / want).max_element());
        }
        // Bilinear filtering of a 32² face: a few per cent on the glow's slope.
        assert!(worst < 0.08, "worst relative difference {worst}");
        // The glow is where it was put (south-east and up), not mirrored.
        let glow = Vec3::new(0.55, 0.55, 0.63);
        assert!(environment.radiance(glow).x > 2.0 * environment.radiance(Vec3::new(-0.55, 0.55, -0.63)).x);
        assert!(environment.radiance(glow).x > 2.0 * environment.radiance(Vec3::new(0.55, 0.55, -0.63)).x);
    }
}
