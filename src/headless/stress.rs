//! The stress matrix: inputs a game can throw at the plugin — lights from 10⁻⁶ to 10⁹ cd, zero-size,
//! flat, degenerate, mirrored and non-finite geometry and materials, a camera inside a mesh or a kilometre
//! away behind a telephoto lens, scenes at 10⁻² and 10³ times their size, an empty scene, GI lights without shadows and more of
//! them than Bevy draws. Every method renders each case headless: it must finish without a panic, no
//! frame read back may hold NaN or infinity, the plugin must log exactly one warning per bad input
//! (and none for inputs that are merely unusual), and the bounced light must be what the case leaves of
//! it ([`LightCheck`]: a scaled scene scales it by the inverse square, unchanged geometry elsewhere keeps
//! it) against the same method on the unchanged scene. `tests/gpu_stress.rs` runs it; `gi_bench --stress`
//! writes what each case produced into `docs/benchmark.md`.

use bevy::prelude::*;

use super::{HeadlessMethod, HeadlessOptions};
use crate::camera::GiMethod;
use crate::light::GiLight;
use crate::scenes::{SceneCamera, SceneStatus, StandardScene};

/// One input of the matrix.
#[derive(Clone, Copy, Debug)]
pub struct StressCase {
    pub name: &'static str,
    /// What the case does to the scene, for the report.
    pub description: &'static str,
    /// The warnings the plugin must log: one per bad input.
    pub expected_warnings: usize,
    /// What the bounced light must do against the unchanged scene's.
    pub light: LightCheck,
    /// Changes the world once the scene has shown for a few frames (after the headless renderer fitted
    /// its Radiance Hints volume to it).
    pub apply: fn(&mut World),
}

/// What a case must leave of the bounced light (the mean luminance of the covered pixels), against the
/// same method on the unchanged scene (the `baseline` case).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightCheck {
    /// Anything finite (the case removes what the light bounces off, or what the camera sees).
    Any,
    /// Some bounced light.
    Some,
    /// The unchanged scene's times this factor, within a factor of two either way.
    Scaled(f64),
}

/// What one method made of one case.
#[derive(Clone, Debug)]
pub struct StressOutcome {
    pub case: &'static str,
    pub method: GiMethod,
    /// `Err` when the run failed, read back a non-finite value or panicked.
    pub result: Result<(), String>,
    /// The plugin's warnings.
    pub warnings: Vec<String>,
    /// Mean luminance of the last frame over the covered pixels (0 with nothing covered).
    pub mean_luminance: f64,
    /// Share of the pixels covered by geometry.
    pub coverage: f64,
    /// Whether a CPU method's background work was still running after [`STRESS_WAIT_SECONDS`].
    pub background_timed_out: bool,
    /// Wall-clock seconds of the run.
    pub seconds: f64,
}

impl StressOutcome {
    /// Whether the outcome is what the case asks for: finished, finite, the expected warnings, each logged
    /// once, and the bounced light [`StressCase::light`] asks for, against `baseline` (the same method's
    /// mean luminance on the unchanged scene; the light is not checked without one, nor while a CPU
    /// method's background work is still running).
    pub fn verdict(&self, case: &StressCase, baseline: Option<f64>) -> Result<(), String> {
        self.result.clone()?;
        // A CPU method whose background work outlasted the wait shows an older solution (or none yet):
        // its light says nothing about the case, only its stability does.
        let light = if self.background_timed_out { LightCheck::Any } else { case.light };
        match (light, baseline) {
            (LightCheck::Some, _) if self.mean_luminance <= 0.0 => return Err("no bounced light".into()),
            (LightCheck::Scaled(factor), Some(base)) => {
                let ratio = self.mean_luminance / (base * factor);
                if !(0.5..=2.0).contains(&ratio) {
                    return Err(format!(
                        "bounced light {:.3e}: {ratio:.3} of the unchanged scene's {base:.3e} × {factor:e}",
                        self.mean_luminance
                    ));
                }
            }
            _ => {}
        }
        let mut distinct = self.warnings.clone();
        distinct.sort();
        distinct.dedup();
        if distinct.len() != self.warnings.len() {
            return Err(format!("a warning was logged more than once: {:?}", self.warnings));
        }
        if self.warnings.len() != case.expected_warnings {
            return Err(format!("{} warnings instead of {}: {:?}", self.warnings.len(), case.expected_warnings, self.warnings));
        }
        Ok(())
    }
}

