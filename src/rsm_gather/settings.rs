//! The RSM gather's settings component: `LOW`/`MEDIUM`/`HIGH` and its validation.

use bevy::prelude::*;

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

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        c.uint(&mut s.samples, 1, Self::MAX_SAMPLES, "samples");
        c.float(&mut s.radius, 0.01, 1.0, Self::MEDIUM.radius, "radius");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
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
