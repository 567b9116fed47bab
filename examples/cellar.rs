//! `cellar` (`shared/SCENES.md`): two rooms joined by a door, a flashlight in one, the camera in the
//! other: the light reaches the camera's room only by bouncing through the door, and thin walls must stop it.
//!
//! `cargo run --release --features tools --example cellar`
//!
//! Keys: G bounced light on/off, M or 1–6 the method (Radiance Hints, VPL, RSM gather, DRM, radiosity, photon grid), P the
//! preset of every method, V the debug view, H half resolution, L the lights' motion, C orbit ↔ fly camera,
//! F1 the tuning panel ("Diffuse GI": every setting, the volume's activity, warnings, per-pass GPU times).
//! Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/cellar.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "cellar",
            title: "cellar: two rooms and a door",
            scene: "cellar",
            method: GiMethod::RadianceHints,
            light_motion: false,
            extra_help: &[],
            // CI: two methods per scene example (every method also runs in its own example and the
            // showcase), to keep the windowed tests short.
            ci: app::CiMode::Methods(&[GiMethod::Vpl, GiMethod::Radiosity]),
        },
        |_| {},
    )
}
