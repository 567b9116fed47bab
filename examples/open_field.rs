//! `open_field` (`shared/SCENES.md`): a 60 m sunlit field with a few buildings: a large, sparse,
//! open world. One Radiance Hints volume over all of it has 1 m cells (see the known issues of
//! `radiance_hints`).
//!
//! `cargo run --release --features tools --example open_field`
//!
//! Keys: G bounced light on/off, M or 1–6 the method (Radiance Hints, VPL, RSM gather, DRM, radiosity, photon grid), P the
//! preset of every method, V the debug view, H half resolution, L the lights' motion, C orbit ↔ fly camera,
//! F1 the tuning panel ("Diffuse GI": every setting, the volume's activity, warnings, per-pass GPU times).
//! Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/open_field.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "open_field",
            title: "open_field: 60 m in the sun",
            scene: "open_field",
            method: GiMethod::RadianceHints,
            light_motion: false,
            extra_help: &[],
            // CI: two methods per scene example (every method also runs in its own example and the
            // showcase), to keep the windowed tests short.
            ci: app::CiMode::Methods(&[GiMethod::Drm, GiMethod::Vpl]),
        },
        |_| {},
    )
}
