//! Bad input never crashes a game: invalid settings are clamped with one warning per field (not one per
//! frame), and the plugin runs in apps without a renderer.

use bevy::prelude::*;
use bevy_diffuse_gi::prelude::*;
use bevy_diffuse_gi::DiffuseGiWarnings;

fn app_with(bundle: impl Bundle) -> App {
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, TransformPlugin, DiffuseGiPlugin::default()));
    app.world_mut().spawn(bundle);
    app
}

#[test]
fn invalid_volume_settings_warn_once_per_field_however_many_frames_pass() {
    let mut app = app_with((
        RadianceHintsVolume {
            resolution: UVec3::new(0, 4, 1_000_000),
            rsm_samples: 0,
            jitter: f32::NAN,
            temporal_blend: -1.0,
            ..RadianceHintsVolume::MEDIUM
        },
        Transform::from_scale(Vec3::splat(4.0)),
    ));
    for _ in 0..20 {
        app.update();
    }
    let messages = &app.world().resource::<DiffuseGiWarnings>().messages;
    for field in ["resolution", "rsm_samples", "jitter", "temporal_blend"] {
        let count = messages.iter().filter(|m| m.contains(&format!("`{field}`"))).count();
        assert_eq!(count, 1, "{field}: {messages:#?}");
    }
    assert_eq!(messages.len(), 4, "{messages:#?}");
    // The warning names the value used instead.
    assert!(messages.iter().any(|m| m.contains("`rsm_samples`, using 1")), "{messages:#?}");
}

#[test]
fn a_new_invalid_value_after_a_valid_one_is_not_warned_again_for_the_same_field() {
    let mut app = app_with((RadianceHintsVolume { rsm_samples: 0, ..default() }, Transform::default()));
    app.update();
    let entity = app.world_mut().query_filtered::<Entity, With<RadianceHintsVolume>>().single(app.world()).unwrap();
    for samples in [5000, 0, 64, 0] {
        app.world_mut().get_mut::<RadianceHintsVolume>(entity).unwrap().rsm_samples = samples;
        app.update();
    }
    let messages = &app.world().resource::<DiffuseGiWarnings>().messages;
    assert_eq!(messages.iter().filter(|m| m.contains("`rsm_samples`")).count(), 1, "{messages:#?}");
}

#[test]
fn degenerate_transforms_and_light_resolutions_warn_once() {
    let mut app = app_with((RadianceHintsVolume::LOW, Transform::from_scale(Vec3::new(0.0, f32::NAN, 1.0))));
    app.world_mut().spawn((SpotLight::default(), GiLight { rsm_resolution: 1 << 20 }));
    for _ in 0..10 {
        app.update();
    }
    let messages = &app.world().resource::<DiffuseGiWarnings>().messages;
    assert_eq!(messages.iter().filter(|m| m.contains("degenerate or non-finite transform")).count(), 1, "{messages:#?}");
    assert_eq!(messages.iter().filter(|m| m.contains("rsm_resolution")).count(), 1, "{messages:#?}");
}

#[test]
fn valid_presets_say_nothing() {
    let mut app = app_with((RadianceHintsVolume::HIGH, Transform::from_scale(Vec3::splat(10.0))));
    app.world_mut().spawn((DirectionalLight::default(), GiLight::default()));
    for _ in 0..5 {
        app.update();
    }
    assert!(app.world().resource::<DiffuseGiWarnings>().messages.is_empty());
}

#[test]
fn invalid_cascade_settings_warn_once_each_and_still_give_sane_levels() {
    use bevy_diffuse_gi::radiance_hints::{CascadeLevel, RadianceHintsCascade};
    let mut app = app_with((
        RadianceHintsCascade { levels: 100, scale: f32::NAN, extent: Vec3::NAN, ..default() },
        Transform::from_xyz(1.0, 2.0, 3.0),
    ));
    for _ in 0..10 {
        app.update();
    }
    let messages = &app.world().resource::<DiffuseGiWarnings>().messages;
    for field in ["levels", "scale", "extent"] {
        let count = messages.iter().filter(|m| m.contains("RadianceHintsCascade") && m.contains(&format!("`{field}`"))).count();
        assert_eq!(count, 1, "{field}: {messages:#?}");
    }
    // Clamped to 6 levels, each a finite, non-empty box.
    let world = app.world_mut();
    let mut levels = world.query::<(&CascadeLevel, &Transform)>();
    let boxes: Vec<_> = levels.iter(world).map(|(l, t)| (l.level, *t)).collect();
    assert_eq!(boxes.len(), 6, "{boxes:?}");
    assert!(boxes.iter().all(|(_, t)| t.translation.is_finite() && t.scale.is_finite() && t.scale.min_element() > 0.0));
}

#[test]
fn invalid_one_bounce_settings_warn_once_per_field_and_name_the_value_used() {
    let mut app = app_with((
        DiffuseGi { method: GiMethod::RsmGather, ..default() },
        RsmGatherSettings { samples: 0, radius: f32::NAN, ..default() },
        DrmSettings { samples_per_axis: 1000, intensity: -3.0, ..default() },
    ));
    for _ in 0..10 {
        app.update();
    }
    let messages = &app.world().resource::<DiffuseGiWarnings>().messages;
    for (field, value) in [("samples", "1"), ("radius", "1"), ("samples_per_axis", "16"), ("intensity", "0")] {
        let warned: Vec<_> = messages.iter().filter(|m| m.contains(&format!("`{field}`, using {value}"))).collect();
        assert_eq!(warned.len(), 1, "{field}: {messages:#?}");
    }
    assert_eq!(messages.len(), 4, "{messages:#?}");
    assert!(messages.iter().any(|m| m.contains("RsmGatherSettings")) && messages.iter().any(|m| m.contains("DrmSettings")));
    // The presets are valid: nothing more when they replace the bad values.
    let entity = app.world_mut().query_filtered::<Entity, With<DrmSettings>>().single(app.world()).unwrap();
    app.world_mut().entity_mut(entity).insert((RsmGatherSettings::HIGH, DrmSettings::LOW));
    app.update();
    assert_eq!(app.world().resource::<DiffuseGiWarnings>().messages.len(), 4);
}
