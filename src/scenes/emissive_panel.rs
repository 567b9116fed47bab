//! `emissive_panel`: the Cornell box of `cornell` with its spot light replaced by a glowing ceiling panel
//! (an emissive `StandardMaterial`, no analytic light), the way Bevy's own Cornell box asset is lit. Bevy
//! renders the panel but casts no light from it, so every lit pixel other than the panel itself is light
//! the GI adds: the scene checks that emissive surfaces bounce, and in the panel's warm colour.
//!
//! The panel is a 0.5 × 0.5 m quad 1 mm under the ceiling (its upper face, which the tracer lets emit too, then lights only the ceiling it hides), facing down, centred on the spot's position,
//! with a black base colour (it reflects nothing) and `emissive` radiance [`PANEL_RADIANCE`] in cd/m².

use bevy::prelude::*;

use super::SceneCamera;
use super::cornell::{cornell_camera, spawn_cornell_geometry};

/// Emitted radiance of the panel in cd/m² per channel (linear RGB): a warm white, about as much flux as
/// `cornell`'s spot (π · 100 · 0.25 ≈ 79 lm in green against the spot's 84 lm).
pub const PANEL_RADIANCE: Vec3 = Vec3::new(160.0, 100.0, 45.0);
/// Half the panel's edge, metres.
pub const PANEL_HALF_SIZE: f32 = 0.25;
/// Height of the panel (the ceiling is at y = 1).
pub const PANEL_HEIGHT: f32 = 0.999;
/// Exposure of the scene (`cornell`'s).
pub const EMISSIVE_PANEL_EV100: f32 = super::cornell::CORNELL_EV100;

/// Spawns the box, the two blocks, the glowing panel and the [`SceneCamera`].
pub fn spawn_emissive_panel(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    spawn_cornell_geometry(commands, meshes, materials);
    let glow = materials.add(StandardMaterial {
        base_color: Color::BLACK,
        emissive: LinearRgba::rgb(PANEL_RADIANCE.x, PANEL_RADIANCE.y, PANEL_RADIANCE.z),
        perceptual_roughness: 1.0,
        metallic: 0.0,
        reflectance: 0.0,
        ..default()
    });
    commands.spawn((
        Mesh3d(meshes.add(Plane3d::new(Vec3::NEG_Y, Vec2::splat(PANEL_HALF_SIZE)))),
        MeshMaterial3d(glow),
        Transform::from_xyz(0.0, PANEL_HEIGHT, 0.0),
        Name::new("glowing panel"),
    ));
    commands.spawn((cornell_camera(ev100), SceneCamera, Name::new("emissive panel camera")));
}
