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