/// At most this long for a CPU method's background work in a stress run, seconds: a case may leave a
/// solve running longer (the report says which); the frames read back meanwhile are checked all the same.
pub const STRESS_WAIT_SECONDS: u32 = 20;

/// The frame (after the scene shows) at which a case changes the world.
const APPLY_AT: u32 = 3;

/// Every case, on `cornell` (a spot light, a box room).
pub fn stress_cases() -> Vec<StressCase> {
    vec![
        StressCase {
            name: "baseline",
            description: "the scene unchanged (the other cases' light is measured against it)",
            expected_warnings: 0,
            light: LightCheck::Some,
            apply: |_| {},
        },
        StressCase {
            name: "dim_lights",
            description: "every GI light at 10⁻⁶ cd (lux for the sun); its bounced light may round to zero in the half-float RSM",
            expected_warnings: 0,
            light: LightCheck::Any,
            apply: |world| set_light_intensity(world, 1e-6),
        },
        StressCase {
            name: "bright_lights",
            description: "every GI light at 10⁹ cd (lux for the sun); the bounced light is clamped to the half-float maximum",
            expected_warnings: 0,
            light: LightCheck::Some,
            apply: |world| set_light_intensity(world, 1e9),
        },
        StressCase {
            name: "odd_geometry",
            description: "on the floor: a mesh scaled to zero, a flat box, a mesh of one point, a mesh squashed flat, one mirrored and one inside out",
            expected_warnings: 0,
            light: LightCheck::Scaled(1.0),
            apply: odd_geometry,
        },
        StressCase {
            name: "non_finite",
            description: "NaN in a mesh's translation, ∞ in another's scale, NaN base colour and ∞ emission in two materials, NaN intensity on a second GI light",
            expected_warnings: 5,
            light: LightCheck::Some,
            apply: non_finite,
        },
        StressCase {
            name: "camera_inside_geometry",
            description: "the camera inside a closed, double-sided box",
            expected_warnings: 0,
            light: LightCheck::Any,
            apply: camera_inside_geometry,
        },
        StressCase {
            name: "camera_far_outside",
            description: "the camera 1 km away behind a 0.2° telephoto lens (far plane 2 km)",
            expected_warnings: 0,
            light: LightCheck::Some,
            apply: |world| move_camera(world, Vec3::splat(1.0e3 / 3f32.sqrt()), 0.2, 2.0e3),
        },
        StressCase {
            name: "tiny_scene",
            description: "everything scaled by 10⁻² (a 2 cm box): the same light 100 times closer, 10⁴ times the bounced light",
            expected_warnings: 0,
            light: LightCheck::Scaled(1e4),
            apply: |world| super::scale_world(world, 1e-2),
        },
        StressCase {
            name: "huge_scene",
            description: "everything scaled by 10³ (a 2 km box): 10⁻⁶ times the bounced light",
            expected_warnings: 0,
            light: LightCheck::Scaled(1e-6),
            apply: |world| super::scale_world(world, 1e3),
        },
        StressCase {
            name: "empty_scene",
            description: "every mesh despawned",
            expected_warnings: 0,
            light: LightCheck::Any,
            apply: |world| {
                let meshes: Vec<Entity> = world.query_filtered::<Entity, With<Mesh3d>>().iter(world).collect();
                for entity in meshes {
                    world.despawn(entity);
                }
            },
        },
        StressCase {
            name: "lights_without_shadow_maps",
            description: "the GI light without shadows, and twelve GI suns (Bevy draws ten directional lights)",
            expected_warnings: 1,
            light: LightCheck::Some,
            apply: lights_without_shadow_maps,
        },
    ]
}

/// The headless options of a stress run: small, few frames, every frame read back, each method's `LOW`
/// preset (the same passes as the others, in a fraction of the time). Indirect light only: what the
/// plugin adds to the HDR target (Bevy's own direct light of a NaN light or an infinite emission is
/// Bevy's).
pub fn stress_options(method: GiMethod) -> HeadlessOptions {
    HeadlessOptions {
        rh: crate::radiance_hints::RadianceHintsVolume::LOW,
        vpl: crate::vpl::VplSettings::LOW,
        rsm_gather: crate::rsm_gather::RsmGatherSettings::LOW,
        drm: crate::drm::DrmSettings::LOW,
        radiosity: crate::radiosity::RadiositySettings::LOW,
        photon_grid: crate::photon_grid::PhotonGridSettings::LOW,
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(method),
        indirect_only: true,
        size: UVec2::splat(32),
        frames: 6,
        wait_background: Some(STRESS_WAIT_SECONDS),
        ..Default::default()
    }
}

