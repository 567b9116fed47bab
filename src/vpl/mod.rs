//! Instant radiosity with virtual point lights (VPLs; Keller 1997), imperfect shadow maps for their
//! visibility (Ritschel et al. 2008), the clamped geometry term and screen-space bias compensation
//! (Novák, Engelhardt, Dachsbacher, "Screen-Space Bias Compensation for Interactive High-Quality Global
//! Illumination with Virtual Point Lights", I3D 2011).
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! # fn setup(mut commands: Commands) {
//! commands.spawn((Camera3d::default(), DiffuseGi { method: GiMethod::Vpl, ..default() }, VplSettings::MEDIUM));
//! commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//! # }
//! ```
//!
//! # Algorithm
//! The indirect light is Eq. 3 of the paper, `L = L_e + Σ_i T_rⁱ (T L_e + T_b L̂)`, truncated after
//! `ssbc_steps` terms:
//! 1. **VPLs** ([`generate`], main world, CPU): `light_paths` paths from the GI lights and the emissive
//!    surfaces ([`crate::emitters`]), split by power and stratified (Owen-scrambled Sobol, a fixed seed, so
//!    a still scene gets the same VPLs every frame), traced through the scene snapshot's BVH. A path from
//!    an emissive surface starts with a VPL on it (Bevy draws no light from emissive materials, so that
//!    VPL carries the surface's direct light too). Each path leaves a VPL at each of its first
//!    `bounces` surface hits, with the reflected flux `ρ·Φ` (the first one is what the light's RSM texel
//!    holds, `ρ·Φ_T`); the walk continues in a cosine-distributed direction. The paper, too, computes the
//!    random walks on the CPU (§5). Redone only when a light, the geometry or the settings change.
//! 2. **Shadow maps**, one small paraboloid depth map over each VPL's hemisphere, made only when the VPLs
//!    changed. By default ([`VplVisibility::Traced`]) they are ray-traced with the walks, in the
//!    background: one ray per texel through the snapshot's BVH, storing the far side of the first
//!    occluder ([`generate::traced_shadow_maps`]). The paper's **imperfect shadow maps**
//!    ([`VplVisibility::Imperfect`]; `shaders/vpl/ism.wgsl`, once per frame before the cameras): a fixed
//!    set of surface points ([`generate::ism_points`], uniform by area), of which each VPL splats its own
//!    run of `ism_points` (nearest depth by atomic max of the inverse distance); pull-push then fills the
//!    holes from up to two coarser levels (Ritschel §3.2).
//! 3. **Clamped gather** (`gather.wgsl`, per view): at each pixel `E_b = Σ Φ/π · G_b · V` with
//!    `G_b = min(G, b)` (§3.1) and `V` the imperfect shadow map test, written into the frame's target.
//! 4. **Screen-space bias compensation** ([`crate::ssbc`], per view, after the opaque pass): the residual
//!    operator `T_r` with `G_r = max(G − b, 0)` (§3.2) applied `ssbc_steps` times to the outgoing light of
//!    the visible surfaces (Bevy's direct light plus the clamped indirect light, then each step's result),
//!    over a mip chain of the G-buffer, inside the bounding radius `r = 1/√b` (§4.1–4.3).
//!
//! # Where this departs from the papers, and why
//! Each change was measured against the path-traced ground truth (`docs/vpl_ssbc.md`):
//! * The VPLs come from light paths traced on the CPU through the snapshot's BVH, the first hit included,
//!   rather than from sampling the GPU reflective shadow maps: the first hit of a path through a texel of
//!   a light's RSM *is* that texel's surface, with the same reflected flux, so the estimator is the same;
//!   reading the RSMs back would add a frame of latency, and the walks need the BVH anyway.
//! * Paths end by Russian roulette on the albedo (Keller 1997) instead of at a fixed depth: two fixed
//!   bounces left `cornell` at 0.75 of its energy.
//! * Directional lights draw their paths from a pilot grid that prefers surfaces facing a camera
//!   ([`generate::EmissionGuide`]; unbiased): a sun fitted to the whole scene otherwise spends most paths
//!   on the outside of a roof.
//! * The bound `b` defaults to the VPL density `N / A` over the scene's surfaces
//!   ([`generate::automatic_bound`]), so the bounding radius is the mean VPL spacing at any scene scale;
//!   a fixed number in 1/m² would be right for one room size only.
//! * **Ray-traced second-depth shadow maps** instead of imperfect ones, by default: on a generated family
//!   of rooms (`docs/unseen_rooms.md`) the imperfect maps lit the camera's room through a 28 cm wall
//!   (room_5: 4.4× its light, block RMSE 8.7; exact visibility on the CPU with the same VPLs: 0.80 /
//!   0.53), through gaps between the splatted points and through the slope-scaled depth tolerance, which
//!   reaches the whole distance for a floor behind a wall seen from a floor VPL. A ray per texel sees
//!   every wall; storing the far side of the first occluder (Wang & Molnar 1994) keeps the first surface
//!   lit with a 1 % tolerance and no slope term. Measured at 256² (medium): `cornell` 0.184 → 0.142,
//!   `cellar` 0.416 → 0.314, `sponza_like` 0.295 → 0.209, room_5 8.7 → 0.73. The rays cost
//!   VPLs × side² × 2 in the background, with the walks.
//!   A sheet (a quad without a back, such as a `Plane3d` panel) has no far side: its own depth plus the
//!   depth it spans over the gather's 2×2 texels is stored instead ([`generate::sheet_depth`]). With the
//!   second surface, the light of `emissive_panel`'s upper face reached the room through the panel
//!   (1.19× the energy, block RMSE 0.506; now 0.938 / 0.305); the other scenes did not change (`cellar`
//!   0.314 → 0.311).
//! * Imperfect shadow-map points are splatted as the disk of surface each stands for, not as single texels, and
//!   the depth test has a slope-scaled tolerance plus that disk's radius: single texels let a room's light
//!   through a 20 cm wall (`cellar` block RMSE 1.05 instead of 0.43), and without the slope term surfaces
//!   shadowed themselves (11 % of `cornell`'s one-bounce energy).
//! * Bevy's rasteriser draws the direct light, and SSBC reads it from the view's main texture after the
//!   opaque pass (with the emission and ambient light Bevy adds there).
//!
//! # Cost (skipping what a scene does not need)
//! No camera with [`GiMethod::Vpl`](crate::camera::GiMethod::Vpl): nothing runs, not even the walks.
//! A still scene reuses its VPLs and shadow maps; per frame only the gather (`O(pixels × VPLs)`) and SSBC
//! (`O(pixels × samples × steps)`) run per view. The walks (the lights' pilot rays, the random walks,
//! the shadow maps' point set) run in the background ([`crate::background`]) when their inputs change,
//! over a copy of the scene snapshot: the frame uses the last finished set (usually the previous
//! frame's inputs: the VPLs lag a change by a frame or two), and the main thread only compares inputs
//! and draws the guides ([`MainThreadCost::vpl_ms`](crate::MainThreadCost)).
//!
//! # Measured (lavapipe, 256², `docs/vpl_ssbc.md`)
//! | scene | medium, traced maps: block RMSE / energy | medium, imperfect maps | high, imperfect | still frame, medium |
//! |---|---|---|---|---|
//! | `cornell` | 0.142 / 0.996 | 0.184 / 0.926 | 0.148 / 0.978 | 9.0 × the frame without GI (3.5 × at half resolution, the default) |
//! | `cellar` | 0.314 / 1.001 | 0.416 / 0.986 | 0.369 / 1.042 | |
//! | `sponza_like` | 0.209 / 1.062 | 0.295 / 0.920 | 0.257 / 0.918 | |
//!
//! On the generated rooms (64², `docs/unseen_rooms.md`) the numbers are in that page's tables.
//!
//! Per pass at 256² (differences of frame times): the gather about 0.3 ms per VPL, each SSBC step about
//! 90 ms, the shadow maps only when the VPLs change. No GPU was available: these are CPU-rasteriser times.
//!
//! # Known issues
//! * Screen space sees only what the camera sees: SSBC cannot return the energy clamped near surfaces
//!   that are off screen or hidden (§4.3).
//! * Imperfect shadow maps (no longer the default) are coarse both ways: too much shadow next to contacts
//!   and concave edges, and light through thin walls where they meet another surface (`cellar`'s
//!   wall–ceiling junction at 1.9 × the truth with the medium preset). Traced maps are exact at their
//!   texels, but a 32² map spans 7° per texel: a receiver beside an occluder's silhouette takes the
//!   neighbouring texels' verdict, and the 1 % tolerance lets light a hair past a wall's far side.
//! * A room lit only through a door gets few VPLs of its own (most land in the lit room): room_136's
//!   camera room gets 0.57 of its light (`docs/unseen_rooms.md`).
//! * Any change of a GI light or of the geometry regenerates every VPL and every shadow map (the walks are
//!   cheap and off the main thread; the splats cost VPLs × `ism_points`); a moving mesh also rebuilds
//!   the snapshot. A new set replaces the last at once, without a blend (consecutive sets of the same
//!   seed differ little).
//! * A sheet's (a quad without a back) depth in the traced maps is its own plus the depth it spans over the
//!   gather's texels: a receiver just behind a sheet at a grazing angle can still be lit.

