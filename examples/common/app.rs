//! The windowed examples' shared app, built once: a standard scene (or a glTF file) whose camera gets
//! bounced light, an orbit/fly camera, method and preset keys, the tuning panel, a window with the keys,
//! and the CI harness ([`crate::common::CiCapturePlugin`]). Each example is a few lines on top
//! ([`ExampleSpec`] and, where it needs more, its own systems).
//!
//! Keys every example has: G bounced light on/off, M or 1–6 the method, P the preset of every method,
//! V the debug view, H half resolution, L the lights' motion, C orbit ↔ fly camera, F1 the panel.
//! Orbit: left drag turns, right or middle drag pans, the wheel zooms. Fly: W A S D move, Q E down/up,
//! Shift faster, right drag looks.
#![allow(dead_code, reason = "each example uses a different subset")]

use bevy::camera::Hdr;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll, MouseScrollUnit};
use bevy::prelude::*;
use bevy::render::diagnostic::RenderDiagnosticsPlugin;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::{DynamicScene, SceneCamera, SceneStatus, StandardScene, StandardScenesPlugin, mesh_bounds, spawn_standard_scene};

use crate::common::{CiStep, CiSteps};

/// What the CI harness steps through after its no-GI screenshot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CiMode {
    /// One screenshot, with the example's own method.
    OwnMethod,
    /// One screenshot per method, in [`GiMethod::ALL`] order.
    AllMethods,
    /// One screenshot per method of the list.
    Methods(&'static [GiMethod]),
    /// The example inserts its own [`CiSteps`] and answers [`CiStep`] itself.
    Custom,
}

/// What makes one windowed example.
#[derive(Clone, Debug)]
pub struct ExampleSpec {
    /// The binary's name (`--help`, the headless fallback's output file).
    pub tool: &'static str,
    /// The window title and `--help` text.
    pub title: &'static str,
    /// The scene shown without `--scene`.
    pub scene: &'static str,
    /// The camera's method at start.
    pub method: GiMethod,
    /// Whether the lights start swinging (L toggles it).
    pub light_motion: bool,
    /// Lines the example adds to the keys window (its own keys).
    pub extra_help: &'static [&'static str],
    pub ci: CiMode,
}

/// The example's state, for its keys and the keys window.
#[derive(Resource, Clone, Debug)]
pub struct Example {
    pub spec: ExampleSpec,
    pub scene: StandardScene,
    /// Index into [`PRESETS`].
    pub preset: usize,
    pub moving: bool,
}

pub const PRESETS: [&str; 3] = ["low", "medium", "high"];

/// Runs the example (`--scene NAME|PATH.glb` picks the scene); without a display, renders one frame
/// headless instead. `customise` adds the example's own systems.
pub fn run(spec: ExampleSpec, customise: impl FnOnce(&mut App)) -> AppExit {
    let mut scene = crate::common::example_scene(spec.tool, spec.title, spec.scene);
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return crate::common::render_headless(spec.tool, scene, spec.method);
    }
    // The asset server resolves relative paths against `assets/`: load the file the user named.
    if let StandardScene::Gltf(path) = &scene
        && let Ok(absolute) = std::fs::canonicalize(path)
    {
        scene = StandardScene::Gltf(absolute);
    }
    let mut app = App::new();
    app.add_plugins((
        DefaultPlugins.set(WindowPlugin {
            primary_window: Some(Window { title: format!("bevy_diffuse_gi — {}", spec.title), ..default() }),
            ..default()
        }),
        RenderDiagnosticsPlugin,
        // 1. The plugin, and its tuning panel.
        DiffuseGiPlugin::default(),
        DiffuseGiInspectorPlugin,
        StandardScenesPlugin,
        crate::common::CiCapturePlugin,
    ))
    .insert_resource(Example { spec: spec.clone(), scene, preset: 1, moving: spec.light_motion })
    .add_systems(Startup, setup)
    .add_systems(Update, (scene_failed, attach_gi, fit_volume, keys, camera_rig, move_lights))
    .add_systems(bevy_egui::EguiPrimaryContextPass, keys_window);
    match spec.ci {
        CiMode::OwnMethod => {
            app.insert_resource(CiSteps(vec![spec.method.name().to_string()])).add_systems(Update, ci_method_step);
        }
        CiMode::AllMethods => {
            app.insert_resource(CiSteps(GiMethod::ALL.iter().map(|m| m.name().to_string()).collect()))
                .add_systems(Update, ci_method_step);
        }
        CiMode::Methods(methods) => {
            app.insert_resource(CiSteps(methods.iter().map(|m| m.name().to_string()).collect()))
                .add_systems(Update, ci_method_step);
        }
        CiMode::Custom => {}
    }
    customise(&mut app);
    app.run()
}

