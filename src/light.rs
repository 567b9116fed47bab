//! [`GiLight`]: marks a light whose light bounces.

use bevy::prelude::*;

/// Put this on a [`DirectionalLight`], [`SpotLight`] or [`PointLight`] to make its light bounce.
///
/// Each such light renders a reflective shadow map (RSM): the position, normal and reflected flux of the
/// surfaces it lights, the input of the GI methods. Lights without it cost nothing and add no indirect
/// light. A GI light should also cast shadows (`shadow_maps_enabled: true`), or its direct light leaks
/// through walls in Bevy while its bounced light does not.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[doc(alias = "RSM")]
#[doc(alias = "ReflectiveShadowMap")]
pub struct GiLight {
    /// Side of the reflective shadow map in texels (for point lights, of each of the six cube faces).
    ///
    /// Default 256 (64 Ki texels, enough for the RSM sampling of Radiance Hints, which reads a few dozen
    /// texels per hint). Valid range 16–2048; values outside are clamped with a warning. Cost: the RSM
    /// pass rasterises the scene once per light (six times for point lights) at this size, O(n²) fill.
    pub rsm_resolution: u32,
}

impl GiLight {
    /// Smallest accepted [`GiLight::rsm_resolution`].
    pub const MIN_RSM_RESOLUTION: u32 = 16;
    /// Largest accepted [`GiLight::rsm_resolution`].
    pub const MAX_RSM_RESOLUTION: u32 = 2048;
}

impl Default for GiLight {
    fn default() -> Self {
        Self { rsm_resolution: 256 }
    }
}