pub mod generate;
pub(crate) mod extract;
pub use extract::VplSet;
mod render;

use bevy::prelude::*;
use bevy::render::RenderApp;

pub use generate::Vpl;

pub use render::{GpuVpl, VplUniform};

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
    /// [`TRACED_DEPTH_BIAS`](render::TRACED_DEPTH_BIAS) and no slope term.
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

    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
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
        (s, c.fields)
    }
}

/// The GPU capabilities the VPL method needs, as `(name, required, found)` for every shortfall.
pub fn missing_capabilities(limits: &bevy::render::settings::WgpuLimits, compute: bool) -> Vec<crate::Shortfall> {
    let mut missing = Vec::new();
    let mut need = |name, required: u64, found: u64| {
        if found < required {
            missing.push((name, required, found));
        }
    };
    need("compute shaders (DownlevelFlags::COMPUTE_SHADERS)", 1, compute as u64);
    need("max_storage_buffers_per_shader_stage", 6, limits.max_storage_buffers_per_shader_stage as u64);
    let threads = crate::WORKGROUP_SIZE as u64;
    need("max_compute_workgroup_size_x", threads, limits.max_compute_workgroup_size_x as u64);
    need("max_compute_invocations_per_workgroup", threads, limits.max_compute_invocations_per_workgroup as u64);
    // The largest shadow-map buffer: 16384 × 32 VPLs would exceed any device; the extraction caps the VPL
    // count to what fits (see `render::max_vpls_for`), so only a minimum is required here.
    need("max_storage_buffer_binding_size", 1 << 24, limits.max_storage_buffer_binding_size);
    missing
}