fn setup(
    mut commands: Commands,
    example: Res<Example>,
    asset_server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    spawn_scene(&mut commands, &asset_server, &mut meshes, &mut materials, &example.scene);
}

/// Spawns `scene` (its meshes, lights with [`GiLight`] and [`SceneCamera`]); the camera gets its GI
/// components once the scene is ready ([`attach_gi`]) and a Radiance Hints volume is fitted around it
/// ([`fit_volume`]).
pub fn spawn_scene(
    commands: &mut Commands,
    asset_server: &AssetServer,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    scene: &StandardScene,
) {
    if *scene == StandardScene::Dynamic {
        // The scene's clock: the light orbits and one object moves.
        commands.insert_resource(DynamicScene { animate_light: true, moving_meshes: 1, ..default() });
    } else {
        commands.remove_resource::<DynamicScene>();
    }
    spawn_standard_scene(commands, asset_server, meshes, materials, scene, None);
}

/// A glTF that does not load ends the example at once, with the loader's message (it names the file).
fn scene_failed(status: Res<SceneStatus>, mut exit: MessageWriter<AppExit>) {
    if let SceneStatus::Failed(message) = &*status {
        error!("{message}");
        exit.write(AppExit::error());
    }
}

/// 2. The camera's GI: the method, and every method's settings so that M switches at run time.
pub fn gi_camera(method: GiMethod) -> impl Bundle {
    (
        DiffuseGi { method, ..default() },
        VplSettings::MEDIUM,
        RsmGatherSettings::MEDIUM,
        DrmSettings::MEDIUM,
        RadiositySettings::MEDIUM,
        PhotonGridSettings::MEDIUM,
        Hdr,
        Tonemapping::TonyMcMapface,
    )
}

/// Gives the scene's camera its GI components and a [`CameraRig`] once the scene is ready.
fn attach_gi(
    mut commands: Commands,
    example: Res<Example>,
    status: Res<SceneStatus>,
    cameras: Query<Entity, (With<SceneCamera>, Without<DiffuseGi>)>,
) {
    if *status != SceneStatus::Ready {
        return;
    }
    for camera in &cameras {
        commands.entity(camera).try_insert((gi_camera(example.spec.method), CameraRig::default()));
    }
}

/// A Radiance Hints volume around the scene's meshes (the medium preset, whose grid adapts to the box),
/// once they have bounds. It costs nothing while no camera uses Radiance Hints.
fn fit_volume(
    mut commands: Commands,
    example: Res<Example>,
    status: Res<SceneStatus>,
    volumes: Query<(), With<RadianceHintsVolume>>,
    meshes: Query<(&bevy::camera::primitives::Aabb, &GlobalTransform), With<Mesh3d>>,
) {
    if *status != SceneStatus::Ready || !volumes.is_empty() {
        return;
    }
    let Some((lo, hi)) = mesh_bounds(meshes.iter()) else {
        return;
    };
    let size = ((hi - lo) * 1.002).max(Vec3::splat(0.05));
    commands.spawn((
        volume_preset(example.preset),
        Transform::from_translation((lo + hi) * 0.5).with_scale(size),
        Name::new("RH volume"),
    ));
}

fn volume_preset(preset: usize) -> RadianceHintsVolume {
    [RadianceHintsVolume::LOW, RadianceHintsVolume::MEDIUM, RadianceHintsVolume::HIGH][preset.min(2)].clone()
}

