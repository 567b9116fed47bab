//! The `dynamic` scene: objects moving through a room and a light orbiting under its ceiling, with the
//! bounced light following every frame.
//!
//! `cargo run --release --example dynamic`
//!
//! Keys: G toggles bounced light, M switches the method (Radiance Hints ↔ VPL), L starts or stops the
//! light, O cycles how many objects move (0, 1, 10), A adds a box at a random place, R removes the newest
//! added box, P pauses everything. The egui panel ("Diffuse GI") tunes every setting and shows the GPU time
//! of each pass; the small window shows the plugin's main-thread cost per frame.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame headless
//! on whatever Vulkan device exists and writes `out/dynamic.png` instead.

#[path = "common/mod.rs"]
mod common;

use bevy::camera::Hdr;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy::render::diagnostic::RenderDiagnosticsPlugin;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::{DynamicScene, SceneCamera, SceneStatus, StandardScene, StandardScenesPlugin, spawn_standard_scene};

fn main() -> AppExit {
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return common::render_headless("dynamic", StandardScene::Dynamic, GiMethod::RadianceHints);
    }
    App::new()
        .add_plugins((
            DefaultPlugins.set(WindowPlugin {
                primary_window: Some(Window { title: "bevy_diffuse_gi — dynamic scene".into(), ..default() }),
                ..default()
            }),
            RenderDiagnosticsPlugin,
            DiffuseGiPlugin::default(),
            DiffuseGiInspectorPlugin,
            StandardScenesPlugin,
            common::CiCapturePlugin,
        ))
        // The scene's clock: the light orbits and one object moves from the start.
        .insert_resource(DynamicScene { animate_light: true, moving_meshes: 1, ..default() })
        .init_resource::<Added>()
        .add_systems(Startup, setup)
        .add_systems(Update, (attach_gi, controls))
        .add_systems(bevy_egui::EguiPrimaryContextPass, help_window)
        .run()
}

/// Boxes added with the A key.
#[derive(Resource, Default)]
struct Added(Vec<Entity>);

fn setup(
    mut commands: Commands,
    asset_server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    // The room, its objects, the light (with `GiLight`) and the camera.
    spawn_standard_scene(&mut commands, &asset_server, &mut meshes, &mut materials, &StandardScene::Dynamic, None);
    // A Radiance Hints volume over the room's interior (6 × 3 × 5 m), cells about 25 cm.
    let size = Vec3::new(6.4, 3.4, 5.4);
    commands.spawn((
        RadianceHintsVolume::MEDIUM.with_cubic_cells(size),
        Transform::from_xyz(0.0, 1.5, 0.0).with_scale(size),
        Name::new("RH volume"),
    ));
}

/// Gives the scene's camera `DiffuseGi` once it exists.
fn attach_gi(mut commands: Commands, status: Res<SceneStatus>, cameras: Query<Entity, (With<SceneCamera>, Without<DiffuseGi>)>) {
    if *status != SceneStatus::Ready {
        return;
    }
    for camera in &cameras {
        commands.entity(camera).insert((DiffuseGi::default(), VplSettings::MEDIUM, Hdr, Tonemapping::TonyMcMapface));
    }
}

fn controls(
    keys: Res<ButtonInput<KeyCode>>,
    mut commands: Commands,
    mut scene: ResMut<DynamicScene>,
    mut added: ResMut<Added>,
    mut cameras: Query<&mut DiffuseGi>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    time: Res<Time>,
) {
    for mut gi in &mut cameras {
        if keys.just_pressed(KeyCode::KeyG) {
            gi.enabled = !gi.enabled;
        }
        if keys.just_pressed(KeyCode::KeyM) {
            gi.method = match gi.method {
                GiMethod::RadianceHints => GiMethod::Vpl,
                _ => GiMethod::RadianceHints,
            };
        }
    }
    if keys.just_pressed(KeyCode::KeyL) {
        scene.animate_light = !scene.animate_light;
    }
    if keys.just_pressed(KeyCode::KeyO) {
        scene.moving_meshes = match scene.moving_meshes {
            0 => 1,
            1 => 10,
            _ => 0,
        };
    }
    if keys.just_pressed(KeyCode::KeyP) {
        scene.paused = !scene.paused;
    }
    if keys.just_pressed(KeyCode::KeyA) {
        let t = time.elapsed_secs();
        let at = Vec3::new(2.4 * (t * 1.7).sin(), 0.2, 2.0 * (t * 1.3).cos());
        let box_ = commands
            .spawn((
                Mesh3d(meshes.add(Cuboid::new(0.4, 0.4, 0.4))),
                MeshMaterial3d(materials.add(StandardMaterial { base_color: Color::srgb(0.9, 0.3, 0.6), perceptual_roughness: 1.0, ..default() })),
                Transform::from_translation(at),
            ))
            .id();
        added.0.push(box_);
    }
    if keys.just_pressed(KeyCode::KeyR)
        && let Some(box_) = added.0.pop()
    {
        commands.entity(box_).despawn();
    }
}

fn help_window(
    mut contexts: bevy_egui::EguiContexts,
    scene: Res<DynamicScene>,
    cost: Res<MainThreadCost>,
    cameras: Query<&DiffuseGi>,
) -> Result {
    bevy_egui::egui::Window::new("Keys").anchor(bevy_egui::egui::Align2::LEFT_BOTTOM, [8.0, -8.0]).show(contexts.ctx_mut()?, |ui| {
        for gi in &cameras {
            ui.label(format!("method {:?}", gi.method));
        }
        ui.label(format!(
            "main thread: snapshot {:.2} ms, voxels {:.2} ms, VPLs {:.2} ms",
            cost.snapshot_ms, cost.voxels_ms, cost.vpl_ms
        ));
        ui.label("G  bounced light on/off");
        ui.label("M  Radiance Hints ↔ VPL");
        ui.label(format!("L  light orbit ({})", if scene.animate_light { "on" } else { "off" }));
        ui.label(format!("O  moving objects ({})", scene.moving_meshes));
        ui.label("A / R  add / remove a box");
        ui.label(format!("P  pause ({})", if scene.paused { "paused" } else { "running" }));
    });
    Ok(())
}
