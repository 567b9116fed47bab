//! Direct Radiance Mapping (Frisvad et al. 2005) on the Cornell box, tuned live.
//!
//! `cargo run --release --example direct_radiance_mapping [-- --scene cornell|near_light|PATH.glb]`
//!
//! Keys: G toggles bounced light, M switches the method at run time, P cycles the presets (2×2, 3×3,
//! 16×16 photons per light face), E cycles the solid-angle approximation (the paper's Eq. 11, 14, 15), B
//! hangs a block next to the light (the paper's Fig. 7: Eq. 11 overexposes, Eq. 14 does not), V cycles
//! the debug views, H toggles half resolution, L starts or stops the light's motion. The egui panel
//! ("Diffuse GI") tunes every setting and shows the GPU time of each pass.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`, as on a CI machine) it renders one frame headless
//! on whatever Vulkan device exists and writes `out/direct_radiance_mapping.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/one_bounce.rs"]
mod one_bounce;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

fn main() -> AppExit {
    one_bounce::run("direct_radiance_mapping", "bevy_diffuse_gi — Direct Radiance Mapping", GiMethod::Drm)
}