/// The keys every example has.
fn keys(
    keys: Res<ButtonInput<KeyCode>>,
    wants: Option<Res<bevy_egui::input::EguiWantsInput>>,
    mut example: ResMut<Example>,
    mut cameras: Query<(
        &mut DiffuseGi,
        &mut VplSettings,
        &mut RsmGatherSettings,
        &mut DrmSettings,
        &mut RadiositySettings,
        &mut PhotonGridSettings,
    )>,
    mut volumes: Query<&mut RadianceHintsVolume>,
) {
    if wants.is_some_and(|w| w.wants_any_keyboard_input()) {
        return;
    }
    let digits = [KeyCode::Digit1, KeyCode::Digit2, KeyCode::Digit3, KeyCode::Digit4, KeyCode::Digit5, KeyCode::Digit6];
    for (mut gi, mut vpl, mut rsm, mut drm, mut radiosity, mut photon_grid) in &mut cameras {
        if keys.just_pressed(KeyCode::KeyG) {
            gi.enabled = !gi.enabled;
        }
        if keys.just_pressed(KeyCode::KeyM) {
            let i = GiMethod::ALL.iter().position(|m| *m == gi.method).unwrap_or(0);
            gi.method = GiMethod::ALL[(i + 1) % GiMethod::ALL.len()];
        }
        for (key, method) in digits.iter().zip(GiMethod::ALL) {
            if keys.just_pressed(*key) {
                gi.method = method;
            }
        }
        if keys.just_pressed(KeyCode::KeyV) {
            let views = GiDebugView::ALL;
            let i = views.iter().position(|v| *v == gi.debug_view).unwrap_or(0);
            gi.debug_view = views[(i + 1) % views.len()];
        }
        if keys.just_pressed(KeyCode::KeyH) {
            gi.half_resolution = !gi.half_resolution;
        }
        if keys.just_pressed(KeyCode::KeyP) {
            let p = (example.preset + 1) % PRESETS.len();
            *vpl = [VplSettings::LOW, VplSettings::MEDIUM, VplSettings::HIGH][p].clone();
            *rsm = [RsmGatherSettings::LOW, RsmGatherSettings::MEDIUM, RsmGatherSettings::HIGH][p].clone();
            *drm = [DrmSettings::LOW, DrmSettings::MEDIUM, DrmSettings::HIGH][p].clone();
            *radiosity = [RadiositySettings::LOW, RadiositySettings::MEDIUM, RadiositySettings::HIGH][p].clone();
            *photon_grid = [PhotonGridSettings::LOW, PhotonGridSettings::MEDIUM, PhotonGridSettings::HIGH][p].clone();
        }
    }
    if keys.just_pressed(KeyCode::KeyP) {
        example.preset = (example.preset + 1) % PRESETS.len();
        for mut volume in &mut volumes {
            *volume = volume_preset(example.preset);
        }
    }
    if keys.just_pressed(KeyCode::KeyL) {
        example.moving = !example.moving;
    }
}

/// L: swings the GI lights in a slow circle around where they started, so the bounced light follows.
fn move_lights(
    time: Res<Time>,
    example: Res<Example>,
    dynamic: Option<Res<DynamicScene>>,
    mut lights: Query<(Entity, &mut Transform), With<GiLight>>,
    mut start: Local<bevy::platform::collections::HashMap<Entity, Vec3>>,
) {
    // The `dynamic` scene moves its own light.
    if !example.moving || dynamic.is_some() {
        start.clear();
        return;
    }
    let t = time.elapsed_secs() * 0.4;
    for (entity, mut transform) in &mut lights {
        let origin = *start.entry(entity).or_insert(transform.translation);
        transform.translation = origin + Vec3::new(t.cos(), 0.0, t.sin()) * 0.3;
    }
}

/// An orbit camera (around a target) or a fly camera; C switches. Set up from the camera's transform
/// and the scene's size the first time it runs.
#[derive(Component, Default, Clone, Debug)]
pub struct CameraRig {
    pub fly: bool,
    pub target: Vec3,
    pub distance: f32,
    pub yaw: f32,
    pub pitch: f32,
    /// The scene's diagonal, metres: the speed of panning and flying.
    pub scale: f32,
    ready: bool,
}

impl CameraRig {
    fn look_from(&mut self, transform: &Transform) {
        let forward = transform.forward();
        self.pitch = forward.y.clamp(-1.0, 1.0).asin();
        self.yaw = forward.x.atan2(-forward.z);
        self.target = transform.translation + forward * self.distance;
    }

    fn forward(&self) -> Vec3 {
        Vec3::new(self.yaw.sin() * self.pitch.cos(), self.pitch.sin(), -self.yaw.cos() * self.pitch.cos())
    }
}

