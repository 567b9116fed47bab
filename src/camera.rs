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
    /// The GI method. Default [`GiMethod::RadianceHints`]. Changing it takes effect on the next frame;
    /// methods that no camera uses run no pass.
    pub method: GiMethod,
    /// How the bounced light reaches the image. Default [`GiOutput::Composite`].
    /// [`GiOutput::IrradianceVolume`] needs a volume to export, which only Radiance Hints has: with the
    /// other methods the camera composites instead, with one warning ([`effective_output`](Self::effective_output)).
    pub output: GiOutput,
    /// What to show. Default [`GiDebugView::None`] (the lit image).
    pub debug_view: GiDebugView,
    /// Compute the bounced light at half the resolution in each axis, filter it there and upsample it
    /// with depth- and normal-aware weights (the frame does this the same way for every method).
    ///
    /// Default `true`: diffuse bounced light is smooth, and at half resolution the error against the
    /// path-traced truth is the same as at full resolution within 0.01 block relative RMSE for Radiance
    /// Hints on the six standard scenes (`docs/radiance_hints.md`, § reconstruction) and for VPLs at
    /// their default preset (`VplSettings::HIGH` on `sponza_like`: 0.237 → 0.257), for about a quarter
    /// of the per-pixel cost (Radiance Hints' reconstruction, the VPL gather and SSBC). `false` computes
    /// every pixel: sharper along thin geometry and silhouettes, where a texel stands for pixels of two
    /// surfaces.
    pub half_resolution: bool,
}

impl DiffuseGi {
    /// The output the camera uses: [`output`](Self::output), except that the per-pixel methods, which
    /// have no volume to export, always composite.
    pub fn effective_output(&self) -> GiOutput {
        if self.method == GiMethod::RadianceHints { self.output } else { GiOutput::Composite }
    }
}

/// Warns once per camera that asks for [`GiOutput::IrradianceVolume`] with a method that has no volume.
pub(crate) fn warn_unsupported_output(
    cameras: Query<(Entity, &DiffuseGi), Changed<DiffuseGi>>,
    mut warned: Local<bevy::platform::collections::HashSet<(Entity, GiMethod)>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    for (entity, gi) in &cameras {
        if gi.output == GiOutput::IrradianceVolume && gi.effective_output() != gi.output && warned.insert((entity, gi.method)) {
            crate::gi_warning(
                &mut warnings,
                format!(
                    "bevy_diffuse_gi: camera {entity} asks for GiOutput::IrradianceVolume with GiMethod::{:?}, which has no \
                     volume to export (only Radiance Hints has); it composites per pixel instead",
                    gi.method
                ),
            );
        }
    }
}

