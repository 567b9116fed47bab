//! The reflective shadow map gather (Dachsbacher & Stamminger, "Reflective Shadow Maps", I3D 2005): the
//! "RSM" row of Table 1 in the Radiance Hints paper, and the plainest one-bounce baseline.
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! # fn setup(mut commands: Commands) {
//! commands.spawn((
//!     Camera3d::default(),
//!     DiffuseGi { method: GiMethod::RsmGather, ..default() },
//!     RsmGatherSettings::HIGH,
//! ));
//! commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//! # }
//! ```
//!
//! # Algorithm
//! Every texel `p` of a light's reflective shadow map ([`crate::rsm`]) is a small light: the surface it
//! shows reflects the flux `Φ_p = ρ·Φ_T` (lumens) diffusely, so it sends the irradiance
//!
//! ```text
//! E_p(x) = Φ_p · max(0, n_p·(x − x_p)) · max(0, n·(x_p − x)) / (π ‖x − x_p‖⁴)        (Eq. 1 of the paper)
//! ```
//!
//! to a point `x` with normal `n`, without any visibility test. Per pixel of the camera's
//! indirect-light target (`shaders/rsm_gather/gather.wgsl`), the sum over all texels is estimated from
//! [`samples`](RsmGatherSettings::samples) texels in a disk of radius `r_max`
//! ([`radius`](RsmGatherSettings::radius)) around `x`'s projection `(s, t)` into the RSM, with the
//! paper's pattern: the sample `(s + r_max ξ₁ sin 2πξ₂, t + r_max ξ₁ cos 2πξ₂)`, denser near the centre,
//! weighted by `ξ₁²` to compensate (§3.3). The pattern is one fixed low-discrepancy set (ξ₁ stratified,
//! ξ₂ the radical inverse) shared by every pixel, as the paper's precomputed one is.
//!
//! Every GI light kind: a spot light up to 60° and a directional light have one face (the disk lies in
//! it); a point light (and a wider spot) has six cube faces, and each sample is a direction around the
//! one from the light to `x`, looked up in whichever face it falls into, so disks cross face edges.
//!
//! # Where this departs from the paper, and why
//! * The `ξ₁²` weights are normalised so that they sum to the disk's area in texels (an exact result
//!   for a constant RSM): the paper leaves the overall scale to a constant, which would then depend on
//!   the sample count and radius.
//! * Eq. 1 has no `1/π`; with it, `Φ_p` in lumens gives irradiance in lux, so the result is comparable
//!   with the path-traced ground truth.
//! * Each sample is treated as a disk of the surface it stands for (`A = weight × texel area`):
//!   `‖x − x_p‖²` becomes `‖x − x_p‖² + A/π` (the exact on-axis irradiance of a disk), which bounds
//!   the singularity where surfaces meet instead of letting single samples flash.
//! * The paper computes the gather at a low resolution and interpolates where that is safe; here the
//!   frame's half-resolution target and its depth- and normal-aware upsampling do that, for every method.
//!
//! # Cost
//! Per pixel of the target: `samples` texel reads per GI light (and face lookups for cube lights); no
//! pass runs without a camera using [`GiMethod::RsmGather`](crate::camera::GiMethod::RsmGather), and
//! the RSMs are redrawn only where something changed.
//!
//! # Measured (lavapipe, 256², `docs/one_bounce.md`)
//! Block relative RMSE / energy against the one-bounce path-traced truth (and against all bounces):
//!
//! | scene | low (64) | medium (144, default) | high (400) | high, the paper's `ξ₁²` weights |
//! |---|---|---|---|---|
//! | `cornell` | 0.252 / 1.02 | 0.209 / 1.07 (0.627 / 0.59) | 0.187 / 1.09 | 0.831 / 0.61 |
//! | `sponza_like` (sun) | 0.799 / 0.95 | 0.533 / 1.02 (0.663 / 0.45) | 0.419 / 1.06 | 1.380 / 0.36 |
//! | `cellar` (no visibility: light through the wall) | 1.965 / 1.91 | 2.433 / 2.25 | 2.719 / 2.41 | |
//!
//! A still `cornell` frame costs 1.44 / 1.82 / 2.74 × the frame without GI at 256² (low / medium /
//! high; 1.65 / 2.19 / 4.05 × at 512²), all of it the gather. CPU-rasteriser times: only the ratios say
//! something about a GPU.
//!
//! # Known issues
//! * No visibility: light arrives through walls and boxes (no indirect shadows), so it is wrong in
//!   scenes of several rooms (`cellar`).
//! * One bounce only: the truth of a closed room holds about as much light again from later bounces.
//! * Surfaces behind a spot light (its ceiling) project outside its map: their disk is centred on the
//!   map's nearest edge, and they get too little light.
//! * The fixed sample pattern shows as smooth bands where few samples carry the light.

mod extract;
mod prepare;
mod render;
mod settings;

use bevy::app::SubApp;
use bevy::prelude::*;

pub use prepare::{RsmGatherSample, RsmGatherUniform, sample_pattern};
pub use settings::{RsmGatherSettings, RsmSampleWeights};

use crate::camera::GiMethod;
use crate::method::{GiMethodModule, GpuCapabilities, Shortfall};

/// The RSM gather: settings validation, the per-view pass. Added by [`crate::DiffuseGiPlugin`].
pub struct RsmGatherPlugin;

impl Plugin for RsmGatherPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "rsm_gather/gather.wgsl", include_str!("../../shaders/rsm_gather/gather.wgsl"));
        crate::method::build_method::<Self>(app);
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(prepare::RsmGatherShaders { gather: shader });
        }
    }

    fn finish(&self, app: &mut App) {
        crate::method::finish_method::<Self>(app);
    }
}

impl GiMethodModule for RsmGatherPlugin {
    const METHOD: GiMethod = GiMethod::RsmGather;
    const NAME: &'static str = "the RSM gather";
    type Settings = RsmGatherSettings;

    /// A fragment shader with three storage buffers (the pattern, the lights, the faces), which WebGPU's
    /// defaults give and WebGL2 does not.
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        gpu.require().storage_buffers(3).missing()
    }

    fn add_render_systems(render_app: &mut SubApp) {
        render::add_render_systems(render_app);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_with_webgpu_default_limits_runs_the_gather_and_webgl2_does_not() {
        assert!(RsmGatherPlugin::missing_capabilities(&GpuCapabilities::desktop()).is_empty());
        let missing = RsmGatherPlugin::missing_capabilities(&GpuCapabilities::webgl2());
        assert_eq!(missing.first().map(|m| m.0), Some("max_storage_buffers_per_shader_stage"), "{missing:?}");
    }
}
