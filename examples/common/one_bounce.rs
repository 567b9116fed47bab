//! The windowed app shared by the one-bounce examples (`rsm_gather`, `direct_radiance_mapping`): the
//! Cornell box (or another standard scene) with a camera using the method, the tuning panel, and keys.

use bevy::camera::Hdr;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy::render::diagnostic::RenderDiagnosticsPlugin;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::{SceneStatus, StandardScene, StandardScenesPlugin, cornell, near_light, spawn_standard_scene};

/// Runs the example `tool` with `method` as the camera's method (`--scene NAME` picks another scene);
/// without a display, renders one frame headless instead.
pub fn run(tool: &'static str, title: &'static str, method: GiMethod) -> AppExit {
    let scene = crate::common::example_scene(tool, title);
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return crate::common::render_headless(tool, scene, method);
    }
    App::new()
        .add_plugins((
            DefaultPlugins.set(WindowPlugin {
                primary_window: Some(Window { title: title.into(), ..default() }),
                ..default()
            }),
            RenderDiagnosticsPlugin,
            // 1. The plugin.
            DiffuseGiPlugin::default(),
            DiffuseGiInspectorPlugin,
            StandardScenesPlugin,
            crate::common::CiCapturePlugin,
        ))
        .insert_resource(Example { scene, method, moving: false, preset: 1, block_near: false })
        .add_systems(Startup, setup)
        .add_systems(Update, (add_gi_to_loaded_cameras, controls, move_light, place_block))
        .add_systems(bevy_egui::EguiPrimaryContextPass, help_window)
        .run()
}

#[derive(Resource)]
struct Example {
    scene: StandardScene,
    method: GiMethod,
    moving: bool,
    preset: usize,
    block_near: bool,
}

/// The block that B hangs below the light (`near_light`'s, the DRM paper's Fig. 7).
#[derive(Component)]
struct Block;

const PRESET_NAMES: [&str; 3] = ["low", "medium", "high"];
const RSM_PRESETS: [RsmGatherSettings; 3] = [RsmGatherSettings::LOW, RsmGatherSettings::MEDIUM, RsmGatherSettings::HIGH];
const DRM_PRESETS: [DrmSettings; 3] = [DrmSettings::LOW, DrmSettings::MEDIUM, DrmSettings::HIGH];

/// 2. The camera's GI: the method, with every method's settings so that M can switch at run time.
fn gi_camera(method: GiMethod) -> impl Bundle {
    (
        DiffuseGi { method, ..default() },
        RsmGatherSettings::MEDIUM,
        DrmSettings::MEDIUM,
        Hdr,
        Tonemapping::TonyMcMapface,
    )
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
        // Other scenes come with their lights (GiLight added) and camera.
        spawn_standard_scene(&mut commands, &asset_server, &mut meshes, &mut materials, &example.scene, None);
        return;
    }
    cornell::spawn_cornell_geometry(&mut commands, &mut meshes, &mut materials);
    commands.insert_resource(SceneStatus::Ready);
    commands.spawn((cornell::cornell_camera(cornell::CORNELL_EV100), gi_camera(example.method)));
    // 3. A light with `GiLight` (and shadows): its reflective shadow map is all these methods read.
    commands.spawn((cornell::cornell_spot_light(), GiLight::default(), Name::new("spot light")));
    // The block B moves next to the light; it starts on the floor, out of the way.
    commands.spawn((
        Mesh3d(meshes.add(Cuboid::from_length(near_light::BLOCK_SIZE))),
        MeshMaterial3d(materials.add(cornell::diffuse_material(cornell::WHITE))),
        Transform::from_xyz(-0.75, -1.0 + near_light::BLOCK_SIZE * 0.5, 0.7),
        Block,
        Name::new("movable block"),
    ));
}

/// For loaded scenes: the GI components on their camera.
fn add_gi_to_loaded_cameras(
    mut commands: Commands,
    example: Res<Example>,
    status: Res<SceneStatus>,
    cameras: Query<Entity, (With<Camera3d>, Without<DiffuseGi>)>,
) {
    if *status == SceneStatus::Ready {
        for camera in &cameras {
            commands.entity(camera).insert(gi_camera(example.method));
        }
    }
}

