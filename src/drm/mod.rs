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

mod render;

use bevy::prelude::*;
use bevy::render::RenderApp;

pub use render::{DrmFaceJob, DrmGatherUniform, DrmPhoton, DrmPhotonsUniform};

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

    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
        c.uint(&mut s.samples_per_axis, 1, Self::MAX_SAMPLES_PER_AXIS, "samples_per_axis");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
        (s, c.fields)
    }
}

/// The GPU capabilities DRM needs, as `(name, required, found)` for every shortfall: compute shaders
/// (the photon pass) with four storage buffers and workgroups of the crate's size.
pub fn missing_capabilities(limits: &bevy::render::settings::WgpuLimits, compute: bool) -> Vec<crate::Shortfall> {
    let mut missing = Vec::new();
    let mut need = |name, required: u64, found: u64| {
        if found < required {
            missing.push((name, required, found));
        }
    };
    need("compute shaders (DownlevelFlags::COMPUTE_SHADERS)", 1, compute as u64);
    need("max_storage_buffers_per_shader_stage", 4, limits.max_storage_buffers_per_shader_stage as u64);
    let threads = crate::WORKGROUP_SIZE as u64;
    need("max_compute_workgroup_size_x", threads, limits.max_compute_workgroup_size_x as u64);
    need("max_compute_invocations_per_workgroup", threads, limits.max_compute_invocations_per_workgroup as u64);
    missing
}

/// Direct Radiance Mapping: settings validation, the photon pass, the per-view gather. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct DrmPlugin;

impl Plugin for DrmPlugin {
    fn build(&self, app: &mut App) {
        let shaders = render::DrmShaders {
            types: crate::add_shader(app, "drm/drm_types.wgsl", include_str!("../../shaders/drm/drm_types.wgsl")),
            photons: crate::add_shader(app, "drm/photons.wgsl", include_str!("../../shaders/drm/photons.wgsl")),
            gather: crate::add_shader(app, "drm/gather.wgsl", include_str!("../../shaders/drm/gather.wgsl")),
        };
        app.register_type::<DrmSettings>()
            .add_systems(PostUpdate, crate::settings::validate_settings::<DrmSettings>);
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(shaders);
        }
    }

    fn finish(&self, app: &mut App) {
        use bevy::render::render_resource::DownlevelFlags;
        let supported = crate::gpu_supports(app, "Direct Radiance Mapping", |limits, flags| {
            missing_capabilities(limits, flags.contains(DownlevelFlags::COMPUTE_SHADERS))
        });
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
    fn a_device_with_webgpu_default_limits_runs_drm_and_webgl2_does_not() {
        use bevy::render::settings::WgpuLimits;
        assert!(missing_capabilities(&WgpuLimits::default(), true).is_empty());
        let names: Vec<_> = missing_capabilities(&WgpuLimits::downlevel_webgl2_defaults(), false).iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("COMPUTE_SHADERS")), "{names:?}");
    }

    #[test]
    fn equations_are_the_papers() {
        assert_eq!(DrmSolidAngle::ALL.map(DrmSolidAngle::equation), [11, 14, 15]);
    }
}
