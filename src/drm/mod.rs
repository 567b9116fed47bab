//! Direct Radiance Mapping (DRM; Frisvad, Frisvad, Christensen, Falster, "Scene Independent Real-Time
//! Indirect Illumination", CGI 2005): the cheapest one-bounce method of the crate.
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! # fn setup(mut commands: Commands) {
//! commands.spawn((Camera3d::default(), DiffuseGi { method: GiMethod::Drm, ..default() }, DrmSettings::MEDIUM));
//! commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//! # }
//! ```
//!
//! # Algorithm
//! The *direct radiance map* of a light is its reflective shadow map ([`crate::rsm`]): per texel the
//! position, the normal and the light the surface reflects (its flux `ρΦ_T` and area `A`, hence the
//! Lambertian radiance `L_o = ρΦ_T / (π A)`). Each frame:
//! 1. **Sample photons** (`shaders/drm/photons.wgsl`, once per frame before the cameras, only when an
//!    RSM changed): each face of each GI light is cut into `n × n` regularly spaced cells
//!    ([`samples_per_axis`](DrmSettings::samples_per_axis), `M = n²` per face), and each cell becomes
//!    one sample photon (the paper's step 2, which it did on the CPU). With
//!    [`mip_mapped`](DrmSettings::mip_mapped) (§5, against the flashing of few samples) the photon is the
//!    cell's mip-map texel: its total flux and surface area, at its flux-weighted mean position and
//!    normal. Without, it is the cell's centre texel, standing for the whole cell.
//! 2. **Gather** (`shaders/drm/gather.wgsl`, per pixel of the camera's indirect-light target), Eq. 10:
//!    `L_r(x) = Σ_j f_r L_o,j cos θ_j Δω'_j`, with the solid angle `Δω'_j` of photon j from
//!    [`solid_angle`](DrmSettings::solid_angle):
//!    * Eq. 11, [`DrmSolidAngle::Constant`]: `2π / M` (M the light's photons): the hemisphere split
//!      evenly. Overexposes when an object nears the light (the paper's Fig. 7).
//!    * Eq. 14, [`DrmSolidAngle::TexelArea`]: `cos θ'_j A_p / (A_p + r²)`, the photon's surface area
//!      `A_p` seen from `x` with Lambert's "five times rule" in the denominator. `A_p = A'_p / cos α`
//!      (Eq. 12–13) is what the RSM stores per texel, summed over the cell.
//!    * Eq. 15, [`DrmSolidAngle::SceneDiagonal`]: `A'_p / ‖B_max − B_min‖²`, the area across the beam
//!      over the scene's diagonal squared.
//!
//!    No visibility (the paper assumes all photons and importons see each other).
//!
//! # Where this departs from the paper, and why
//! * The paper computes Eq. 12 from one texel of a w-texel map; here a photon stands for its whole cell
//!   (its `(w/n)²` texels), so `A_p` is the cell's area, as the mip level the paper suggests in §5 would
//!   give. With one texel's area, M photons would carry `M / w²` of the light.
//! * Several lights (the paper handles one): each light's photons estimate its own contribution (Eq. 11
//!   splits the hemisphere among that light's photons), and the lights add up. Point lights (and spots
//!   over 60°) give six faces of `n × n` photons each.
//! * The paper's own direct light (Eq. 5, 9) is Bevy's; only the indirect term is this module's.
//!
//! # Cost
//! Per pixel: `n² × faces` photons per GI light, a few arithmetic operations each (no texture reads).
//! The photon pass reads every RSM texel once (mip-mapped) or `n²` texels, only after an RSM changed.
//! Nothing runs without a camera using [`GiMethod::Drm`](crate::camera::GiMethod::Drm).
//!
//! # Measured (lavapipe, 256², `docs/one_bounce.md`)
//! Block relative RMSE / energy against the one-bounce path-traced truth of `cornell`:
//!
//! | photons per face | Eq. 11 | Eq. 14 (default) | Eq. 15 |
//! |---|---|---|---|
//! | 2 × 2 (low) | 8.51 / 7.59 | 0.765 / 0.66 | 1.296 / 0.22 |
//! | 3 × 3 (medium, the paper's) | 8.98 / 7.97 | 0.731 / 0.80 | 1.284 / 0.24 |
//! | 8 × 8 | 13.8 / 11.8 | 0.504 / 1.02 | 1.249 / 0.28 |
//! | 16 × 16 (high) | 15.3 / 12.9 | 0.382 / 1.08 | 1.228 / 0.30 |
//!
//! With a block hung below the light (`near_light`, the paper's Fig. 7) Eq. 11's energy grows from 8 to
//! 91 times the truth's while Eq. 14's stays at 0.75. Without visibility `cellar` gets 1.5–2.3 times
//! the truth's one-bounce energy through its dividing wall.
//!
//! A still `cornell` frame costs 1.14 × the frame without GI at 256² with 3 × 3 photons (1.18 × at
//! 512²), 1.25 × with 8 × 8 and 1.57 × with 16 × 16 (1.99 × at 512²); the equations cost the same
//! within the noise. CPU-rasteriser times: only the ratios say something about a GPU.
//!
//! # Known issues
//! * No visibility: light arrives through walls and boxes (no indirect shadows).
//! * One bounce only, and few photons: a receiver near a photon sees it as a bright patch (Eq. 14) or
//!   as a point among M (Eq. 11), so colour bleeding is coarse at small M.
//! * Eq. 11 and 15 ignore the photon's normal: the back of a lit surface shines too (as the paper says).

mod extract;
mod prepare;
mod render;
mod settings;

use bevy::app::SubApp;
use bevy::prelude::*;

pub use prepare::{DrmFaceJob, DrmGatherUniform, DrmPhoton, DrmPhotonsUniform};
pub use settings::{DrmSettings, DrmSolidAngle};

use crate::camera::GiMethod;
use crate::method::{GiMethodModule, GpuCapabilities, Shortfall};

/// Direct Radiance Mapping: settings validation, the photon pass, the per-view gather. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct DrmPlugin;

impl Plugin for DrmPlugin {
    fn build(&self, app: &mut App) {
        let shaders = prepare::DrmShaders {
            types: crate::add_shader(app, "drm/drm_types.wgsl", include_str!("../../shaders/drm/drm_types.wgsl")),
            photons: crate::add_shader(app, "drm/photons.wgsl", include_str!("../../shaders/drm/photons.wgsl")),
            gather: crate::add_shader(app, "drm/gather.wgsl", include_str!("../../shaders/drm/gather.wgsl")),
        };
        crate::method::build_method::<Self>(app);
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(shaders);
        }
    }

    fn finish(&self, app: &mut App) {
        crate::method::finish_method::<Self>(app);
    }
}

impl GiMethodModule for DrmPlugin {
    const METHOD: GiMethod = GiMethod::Drm;
    const NAME: &'static str = "Direct Radiance Mapping";
    type Settings = DrmSettings;

    /// Compute shaders (the photon pass) with four storage buffers and workgroups of the crate's size.
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        gpu.require().compute().storage_buffers(4).missing()
    }

    fn add_render_systems(render_app: &mut SubApp) {
        render::add_render_systems(render_app);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_with_webgpu_default_limits_runs_drm_and_webgl2_does_not() {
        assert!(DrmPlugin::missing_capabilities(&GpuCapabilities::desktop()).is_empty());
        let names: Vec<_> = DrmPlugin::missing_capabilities(&GpuCapabilities::webgl2()).iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("COMPUTE_SHADERS")), "{names:?}");
    }
}