/// The VPL method: settings validation, the walks, the shadow maps, the gather. SSBC is
/// [`crate::ssbc::SsbcPlugin`]. Added by [`crate::DiffuseGiPlugin`].
pub struct VplPlugin;

impl Plugin for VplPlugin {
    fn build(&self, app: &mut App) {
        let shaders = render::VplShaders {
            types: crate::add_shader(app, "vpl/vpl_types.wgsl", include_str!("../../shaders/vpl/vpl_types.wgsl")),
            ism: crate::add_shader(app, "vpl/ism.wgsl", include_str!("../../shaders/vpl/ism.wgsl")),
            gather: crate::add_shader(app, "vpl/gather.wgsl", include_str!("../../shaders/vpl/gather.wgsl")),
        };
        app.register_type::<VplSettings>()
            .init_resource::<extract::VplSet>()
            .init_resource::<extract::VplWalks>()
            .add_systems(
                PostUpdate,
                (
                    crate::settings::validate_settings::<VplSettings>,
                    extract::update_vpls.after(crate::scene::SceneSnapshotSystems::Update).after(crate::emitters::update_emitters),
                ),
            );
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(shaders);
        }
    }

    fn finish(&self, app: &mut App) {
        use bevy::render::render_resource::DownlevelFlags;
        let supported = crate::gpu_supports(app, "the VPL method", |limits, flags| {
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

    #[test]
    fn a_device_with_webgpu_default_limits_runs_vpls() {
        assert!(missing_capabilities(&bevy::render::settings::WgpuLimits::default(), true).is_empty());
        let names: Vec<_> = missing_capabilities(&bevy::render::settings::WgpuLimits::downlevel_webgl2_defaults(), false)
            .iter()
            .map(|m| m.0)
            .collect();
        assert!(names.iter().any(|n| n.contains("COMPUTE_SHADERS")), "{names:?}");
    }
}
