//! Every standard scene with every method: a slide show that moves on every 12 seconds (Space stops and
//! starts it, N shows the next slide at once). Each slide is a scene with a method; the methods of one
//! scene follow each other, then the next scene comes.
//!
//! `cargo run --release --features tools --example showcase`
//!
//! Keys: the common ones (G bounced light, M or 1–6 the method, P preset, V debug view, H half resolution,
//! L the lights' motion, C orbit ↔ fly camera, F1 the panel), and N next slide, Space auto-advance.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame of
//! `cornell` headless on whatever Vulkan device exists and writes `out/showcase.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::camera::Exposure;
use bevy::light::{DirectionalLight, PointLight, SpotLight};
use bevy::prelude::*;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::scenes::{SceneCamera, StandardScene};

/// The scenes of the show, in order.
const SCENES: [StandardScene; 7] = [
    StandardScene::Cornell,
    StandardScene::Cellar,
    StandardScene::SponzaLike,
    StandardScene::OpenField,
    StandardScene::Dynamic,
    StandardScene::EmissivePanel,
    StandardScene::SkyRoom,
];

/// Seconds per slide.
const SLIDE_SECONDS: f32 = 12.0;

/// What CI shows, one screenshot each: every scene once and every method at least once (the emissive
/// panel with radiosity and the sky-lit room with the photon grid, which need no light's shadow map).
const CI_SLIDES: [(usize, GiMethod); 7] = [
    (0, GiMethod::RadianceHints),
    (1, GiMethod::Vpl),
    (2, GiMethod::RsmGather),
    (3, GiMethod::Drm),
    (4, GiMethod::Vpl),
    (5, GiMethod::Radiosity),
    (6, GiMethod::PhotonGrid),
];

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "showcase",
            title: "showcase: every scene, every method",
            scene: "cornell",
            method: GiMethod::RadianceHints,
            light_motion: false,
            extra_help: &["N  next slide    Space  auto-advance on/off"],
            ci: app::CiMode::Custom,
        },
        |app| {
            app.insert_resource(common::CiSteps(
                CI_SLIDES.iter().map(|(scene, method)| format!("{}_{}", SCENES[*scene].name(), method.name())).collect(),
            ))
            .insert_resource(Show { slide: 0, auto: true, since: 0.0, pending: None })
            .add_systems(Update, (slides, ci_slides))
            .add_observer(adopt_scene_camera)
            .add_systems(bevy_egui::EguiPrimaryContextPass, slide_window);
        },
    )
}

#[derive(Resource)]
struct Show {
    /// Scene index × methods + method index.
    slide: usize,
    auto: bool,
    /// Seconds on this slide.
    since: f32,
    /// The slide to switch to this frame.
    pending: Option<(usize, GiMethod)>,
}

/// The camera that stays from slide to slide (it holds the GI settings and the panel's egui context); a
/// new scene's own camera only lends it its view.
#[derive(Component)]
struct ShowCamera;

fn slides(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    mut show: ResMut<Show>,
    ci: Option<Res<common::CiSteps>>,
    capture: Option<Res<bevy::time::TimeUpdateStrategy>>,
    mut switch: SceneSwitch,
) {
    // Under the CI harness (fixed frame time) the slides follow its steps instead of the clock.
    let under_ci = ci.is_some() && capture.is_some_and(|c| matches!(*c, bevy::time::TimeUpdateStrategy::ManualDuration(_)));
    if keys.just_pressed(KeyCode::Space) {
        show.auto = !show.auto;
    }
    show.since += time.delta_secs();
    let methods = GiMethod::ALL.len();
    let mut next = show.pending.take();
    if next.is_none() && (keys.just_pressed(KeyCode::KeyN) || (show.auto && !under_ci && show.since > SLIDE_SECONDS)) {
        let slide = (show.slide + 1) % (SCENES.len() * methods);
        next = Some((slide / methods, GiMethod::ALL[slide % methods]));
    }
    let Some((scene, method)) = next else {
        return;
    };
    let index = GiMethod::ALL.iter().position(|m| *m == method).unwrap_or(0);
    let old_scene = show.slide / methods;
    show.slide = scene * methods + index;
    show.since = 0.0;
    switch.show(scene != old_scene, scene, method);
}

