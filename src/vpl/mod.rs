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
//!    background: one ray per texel through the snapshot's BVH, storing the distances to the first
//!    occluder and to its far side ([`generate::traced_shadow_maps`]). The paper's **imperfect shadow maps**
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
//!   **A receiver on the surface its texels met is lit** ([`generate::traced_visibility`]): across the
//!   gather's 2×2 texels a surface at a slant spans more depth than its solid is thick (at 32², 4 m away
//!   and 45°, about 0.7 m), so the far-side test shadowed the far part of every slanted surface's texels
//!   (a single spot-lit room, room_3, got 0.87 of its light; 0.94 with 64² maps, 0.95 with 128²). Each
//!   texel also keeps the distance to its first surface, and a receiver whose four texels all either see
//!   past it or met its own plane is lit whole. A receiver behind a wall has a texel on the wall among
//!   its four, so the wall still stops its light (stretching the far side over the slant instead lit the
//!   next room through the wall: room_5 at 1.8× its light). Measured at 64² on the tuning rooms: room_0
//!   0.213 → 0.178, room_3 0.267 → 0.230 (energy 0.87 → 0.94), room_4 0.231 → 0.167, room_136 0.583 →
//!   0.358 (its camera room 0.57 → 0.70), room_5 0.728 → 0.723, room_7 unchanged, room_2 0.489 → 0.531
//!   (its camera room, already too bright, 1.43 → 1.47); at 256² `cornell` 0.142 (unchanged), `cellar`
//!   0.314 → 0.312, `sponza_like` 0.209 → 0.213, `open_field` energy 0.86 → 0.87. Same rays, same memory
//!   (two half floats per texel instead of one float).
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
//! The walk after a sphere's move in `dynamic` (128², in the background): 5 of 160 paths walked again and
//! 40 000 of 478 000 traced texels, 33–37 ms against 145–149 ms for a walk from scratch.
//!
//! # Known issues
//! * Screen space sees only what the camera sees: SSBC cannot return the energy clamped near surfaces
//!   that are off screen or hidden (§4.3).
//! * Imperfect shadow maps (no longer the default) are coarse both ways: too much shadow next to contacts
//!   and concave edges, and light through thin walls where they meet another surface (`cellar`'s
//!   wall–ceiling junction at 1.9 × the truth with the medium preset). Traced maps are exact at their
//!   texels, but a 32² map spans 7° per texel: a receiver beside an occluder's silhouette or in a concave
//!   corner takes the neighbouring texels' verdict, and the 1 % tolerance lets light a hair past a wall's
//!   far side.
//! * A room lit only through a door gets few VPLs of its own (most land in the lit room): room_136's
//!   camera room gets 0.70 of its light (`docs/unseen_rooms.md`); with 1 000 paths instead of 160, 0.85.
//!   room_2's camera room (sunlit next door) gets 1.47 of its light: not investigated.
//! * Any change of a GI light, of the emissive surfaces, of the settings or of which meshes exist
//!   regenerates every VPL and every shadow map (off the main thread; the splats cost VPLs ×
//!   `ism_points`). When meshes only move, the walk keeps every path whose rays did not run through
//!   their old or new bounds and walks the others again (each path draws from its own index of its
//!   light's Sobol stream, so a kept path is the path a new walk would make), and the traced maps keep
//!   the texels of kept VPLs whose rays do not pass through those bounds
//!   ([`generate::VplPaths::rewalk`], [`generate::traced_shadow_maps_update`]; the same VPLs and maps
//!   as from scratch, checked by a unit test). A sun whose guides change with the move (a pilot ray's
//!   surface turns from or to the cameras) still regenerates all. A new set replaces the last at once,
//!   without a blend (consecutive sets of the same seed differ little).
//! * A sheet's (a quad without a back) depth in the traced maps is its own plus the depth it spans over the
//!   gather's texels: a receiver just behind a sheet at a grazing angle can still be lit.

mod extract;
pub mod generate;
mod prepare;
mod render;
mod settings;

use bevy::app::SubApp;
use bevy::prelude::*;

pub use extract::{VplRedone, VplSet};
pub use generate::Vpl;
pub use prepare::{GpuVpl, VplUniform};
pub use settings::{VplSettings, VplVisibility};

use crate::camera::GiMethod;
use crate::method::{GiMethodModule, GpuCapabilities, Shortfall};

/// The VPL method: settings validation, the walks, the shadow maps, the gather. SSBC is
/// [`crate::ssbc::SsbcPlugin`]. Added by [`crate::DiffuseGiPlugin`].
pub struct VplPlugin;

impl Plugin for VplPlugin {
    fn build(&self, app: &mut App) {
        let shaders = prepare::VplShaders {
            types: crate::add_shader(app, "vpl/vpl_types.wgsl", include_str!("../../shaders/vpl/vpl_types.wgsl")),
            ism: crate::add_shader(app, "vpl/ism.wgsl", include_str!("../../shaders/vpl/ism.wgsl")),
            gather: crate::add_shader(app, "vpl/gather.wgsl", include_str!("../../shaders/vpl/gather.wgsl")),
        };
        crate::method::build_method::<Self>(app);
        extract::add_main_systems(app);
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(shaders);
        }
    }

    fn finish(&self, app: &mut App) {
        crate::method::finish_method::<Self>(app);
    }
}

impl GiMethodModule for VplPlugin {
    const METHOD: GiMethod = GiMethod::Vpl;
    const NAME: &'static str = "the VPL method";
    type Settings = VplSettings;

    /// Compute shaders (the shadow maps) with six storage buffers. The largest shadow-map buffer
    /// (16384 × 32 VPLs) would exceed any device; the extraction caps the VPL count to what fits
    /// (`prepare::max_vpls_for`), so only a minimum binding size is required.
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        let binding = gpu.limits.max_storage_buffer_binding_size;
        gpu.require().compute().storage_buffers(6).at_least("max_storage_buffer_binding_size", 1 << 24, binding).missing()
    }

    fn add_render_systems(render_app: &mut SubApp) {
        render::add_render_systems(render_app);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_with_webgpu_default_limits_runs_vpls() {
        assert!(VplPlugin::missing_capabilities(&GpuCapabilities::desktop()).is_empty());
        let names: Vec<_> = VplPlugin::missing_capabilities(&GpuCapabilities::webgl2()).iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("COMPUTE_SHADERS")), "{names:?}");
    }
}
