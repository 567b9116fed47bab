//! Direct Radiance Mapping's settings component: `LOW`/`MEDIUM`/`HIGH`, the solid-angle choice and
//! their validation.

use bevy::prelude::*;

use crate::settings::{Clamped, GiSettings};

/// How a sample photon's solid angle `Δω'` is approximated (the paper's §4).
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum DrmSolidAngle {
    /// Eq. 11: `2π / M`, the hemisphere split evenly among the light's M photons. The cheapest and the
    /// least accurate: overexposed when an object nears the light.
    Constant,
    /// Eq. 14: `cos θ' A_p / (A_p + r²)` from the photon's surface area `A_p` (Eq. 12–13) and distance
    /// `r`. The most accurate (the default).
    #[default]
    TexelArea,
    /// Eq. 15: `A'_p / ‖B_max − B_min‖²`, the photon's area across the beam over the scene's diagonal
    /// squared: no normal, no distance.
    SceneDiagonal,
}

impl DrmSolidAngle {
    /// Every choice, for menus and reports.
    pub const ALL: [DrmSolidAngle; 3] = [DrmSolidAngle::Constant, DrmSolidAngle::TexelArea, DrmSolidAngle::SceneDiagonal];

    /// The paper's equation number, also the shader's `DRM_SOLID_ANGLE` value.
    pub const fn equation(self) -> u32 {
        match self {
            DrmSolidAngle::Constant => 11,
            DrmSolidAngle::TexelArea => 14,
            DrmSolidAngle::SceneDiagonal => 15,
        }
    }
}

/// The settings of Direct Radiance Mapping, on a camera with [`DiffuseGi`](crate::camera::DiffuseGi)
/// `{ method: GiMethod::Drm, .. }`. A camera without it uses [`DrmSettings::default`] (the medium
/// preset). Invalid values are clamped to their range with one warning.
///
/// Only the light of [`GiLight`](crate::light::GiLight)s bounces (the method gathers their reflective
/// shadow maps): emissive surfaces are not gathered, and a scene lit by them alone gets no bounced light
/// from this method and one warning; [`GiMethod::Vpl`](crate::camera::GiMethod::Vpl), Radiance Hints,
/// radiosity and the photon grid bounce emissive light.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[doc(alias = "DirectRadianceMapping")]
pub struct DrmSettings {
    /// Sample photons along each side of each light face's map: `M = n²` per face. Range 1–16; low 2,
    /// medium 3 (the paper's choice, the default), high 16. Cost: linear in `M` per pixel and light face.
    /// Few photons stand for large cells (at 3 × 3 on `cornell`, half a square metre each) whose mean
    /// position can fall behind the surfaces next to them, which then get nothing: 3 × 3 is 0.73 block
    /// RMSE against the one-bounce truth there, 8 × 8 0.50, 16 × 16 0.38 (`docs/one_bounce.md`).
    pub samples_per_axis: u32,
    /// The solid-angle approximation. Default [`DrmSolidAngle::TexelArea`] (Eq. 14). No effect on cost
    /// worth measuring.
    pub solid_angle: DrmSolidAngle,
    /// Each photon is its cell's mip-map texel (total flux and area, mean position and normal) rather
    /// than the cell's centre texel (§5). Default `true`: the centre texel jumps between surfaces as
    /// things move (the flashing the paper describes). Cost: the photon pass reads every RSM texel
    /// instead of `M`, only when an RSM changes.
    pub mip_mapped: bool,
    /// Multiplies the indirect light. Range 0–1000; default 1.
    pub intensity: f32,
}

impl DrmSettings {
    /// 2 × 2 photons per face, Eq. 14, mip-mapped.
    pub const LOW: Self = Self { samples_per_axis: 2, solid_angle: DrmSolidAngle::TexelArea, mip_mapped: true, intensity: 1.0 };
    /// 3 × 3 photons per face (the default, the paper's choice).
    pub const MEDIUM: Self = Self { samples_per_axis: 3, ..Self::LOW };
    /// 16 × 16 photons per face.
    pub const HIGH: Self = Self { samples_per_axis: 16, ..Self::LOW };
    /// Largest accepted [`samples_per_axis`](Self::samples_per_axis).
    pub const MAX_SAMPLES_PER_AXIS: u32 = 16;
}

impl Default for DrmSettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for DrmSettings {
    const NAME: &'static str = "DrmSettings";

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        c.uint(&mut s.samples_per_axis, 1, Self::MAX_SAMPLES_PER_AXIS, "samples_per_axis");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        for preset in [DrmSettings::LOW, DrmSettings::MEDIUM, DrmSettings::HIGH] {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
            assert_eq!(preset.solid_angle, DrmSolidAngle::TexelArea);
        }
        let counts = [DrmSettings::LOW, DrmSettings::MEDIUM, DrmSettings::HIGH].map(|p| p.samples_per_axis);
        assert!(counts.windows(2).all(|w| w[0] < w[1]), "{counts:?}");
        assert_eq!(DrmSettings::default().samples_per_axis, 3);
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = DrmSettings { samples_per_axis: 0, intensity: f32::INFINITY, ..default() };
        let (clean, bad) = s.sanitized();
        assert_eq!(bad.iter().map(|b| b.0).collect::<Vec<_>>(), ["samples_per_axis", "intensity"]);
        assert_eq!((clean.samples_per_axis, clean.intensity), (1, 1.0));
        let big = DrmSettings { samples_per_axis: 99, ..default() }.sanitized().0;
        assert_eq!(big.samples_per_axis, DrmSettings::MAX_SAMPLES_PER_AXIS);
        // A negative intensity is clamped to 0 (no light; the GPU test of absurd settings checks the light).
        assert_eq!(DrmSettings { intensity: -1.0, ..default() }.sanitized().0.intensity, 0.0);
    }

    #[test]
    fn equations_are_the_papers() {
        assert_eq!(DrmSolidAngle::ALL.map(DrmSolidAngle::equation), [11, 14, 15]);
    }
}