impl Default for DiffuseGi {
    fn default() -> Self {
        Self {
            enabled: true,
            method: GiMethod::RadianceHints,
            output: GiOutput::Composite,
            debug_view: GiDebugView::None,
            half_resolution: true,
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
    /// Instant radiosity with virtual point lights (Keller 1997), their visibility from imperfect shadow
    /// maps (Ritschel 2008), the clamped geometry term, and screen-space bias compensation (Novák 2011).
    /// Settings: [`VplSettings`](crate::vpl::VplSettings) on the camera.
    Vpl,
    /// The reflective shadow map gather (Dachsbacher & Stamminger 2005): each pixel sums the texels of
    /// every GI light's RSM in a disk around its projection, as point lights without visibility. One
    /// bounce of the GI lights' light (not of emissive surfaces), no indirect shadows; no volume. Settings:
    /// [`RsmGatherSettings`](crate::rsm_gather::RsmGatherSettings) on the camera.
    RsmGather,
    /// Direct Radiance Mapping (Frisvad et al. 2005): each pixel gathers a few regularly spaced
    /// "sample photons" of every GI light's direct radiance map (its RSM), weighted by an approximate
    /// solid angle. One bounce of the GI lights' light (not of emissive surfaces), no indirect shadows;
    /// the cheapest method. Settings:
    /// [`DrmSettings`](crate::drm::DrmSettings) on the camera.
    Drm,
    /// Hierarchical radiosity with implicit visibility (Dong et al. 2007): multi-bounce light between
    /// surface elements at mesh vertices, visibility from the shortest link per cube-map bin, solved on
    /// the CPU; no reflective shadow map and no volume, and emissive meshes light the scene. Settings:
    /// [`RadiositySettings`](crate::radiosity::RadiositySettings) on the camera.
    Radiosity,
    /// The photon grid and SH field (Chang, Park & Ihm): photons from every light, eight reflections
    /// deep by default (the paper keeps four), accumulated on the faces of a grid, turned into spherical
    /// harmonics of the incoming light near the surfaces and gathered per pixel; prepared on the CPU, no reflective shadow map and no
    /// volume; emissive meshes and the environment map light the scene. Settings:
    /// [`PhotonGridSettings`](crate::photon_grid::PhotonGridSettings) on the camera.
    PhotonGrid,
}

impl serde::Serialize for GiMethod {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl GiMethod {
    /// Every method, for menus.
    pub const ALL: [GiMethod; 6] =
        [GiMethod::RadianceHints, GiMethod::Vpl, GiMethod::RsmGather, GiMethod::Drm, GiMethod::Radiosity, GiMethod::PhotonGrid];

    /// Short name, as the headless renderer's `--method` spells it.
    pub const fn name(self) -> &'static str {
        match self {
            GiMethod::RadianceHints => "rh",
            GiMethod::Vpl => "vpl",
            GiMethod::RsmGather => "rsm",
            GiMethod::Drm => "drm",
            GiMethod::Radiosity => "radiosity",
            GiMethod::PhotonGrid => "photon-grid",
        }
    }

    /// Whether the method reads the GI lights' reflective shadow maps per pixel of the view (so that the
    /// RSMs must be drawn while a camera uses it, even without a volume).
    pub const fn gathers_rsm_per_pixel(self) -> bool {
        matches!(self, GiMethod::RsmGather | GiMethod::Drm)
    }
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
    /// no per-pixel hemisphere sampling, six directions per hint. `Composite` is skipped. Radiance Hints
    /// only: the per-pixel methods composite instead.
    IrradianceVolume,
}

/// Debug views; all but [`GiDebugView::None`] replace the image.
///
/// The first three are the frame's and work with every method. The others belong to one method (or to
/// the reflective shadow maps, an input shared by several): the method writes something else into the
/// camera's indirect-light target, which the frame then shows like [`GiDebugView::IndirectOnly`] or
/// [`GiDebugView::Irradiance`]. A view of a method the camera does not use shows that method's target
/// as it is (usually nothing).
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
    /// Radiance Hints: each pixel shows the irradiance of its nearest hint (no interpolation), with
    /// cell borders drawn dark.
    HintGrid,
    /// The reflected flux of the first GI light's reflective shadow map (cube faces side by side).
    RsmFlux,
    /// The normals of the first GI light's reflective shadow map.
    RsmNormal,
    /// The world positions of the first GI light's reflective shadow map (fractional metres).
    RsmPosition,
    /// VPL: the clamped VPL gather alone (`G_b = min(G, b)`, no compensation), as indirect light.
    VplClampedOnly,
    /// VPL: the screen-space bias compensation alone (the energy clamping removed), as indirect light.
    VplCompensationOnly,
    /// VPL: the virtual point lights as dots coloured by their flux, over the irradiance.
    VplPositions,
}

/// How the frame shows a camera's indirect-light target for a [`GiDebugView`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TargetDisplay {
    /// Added to the lit image.
    Lit,
    /// `albedo × target × exposure`, filtered.
    Indirect,
    /// `target × exposure`, filtered.
    Irradiance,
    /// `target × exposure` texel by texel (views with sharp detail: hint grid, VPL dots).
    RawIrradiance,
    /// The first GI light's RSM (0 flux, 1 normal, 2 position) instead of the target.
    Rsm(u32),
}

impl GiDebugView {
    /// Every view, for menus.
    pub const ALL: [GiDebugView; 10] = [
        GiDebugView::None,
        GiDebugView::IndirectOnly,
        GiDebugView::Irradiance,
        GiDebugView::HintGrid,
        GiDebugView::RsmFlux,
        GiDebugView::RsmNormal,
        GiDebugView::RsmPosition,
        GiDebugView::VplClampedOnly,
        GiDebugView::VplCompensationOnly,
        GiDebugView::VplPositions,
    ];

    /// How the frame shows the target in this view.
    pub const fn display(self) -> TargetDisplay {
        match self {
            GiDebugView::None => TargetDisplay::Lit,
            GiDebugView::IndirectOnly | GiDebugView::VplClampedOnly | GiDebugView::VplCompensationOnly => {
                TargetDisplay::Indirect
            }
            GiDebugView::Irradiance => TargetDisplay::Irradiance,
            GiDebugView::HintGrid | GiDebugView::VplPositions => TargetDisplay::RawIrradiance,
            GiDebugView::RsmFlux => TargetDisplay::Rsm(0),
            GiDebugView::RsmNormal => TargetDisplay::Rsm(1),
            GiDebugView::RsmPosition => TargetDisplay::Rsm(2),
        }
    }
}
