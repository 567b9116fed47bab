//! `near_light`: `cornell` with a white block hung just below its spot light, the situation of Fig. 7 in
//! the Direct Radiance Mapping paper (Frisvad et al. 2005): an object close to the light fills most of
//! the light's map with a few square centimetres of brightly lit surface. Approximations of the solid
//! angle that ignore the area a map texel covers (DRM's Eq. 11) then overexpose the whole room; the
//! truth changes little.
//!
//! The block is a [`BLOCK_SIZE`] cube centred [`BLOCK_DEPTH`] below the light (its top 24 cm below it), so
//! it catches most of the spot's 30° cone; the rest of the cone still reaches the floor around it.

use bevy::prelude::*;

use super::SceneCamera;
use super::cornell::{LIGHT_POSITION, WHITE, cornell_camera, cornell_spot_light, diffuse_material, spawn_cornell_geometry};
use crate::light::GiLight;

/// Edge of the hanging block, metres.
pub const BLOCK_SIZE: f32 = 0.24;
/// Depth of the block's centre below the light, metres.
pub const BLOCK_DEPTH: f32 = 0.36;
/// Exposure of the scene (`cornell`'s).
pub const NEAR_LIGHT_EV100: f32 = super::cornell::CORNELL_EV100;

/// Spawns `cornell` (box, blocks, spot light with a [`GiLight`], camera) and the hanging block.
pub fn spawn_near_light(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    spawn_cornell_geometry(commands, meshes, materials);
    commands.spawn((
        Mesh3d(meshes.add(Cuboid::from_length(BLOCK_SIZE))),
        MeshMaterial3d(materials.add(diffuse_material(WHITE))),
        Transform::from_translation(LIGHT_POSITION - Vec3::Y * BLOCK_DEPTH),
        Name::new("block near the light"),
    ));
    commands.spawn((cornell_spot_light(), GiLight::default(), Name::new("spot light")));
    commands.spawn((cornell_camera(ev100), SceneCamera, Name::new("near light camera")));
}
