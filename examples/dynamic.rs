//! The `dynamic` scene: objects moving through a room and a light orbiting under its ceiling, with the
//! bounced light following every frame.
//!
//! `cargo run --release --features tools --example dynamic`
//!
//! Keys: the common ones (G bounced light, M or 1–6 the method, P preset, V debug view, H half resolution,
//! C orbit ↔ fly camera, F1 the panel), and: L the light's orbit, O how many objects move (0, 1, 10),
//! N adds a box at a random place, R removes the newest added box, Space pauses everything. The small
//! window shows the plugin's main-thread cost per frame.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame headless
//! on whatever Vulkan device exists and writes `out/dynamic.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::DynamicScene;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "dynamic",
            title: "dynamic scene",
            scene: "dynamic",
            method: GiMethod::RadianceHints,
            // The scene animates its own light (L below).
            light_motion: false,
            extra_help: &["L light orbit  O moving objects (0, 1, 10)  N / R add / remove a box  Space pause"],
            // Radiosity re-solves (seconds on CI's two cores) in every frame that objects move, so CI
            // skips it here: its moving meshes are tested headless (`tests/gpu_radiosity.rs`) and in the
            // `implicit_visibility` example.
            ci: app::CiMode::Methods(&[GiMethod::RadianceHints, GiMethod::Vpl, GiMethod::RsmGather, GiMethod::Drm]),
        },
        |app| {
            app.init_resource::<Added>()
                .add_systems(Update, controls)
                .add_systems(bevy_egui::EguiPrimaryContextPass, cost_window);
        },
    )
}

/// Boxes added with the N key.
#[derive(Resource, Default)]
struct Added(Vec<Entity>);

fn controls(
    keys: Res<ButtonInput<KeyCode>>,
    mut commands: Commands,
    scene: Option<ResMut<DynamicScene>>,
    mut added: ResMut<Added>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    time: Res<Time>,
) {
    let Some(mut scene) = scene else {
        return;
    };
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
    if keys.just_pressed(KeyCode::Space) {
        scene.paused = !scene.paused;
    }
    if keys.just_pressed(KeyCode::KeyN) {
        let t = time.elapsed_secs();
        let at = Vec3::new(2.4 * (t * 1.7).sin(), 0.2, 2.0 * (t * 1.3).cos());
        let box_ = commands
            .spawn((
                Mesh3d(meshes.add(Cuboid::new(0.4, 0.4, 0.4))),
                MeshMaterial3d(materials.add(StandardMaterial {
                    base_color: Color::srgb(0.9, 0.3, 0.6),
                    perceptual_roughness: 1.0,
                    ..default()
                })),
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

/// What the plugin costs the main thread each frame, and what moves.
fn cost_window(mut contexts: bevy_egui::EguiContexts, scene: Option<Res<DynamicScene>>, cost: Res<MainThreadCost>) -> Result {
    use bevy_egui::egui;
    egui::Window::new("Main thread").anchor(egui::Align2::LEFT_TOP, [8.0, 8.0]).show(contexts.ctx_mut()?, |ui| {
        ui.label(format!(
            "snapshot {:.2} ms, voxels {:.2} ms, VPLs {:.2} ms",
            cost.snapshot_ms, cost.voxels_ms, cost.vpl_ms
        ));
        if let Some(scene) = scene {
            ui.label(format!(
                "light orbit {}, {} moving objects{}",
                if scene.animate_light { "on" } else { "off" },
                scene.moving_meshes,
                if scene.paused { ", paused" } else { "" }
            ));
        }
    });
    Ok(())
}
