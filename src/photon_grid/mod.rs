//! The photon grid and spherical-harmonics field (Chang, Park & Ihm, "Ray Tracing-based Interactive
//! Diffuse Indirect Illumination"): photons traced from every light, many bounces deep, turned into the
//! reflected radiance on the faces of a grid and from there into a field of incoming radiance in
//! spherical harmonics around the surfaces, which each pixel gathers. It needs no reflective shadow map
//! and no volume: the grid covers the scene; emissive meshes and the camera's environment map light it
//! too. The plugin's multi-bounce method for large, mostly indirectly lit spaces.
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! # fn setup(mut commands: Commands) {
//! commands.spawn((Camera3d::default(), DiffuseGi { method: GiMethod::PhotonGrid, ..default() }, PhotonGridSettings::MEDIUM));
//! commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//! # }
//! ```
//!
//! # Algorithm (the preparation stage, §3, in a background task: on the CPU with rayon, [`grid`]; the SH field on the GPU too, `field_gpu.rs`)
//! 1. **Grids** (§3.1): the scene's box is cut into cubic SH-grid cells,
//!    [`resolution`](PhotonGridSettings::resolution) along its longest side, and each into 4 × 4 × 4
//!    V-grid cells. Every triangle marks the V-cells it overlaps (a triangle–box test) as *boundary
//!    cells*, which keep the area-weighted sum of their triangles' normals; an SH cell is a boundary
//!    cell when one of its V-cells is.
//! 2. **Photons** (§3.2): [`photons`](PhotonGridSettings::photons) photons leave the GI lights (every
//!    kind: points over the sphere, spots over their cone with Bevy's falloff, directional lights
//!    through a disc before the scene), the emissive triangles (by power) and the environment map, in
//!    proportion to their flux. At each surface the photon is reflected by Russian roulette on the
//!    diffuse albedo (textures included) into a cosine-distributed direction; a reflected photon is
//!    stored in the *global photon list* with that outgoing direction, the flux it leaves with and its
//!    SH cell, up to [`max_reflections`](PhotonGridSettings::max_reflections) per path (the paper
//!    keeps four; the default is eight, see the field). Emission is stored where it leaves an emitter.
//! 3. **R-grid** (§3.3, Fig. 3): the list is sorted by cell ([A] → [B]), the first photon of each cell
//!    flagged ([C]), the flags scanned ([D]) into the offsets of each non-empty cell ([E]), and one task
//!    per non-empty cell sums its photons' flux into the six faces of the cell with the weights
//!    `d_x², d_y², d_z²` of the faces the outgoing direction `d` points through (Fig. 2), without
//!    atomics. Coarser levels sum 2 × 2 × 2 cells.
//! 4. **SH field** (§3.4): at the centre of every boundary SH cell and its 26 neighbours,
//!    [`sh_directions`](PhotonGridSettings::sh_directions) (`N_sh`) rays of a spherical Fibonacci
//!    lattice cross the grid (empty SH cells in one step, then V-cell by V-cell: the two-level
//!    traversal of §3.4.2) to the first boundary V-cell, and read the R-grid there at the level whose
//!    face area bounds the ray's footprint `4π d² / (N_sh cos β)` (§3.4.3, interpolated between two
//!    levels, no coarser than [`filter_levels`](PhotonGridSettings::filter_levels)). Rays that leave the grid see the environment map. The radiance and the distance are
//!    projected on nine SH coefficients (bands 0–2) by Eq. 1 (§3.4.4: the distance is the fourth
//!    component). Where [`field_device`](PhotonGridSettings::field_device) says so (by default on
//!    hardware GPUs where it measures faster), this stage runs on the GPU, as in the paper: the background task uploads the
//!    V-grid, the R-grid and the directions, dispatches `shaders/photon_grid/field.wgsl` (a workgroup
//!    per eight probes, each probe's directions split over eight threads, so that neighbouring threads
//!    march one direction from neighbouring probes) in chunks of about 2¹⁸ rays, waiting for each so
//!    that the frame's own work runs between them, and reads the coefficients back; the rest of the
//!    preparation is the CPU's either way. A probe whose rays have met the back of a surface
//!    [`inside_limit`](grid::inside_limit) times is dropped at once, without marching its other rays
//!    (on both; the field is the same).
//! 5. **Final gather** (§4, `shaders/photon_grid/gather.wgsl`, per pixel of each view): the
//!    coefficients of the 27 cells around the pixel's surface point, weighted by
//!    `w_sh(d) = 2d³/r³ − 3d²/r² + 1` with `r` = [`r_max`](PhotonGridSettings::r_max) cells (1.75, the
//!    paper's), then the hemisphere integral of §4.2 with the pixel's G-buffer normal, either by the
//!    paper's `N_d` sample directions ([`gather_samples`](PhotonGridSettings::gather_samples)) or exactly
//!    with the clamped-cosine convolution of the nine coefficients (`N_d = 0`). The obscurance of §4.4
//!    from the distance field is optional ([`obscurance_distance`](PhotonGridSettings::obscurance_distance)).
//!    The frame's filter, upsampling and composite do the rest.
//!
//! # Where this departs from the paper, and why
//! * **Bevy's rasteriser** sees the primary surfaces, and the preparation runs on the CPU's threads
//!   (with the snapshot's BVH for photons), not in CUDA, except the SH field where the GPU builds it:
//!   see *Cost*.
//! * **Face radiance**: the paper's face value `Σ f_r δ Φ / A` reads a Lambertian plane across a cell at
//!   half its radiance (only half the flux of cosine-distributed directions leaves through the face it
//!   faces: `E[cos²θ] = ½`), and its blend of visible faces by the angle to their centres reads a floor
//!   seen at 45° at 0.6 of that. Here the ray reads the face flux at the hit V-cell's own normal (turned
//!   towards the ray), `L = 2 Σ_j n_j² F_j / (π A)`: exact for a plane across a cell, within 5 % at
//!   45° (unit tests). The V-cell normal is what the paper uses to decide visibility.
//! * **Two-sided surfaces**, as in the path tracer: a ray stops at any boundary V-cell. A probe whose
//!   rays meet the back of surfaces in more than 10 % of directions lies inside solid geometry and is
//!   dropped.
//! * **Walls thinner than a cell**: the paper's faces carry the light of everything in their cell, so
//!   a floor photon beside a thin wall lit the face behind it. A photon does not light the faces of its
//!   cell that a surface facing it hides ([`VGrid::blocked_faces`]), and light that meets another
//!   surface within a V-cell (a panel 1 mm under a ceiling) is not stored at all. The radiance filter
//!   reads at most [`filter_levels`](PhotonGridSettings::filter_levels) above the base (coarse cells mix
//!   both sides of a wall). The gather weighs the probes by a *side weight* (0 from a quarter cell
//!   behind the surface, 1 from half a cell in front), drops those whose distance field puts a surface
//!   between them and the pixel, and those a boundary V-cell hides from it (a march through the V-grid,
//!   unless that drops them all): a wall pixel under a thin roof no longer gathers the probe above the
//!   roof, which sees the sky.
//! * **The gather's integral** is exact for the nine coefficients by default; the paper's 32 uniform
//!   directions estimate the same integral with noise.
//! * **Glossy reflection** of indirect light (§4.3) is not done: the frame carries diffuse irradiance
//!   only.
//!
//! # Cost
//! Nothing runs without an active camera using [`GiMethod::PhotonGrid`](crate::camera::GiMethod).
//! The preparation never runs on the main thread: it is a task on the crate's background thread pool
//! (its rayon loops stay on that pool) over a copy of the scene snapshot ([`crate::background`]), started
//! when what it depends on changed since the last one began, one at a time (changes made meanwhile are
//! coalesced into the next). It redoes the V-grid when geometry changed, and photons, R-grid and SH
//! field when geometry, lighting or a preparation setting did (the paper redoes all four every frame
//! on the GPU). **When meshes move** (and nothing else changed), only what ran near them is redone:
//! each photon path draws its random numbers from its own stream, so a path is the same path until a
//! change lies along it; the preparation keeps each path's ray end points and flux balance, and the
//! V-cell each probe ray met, and traces again only the paths whose rays ran within an SH cell (and a
//! V-cell) of a moved instance's old or new bounds, and marches only the probe rays that did (the
//! others read their radiance from the new R-grid). The photons and the field are those of a
//! preparation from scratch (`grid::tests`). The records are kept only once a mesh has moved between
//! two preparations ([`PhotonGridActivity::kept_bytes`]); a light, the sky, an emissive mesh or a mesh
//! added or removed redoes every path. The gather-only settings (`intensity`, `r_max`, `gather_samples`,
//! `obscurance_distance`) run no preparation. The last field is gathered from until the new one is
//! ready, then blended in over [`BLEND_FRAMES`](crate::background::BLEND_FRAMES) frames, cell by cell:
//! the task also flattens the new coefficients and lays the last field's out at the new probes, and the
//! gather mixes the two buffers by a weight in its uniform. A field that arrives while the one before
//! it still blends in waits for that blend to end (at most five frames) and then starts from the
//! laid-out last field; a third field arriving meanwhile (a preparation shorter than the blend's
//! frames) replaces the waiting one, and its start is laid out again in the background from where the
//! shown field's blend ends (the waiting field was never shown). The main thread pays for polling and
//! copying the snapshot when a task starts (O(instances)), and swaps `Arc`s when a field arrives
//! ([`MainThreadCost::photon_grid_ms`](crate::MainThreadCost): at most 0.26 ms a frame in `dynamic`
//! with one mesh moving at 64² and 0.08–0.16 ms at 256²; 3.2 ms when a new field's coefficients were
//! copied and blended on it, 0.5–0.8 ms in each blend frame at the default, and 0.9–4.3 ms at 256² when
//! a field arriving mid-blend had its start mixed on the main thread: on a machine whose frames are
//! slow next to the preparation, that was the worst frame of every motion). [`PhotonGridActivity`]
//! and the diagnostics `diffuse_gi/photon_{voxelize,trace,rgrid,field}` report the paper's Table 1
//! stages (milliseconds of the background task); the gather is the GPU span `diffuse_gi/photon_gather`.
//!
//! # Measured (`docs/photon_grid.md`, 256², lavapipe for the gather, two CPU cores for the preparation)
//! Default preset (32 cells, 262 144 photons, eight reflections, `N_sh` 256), block relative RMSE /
//! energy against the full path-traced truth: `cornell` 0.141 / 0.92, `cellar` (a second room lit
//! through a door) 0.181 / 1.02, `sponza_like` (the sun through a roof) 0.169 / 0.95, `dynamic` (a
//! point light) 0.069 / 0.99, `emissive_panel` 0.231 / 0.96, `sky_room` (the sky only) 0.184 / 0.89;
//! `open_field` 0.92 / 0.52 (60 m under one grid: cells of 1.9 m). With the paper's four reflections
//! `cornell`'s energy is 0.86; without the radiance filter (the base level only) `cornell` is 0.11 but
//! `cellar` loses 12 % of its light, with the paper's unbounded filter `cellar` is 0.30.
//!
//! The preparation at the default takes 2.0 s for `cornell` (voxelisation 2 %, photons 20 %, R-grid
//! 2 %, SH field 77 %), 0.76 s for `cellar` and 0.75 s for `sponza_like` on two cores; the high preset
//! 19 s, 4.9 s and 7.7 s (the paper's Table 1, on a GPU, has its R-grid and SH field at 35–70 %). A
//! still frame costs 1.41 × the frame without GI on `cornell` at 256² (1.88 at 512²), 1.21 (1.62) on
//! `sponza_like`: the gather reads 27 cells of nine coefficients and marches the V-grid to each.
//!
//! A moving mesh (`dynamic`, the sphere, default preset, 128², alternating runs of the builds before
//! and after the partial update): 28 000 of 262 144 paths traced again and 92 000 of 3.4 million probe
//! rays marched per preparation; photons 376–550 → 137–171 ms, SH field 1 045–1 515 → 432–611 ms (its
//! rest is reading every ray's radiance again), the preparation 1.5–2.2 → 0.65–0.9 s; the records
//! take 41 MiB (`cornell`: 48 MiB).
//!
//! **The SH field on the GPU or the CPU** (`photon_grid_report --section field_device`, 256², two
//! alternating rounds, the field's milliseconds in the background task while frames render, lavapipe on
//! the same two cores as the CPU path): `cornell` 2 048–2 180 on the CPU against 2 443–3 049 on the GPU,
//! `cellar` 393–442 against 1 036–1 155, `sponza_like` 675–715 against 1 339–1 439, `dynamic`
//! 1 158–1 280 against 2 268–2 784. On a CPU rasteriser the CPU path is faster (scalar walks on the
//! same cores, against 8-wide SIMD batches that last as long as their longest walk), so
//! [`FieldDevice::Auto`] builds there on the CPU. On hardware GPUs, where no session of this work could
//! measure (none was lent), `Auto` measures at run time: the first field on the GPU (the paper's
//! Table 1 has its field in milliseconds on a 2011 GPU), the second on the CPU, then on whichever built
//! its last field faster per probe ray ([`FieldTimings`]). The two fields agree (block RMSE 0.0000–0.0002 between the images; 20 of
//! `cornell`'s 11 523 probes cross the inside threshold on one and not the other, where a ray grazes a
//! surface; `tests/gpu_photon_grid.rs`). The pipeline is made by the render world's pipeline cache when
//! a preparation first asks for it, and handed to the background task.
//! Dropping the probes inside solid geometry after `inside_limit` back faces took `cornell`'s CPU field
//! from 2 273–2 358 ms (4.9 million rays marched) to 1 817–2 047 ms (3.4 million), with the same field.
//! The other stages stay on the CPU: they are written as the GPU would run them (one task per photon,
//! per non-empty cell, no atomics), so that a compute port can follow.
//!
//! # Known issues
//! * A moving light costs a whole preparation (seconds at the high preset); a moving mesh the paths
//!   and probe rays near it, but still the V-grid, the R-grid and every probe ray's radiance (0.5–0.8 s
//!   in `dynamic` at the default). The frame does not wait for it, but the light lags by one
//!   preparation. Of the paper's GPU preparation only the SH field is ported; photon tracing, the
//!   R-grid and the V-grid stay on the CPU. The GPU's field marches every probe ray after a move (the
//!   CPU's only those near it).
//! * On a CPU rasteriser, `FieldDevice::Gpu` is slower than the CPU, and each of its chunks (19 for
//!   `cornell`'s 2.2–2.4 s on lavapipe) delays the frame queued behind it.
//! * After a mesh moved, the preparation keeps 40–50 MiB of records at the default preset (about 100
//!   bytes a photon path and 4 a probe ray; some 170 MiB at the high preset) until the method is
//!   switched off.
//! * One grid over the whole scene's box: a large scene gets large cells (`open_field`), and a surface
//!   smaller than a cell (a small object, a light 10 cm under a ceiling) is averaged over the cell.
//! * A wall thinner than an SH cell has both faces in one R-grid cell; its faces are kept apart by the
//!   photons' directions and the blocked faces, but the coarser R-grid levels mix them.
//! * The obscurance (§4.4) is optional and off: it is not physically based, and the distance field
//!   keeps distances up to four cells only.