fn controls(
    keys: Res<ButtonInput<KeyCode>>,
    mut example: ResMut<Example>,
    mut cameras: Query<(&mut DiffuseGi, &mut RsmGatherSettings, &mut DrmSettings)>,
) {
    for (mut gi, mut rsm, mut drm) in &mut cameras {
        if keys.just_pressed(KeyCode::KeyG) {
            gi.enabled = !gi.enabled;
        }
        if keys.just_pressed(KeyCode::KeyM) {
            let i = GiMethod::ALL.iter().position(|m| *m == gi.method).unwrap_or(0);
            gi.method = GiMethod::ALL[(i + 1) % GiMethod::ALL.len()];
        }
        if keys.just_pressed(KeyCode::KeyP) {
            example.preset = (example.preset + 1) % PRESET_NAMES.len();
            *rsm = RSM_PRESETS[example.preset].clone();
            *drm = DRM_PRESETS[example.preset].clone();
        }
        if keys.just_pressed(KeyCode::KeyE) {
            let i = DrmSolidAngle::ALL.iter().position(|s| *s == drm.solid_angle).unwrap_or(0);
            drm.solid_angle = DrmSolidAngle::ALL[(i + 1) % DrmSolidAngle::ALL.len()];
        }
        if keys.just_pressed(KeyCode::KeyW) {
            rsm.weights = match rsm.weights {
                RsmSampleWeights::Density => RsmSampleWeights::Paper,
                RsmSampleWeights::Paper => RsmSampleWeights::Density,
            };
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
    if keys.just_pressed(KeyCode::KeyB) {
        example.block_near = !example.block_near;
    }
}

/// B: hangs the block just below the light (Fig. 7 of the DRM paper) or puts it back on the floor.
fn place_block(example: Res<Example>, lights: Query<&Transform, (With<GiLight>, Without<Block>)>, mut blocks: Query<&mut Transform, With<Block>>) {
    if !example.is_changed() {
        return;
    }
    for mut block in &mut blocks {
        block.translation = match (example.block_near, lights.iter().next()) {
            (true, Some(light)) => light.translation - Vec3::Y * near_light::BLOCK_DEPTH,
            _ => Vec3::new(-0.75, -1.0 + near_light::BLOCK_SIZE * 0.5, 0.7),
        };
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
fn help_window(
    mut contexts: bevy_egui::EguiContexts,
    example: Res<Example>,
    cameras: Query<(&DiffuseGi, &RsmGatherSettings, &DrmSettings)>,
) -> Result {
    bevy_egui::egui::Window::new("Keys").anchor(bevy_egui::egui::Align2::LEFT_BOTTOM, [8.0, -8.0]).show(
        contexts.ctx_mut()?,
        |ui| {
            ui.label(format!("scene {} — preset {}", example.scene.name(), PRESET_NAMES[example.preset]));
            for (gi, rsm, drm) in &cameras {
                ui.label(format!(
                    "method {:?}, view {:?}; RSM weights {:?}; DRM Eq. {}, {}×{}",
                    gi.method,
                    gi.debug_view,
                    rsm.weights,
                    drm.solid_angle.equation(),
                    drm.samples_per_axis,
                    drm.samples_per_axis
                ));
            }
            ui.label("G  bounced light on/off");
            ui.label("M  next method");
            ui.label("P  next preset (RSM gather and DRM)");
            ui.label("E  DRM: next solid angle (Eq. 11, 14, 15)");
            ui.label("W  RSM gather: density or paper weights");
            ui.label("V  next debug view");
            ui.label("H  half resolution");
            ui.label(format!("B  block next to the light ({})", if example.block_near { "on" } else { "off" }));
            ui.label(format!("L  light motion ({})", if example.moving { "on" } else { "off" }));
        },
    );
    Ok(())
}
