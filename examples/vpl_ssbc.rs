//! VPLs with imperfect shadow maps and screen-space bias compensation on the Cornell box, tuned live.
//!
//! `cargo run --release --example vpl_ssbc [-- --scene cornell|cellar|sponza_like|PATH.glb]`
//!
//! Keys: G toggles bounced light, M switches the method (VPL ↔ Radiance Hints, at run time), V cycles
//! the debug views (clamped only, compensation only, VPL positions, …), P cycles the VPL presets,
//! S cycles the SSBC steps (0–3), H toggles half resolution, L starts or stops the light's motion. The
//! egui panel ("Diffuse GI") tunes every setting and shows the GPU time of each pass.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame headless
//! on whatever Vulkan device exists and writes `out/vpl_ssbc.png` instead.

#[path = "common/mod.rs"]
mod common;

use bevy::camera::Hdr;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy::render::diagnostic::RenderDiagnosticsPlugin;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::{SceneStatus, StandardScene, StandardScenesPlugin, cornell, mesh_bounds, spawn_standard_scene};

fn main() -> AppExit {
    let scene = common::example_scene("vpl_ssbc", "VPLs with screen-space bias compensation, tuned live in a window.");
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return common::render_headless("vpl_ssbc", scene, GiMethod::Vpl);
    }

    App::new()
        .add_plugins((
            DefaultPlugins.set(WindowPlugin {
                primary_window: Some(Window {
                    title: "bevy_diffuse_gi — VPLs with SSBC".into(),
                    ..default()
                }),
                ..default()
            }),
            RenderDiagnosticsPlugin,
            // 1. The plugin.
            DiffuseGiPlugin::default(),
            DiffuseGiInspectorPlugin,
            StandardScenesPlugin,
            common::CiCapturePlugin,
        ))
        .insert_resource(Example { scene, moving: false, preset: 1 })
        .add_systems(Startup, setup)
        .add_systems(Update, (fit_volume, controls, move_light))
        .add_systems(bevy_egui::EguiPrimaryContextPass, help_window)
        .run()
}

#[derive(Resource)]
struct Example {
    scene: StandardScene,
    moving: bool,
    preset: usize,
}

const PRESETS: [(&str, VplSettings); 3] = [("low", VplSettings::LOW), ("medium", VplSettings::MEDIUM), ("high", VplSettings::HIGH)];

/// The camera's GI: the VPL method with the medium preset.
fn vpl_camera() -> (DiffuseGi, VplSettings) {
    (DiffuseGi { method: GiMethod::Vpl, ..default() }, VplSettings::MEDIUM)
}

fn setup(
    mut commands: Commands,
    example: Res<Example>,
    asset_server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    commands.insert_resource(bevy::light::GlobalAmbientLight { brightness: 0.0, ..default() });
    if example.scene != StandardScene::Cornell {
        // Other scenes come with their lights (GiLight added) and camera; the volume is fitted once loaded.
        spawn_standard_scene(&mut commands, &asset_server, &mut meshes, &mut materials, &example.scene, None);
        return;
    }
    // An existing scene: the Cornell box's walls and blocks...
    cornell::spawn_cornell_geometry(&mut commands, &mut meshes, &mut materials);
    commands.insert_resource(SceneStatus::Ready);
    // 2. ...a camera with `DiffuseGi { method: GiMethod::Vpl, .. }` and its settings...
    commands.spawn((cornell::cornell_camera(cornell::CORNELL_EV100), Hdr, Tonemapping::TonyMcMapface, vpl_camera()));
    // 3. ...and a light with `GiLight` (and shadows). The VPL method needs nothing else.
    commands.spawn((cornell::cornell_spot_light(), GiLight::default(), Name::new("spot light")));
    // For the M key: a Radiance Hints volume, which costs nothing while no camera uses that method.
    commands.spawn((RadianceHintsVolume::MEDIUM, Transform::from_scale(Vec3::splat(2.02)), Name::new("RH volume")));
}