mod extract;
mod field_gpu;
pub mod grid;
mod prepare;
mod render;
mod settings;

use bevy::app::SubApp;
use bevy::prelude::*;

pub use extract::{
    DIAGNOSTIC_FIELD, DIAGNOSTIC_RGRID, DIAGNOSTIC_TRACE, DIAGNOSTIC_VOXELIZE, DISTANCE_CELLS, FieldTimings, PhotonGridActivity,
    PhotonGridCore, PhotonGridOutput, PhotonGridState, PhotonGridTimes,
};
pub use prepare::PhotonGridUniform;
pub use settings::{FieldDevice, PhotonGridSettings};

use crate::camera::GiMethod;
use crate::method::{GiMethodModule, GpuCapabilities, Shortfall};

/// The photon grid: settings validation, the CPU preparation, the per-view gather. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct PhotonGridPlugin;

impl Plugin for PhotonGridPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "photon_grid/gather.wgsl", include_str!("../../shaders/photon_grid/gather.wgsl"));
        crate::method::build_method::<Self>(app);
        crate::background::add_cpu_method::<PhotonGridState, PhotonGridOutput, PhotonGridActivity, _>(
            app,
            &[DIAGNOSTIC_VOXELIZE, DIAGNOSTIC_TRACE, DIAGNOSTIC_RGRID, DIAGNOSTIC_FIELD],
            extract::update_photon_grid,
        );
        // The SH field's compute pipeline: made by the render world when a preparation first asks for
        // it, used from the main world's background task.
        let field_shader = crate::add_shader(app, "photon_grid/field.wgsl", include_str!("../../shaders/photon_grid/field.wgsl"));
        let field_pipeline = field_gpu::FieldPipeline::default();
        app.insert_resource(field_pipeline.clone());
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app
                .insert_resource(prepare::PhotonGridShaders { gather: shader })
                .insert_resource(field_pipeline)
                .insert_resource(field_gpu::FieldPipelineSource::new(field_shader))
                .add_systems(bevy::render::Render, field_gpu::make_field_pipeline.in_set(bevy::render::RenderSystems::Prepare));
        }
    }

    fn finish(&self, app: &mut App) {
        crate::method::finish_method::<Self>(app);
    }
}

impl GiMethodModule for PhotonGridPlugin {
    const METHOD: GiMethod = GiMethod::PhotonGrid;
    const NAME: &'static str = "the photon grid";
    type Settings = PhotonGridSettings;

    /// Three storage buffers in the fragment shader.
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        gpu.require().storage_buffers(3).missing()
    }

    fn add_render_systems(render_app: &mut SubApp) {
        render::add_render_systems(render_app);
    }
}
