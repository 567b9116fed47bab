//! The tuning panel's settings changes, driven through the same code path its widgets use
//! ([`bevy_diffuse_gi::ui::commit`]), change the rendered indirect light as they say.
#![cfg(all(feature = "gpu_tests", feature = "egui"))]

mod common;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::drm::DrmSettings;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, HeadlessOptions};
use bevy_diffuse_gi::rsm_gather::RsmGatherSettings;
use bevy_diffuse_gi::scenes::StandardScene;
use bevy_diffuse_gi::ui::commit;
use common::check;

/// Renders `method` on `cornell`; with `edit`, the panel's commit applies it to the camera's settings
/// on the third frame the camera exists (after frames were drawn with the old values).
fn render_with_edit(method: GiMethod, edit: Option<fn(&mut Mut<RsmGatherSettings>, &mut Mut<DrmSettings>)>) -> bevy_diffuse_gi::hdr_image::HdrImage {
    let options = HeadlessOptions {
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(method),
        indirect_only: true,
        frames: 6,
        ..Default::default()
    };
    let _guard = common::render_lock();
    headless::run_with(&options, |app| {
        if let Some(edit) = edit {
            app.add_systems(Update, move |mut frames: Local<u32>, mut cameras: Query<(&mut RsmGatherSettings, &mut DrmSettings)>| {
                if cameras.is_empty() {
                    return;
                }
                *frames += 1;
                if *frames == 3 {
                    for (mut rsm, mut drm) in &mut cameras {
                        edit(&mut rsm, &mut drm);
                    }
                }
            });
        }
    })
    .expect("render")
    .image
}

fn total(image: &bevy_diffuse_gi::hdr_image::HdrImage) -> f64 {
    image.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum()
}

#[test]
fn intensity_two_from_the_panel_doubles_the_indirect_light() {
    for method in [GiMethod::RsmGather, GiMethod::Drm] {
        let test = format!("panel_intensity_{}", method.name());
        let before = render_with_edit(method, None);
        let after = render_with_edit(
            method,
            Some(|rsm, drm| {
                commit(RsmGatherSettings { intensity: 2.0, ..(**rsm).clone() }, rsm);
                commit(DrmSettings { intensity: 2.0, ..(**drm).clone() }, drm);
            }),
        );
        let ratio = total(&after) / total(&before).max(1e-12);
        check(&test, (ratio - 2.0).abs() < 0.04, &after, Some(&before), format!("{}: intensity 2 gives {ratio:.4} × the light", method.name()));
    }
}

/// What the panel shows of each Radiance Hints volume, frame by frame: its activity as the main world sees
/// it (the same resource the panel reads), on a still `cornell` with the medium preset and
/// `bounce_threshold` as given.
fn volume_activity(bounce_threshold: f32, frames: u32) -> Vec<Option<bevy_diffuse_gi::radiance_hints::RhVolumeActivity>> {
    use bevy_diffuse_gi::radiance_hints::{RadianceHintsActivity, RadianceHintsVolume};
    use std::sync::{Arc, Mutex};
    let options = HeadlessOptions {
        scene: StandardScene::Cornell,
        method: HeadlessMethod::Gi(GiMethod::RadianceHints),
        rh: RadianceHintsVolume { bounce_threshold, ..RadianceHintsVolume::MEDIUM },
        size: UVec2::new(64, 64),
        frames,
        ..Default::default()
    };
    let seen = Arc::new(Mutex::new(Vec::new()));
    let record = seen.clone();
    let _guard = common::render_lock();
    headless::run_with(&options, move |app| {
        app.add_systems(Last, move |activity: Res<RadianceHintsActivity>, volumes: Query<Entity, With<RadianceHintsVolume>>| {
            if let Some(volume) = volumes.iter().next() {
                record.lock().unwrap().push(activity.get(volume));
            }
        });
    })
    .expect("render");
    seen.lock().unwrap().clone()
}

#[test]
fn the_panel_shows_a_still_volume_updating_then_reused_and_the_bounces_it_ran() {
    let frames = volume_activity(0.01, 40);
    let active: Vec<_> = frames.iter().flatten().collect();
    assert!(active.len() >= 20, "the volume was active in only {} of {} frames", active.len(), frames.len());
    assert!(active.iter().any(|a| a.updating), "the volume never updated: {active:?}");
    let last = active.last().unwrap();
    // Medium preset: 17 updates to converge (blend 0.5, 16 refinement updates), then the field is reused.
    assert!(!last.updating && last.frames_reused >= 3, "a still volume keeps updating: {last:?}");
    let run = last.extra_bounces_run.expect("the bounce count was never read back");
    assert!((1..=last.extra_bounces_max).contains(&run), "{run} extra bounces of at most {}", last.extra_bounces_max);
    eprintln!("{}", bevy_diffuse_gi::ui::activity_line(Some(last)));

    // The count is the GPU's decision: with no stop threshold every allowed bounce runs; with a stop at
    // 100 % of the light so far (no bounce adds that much) only the first one does.
    let all = volume_activity(0.0, 12);
    let all = all.iter().flatten().last().and_then(|a| a.extra_bounces_run.map(|k| (k, a.extra_bounces_max)));
    assert!(matches!(all, Some((k, max)) if k == max), "threshold 0: {all:?}");
    let one = volume_activity(1.0, 12);
    let one = one.iter().flatten().last().and_then(|a| a.extra_bounces_run);
    assert_eq!(one, Some(1), "threshold 1: only the first extra bounce runs");
}
