//! VPLs with imperfect shadow maps and screen-space bias compensation (Novák 2011) on the Cornell box.
//!
//! `cargo run --release --features tools --example vpl_ssbc [-- --scene NAME|PATH.glb]`
//!
//! Keys: G bounced light on/off, M or 1–6 the method (Radiance Hints, VPL, RSM gather, DRM, radiosity, photon grid), P the
//! preset of every method, V the debug view, H half resolution, L the lights' motion, C orbit ↔ fly camera,
//! F1 the tuning panel ("Diffuse GI": every setting, the volume's activity, warnings, per-pass GPU times).
//! Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/vpl_ssbc.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "vpl_ssbc",
            title: "VPLs with screen-space bias compensation",
            scene: "cornell",
            method: GiMethod::Vpl,
            light_motion: false,
            extra_help: &[],
            ci: app::CiMode::OwnMethod,
        },
        |_| {},
    )
}
