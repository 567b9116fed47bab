//! Main world → render world: each DRM camera's settings. The method keeps no CPU state: its photons are
//! made on the GPU from the shared reflective shadow maps.

use bevy::app::SubApp;
use bevy::render::ExtractSchedule;

use crate::method::extract_camera_settings;

/// The camera's [`DrmSettings`](super::DrmSettings) in the render world.
pub type ExtractedDrmSettings = crate::method::ExtractedSettings<super::DrmSettings>;

pub(super) fn add_extract_systems(render_app: &mut SubApp) {
    render_app.add_systems(ExtractSchedule, extract_camera_settings::<super::DrmPlugin>);
}
