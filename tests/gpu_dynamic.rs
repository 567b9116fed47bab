//! Dynamic scenes on the GPU (lavapipe in CI): lights and meshes that change, move, appear and go away
//! while the plugin renders. Each test changes the world from a system added through
//! `headless::run_with`, at a rendering frame read from `HeadlessClock`.
#![cfg(feature = "gpu_tests")]

mod common;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::{DiffuseGi, GiMethod};
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessClock, HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::light::GiLight;
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::radiance_hints::RadianceHintsVolume;
use bevy_diffuse_gi::scenes::StandardScene;
use bevy_diffuse_gi::scenes::dynamic::DynamicObject;
use common::{check, render_lock};

fn options(scene: StandardScene, method: GiMethod, size: u32, frames: u32) -> HeadlessOptions {
    HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(method),
        indirect_only: true,
        size: UVec2::splat(size),
        frames,
        ..Default::default()
    }
}

fn run_with(options: &HeadlessOptions, customise: impl FnOnce(&mut App)) -> HdrImage {
    let _guard = render_lock();
    headless::run_with(options, customise).unwrap_or_else(|e| panic!("headless render failed: {e}")).image
}

fn energy(image: &HdrImage) -> f64 {
    image.pixels.iter().filter(|p| p[3] > 0.5).map(|p| (p[0] + p[1] + p[2]) as f64).sum()
}

/// Doubles every GI light's intensity at rendering frame 2.
fn double_intensity(clock: Res<HeadlessClock>, mut spots: Query<&mut SpotLight, With<GiLight>>) {
    if clock.rendering && clock.frame == 2 {
        for mut spot in &mut spots {
            spot.intensity *= 2.0;
        }
    }
}

#[test]
fn an_intensity_change_alone_scales_the_bounced_light_by_the_same_factor() {
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        let test = format!("dynamic_intensity_{}", method.name());
        let o = options(StandardScene::Cornell, method, 96, 40);
        let once = run_with(&o, |_| {});
        let doubled = run_with(&o, |app| {
            app.add_systems(Update, double_intensity);
        });
        let ratio = energy(&doubled) / energy(&once).max(1e-12);
        check(&test, energy(&once) > 0.0, &once, None, format!("{}: no bounced light at all", method.name()));
        check(
            &test,
            (ratio - 2.0).abs() <= 0.04,
            &doubled,
            Some(&once),
            format!("{}: doubling the light's intensity scaled the bounced light by {ratio:.4}, not 2 ± 2 %", method.name()),
        );
    }
}

#[test]
fn a_removed_light_leaves_no_bounced_light_behind() {
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        let test = format!("dynamic_light_removed_{}", method.name());
        let o = options(StandardScene::Cornell, method, 96, 30);
        let lit = run_with(&o, |_| {});
        let removed = run_with(&o, |app| {
            app.add_systems(Update, |clock: Res<HeadlessClock>, mut commands: Commands, lights: Query<Entity, With<GiLight>>| {
                if clock.rendering && clock.frame == 3 {
                    for light in &lights {
                        commands.entity(light).despawn();
                    }
                }
            });
        });
        let left = energy(&removed) / energy(&lit).max(1e-12);
        check(
            &test,
            left < 0.01,
            &removed,
            Some(&lit),
            format!("{}: {:.2} % of the bounced light stayed after its light was removed", method.name(), left * 100.0),
        );
    }
}

#[test]
fn removed_meshes_leave_no_bounced_light_behind() {
    // The dynamic scene's coloured objects, removed while rendering, against a run where they were
    // removed before the first frame: the same image, up to the method's noise.
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        let test = format!("dynamic_mesh_removed_{}", method.name());
        let o = options(StandardScene::Dynamic, method, 96, 30);
        let remove_at = |at: Option<u32>| {
            move |clock: Res<HeadlessClock>, mut commands: Commands, objects: Query<Entity, With<DynamicObject>>| {
                let now = match at {
                    Some(frame) => clock.rendering && clock.frame == frame,
                    None => true,
                };
                if now {
                    for object in &objects {
                        commands.entity(object).despawn();
                    }
                }
            }
        };
        let never = run_with(&o, |app| {
            app.add_systems(Update, remove_at(None));
        });
        let later = run_with(&o, |app| {
            app.add_systems(Update, remove_at(Some(3)));
        });
        let with_objects = run_with(&o, |_| {});
        let m = metrics::compare(&later, &never).expect("same size");
        let from_objects = metrics::compare(&with_objects, &never).expect("same size");
        check(
            &test,
            m.block_relative_rmse < 0.5 * from_objects.block_relative_rmse && (m.energy_ratio - 1.0).abs() < 0.05,
            &later,
            Some(&never),
            format!(
                "{}: after removing the objects the image is {:.3} block RMSE / {:.3} energy from the scene without \
                 them (with the objects: {:.3} / {:.3})",
                method.name(),
                m.block_relative_rmse,
                m.energy_ratio,
                from_objects.block_relative_rmse,
                from_objects.energy_ratio
            ),
        );
    }
}

