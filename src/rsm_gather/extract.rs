//! Main world → render world: each RSM-gather camera's settings. The method keeps no CPU state: the
//! reflective shadow maps it reads are the shared `rsm` input.

use bevy::app::SubApp;
use bevy::render::ExtractSchedule;

use crate::method::extract_camera_settings;

/// The camera's [`RsmGatherSettings`](super::RsmGatherSettings) in the render world.
pub type ExtractedRsmGatherSettings = crate::method::ExtractedSettings<super::RsmGatherSettings>;

pub(super) fn add_extract_systems(render_app: &mut SubApp) {
    render_app.add_systems(ExtractSchedule, extract_camera_settings::<super::RsmGatherPlugin>);
}
