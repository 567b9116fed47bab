//! [`DiffuseGi`]: turns bounced light on for a camera.

use bevy::core_pipeline::prepass::{DeferredPrepass, DepthPrepass};
use bevy::prelude::*;

/// Put this on a `Camera3d` to light what it sees with bounced light from every
/// [`GiLight`](crate::light::GiLight), inside the volumes of the chosen method (for Radiance Hints, every
/// [`RadianceHintsVolume`](crate::radiance_hints::RadianceHintsVolume)).
///
/// Requires the deferred prepass ([`DepthPrepass`] and [`DeferredPrepass`] are added for you): the
/// reconstruction reads each pixel's depth, normal and albedo from Bevy's G-buffer, and adds
/// `albedo × L_indirect × exposure` to the HDR target after the opaque pass. Forward-rendered apps, whose
/// materials write no G-buffer, use [`GiOutput::IrradianceVolume`] instead, which StandardMaterial applies
/// itself. Cameras without this component cost nothing.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[require(DepthPrepass, DeferredPrepass)]
#[doc(alias = "GlobalIllumination")]
pub struct DiffuseGi {
    /// Whether the camera shows bounced light at all. Default `true`; `false` skips every pass of this
    /// camera (volumes still update if another GI camera needs them).
    pub enabled: bool,
    /// The GI method. Default [`GiMethod::RadianceHints`].
    pub method: GiMethod,
    /// How the bounced light reaches the image. Default [`GiOutput::Composite`].
    pub output: GiOutput,
    /// What to show. Default [`GiDebugView::None`] (the lit image).
    pub debug_view: GiDebugView,
    /// Reconstruct the bounced light at half the resolution in each axis and upsample it with depth- and
    /// normal-aware weights. Default `false`. Saves about three quarters of the reconstruction's cost; the
    /// diffuse light is smooth, so the difference is small except along thin geometry.
    pub half_resolution: bool,
}

impl Default for DiffuseGi {
    fn default() -> Self {
        Self {
            enabled: true,
            method: GiMethod::RadianceHints,
            output: GiOutput::Composite,
            debug_view: GiDebugView::None,
            half_resolution: false,
        }
    }
}

/// The GI methods of this crate.
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum GiMethod {
    /// Radiance Hints (Papaioannou 2011): an SH radiance grid filled from reflective shadow maps, with
    /// extra bounces exchanged between hints.
    #[default]
    RadianceHints,
}

/// Where the bounced light goes.
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum GiOutput {
    /// Reconstruct per pixel from the G-buffer (paper §5, Eq. 6–7) and add it to the HDR target. The most
    /// accurate; needs deferred materials.
    #[default]
    Composite,
    /// Write the volume's irradiance into a Bevy [`IrradianceVolume`](bevy::light::IrradianceVolume)
    /// (ambient cube per hint) that `StandardMaterial` applies in forward and deferred rendering. Coarser:
    /// no per-pixel hemisphere sampling, six directions per hint. `Composite` is skipped.
    IrradianceVolume,
}

/// Debug views; all but [`GiDebugView::None`] replace the image.
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum GiDebugView {
    /// The lit image with bounced light added.
    #[default]
    None,
    /// Only the bounced light `albedo × L_indirect × exposure`: what the metrics compare.
    IndirectOnly,
    /// Bounced irradiance on a white surface, `E/π × exposure`.
    Irradiance,
    /// The hint grid: each pixel shows the irradiance of its nearest hint (no interpolation), with
    /// cell borders drawn dark.
    HintGrid,
    /// The reflected flux of the first GI light's reflective shadow map (cube faces side by side).
    RsmFlux,
    /// The normals of the first GI light's reflective shadow map.
    RsmNormal,
    /// The world positions of the first GI light's reflective shadow map (fractional metres).
    RsmPosition,
}

impl GiDebugView {
    /// Every view, for menus.
    pub const ALL: [GiDebugView; 7] = [
        GiDebugView::None,
        GiDebugView::IndirectOnly,
        GiDebugView::Irradiance,
        GiDebugView::HintGrid,
        GiDebugView::RsmFlux,
        GiDebugView::RsmNormal,
        GiDebugView::RsmPosition,
    ];

    /// The index the composite shader switches on.
    pub const fn shader_index(self) -> u32 {
        self as u32
    }
}