/// Every frame something changes: lights and meshes added and removed, objects and a light moving, the
/// volume moved and resized and its resolution changed, the camera's viewport resized. From
/// [`CHURN_ENDS`] on, everything the churn added is gone and the scene is the still `dynamic` again.
#[derive(Resource, Default)]
struct Churn {
    lights: Vec<Entity>,
    meshes: Vec<Entity>,
    mesh: Option<Handle<Mesh>>,
    material: Option<Handle<StandardMaterial>>,
}

#[allow(clippy::too_many_arguments, reason = "a system that changes everything")]
fn churn(
    clock: Res<HeadlessClock>,
    mut state: ResMut<Churn>,
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut volumes: Query<(&mut RadianceHintsVolume, &mut Transform), Without<Camera>>,
    mut cameras: Query<&mut Camera, With<DiffuseGi>>,
    mut scene: Option<ResMut<bevy_diffuse_gi::scenes::DynamicScene>>,
) {
    if !clock.rendering || clock.frame > CHURN_ENDS {
        return;
    }
    let f = clock.frame;
    let t = f as f32;
    if f == CHURN_ENDS {
        let state = &mut *state;
        for entity in state.lights.drain(..).chain(state.meshes.drain(..)) {
            commands.entity(entity).despawn();
        }
        for mut camera in &mut cameras {
            camera.viewport = None;
        }
        if let Some(scene) = scene.as_mut() {
            (scene.animate_light, scene.moving_meshes) = (false, 0);
        }
        return;
    }
    if let Some(scene) = scene.as_mut() {
        scene.animate_light = true;
        scene.moving_meshes = 10;
    }
    if state.mesh.is_none() {
        state.mesh = Some(meshes.add(Cuboid::new(0.3, 0.3, 0.3)));
        state.material = Some(materials.add(StandardMaterial::from(Color::srgb(0.9, 0.5, 0.1))));
    }
    if f.is_multiple_of(7) {
        let at = Vec3::new(2.0 * (t * 0.37).sin(), 1.0 + 0.8 * (t * 0.11).cos(), 1.5 * (t * 0.23).cos());
        let kind = (f / 7) % 3;
        let entity = match kind {
            0 => commands
                .spawn((
                    PointLight { intensity: 2000.0, shadow_maps_enabled: true, ..default() },
                    Transform::from_translation(at),
                    GiLight { rsm_resolution: 48 },
                ))
                .id(),
            1 => commands
                .spawn((
                    SpotLight { intensity: 4000.0, shadow_maps_enabled: true, ..default() },
                    Transform::from_translation(at).looking_at(Vec3::ZERO, Vec3::Y),
                    GiLight { rsm_resolution: 32 + (f % 5) * 16 },
                ))
                .id(),
            _ => commands
                .spawn((
                    DirectionalLight { illuminance: 500.0, shadow_maps_enabled: f.is_multiple_of(2), ..default() },
                    Transform::from_translation(at).looking_at(Vec3::ZERO, Vec3::Y),
                    GiLight { rsm_resolution: 64 },
                ))
                .id(),
        };
        state.lights.push(entity);
    }
    // At most four lights and a dozen extra meshes at a time.
    if (f % 11 == 5 || state.lights.len() > 3) && !state.lights.is_empty() {
        let light = state.lights.remove(0);
        commands.entity(light).despawn();
    }
    if f.is_multiple_of(3) {
        let at = Vec3::new(2.5 * (t * 0.29).cos(), 0.2 + (t * 0.07).sin().abs(), 2.0 * (t * 0.19).sin());
        let (mesh, material) = (state.mesh.clone().unwrap(), state.material.clone().unwrap());
        state.meshes.push(commands.spawn((Mesh3d(mesh), MeshMaterial3d(material), Transform::from_translation(at))).id());
    }
    if (f % 4 == 1 && state.meshes.len() > 6) || state.meshes.len() > 12 {
        let index = (f as usize) % state.meshes.len();
        let mesh = state.meshes.remove(index);
        commands.entity(mesh).despawn();
    }
    for (mut volume, mut transform) in &mut volumes {
        if f % 50 == 25 {
            volume.resolution = UVec3::new(8 + f % 9, 6 + f % 5, 8 + f % 7);
        }
        if f.is_multiple_of(13) {
            transform.scale *= if (f / 13).is_multiple_of(2) { 1.2 } else { 1.0 / 1.2 };
            transform.translation.x += 0.1 * (t * 0.3).sin();
        }
    }
    if f.is_multiple_of(17) {
        for mut camera in &mut cameras {
            camera.viewport = if (f / 17).is_multiple_of(2) {
                Some(bevy::camera::Viewport { physical_size: UVec2::new(40 + f % 20, 48), ..default() })
            } else {
                None
            };
        }
    }
}

