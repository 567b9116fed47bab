//! Direct Radiance Mapping (Frisvad et al. 2005) on the Cornell box, tuned live. `--scene near_light`
//! hangs a block just below the light (the paper's Fig. 7).
//!
//! `cargo run --release --features tools --example direct_radiance_mapping [-- --scene NAME|PATH.glb]`
//!
//! Keys: G bounced light on/off, M or 1–6 the method (Radiance Hints, VPL, RSM gather, DRM, radiosity, photon grid), P the
//! preset of every method, V the debug view, H half resolution, L the lights' motion, C orbit ↔ fly camera,
//! F1 the tuning panel ("Diffuse GI": every setting, the volume's activity, warnings, per-pass GPU times).
//! Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/direct_radiance_mapping.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "direct_radiance_mapping",
            title: "Direct Radiance Mapping",
            scene: "cornell",
            method: GiMethod::Drm,
            light_motion: false,
            extra_help: &[],
            ci: app::CiMode::OwnMethod,
        },
        |_| {},
    )
}
