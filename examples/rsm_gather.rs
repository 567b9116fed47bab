//! The RSM gather (Dachsbacher & Stamminger 2005) on the Cornell box, tuned live.
//!
//! `cargo run --release --example rsm_gather [-- --scene cornell|cellar|sponza_like|near_light|PATH.glb]`
//!
//! Keys: G toggles bounced light, M switches the method at run time, P cycles the presets, W switches
//! the sample weights (density ξ₁ ↔ the paper's ξ₁²), V cycles the debug views, H toggles half
//! resolution, B hangs a block next to the light, L starts or stops the light's motion. The egui panel
//! ("Diffuse GI") tunes every setting and shows the GPU time of each pass.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame headless
//! on whatever Vulkan device exists and writes `out/rsm_gather.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/one_bounce.rs"]
mod one_bounce;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    one_bounce::run("rsm_gather", "bevy_diffuse_gi — RSM gather", GiMethod::RsmGather)
}
