//! The photon grid and SH field (Chang, Park & Ihm) on `sky_room`: an 8 m room lit only by the sky,
//! through a roof opening and a door. Photons from the sky bounce up to eight times; the SH field holds
//! the light near every surface, and each pixel gathers it. Try `--scene cellar` (a second room lit
//! through a door) or `--scene cornell`, and the photon-grid presets (P) in the tuning panel: the grid's
//! cells, photons, probe directions and the radiance filter.
//!
//! `cargo run --release --features tools --example photon_grid [-- --scene NAME|PATH.glb]`
//!
//! Keys: G bounced light on/off, M or 1–6 the method (Radiance Hints, VPL, RSM gather, DRM, radiosity, photon
//! grid), P the preset of every method, V the debug view, H half resolution, L the lights' motion, C orbit ↔
//! fly camera, F1 the tuning panel ("Diffuse GI": the photon grid's settings and the stages of its last
//! update). Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/photon_grid.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "photon_grid",
            title: "Photon grid and SH field",
            scene: "sky_room",
            method: GiMethod::PhotonGrid,
            light_motion: false,
            extra_help: &[],
            ci: app::CiMode::OwnMethod,
        },
        |_| {},
    )
}
