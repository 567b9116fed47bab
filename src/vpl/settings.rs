//! The VPL method's settings component: `LOW`/`MEDIUM`/`HIGH`, the visibility choice and their
//! validation.

use bevy::prelude::*;

use crate::settings::{Clamped, GiSettings};

/// The settings of the VPL method, on a camera with [`DiffuseGi`](crate::camera::DiffuseGi)
/// `{ method: GiMethod::Vpl, .. }`. A camera without it uses [`VplSettings::default`] (the medium preset).
///
/// The VPLs and their shadow maps are shared by every camera: the first VPL camera's generation fields
/// (`light_paths`, `bounces`, `seed`, `ism_*`) decide them; the gather and SSBC fields are per camera.
/// Invalid values are clamped to their range with one warning.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[doc(alias = "InstantRadiosity")]
#[doc(alias = "SSBC")]
pub struct VplSettings {
    /// Light paths traced from the GI lights (split between them by power). Each leaves up to
    /// [`bounces`](Self::bounces) VPLs. Range 1–16384; low 64, medium 160, high 384. Cost: the gather is
    /// linear in the VPL count per pixel, and the shadow maps in VPLs × `ism_points`. A change: new walks
    /// (in the background) and shadow maps.
    pub light_paths: u32,
    /// Most surface hits per light path that leave a VPL: 1 is one-bounce indirect light, 2 adds light
    /// that bounced twice, and so on. Paths end earlier by Russian roulette on the albedo, so a room of
    /// albedo ρ gets about `paths / (1 − ρ)` VPLs whatever the cap; a low cap loses the light of the
    /// longer paths (the tail `ρ^bounces`). Range 1–32; default 16. Cost: at most paths × bounces VPLs.
    /// A change: new walks (in the background) and shadow maps.
    pub bounces: u32,
    /// Seed of the quasi-random light paths. Any value; default 0. Changing it gives another, equally good
    /// VPL set (an animation of it flickers, a fixed one does not). A change: new walks and points (in
    /// the background) and shadow maps.
    pub seed: u32,
    /// Bound `b` of the clamped geometry term `G_b = min(G, b)` (§3.1), in 1/m². `0` (the default) picks it
    /// from the VPL density: `b = N_VPL / A_surfaces`, so that the bounding radius `r = 1/√b` is the mean
    /// VPL spacing. Range 0 or 10⁻⁶–10⁶. Larger values clamp less (brighter splotches near VPLs, less for
    /// SSBC to return); smaller values clamp more and make SSBC search a larger radius (slower).
    pub geometry_bound: f32,
    /// How the VPLs' shadow maps are made. Default [`VplVisibility::Traced`]. A change: new shadow maps
    /// (traced in the background, or splatted), no new walks.
    pub visibility: VplVisibility,
    /// Side of each VPL's shadow map (paraboloid over its hemisphere), in texels, rounded down to a
    /// multiple of 4. Range 8–128; medium 32. Cost: memory VPLs × side² × 5.25 bytes; traced maps cost
    /// VPLs × side² rays in the background, imperfect ones need more `ism_points` to fill finer maps.
    /// A change: new shadow maps (no new walks).
    pub ism_resolution: u32,
    /// [`VplVisibility::Imperfect`] only: scene points each VPL splats into its shadow map, each as the
    /// footprint of the surface disk it stands for (`area / ism_points`). Range 64–65536; medium 8192.
    /// Cost: linear, once per VPL change.
    /// A change: a new point set (in the background) and shadow maps.
    /// Too few make coarse disks that shadow nearby surfaces too much and leave gaps where thin walls meet
    /// (light through walls).
    pub ism_points: u32,
    /// [`VplVisibility::Imperfect`] only: depth tolerance of the shadow map test, as a fraction of the
    /// distance to the VPL, on top of a slope-scaled part that grows with the receiver's tilt (see
    /// `gather.wgsl`). Range 0–1; default 0.05. Smaller values shadow more surfaces wrongly
    /// (self-shadowing acne); larger ones let light through thin occluders. Traced maps use
    /// [`TRACED_DEPTH_BIAS`](super::prepare::TRACED_DEPTH_BIAS) and no slope term.
    pub ism_bias: f32,
    /// Screen-space bias compensation steps (terms of Eq. 3 after the first): 0 is the clamped solution
    /// alone. Range 0–3; medium 1. Cost: each step is one hierarchical gather per pixel.
    pub ssbc_steps: u32,
    /// Projected solid angle above which SSBC refines a G-buffer sample into its four children (§4.2),
    /// in steradians. Range 0.001–1; default 0.08 (the paper's). Smaller is more accurate and slower.
    pub ssbc_solid_angle: f32,
    /// Projected solid angle above which a sample spanning a depth or normal discontinuity is refined
    /// (§4.2), in steradians. Range 0.001–1; default 0.04 (the paper's).
    pub ssbc_discontinuity_solid_angle: f32,
    /// Levels of the hierarchical G-buffer SSBC traverses. Range 1–8; default 6 (the paper's).
    pub ssbc_levels: u32,
    /// Blur the compensation with a 5×5 depth- and normal-aware filter before adding it (§5, optional in
    /// the paper). Default `true`. Cost: one small pass.
    pub ssbc_blur: bool,
    /// Multiplies the indirect light. Range 0–1000; default 1.
    pub intensity: f32,
}