/// Renders `case` with `method` (see [`stress_options`]), catching a panic.
pub fn run_stress(case: &StressCase, method: GiMethod) -> StressOutcome {
    let apply = case.apply;
    let options = stress_options(method);
    let started = std::time::Instant::now();
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        super::run_with(&options, move |app| {
            app.add_systems(Update, move |world: &mut World, mut frames: Local<u32>| {
                if world.get_resource::<SceneStatus>() != Some(&SceneStatus::Ready) {
                    return;
                }
                *frames += 1;
                if *frames == APPLY_AT {
                    apply(world);
                }
            });
        })
    }));
    let mut outcome = StressOutcome {
        case: case.name,
        method,
        result: Ok(()),
        warnings: Vec::new(),
        mean_luminance: 0.0,
        coverage: 0.0,
        background_timed_out: false,
        seconds: started.elapsed().as_secs_f64(),
    };
    match run {
        Err(panic) => {
            let message = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic".into());
            outcome.result = Err(format!("panicked: {message}"));
        }
        Ok(Err(message)) => outcome.result = Err(message),
        Ok(Ok(report)) => {
            outcome.background_timed_out = report.sidecar["background_timed_out"].as_bool().unwrap_or(false);
            outcome.warnings = report.sidecar["warnings"]
                .as_array()
                .map(|a| a.iter().filter_map(|w| w.as_str().map(str::to_string)).collect())
                .unwrap_or_default();
            let image = &report.image;
            let covered = (0..image.pixels.len()).filter(|&i| image.covered(i)).count();
            outcome.coverage = covered as f64 / image.pixels.len().max(1) as f64;
            outcome.mean_luminance = image
                .region_mean(0, 0, image.width, image.height)
                .map_or(0.0, |[r, g, b]| (0.2126 * r + 0.7152 * g + 0.0722 * b) as f64);
            if report.image.has_non_finite() {
                outcome.result = Err("the image holds NaN or infinity".into());
            }
        }
    }
    outcome
}

/// Sets every GI light to `candela` (spot and point: `candela × 4π` lumens; suns: `candela` lux).
fn set_light_intensity(world: &mut World, candela: f32) {
    let mut lights = world.query_filtered::<(Option<&mut SpotLight>, Option<&mut PointLight>, Option<&mut DirectionalLight>), With<GiLight>>();
    for (spot, point, sun) in lights.iter_mut(world) {
        if let Some(mut s) = spot {
            s.intensity = candela * 4.0 * std::f32::consts::PI;
        }
        if let Some(mut p) = point {
            p.intensity = candela * 4.0 * std::f32::consts::PI;
        }
        if let Some(mut d) = sun {
            d.illuminance = candela;
        }
    }
}

/// The mesh entities of the scene, in spawn order.
fn meshes(world: &mut World) -> Vec<Entity> {
    let mut list: Vec<Entity> = world.query_filtered::<Entity, With<Mesh3d>>().iter(world).collect();
    list.sort();
    list
}

fn grey(world: &mut World) -> Handle<StandardMaterial> {
    world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial::from(Color::srgb(0.6, 0.6, 0.6)))
}

fn odd_geometry(world: &mut World) {
    let material = grey(world);
    let (cube, flat, point) = {
        let mut meshes = world.resource_mut::<Assets<Mesh>>();
        let point = Mesh::from(Triangle3d::new(Vec3::ZERO, Vec3::ZERO, Vec3::ZERO));
        (meshes.add(Cuboid::new(0.3, 0.3, 0.3)), meshes.add(Cuboid::new(0.4, 0.0, 0.4)), meshes.add(point))
    };
    // Near the floor at the front, away from the light and the two boxes.
    let centre = Vec3::new(0.0, -0.8, 0.55);
    world.spawn((Mesh3d(cube.clone()), MeshMaterial3d(material.clone()), Transform::from_translation(centre).with_scale(Vec3::ZERO)));
    world.spawn((Mesh3d(flat), MeshMaterial3d(material.clone()), Transform::from_translation(centre + Vec3::X * 0.3)));
    world.spawn((Mesh3d(point), MeshMaterial3d(material.clone()), Transform::from_translation(centre - Vec3::X * 0.3)));
    world.spawn((Mesh3d(cube.clone()), MeshMaterial3d(material.clone()), Transform::from_translation(centre + Vec3::Z * 0.25).with_scale(Vec3::new(1.0, 0.0, 1.0))));
    world.spawn((Mesh3d(cube.clone()), MeshMaterial3d(material.clone()), Transform::from_translation(centre + Vec3::X * 0.6).with_scale(Vec3::new(-1.0, 1.0, 1.0))));
    world.spawn((Mesh3d(cube), MeshMaterial3d(material), Transform::from_translation(centre - Vec3::X * 0.6).with_scale(Vec3::splat(-1.0))));
}