/// For loaded scenes: a camera component and a volume around the meshes once they have bounds.
fn fit_volume(
    mut commands: Commands,
    status: Res<SceneStatus>,
    volumes: Query<(), With<RadianceHintsVolume>>,
    cameras: Query<Entity, (With<Camera3d>, Without<DiffuseGi>)>,
    meshes: Query<(&bevy::camera::primitives::Aabb, &GlobalTransform), With<Mesh3d>>,
) {
    if *status != SceneStatus::Ready || !volumes.is_empty() {
        return;
    }
    let Some((lo, hi)) = mesh_bounds(meshes) else {
        return;
    };
    for camera in &cameras {
        commands.entity(camera).insert((vpl_camera(), Hdr, Tonemapping::TonyMcMapface));
    }
    let size = ((hi - lo) * 1.002).max(Vec3::splat(0.05));
    commands.spawn((
        RadianceHintsVolume::MEDIUM.with_cubic_cells(size),
        Transform::from_translation((lo + hi) * 0.5).with_scale(size),
        Name::new("RH volume"),
    ));
}

fn controls(keys: Res<ButtonInput<KeyCode>>, mut example: ResMut<Example>, mut cameras: Query<(&mut DiffuseGi, &mut VplSettings)>) {
    for (mut gi, mut vpl) in &mut cameras {
        if keys.just_pressed(KeyCode::KeyG) {
            gi.enabled = !gi.enabled;
        }
        if keys.just_pressed(KeyCode::KeyM) {
            gi.method = match gi.method {
                GiMethod::Vpl => GiMethod::RadianceHints,
                _ => GiMethod::Vpl,
            };
        }
        if keys.just_pressed(KeyCode::KeyS) {
            vpl.ssbc_steps = (vpl.ssbc_steps + 1) % 4;
        }
        if keys.just_pressed(KeyCode::KeyP) {
            example.preset = (example.preset + 1) % PRESETS.len();
            *vpl = PRESETS[example.preset].1.clone();
        }
        if keys.just_pressed(KeyCode::KeyV) {
            let views = GiDebugView::ALL;
            let i = views.iter().position(|v| *v == gi.debug_view).unwrap_or(0);
            gi.debug_view = views[(i + 1) % views.len()];
        }
        if keys.just_pressed(KeyCode::KeyH) {
            gi.half_resolution = !gi.half_resolution;
        }
    }
    if keys.just_pressed(KeyCode::KeyL) {
        example.moving = !example.moving;
    }
}

/// Swings the GI lights in a slow circle, so the bounced light has to follow.
fn move_light(time: Res<Time>, example: Res<Example>, mut lights: Query<&mut Transform, With<GiLight>>, mut start: Local<Option<Vec<Vec3>>>) {
    let start = start.get_or_insert_with(|| lights.iter().map(|t| t.translation).collect());
    if !example.moving {
        return;
    }
    let t = time.elapsed_secs() * 0.4;
    for (mut transform, origin) in lights.iter_mut().zip(start.iter()) {
        transform.translation = *origin + Vec3::new(0.5 * t.cos(), 0.0, 0.5 * t.sin()) * 0.6;
    }
}

/// The keys, in a small egui window beside the tuning panel.
fn help_window(mut contexts: bevy_egui::EguiContexts, example: Res<Example>, cameras: Query<(&DiffuseGi, &VplSettings)>) -> Result {
    bevy_egui::egui::Window::new("Keys").anchor(bevy_egui::egui::Align2::LEFT_BOTTOM, [8.0, -8.0]).show(
        contexts.ctx_mut()?,
        |ui| {
            ui.label(format!("scene {} — preset {}", example.scene.name(), PRESETS[example.preset].0));
            for (gi, vpl) in &cameras {
                ui.label(format!("method {:?}, view {:?}, {} SSBC steps", gi.method, gi.debug_view, vpl.ssbc_steps));
            }
            ui.label("G  bounced light on/off");
            ui.label("M  VPL ↔ Radiance Hints");
            ui.label("V  next debug view");
            ui.label("P  next VPL preset");
            ui.label("S  SSBC steps 0–3");
            ui.label("H  half resolution");
            ui.label(format!("L  light motion ({})", if example.moving { "on" } else { "off" }));
        },
    );
    Ok(())
}