/// How a VPL's visibility is found ([`VplSettings::visibility`]).
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum VplVisibility {
    /// Shadow maps ray-traced on the CPU through the scene snapshot's BVH, one ray per texel, with the
    /// walks in the background ([`generate::traced_shadow_maps`]). Every wall blocks light whatever its
    /// thickness. The default.
    #[default]
    Traced,
    /// Imperfect shadow maps (Ritschel et al. 2008), the paper's: each VPL splats `ism_points` scene
    /// points on the GPU, then pull-push fills the holes. No CPU rays, but light leaks through walls
    /// thinner than the gaps between the points and where walls meet (`docs/unseen_rooms.md`).
    Imperfect,
}

impl VplSettings {
    /// 64 paths (about 200 VPLs in a room of albedo 0.7), 16² shadow maps of 2048 points, one SSBC step.
    pub const LOW: Self = Self {
        light_paths: 64,
        bounces: 16,
        seed: 0,
        geometry_bound: 0.0,
        visibility: VplVisibility::Traced,
        ism_resolution: 16,
        ism_points: 2048,
        ism_bias: 0.05,
        ssbc_steps: 1,
        ssbc_solid_angle: 0.08,
        ssbc_discontinuity_solid_angle: 0.04,
        ssbc_levels: 6,
        ssbc_blur: true,
        intensity: 1.0,
    };
    /// 160 paths (about 530 VPLs at albedo 0.7), 32² shadow maps of 8192 points, one SSBC step (the
    /// default).
    pub const MEDIUM: Self = Self {
        light_paths: 160,
        ism_resolution: 32,
        ism_points: 8192,
        ..Self::LOW
    };
    /// 384 paths (about 1300 VPLs at albedo 0.7), 48² shadow maps of 16384 points, two SSBC steps.
    pub const HIGH: Self = Self {
        light_paths: 384,
        ism_resolution: 48,
        ism_points: 16384,
        ssbc_steps: 2,
        ..Self::MEDIUM
    };

    /// The VPL count this allows at most (paths × bounces; Russian roulette usually stops far below).
    pub fn max_vpls(&self) -> u32 {
        self.light_paths * self.bounces
    }
}

impl Default for VplSettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for VplSettings {
    const NAME: &'static str = "VplSettings";

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        c.uint(&mut s.light_paths, 1, 16384, "light_paths");
        c.uint(&mut s.bounces, 1, 32, "bounces");
        // 0 is valid: the automatic bound.
        if s.geometry_bound != 0.0 {
            c.float(&mut s.geometry_bound, 1e-6, 1e6, 0.0, "geometry_bound");
        }
        c.uint(&mut s.ism_resolution, 8, 128, "ism_resolution");
        c.uint(&mut s.ism_points, 64, 65536, "ism_points");
        c.float(&mut s.ism_bias, 0.0, 1.0, 0.05, "ism_bias");
        c.uint(&mut s.ssbc_steps, 0, 3, "ssbc_steps");
        c.float(&mut s.ssbc_solid_angle, 0.001, 1.0, 0.08, "ssbc_solid_angle");
        c.float(&mut s.ssbc_discontinuity_solid_angle, 0.001, 1.0, 0.04, "ssbc_discontinuity_solid_angle");
        c.uint(&mut s.ssbc_levels, 1, 8, "ssbc_levels");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        for preset in [VplSettings::LOW, VplSettings::MEDIUM, VplSettings::HIGH] {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
        }
        assert!(VplSettings::LOW.max_vpls() < VplSettings::MEDIUM.max_vpls());
        assert!(VplSettings::MEDIUM.max_vpls() < VplSettings::HIGH.max_vpls());
        assert_eq!(VplSettings::default(), VplSettings::MEDIUM);
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = VplSettings {
            light_paths: 0,
            bounces: 100,
            geometry_bound: f32::NAN,
            ism_resolution: 4096,
            ism_bias: -1.0,
            ssbc_steps: 9,
            intensity: f32::INFINITY,
            ..VplSettings::MEDIUM
        };
        let (clean, bad) = s.sanitized();
        let bad: Vec<_> = bad.iter().map(|b| b.0).collect();
        assert_eq!(
            bad,
            vec!["light_paths", "bounces", "geometry_bound", "ism_resolution", "ism_bias", "ssbc_steps", "intensity"]
        );
        assert_eq!((clean.light_paths, clean.bounces, clean.ism_resolution, clean.ssbc_steps), (1, 32, 128, 3));
        assert_eq!((clean.geometry_bound, clean.ism_bias, clean.intensity), (0.0, 0.0, 1.0));
        assert!(clean.sanitized().1.is_empty());
    }
}