fn non_finite(world: &mut World) {
    let list = meshes(world);
    let nan_base = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::LinearRgba(LinearRgba::new(f32::NAN, 0.5, 0.5, 1.0)),
        ..default()
    });
    let infinite_emission = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        emissive: LinearRgba::new(f32::INFINITY, 1.0, 1.0, 1.0),
        ..default()
    });
    let cube = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(0.2, 0.2, 0.2));
    world.spawn((Mesh3d(cube.clone()), MeshMaterial3d(nan_base), Transform::from_xyz(0.3, 0.2, 0.3)));
    world.spawn((Mesh3d(cube.clone()), MeshMaterial3d(infinite_emission), Transform::from_xyz(-0.3, 0.2, 0.3)));
    if let Some(&first) = list.first() {
        world.entity_mut(first).insert(Transform::from_xyz(f32::NAN, 0.0, 0.0));
    }
    if let Some(&second) = list.get(1) {
        world.entity_mut(second).insert(Transform::from_scale(Vec3::new(f32::INFINITY, 1.0, 1.0)));
    }
    world.spawn((
        SpotLight { intensity: f32::NAN, shadow_maps_enabled: true, ..default() },
        Transform::from_xyz(0.0, 1.5, 0.0).looking_at(Vec3::ZERO, Vec3::Z),
        GiLight::default(),
    ));
}

fn camera_inside_geometry(world: &mut World) {
    let Some(position) = world.query_filtered::<&Transform, With<SceneCamera>>().iter(world).next().map(|t| t.translation) else {
        return;
    };
    // Double-sided, so that the camera sees its inside (a back face would be culled and seen through).
    let material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::srgb(0.6, 0.6, 0.6),
        cull_mode: None,
        double_sided: true,
        ..default()
    });
    let cube = world.resource_mut::<Assets<Mesh>>().add(Cuboid::new(0.6, 0.6, 0.6));
    world.spawn((Mesh3d(cube), MeshMaterial3d(material), Transform::from_translation(position)));
}

/// Puts the camera at `position` looking at the middle of the box, with a vertical field of view of
/// `fov_degrees` and the far plane at `far`.
fn move_camera(world: &mut World, position: Vec3, fov_degrees: f32, far: f32) {
    let mut cameras = world.query_filtered::<(&mut Transform, &mut Projection), With<SceneCamera>>();
    for (mut transform, mut projection) in cameras.iter_mut(world) {
        *transform = Transform::from_translation(position).looking_at(Vec3::new(0.0, 1.0, 0.0), Vec3::Y);
        if let Projection::Perspective(p) = &mut *projection {
            p.fov = fov_degrees.to_radians();
            p.far = far;
        }
    }
}

fn lights_without_shadow_maps(world: &mut World) {
    let mut lights = world.query_filtered::<(Option<&mut SpotLight>, Option<&mut PointLight>, Option<&mut DirectionalLight>), With<GiLight>>();
    for (spot, point, sun) in lights.iter_mut(world) {
        if let Some(mut s) = spot {
            s.shadow_maps_enabled = false;
        }
        if let Some(mut p) = point {
            p.shadow_maps_enabled = false;
        }
        if let Some(mut d) = sun {
            d.shadow_maps_enabled = false;
        }
    }
    for i in 0..12 {
        let angle = i as f32 * 0.5;
        world.spawn((
            DirectionalLight { illuminance: 50.0, shadow_maps_enabled: true, ..default() },
            Transform::from_xyz(angle.cos(), 2.0, angle.sin()).looking_at(Vec3::ZERO, Vec3::Y),
            GiLight { rsm_resolution: 64 },
        ));
    }
}
