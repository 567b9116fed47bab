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

mod render;

use bevy::prelude::*;
use bevy::render::RenderApp;

pub use render::{RsmGatherSample, RsmGatherUniform, sample_pattern};

use crate::settings::{Clamped, GiSettings};

/// The settings of the RSM gather, on a camera with [`DiffuseGi`](crate::camera::DiffuseGi)
/// `{ method: GiMethod::RsmGather, .. }`. A camera without it uses [`RsmGatherSettings::default`] (the
/// medium preset). Invalid values are clamped to their range with one warning.
///
/// Only the light of [`GiLight`](crate::light::GiLight)s bounces (the method gathers their reflective
/// shadow maps): emissive surfaces are not gathered, and a scene lit by them alone gets no bounced light
/// from this method and one warning; [`GiMethod::Vpl`](crate::camera::GiMethod::Vpl), Radiance Hints,
/// radiosity and the photon grid bounce emissive light.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[doc(alias = "ReflectiveShadowMaps")]
pub struct RsmGatherSettings {
    /// RSM texels sampled per pixel and GI light face lookup (the paper used 400). Range 1–1024; low 64,
    /// medium 144, high 400. Cost: linear, per pixel of the target and per GI light.
    pub samples: u32,
    /// Radius `r_max` of the sampled disk, as a fraction of the RSM's side (of one cube face for point
    /// lights). Range 0.01–1; default 1 (from any centre the disk covers most of the map, which the
    /// one-bounce light of a room needs; `docs/one_bounce.md` measures 0.25–1). Smaller radii gather
    /// only nearby texels and miss the rest of the light. No effect on cost.
    pub radius: f32,
    /// How the samples are weighted for their density. Default [`RsmSampleWeights::Density`]; the paper's
    /// [`RsmSampleWeights::Paper`] under-weights the texels near the centre. No effect on cost.
    pub weights: RsmSampleWeights,
    /// Multiplies the indirect light. Range 0–1000; default 1.
    pub intensity: f32,
}

/// How the disk samples are weighted to compensate for their density, which falls as `1/r` from the
/// centre (ξ₁ uniform).
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum RsmSampleWeights {
    /// `ξ₁²`, as the paper writes it (§3.3). It over-weights the rim against the centre by a factor
    /// `ξ₁`: the estimate of a falloff around the pixel's projection comes out too low (by a quarter for a
    /// linear falloff), and the light of nearby texels is lost (`docs/one_bounce.md`).
    Paper,
    /// `ξ₁`, the inverse of the density: unbiased for any RSM content. The default.
    #[default]
    Density,
}

impl RsmSampleWeights {
    /// The power k of the weight `ξ₁^k`.
    pub const fn power_of_xi1(self) -> f32 {
        match self {
            RsmSampleWeights::Paper => 2.0,
            RsmSampleWeights::Density => 1.0,
        }
    }
}

impl RsmGatherSettings {
    /// 64 samples.
    pub const LOW: Self = Self { samples: 64, radius: 1.0, weights: RsmSampleWeights::Density, intensity: 1.0 };
    /// 144 samples (the default).
    pub const MEDIUM: Self = Self { samples: 144, ..Self::LOW };
    /// 400 samples, the paper's count.
    pub const HIGH: Self = Self { samples: 400, ..Self::LOW };
    /// Largest accepted [`samples`](Self::samples).
    pub const MAX_SAMPLES: u32 = 1024;
}

impl Default for RsmGatherSettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for RsmGatherSettings {
    const NAME: &'static str = "RsmGatherSettings";

    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
        c.uint(&mut s.samples, 1, Self::MAX_SAMPLES, "samples");
        c.float(&mut s.radius, 0.01, 1.0, Self::MEDIUM.radius, "radius");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
        (s, c.fields)
    }
}

/// The GPU capabilities the RSM gather needs, as `(name, required, found)` for every shortfall: a
/// fragment shader with three storage buffers (the pattern, the lights, the faces), which WebGPU's
/// defaults give and WebGL2 does not.
pub fn missing_capabilities(limits: &bevy::render::settings::WgpuLimits) -> Vec<crate::Shortfall> {
    let found = limits.max_storage_buffers_per_shader_stage as u64;
    if found < 3 { vec![("max_storage_buffers_per_shader_stage", 3, found)] } else { Vec::new() }
}

/// The RSM gather: settings validation, the per-view pass. Added by [`crate::DiffuseGiPlugin`].
pub struct RsmGatherPlugin;

impl Plugin for RsmGatherPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "rsm_gather/gather.wgsl", include_str!("../../shaders/rsm_gather/gather.wgsl"));
        app.register_type::<RsmGatherSettings>()
            .add_systems(PostUpdate, crate::settings::validate_settings::<RsmGatherSettings>);
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(render::RsmGatherShader(shader));
        }
    }

    fn finish(&self, app: &mut App) {
        let supported = crate::gpu_supports(app, "the RSM gather", |limits, _| missing_capabilities(limits));
        let Some(render_app) = app.get_sub_app_mut(RenderApp).filter(|_| supported) else {
            return;
        };
        render::add_render_systems(render_app);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        for preset in [RsmGatherSettings::LOW, RsmGatherSettings::MEDIUM, RsmGatherSettings::HIGH] {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
        }
        let counts = [RsmGatherSettings::LOW, RsmGatherSettings::MEDIUM, RsmGatherSettings::HIGH].map(|p| p.samples);
        assert!(counts.windows(2).all(|w| w[0] < w[1]), "{counts:?}");
        assert_eq!(RsmGatherSettings::default(), RsmGatherSettings::MEDIUM);
    }

    #[test]
    fn a_device_with_webgpu_default_limits_runs_the_gather_and_webgl2_does_not() {
        use bevy::render::settings::WgpuLimits;
        assert!(missing_capabilities(&WgpuLimits::default()).is_empty());
        let missing = missing_capabilities(&WgpuLimits::downlevel_webgl2_defaults());
        assert_eq!(missing.first().map(|m| m.0), Some("max_storage_buffers_per_shader_stage"), "{missing:?}");
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = RsmGatherSettings { samples: 0, radius: f32::NAN, intensity: -2.0, ..default() };
        let (clean, bad) = s.sanitized();
        let names: Vec<_> = bad.iter().map(|b| b.0).collect();
        assert_eq!(names, ["samples", "radius", "intensity"]);
        assert_eq!((clean.samples, clean.radius, clean.intensity), (1, RsmGatherSettings::MEDIUM.radius, 0.0));
        assert!(clean.sanitized().1.is_empty());
        let big = RsmGatherSettings { samples: 1 << 20, radius: 3.0, ..default() }.sanitized().0;
        assert_eq!((big.samples, big.radius), (RsmGatherSettings::MAX_SAMPLES, 1.0));
    }
}