/// CI step `i` shows [`CI_SLIDES`]`[i]`.
fn ci_slides(mut steps: MessageReader<common::CiStep>, mut show: ResMut<Show>) {
    for common::CiStep(i) in steps.read() {
        if let Some(&slide) = CI_SLIDES.get(*i) {
            show.pending = Some(slide);
        }
    }
}

/// Everything a slide change touches.
#[derive(bevy::ecs::system::SystemParam)]
struct SceneSwitch<'w, 's> {
    commands: Commands<'w, 's>,
    example: ResMut<'w, app::Example>,
    asset_server: Res<'w, AssetServer>,
    meshes: ResMut<'w, Assets<Mesh>>,
    materials: ResMut<'w, Assets<StandardMaterial>>,
    cameras: Query<'w, 's, (Entity, &'static mut DiffuseGi), With<ShowCamera>>,
    scene_entities: Query<
        'w,
        's,
        Entity,
        (
            Or<(With<Mesh3d>, With<PointLight>, With<SpotLight>, With<DirectionalLight>, With<RadianceHintsVolume>, With<SceneCamera>)>,
            Without<ShowCamera>,
        ),
    >,
}

impl SceneSwitch<'_, '_> {
    fn show(&mut self, new_scene: bool, scene: usize, method: GiMethod) {
        for (_, mut gi) in &mut self.cameras {
            gi.method = method;
        }
        if !new_scene {
            return;
        }
        // A scene that lights itself with the sky gives the camera its environment map (`sky_room`);
        // the next scene starts without it.
        for (camera, _) in &self.cameras {
            self.commands.entity(camera).remove::<bevy::light::EnvironmentMapLight>();
        }
        for entity in &self.scene_entities {
            self.commands.entity(entity).despawn();
        }
        self.example.scene = SCENES[scene].clone();
        app::spawn_scene(&mut self.commands, &self.asset_server, &mut self.meshes, &mut self.materials, &SCENES[scene]);
    }
}

/// The first scene's camera stays; each later scene's camera, as it is spawned, gives it its place, lens
/// and exposure and goes (an observer, so that no frame renders through two cameras).
fn adopt_scene_camera(
    add: On<Add, SceneCamera>,
    mut commands: Commands,
    new: Query<(&Transform, &Projection, &Exposure), Without<ShowCamera>>,
    kept: Query<Entity, With<ShowCamera>>,
) {
    let entity = add.event_target();
    let Ok((transform, projection, exposure)) = new.get(entity) else {
        return;
    };
    match kept.single() {
        Ok(camera) => {
            commands.entity(camera).insert((*transform, projection.clone(), *exposure, app::CameraRig::default()));
            commands.entity(entity).despawn();
        }
        Err(_) => {
            commands.entity(entity).insert(ShowCamera);
        }
    }
}

fn slide_window(mut contexts: bevy_egui::EguiContexts, show: Res<Show>, example: Res<app::Example>) -> Result {
    use bevy_egui::egui;
    let methods = GiMethod::ALL.len();
    egui::Window::new("Showcase").anchor(egui::Align2::LEFT_TOP, [8.0, 8.0]).show(contexts.ctx_mut()?, |ui| {
        ui.label(format!(
            "slide {} of {}: {} with {}",
            show.slide + 1,
            SCENES.len() * methods,
            example.scene.name(),
            GiMethod::ALL[show.slide % methods].name()
        ));
        ui.label(if show.auto { format!("next in {:.0} s", (SLIDE_SECONDS - show.since).max(0.0)) } else { "paused".into() });
    });
    Ok(())
}