#[expect(clippy::too_many_arguments, reason = "reads every input the camera follows")]
fn camera_rig(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    buttons: Res<ButtonInput<MouseButton>>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    wants: Option<Res<bevy_egui::input::EguiWantsInput>>,
    meshes: Query<(&bevy::camera::primitives::Aabb, &GlobalTransform), With<Mesh3d>>,
    mut cameras: Query<(&mut CameraRig, &mut Transform)>,
) {
    let pointer_free = !wants.as_ref().is_some_and(|w| w.wants_any_pointer_input());
    let keys_free = !wants.as_ref().is_some_and(|w| w.wants_any_keyboard_input());
    for (mut rig, mut transform) in &mut cameras {
        if !rig.ready {
            let Some((lo, hi)) = mesh_bounds(meshes.iter()) else {
                continue;
            };
            rig.scale = (hi - lo).length().max(0.1);
            // Orbit around the point in front of the camera as far away as the scene's centre.
            rig.distance = ((lo + hi) * 0.5 - transform.translation).dot(*transform.forward()).max(0.05 * rig.scale);
            rig.look_from(&transform);
            rig.ready = true;
        }
        if keys_free && keys.just_pressed(KeyCode::KeyC) {
            rig.fly = !rig.fly;
            if !rig.fly {
                rig.look_from(&transform);
            }
        }
        let mut turned = false;
        let drag = motion.delta * 0.005;
        if pointer_free && drag != Vec2::ZERO {
            let look = if rig.fly { buttons.pressed(MouseButton::Right) } else { buttons.pressed(MouseButton::Left) };
            if look {
                rig.yaw += drag.x;
                rig.pitch = (rig.pitch - drag.y).clamp(-1.5, 1.5);
                turned = true;
            }
            if !rig.fly && (buttons.pressed(MouseButton::Right) || buttons.pressed(MouseButton::Middle)) {
                let pan = (transform.left() * drag.x + transform.up() * drag.y) * rig.distance * 0.5;
                rig.target += pan;
                turned = true;
            }
        }
        if pointer_free && !rig.fly && scroll.delta.y != 0.0 {
            let lines = match scroll.unit {
                MouseScrollUnit::Line => scroll.delta.y,
                MouseScrollUnit::Pixel => scroll.delta.y / 40.0,
            };
            rig.distance = (rig.distance * 0.9f32.powf(lines)).clamp(0.01 * rig.scale, 4.0 * rig.scale);
            turned = true;
        }
        let mut step = Vec3::ZERO;
        if rig.fly && keys_free {
            for (key, direction) in [
                (KeyCode::KeyW, *transform.forward()),
                (KeyCode::KeyS, *transform.back()),
                (KeyCode::KeyA, *transform.left()),
                (KeyCode::KeyD, *transform.right()),
                (KeyCode::KeyE, Vec3::Y),
                (KeyCode::KeyQ, Vec3::NEG_Y),
            ] {
                if keys.pressed(key) {
                    step += direction;
                }
            }
            let fast = if keys.pressed(KeyCode::ShiftLeft) { 4.0 } else { 1.0 };
            step = step.normalize_or_zero() * rig.scale * 0.15 * fast * time.delta_secs();
        }
        if !turned && step == Vec3::ZERO {
            continue;
        }
        let forward = rig.forward();
        if rig.fly {
            let position = transform.translation + step;
            *transform = Transform::from_translation(position).looking_to(forward, Vec3::Y);
        } else {
            let position = rig.target - forward * rig.distance;
            *transform = Transform::from_translation(position).looking_to(forward, Vec3::Y);
        }
    }
}

/// The keys, in a small window at the bottom left (the tuning panel is the larger one).
fn keys_window(
    mut contexts: bevy_egui::EguiContexts,
    example: Res<Example>,
    cameras: Query<(&DiffuseGi, Option<&CameraRig>)>,
) -> Result {
    use bevy_egui::egui;
    egui::Window::new("Keys").anchor(egui::Align2::LEFT_BOTTOM, [8.0, -8.0]).min_width(440.0).show(contexts.ctx_mut()?, |ui| {
        ui.label(format!("{} — scene {} — preset {}", example.spec.title, example.scene.name(), PRESETS[example.preset]));
        for (gi, rig) in &cameras {
            ui.label(format!(
                "method {} ({}), view {:?}, {} camera",
                gi.method.name(),
                if gi.enabled { "on" } else { "off" },
                gi.debug_view,
                if rig.is_some_and(|r| r.fly) { "fly" } else { "orbit" }
            ));
        }
        ui.label(format!(
            "G bounced light  M/1-6 method  P preset  V view  H half res  L lights ({})",
            if example.moving { "moving" } else { "still" }
        ));
        ui.label("C orbit/fly  F1 panel  orbit: drag turns, right drag pans, wheel zooms");
        ui.label("fly: W A S D Q E (Shift: faster), right drag looks");
        for line in example.spec.extra_help {
            ui.label(*line);
        }
    });
    Ok(())
}

/// CI: step `i` shows the `i`-th method of [`CiSteps`].
fn ci_method_step(mut steps: MessageReader<CiStep>, labels: Res<CiSteps>, mut cameras: Query<&mut DiffuseGi>) {
    for CiStep(i) in steps.read() {
        let Some(method) = labels.0.get(*i).and_then(|l| GiMethod::ALL.into_iter().find(|m| m.name() == l)) else {
            continue;
        };
        for mut gi in &mut cameras {
            gi.method = method;
        }
    }
}