/// The rendering frame at which the churn stops and removes what it added.
const CHURN_ENDS: u32 = 900;

/// Largest block relative RMSE between the image after the churn and the still scene's: what is left
/// after 900 frames of lights and meshes coming and going must be the scene as it is now. Measured
/// 0.0000 / energy 1.000 (the VPL walks are seeded, so the same scene gives the same set). Broken on
/// purpose, a VPL set uploaded to the GPU once and never again (the one made while the churn's lights
/// shone) gives 0.819 / energy 1.65; the test before it asserted only some light at the end.
const AFTER_CHURN_MAX_ERROR: f64 = 0.02;

#[test]
fn a_thousand_frames_of_lights_and_meshes_coming_and_going_leave_the_still_scene_behind() {
    // 500 frames with Radiance Hints, then VPLs; `run_with` fails on any frame read back with NaN or
    // Inf, and a panic anywhere fails the test. After the churn ends, the image must be the still
    // scene's, rendered alone.
    let o = HeadlessOptions {
        rh: RadianceHintsVolume::LOW,
        vpl: bevy_diffuse_gi::vpl::VplSettings::LOW,
        switch_method: Some((500, GiMethod::Vpl)),
        wait_background: Some(60),
        ..options(StandardScene::Dynamic, GiMethod::RadianceHints, 48, 1000)
    };
    let image = run_with(&o, |app| {
        app.init_resource::<Churn>().add_systems(Update, churn);
    });
    let still = run_with(
        &HeadlessOptions {
            vpl: bevy_diffuse_gi::vpl::VplSettings::LOW,
            wait_background: Some(60),
            ..options(StandardScene::Dynamic, GiMethod::Vpl, 48, 8)
        },
        |_| {},
    );
    let test = "dynamic_churn";
    check(test, energy(&still) > 0.0, &still, None, "the still scene has no bounced light".into());
    let m = metrics::compare(&image, &still).expect("same size");
    let (error, ratio) = (m.block_relative_rmse, m.energy_ratio);
    eprintln!("after the churn: block RMSE {error:.4} against the still scene, energy {ratio:.3}");
    check(
        test,
        error <= AFTER_CHURN_MAX_ERROR,
        &image,
        Some(&still),
        format!("after the churn, block RMSE {error:.4} against the still scene (bound {AFTER_CHURN_MAX_ERROR}); energy {ratio:.3}"),
    );
}

#[test]
fn a_camera_without_its_prepass_skips_the_gi_passes_without_a_panic() {
    for method in [GiMethod::RadianceHints, GiMethod::Vpl] {
        let o = options(StandardScene::Cornell, method, 64, 12);
        let image = run_with(&o, |app| {
            app.add_systems(Update, |clock: Res<HeadlessClock>, mut commands: Commands, cameras: Query<Entity, With<DiffuseGi>>| {
                if clock.rendering && clock.frame == 3 {
                    for camera in &cameras {
                        commands
                            .entity(camera)
                            .remove::<(bevy::core_pipeline::prepass::DeferredPrepass, bevy::core_pipeline::prepass::DepthPrepass)>();
                    }
                }
            });
        });
        assert!(!image.has_non_finite());
        // Skipped, not stale: without the prepass the GI target holds no light (measured: none of the
        // 4096 pixels), where the same run with its prepass lights most of them.
        let lit = |image: &HdrImage| image.pixels.iter().filter(|p| p[0] + p[1] + p[2] > 0.0).count();
        assert_eq!(lit(&image), 0, "{method:?}: light left in the GI target after the prepass went");
        let with_prepass = run_with(&o, |_| {});
        assert!(lit(&with_prepass) > with_prepass.pixels.len() / 2, "{method:?}: no light even with the prepass");
    }
}
