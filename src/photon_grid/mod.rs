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
//! # Algorithm (the preparation stage, §3, on the CPU with rayon: [`grid`])
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
//!    component).
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
//!   (with the snapshot's BVH for photons), not in CUDA: see *Cost*.
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
//! on the GPU). The gather-only settings (`intensity`, `r_max`, `gather_samples`,
//! `obscurance_distance`) run no preparation. The last field is gathered from until the new one is
//! ready, then blended in over [`BLEND_FRAMES`](crate::background::BLEND_FRAMES) frames, cell by cell.
//! The main thread pays for polling, copying the snapshot when a task starts and writing the blended
//! coefficients ([`MainThreadCost::photon_grid_ms`](crate::MainThreadCost)). [`PhotonGridActivity`]
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
//! Why the CPU: this is the first version of the method; its stages are written as the GPU would run
//! them (one task per photon, per non-empty cell, per probe, no atomics), so that a compute port can
//! follow them one by one, starting with the SH field. (Not measured on a GPU: no GPU machine was lent
//! to this work.)
//!
//! # Known issues
//! * A moving mesh or light costs a whole preparation (seconds at the high preset), not one in
//!   proportion to what moved: the frame does not wait for it, but the light lags by one preparation.
//!   The paper's GPU preparation (and re-tracing only the photons a change touches) is not done yet.
//! * One grid over the whole scene's box: a large scene gets large cells (`open_field`), and a surface
//!   smaller than a cell (a small object, a light 10 cm under a ceiling) is averaged over the cell.
//! * A wall thinner than an SH cell has both faces in one R-grid cell; its faces are kept apart by the
//!   photons' directions and the blocked faces, but the coarser R-grid levels mix them.
//! * The obscurance (§4.4) is optional and off: it is not physically based, and the distance field
//!   keeps distances up to four cells only.

pub mod grid;
mod render;

use std::sync::Arc;

use bevy::camera::Exposure;
use bevy::diagnostic::{Diagnostic, DiagnosticPath, Diagnostics, RegisterDiagnostic};
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::extract_resource::{ExtractResource, ExtractResourcePlugin};
use bevy::render::render_resource::ShaderType;

use crate::background::{self, BackgroundJob, Blend};
use crate::camera::{DiffuseGi, GiMethod};
use crate::light::GiLight;
use crate::scene::{SceneSnapshot, SceneSnapshotSystems};
use crate::settings::{Clamped, GiSettings};
use grid::{FieldParams, GridLayout, PhotonStats, RGrid, ShField, TraceParams, VGrid};

/// The settings of the photon grid, on a camera with [`DiffuseGi`](crate::camera::DiffuseGi)
/// `{ method: GiMethod::PhotonGrid, .. }`. A camera without it uses [`PhotonGridSettings::default`] (the
/// medium preset). The field is the scene's, not the view's: with several photon-grid cameras, the first
/// active one's settings apply. Invalid values are clamped to their range with one warning.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
pub struct PhotonGridSettings {
    /// SH-grid cells along the longest side of the scene's bounding box (the V-grid has four times as
    /// many; one more cell pads each side). Range 4–96; low 16, medium 32 (the default, the paper's for
    /// rooms), high 64 (the paper's for Sponza). Cost: memory and voxelisation grow with the cube; the
    /// field's probes with the square (they follow the surfaces). A change: a new preparation (V-grid
    /// included), in the background.
    pub resolution: u32,
    /// Photons emitted per update over all sources. Range 1 024 – 4 194 304; low 65 536, medium 262 144
    /// (the paper's), high 1 048 576. Cost: linear (tracing and the R-grid's sort). A change: new
    /// photons, R-grid and field (the V-grid is kept), in the background.
    pub photons: u32,
    /// Stored reflections per photon path (the final gather adds one more bounce); Russian roulette ends
    /// most paths earlier. Range 1–32; low 4 (the paper's), medium 8 (the default), high 16. The paper
    /// saw no visual difference beyond four, but light is lost: in `cornell` (albedo about 0.75) the
    /// surfaces' radiance is 0.85 of the path tracer's with 4 and 0.97 with 8. Cost: at most linear in
    /// the stored photons (`cornell`: 2.0 N with 4, 2.6 N with 8). A change: new photons, R-grid and
    /// field, in the background.
    pub max_reflections: u32,
    /// Ray directions per SH probe (`N_sh`). Range 16–2048; low 128, medium 256, high 400 (the
    /// paper's). Cost: linear in the field's construction. A change: new photons, R-grid and field, in
    /// the background.
    pub sh_directions: u32,
    /// The coarsest R-grid level the radiance filter of §3.4.3 may read for a far hit (level `k` has
    /// cells `2^k` times the SH cell's side); 0 reads the base level only. Range 0–5; default 1 (the
    /// paper's filter is unbounded). A coarse cell mixes the light of surfaces on both sides of a wall
    /// and spreads a small surface's flux over its whole face: block RMSE / energy on `cornell` 0.109 /
    /// 0.96 with 0, 0.141 / 0.92 with 1, 0.211 / 0.86 unbounded; on `cellar` 0.199 / 0.88, 0.181 / 1.02,
    /// 0.290 / 1.10 (the base level alone is darker where photons are few). Cost: none per frame; a
    /// change: new photons, R-grid and field, in the background.
    pub filter_levels: u32,
    /// Hemisphere directions of the final gather (`N_d`, §4.2); 0 integrates the nine coefficients
    /// exactly. Range 0–256; default 0. Cost: per pixel, linear (0 costs about as much as 4). A change
    /// runs no preparation: the gather reads it in the same frame.
    pub gather_samples: u32,
    /// Extent of the gather's distance weight `w_sh`, in SH cells. Range 1–3; default 1.75 (the
    /// paper's). Cost: none; a change runs no preparation.
    pub r_max: f32,
    /// Distance in metres at which the obscurance of §4.4 (`ρ(d) = min(d / D, 1)` over the distance
    /// field) stops darkening; 0 turns it off. Range 0–1000; default 0 (it is not physically based).
    /// The field keeps distances up to four SH cells, so a larger `D` darkens everything.
    /// Cost: per pixel, a second pass over the gather's directions. A change runs no preparation.
    pub obscurance_distance: f32,
    /// Multiplies the indirect light. Range 0–1000; default 1. Cost: none; a change runs no preparation.
    pub intensity: f32,
}

impl PhotonGridSettings {
    /// 16 cells, 65 536 photons, four reflections, 128 probe directions.
    pub const LOW: Self = Self {
        resolution: 16,
        photons: 65_536,
        max_reflections: 4,
        sh_directions: 128,
        filter_levels: 1,
        gather_samples: 0,
        r_max: 1.75,
        obscurance_distance: 0.0,
        intensity: 1.0,
    };
    /// 32 cells, 262 144 photons, eight reflections, 256 probe directions (the default).
    pub const MEDIUM: Self = Self { resolution: 32, photons: 262_144, max_reflections: 8, sh_directions: 256, ..Self::LOW };
    /// 64 cells, 1 048 576 photons, sixteen reflections, 400 probe directions.
    pub const HIGH: Self = Self { resolution: 64, photons: 1_048_576, max_reflections: 16, sh_directions: 400, ..Self::LOW };
}

impl Default for PhotonGridSettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for PhotonGridSettings {
    const NAME: &'static str = "PhotonGridSettings";

    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
        c.uint(&mut s.resolution, 4, 96, "resolution");
        c.uint(&mut s.photons, 1024, 4_194_304, "photons");
        c.uint(&mut s.max_reflections, 1, 32, "max_reflections");
        c.uint(&mut s.sh_directions, 16, 2048, "sh_directions");
        c.uint(&mut s.filter_levels, 0, 5, "filter_levels");
        c.uint(&mut s.gather_samples, 0, 256, "gather_samples");
        c.float(&mut s.r_max, 1.0, 3.0, 1.75, "r_max");
        c.float(&mut s.obscurance_distance, 0.0, 1000.0, 0.0, "obscurance_distance");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
        (s, c.fields)
    }
}

/// The grid the gather reads (`PhotonGridUniform` in `shaders/photon_grid/gather.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct PhotonGridUniform {
    /// World position of the grid's minimum corner.
    pub origin: Vec3,
    /// SH-grid cell side, metres.
    pub cell_size: f32,
    /// SH-grid cells per axis.
    pub dims: UVec3,
    /// `w_sh`'s extent, metres.
    pub r_max: f32,
    pub intensity: f32,
    /// `N_d`; 0: the exact integral.
    pub gather_samples: u32,
    /// Obscurance distance, metres; 0: off.
    pub obscurance_distance: f32,
    pub probes: u32,
}

/// The field the frame gathers from. Extracted to the render world.
#[derive(Resource, Clone, Debug, Default, ExtractResource)]
pub struct PhotonGridOutput {
    /// Bumped whenever the field changes.
    pub generation: u64,
    pub grid: PhotonGridUniform,
    /// Per SH cell: its probe, or `u32::MAX`.
    pub cell_probe: Arc<Vec<u32>>,
    /// Nine `vec4`s per probe: radiance SH (rgb, cd/m² before exposure) and distance SH (a, metres).
    pub coefficients: Arc<Vec<Vec4>>,
    /// The V-grid's boundary cells, a bit each ([`VGrid::occupancy_words`]): the gather's visibility.
    pub occupancy: Arc<Vec<u32>>,
}

/// Milliseconds of the preparation's stages in the background task (the paper's Table 1 rows).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhotonGridTimes {
    pub voxelize_ms: f32,
    pub trace_ms: f32,
    pub rgrid_ms: f32,
    pub field_ms: f32,
}

/// What the last update did, for the panel, the tools and the tests.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct PhotonGridActivity {
    /// SH cells per axis.
    pub dims: UVec3,
    /// Boundary V-cells and SH cells.
    pub boundary_v_cells: usize,
    pub boundary_sh_cells: usize,
    /// Probes of the field, and those dropped inside solid geometry.
    pub probes: usize,
    pub inside: u32,
    /// The photon list and where the flux went.
    pub photons: usize,
    pub stats: PhotonStats,
    /// The stages of the last update, ms (zero for one that did not run).
    pub times: PhotonGridTimes,
    /// Preparations finished so far (background tasks). A change of a gather-only setting
    /// (`intensity`, `r_max`, `gather_samples`, `obscurance_distance`) runs none.
    pub updates: u64,
    /// Whether the field shown is not yet the one of the scene as it is now: a preparation is running
    /// or due, or a new field is still being blended in.
    pub busy: bool,
    /// Whether a result is drawn: false from the method's activation until its first background
    /// result arrives (the frame shows no bounced light from it until then).
    pub ready: bool,
    /// Frames since the last preparation was started from the scene as it was then.
    pub frames_since_start: u32,
}

/// The grids the preparation keeps between runs: the state a background preparation takes and hands
/// back.
#[derive(Default)]
pub struct PhotonGridCore {
    pub vgrid: VGrid,
    voxels_key: Option<(u64, u32)>,
}

/// The main-world state: the grids (in a background task while one runs), the running preparation and
/// the field shown.
#[derive(Resource, Default)]
pub struct PhotonGridState {
    /// `None` while a background preparation holds it.
    core: Option<Box<PhotonGridCore>>,
    job: BackgroundJob<FieldKey, Prepared>,
    shown: Option<ShownField>,
}

/// Everything the preparation depends on (not the gather-only settings).
#[derive(Clone, Debug, PartialEq)]
struct FieldKey {
    geometry: u64,
    lights: u64,
    gi_lights: Vec<Entity>,
    exposure: u32,
    environment: u64,
    settings: PhotonGridSettings,
}

/// What a background preparation hands back.
struct Prepared {
    core: Box<PhotonGridCore>,
    /// `None` for an empty scene.
    field: Option<(GridLayout, ShField)>,
    occupancy: Arc<Vec<u32>>,
    activity: PhotonGridActivity,
}

/// The field drawn, blending from the previous one.
struct ShownField {
    layout: GridLayout,
    cell_probe: Arc<Vec<u32>>,
    occupancy: Arc<Vec<u32>>,
    /// Nine coefficients per probe: where the blend starts (the previous field at the same cells) and
    /// where it ends.
    from: Vec<Vec4>,
    to: Vec<Vec4>,
    blend: Blend,
    /// The gather settings last drawn with.
    drawn: Option<PhotonGridSettings>,
}

impl PhotonGridSettings {
    /// The settings the preparation reads: the gather-only fields set to their defaults.
    fn preparation(&self) -> Self {
        let d = Self::default();
        Self { gather_samples: d.gather_samples, r_max: d.r_max, obscurance_distance: d.obscurance_distance, intensity: d.intensity, ..self.clone() }
    }
}

/// Distances of the SH distance field are clamped to this many SH cells: the gather's visibility only
/// needs what lies within its reach, and a far distance (a ray into the sky) blurs into the near ones.
pub const DISTANCE_CELLS: f32 = 4.0;

pub const DIAGNOSTIC_VOXELIZE: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_voxelize");
pub const DIAGNOSTIC_TRACE: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_trace");
pub const DIAGNOSTIC_RGRID: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_rgrid");
pub const DIAGNOSTIC_FIELD: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_field");

/// The photon grid: settings validation, the CPU preparation, the per-view gather. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct PhotonGridPlugin;

impl Plugin for PhotonGridPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "photon_grid/gather.wgsl", include_str!("../../shaders/photon_grid/gather.wgsl"));
        for path in [DIAGNOSTIC_VOXELIZE, DIAGNOSTIC_TRACE, DIAGNOSTIC_RGRID, DIAGNOSTIC_FIELD] {
            app.register_diagnostic(Diagnostic::new(path).with_suffix(" ms"));
        }
        app.register_type::<PhotonGridSettings>()
            .init_resource::<PhotonGridState>()
            .init_resource::<PhotonGridOutput>()
            .init_resource::<PhotonGridActivity>()
            .add_plugins(ExtractResourcePlugin::<PhotonGridOutput>::default())
            .add_systems(
                PostUpdate,
                (
                    crate::settings::validate_settings::<PhotonGridSettings>,
                    update_photon_grid.after(SceneSnapshotSystems::Update),
                ),
            );
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(render::PhotonGridShader(shader));
        }
    }

    fn finish(&self, app: &mut App) {
        let supported = crate::gpu_supports(app, "PhotonGrid", |limits, _| missing_capabilities(limits));
        let Some(render_app) = app.get_sub_app_mut(RenderApp).filter(|_| supported) else {
            return;
        };
        render::add_render_systems(render_app);
    }
}

/// The GPU capabilities the gather needs, as `(name, required, found)` for every shortfall: three
/// storage buffers in the fragment shader.
pub fn missing_capabilities(limits: &bevy::render::settings::WgpuLimits) -> Vec<crate::Shortfall> {
    let mut missing = Vec::new();
    if limits.max_storage_buffers_per_shader_stage < 3 {
        missing.push(("max_storage_buffers_per_shader_stage", 3, limits.max_storage_buffers_per_shader_stage as u64));
    }
    missing
}

/// Keeps the field current for the first active photon-grid camera, without waiting for it: takes a
/// finished background preparation (V-grid when geometry changed; photons, R-grid and SH field), starts
/// the next when the scene or a preparation setting changed since the last one began, and writes the
/// output (blending a new field in; gather-only settings are applied here, with no preparation).
#[expect(clippy::too_many_arguments, reason = "the preparation reads the cameras, the lights and the snapshot")]
fn update_photon_grid(
    mut commands: Commands,
    cameras: Query<(&Camera, &DiffuseGi, Option<&PhotonGridSettings>, Option<&Exposure>)>,
    gi_lights: Query<Entity, With<GiLight>>,
    snapshot: Option<Res<SceneSnapshot>>,
    mut state: ResMut<PhotonGridState>,
    mut output: ResMut<PhotonGridOutput>,
    mut activity: ResMut<PhotonGridActivity>,
    mut cost: ResMut<crate::MainThreadCost>,
    mut diagnostics: Diagnostics,
) {
    cost.photon_grid_ms = 0.0;
    let camera = cameras
        .iter()
        .find(|(camera, gi, _, _)| camera.is_active && gi.enabled && gi.method == GiMethod::PhotonGrid);
    let Some((_, _, settings, exposure)) = camera else {
        if state.shown.is_some() || state.job.is_running() || state.core.is_some() {
            state.job.reset();
            (state.core, state.shown) = (None, None);
            let generation = output.generation + 1;
            *output = PhotonGridOutput { generation, ..default() };
            (activity.busy, activity.ready) = (false, false);
        }
        return;
    };
    let Some(snapshot) = snapshot else {
        commands.init_resource::<SceneSnapshot>();
        return;
    };
    let frame_start = std::time::Instant::now();
    let settings = settings.cloned().unwrap_or_default().sanitized().0;
    let exposure = exposure.copied().unwrap_or_default().exposure();
    let mut lights: Vec<Entity> = gi_lights.iter().collect();
    lights.sort();
    let key = FieldKey {
        geometry: snapshot.geometry_generation,
        lights: snapshot.light_generation,
        gi_lights: lights,
        exposure: exposure.to_bits(),
        environment: snapshot.environment_generation,
        settings: settings.preparation(),
    };
    let state = &mut *state;

    // 1. A finished preparation: its grids come back, its field is blended in.
    if let Some((_, prepared)) = state.job.poll() {
        let Prepared { core, field, occupancy, activity: done } = prepared;
        state.core = Some(core);
        let t = done.times;
        background::record_stages(
            &mut diagnostics,
            &[(&DIAGNOSTIC_VOXELIZE, t.voxelize_ms), (&DIAGNOSTIC_TRACE, t.trace_ms), (&DIAGNOSTIC_RGRID, t.rgrid_ms), (&DIAGNOSTIC_FIELD, t.field_ms)],
        );
        *activity = PhotonGridActivity { updates: activity.updates + 1, frames_since_start: activity.frames_since_start, ..done };
        state.shown = field.map(|(layout, field)| ShownField::after(state.shown.take(), layout, field, occupancy));
        if state.shown.is_none() {
            let generation = output.generation + 1;
            *output = PhotonGridOutput { generation, ..default() };
        }
    }

    // 2. The scene or a preparation setting changed since the last preparation began: start the next.
    if state.job.wants(&key) {
        let mut core = state.core.take().unwrap_or_default();
        let snapshot = snapshot.clone();
        let prepare_key = key.clone();
        state.job.start(key.clone(), move || prepare(&mut core, &snapshot, &prepare_key).with_core(core));
        activity.frames_since_start = 0;
    } else {
        activity.frames_since_start += 1;
    }

    // 3. Write the output when the field, the blend or a gather setting changed.
    if let Some(shown) = &mut state.shown {
        let weight = shown.blend.advance();
        if weight.is_some() || shown.drawn.as_ref() != Some(&settings) {
            shown.drawn = Some(settings.clone());
            let layout = shown.layout;
            let coefficients = shown.current();
            let generation = output.generation + 1;
            *output = PhotonGridOutput {
                generation,
                grid: PhotonGridUniform {
                    origin: layout.origin,
                    cell_size: layout.cell,
                    dims: layout.dims,
                    r_max: settings.r_max * layout.cell,
                    intensity: settings.intensity,
                    gather_samples: settings.gather_samples,
                    obscurance_distance: settings.obscurance_distance,
                    probes: (coefficients.len() / 9) as u32,
                },
                cell_probe: shown.cell_probe.clone(),
                coefficients: Arc::new(coefficients),
                occupancy: shown.occupancy.clone(),
            };
        }
    }
    activity.busy = state.job.is_running() || !state.job.is_current(&key) || state.shown.as_ref().is_some_and(|s| !s.blend.is_done());
    activity.ready = state.shown.is_some();
    cost.photon_grid_ms = frame_start.elapsed().as_secs_f32() * 1e3;
}

impl ShownField {
    /// The new field, blending from `previous` at the cells both have a probe in (same grid only).
    fn after(previous: Option<Self>, layout: GridLayout, field: ShField, occupancy: Arc<Vec<u32>>) -> Self {
        let to: Vec<Vec4> = field.coefficients.iter().flatten().copied().collect();
        let previous = previous.filter(|p| p.layout == layout && p.cell_probe.len() == field.cell_probe.len());
        let (from, blend) = match previous {
            Some(previous) => {
                let old = previous.current();
                let mut from = to.clone();
                for (&new, &was) in field.cell_probe.iter().zip(previous.cell_probe.iter()) {
                    if new != u32::MAX && was != u32::MAX {
                        let (new, was) = (new as usize * 9, was as usize * 9);
                        from[new..new + 9].copy_from_slice(&old[was..was + 9]);
                    }
                }
                (from, Blend::start())
            }
            None => (to.clone(), Blend::DONE),
        };
        Self { layout, cell_probe: Arc::new(field.cell_probe), occupancy, from, to, blend, drawn: None }
    }

    /// The coefficients on screen now.
    fn current(&self) -> Vec<Vec4> {
        self.blend.mix(&self.from, &self.to, Vec4::lerp)
    }
}

/// What [`prepare`] made, before the grids go back with it.
struct PreparedField {
    field: Option<(GridLayout, ShField)>,
    occupancy: Arc<Vec<u32>>,
    activity: PhotonGridActivity,
}

impl PreparedField {
    fn with_core(self, core: Box<PhotonGridCore>) -> Prepared {
        Prepared { core, field: self.field, occupancy: self.occupancy, activity: self.activity }
    }
}

/// One preparation, on a background task: the V-grid (only when geometry or the resolution changed
/// since `core` was built), photons, R-grid and SH field.
fn prepare(core: &mut PhotonGridCore, snapshot: &SceneSnapshot, key: &FieldKey) -> PreparedField {
    let settings = &key.settings;
    let exposure = f32::from_bits(key.exposure);
    let mut times = PhotonGridTimes::default();
    let Some((lo, hi)) = snapshot.bounds() else {
        return PreparedField { field: None, occupancy: Arc::default(), activity: PhotonGridActivity::default() };
    };
    let layout = GridLayout::fit(lo, hi, settings.resolution);

    // 1. V-grid and SH-grid, when geometry or the resolution changed.
    let voxels_key = Some((snapshot.geometry_generation, settings.resolution));
    if core.voxels_key != voxels_key || core.vgrid.layout != Some(layout) {
        let start = std::time::Instant::now();
        core.vgrid = VGrid::build(snapshot, layout);
        core.voxels_key = voxels_key;
        times.voxelize_ms = start.elapsed().as_secs_f32() * 1e3;
    }

    // 2. Photons.
    let start = std::time::Instant::now();
    let gi_lights: Vec<_> = snapshot.lights.iter().filter(|l| key.gi_lights.contains(&l.entity)).map(|l| l.light).collect();
    let params = TraceParams { photons: settings.photons, max_reflections: settings.max_reflections, seed: 0x9e37_79b9, exposure };
    let (photons, stats) = grid::trace_photons(snapshot, &gi_lights, snapshot.environment.as_deref(), &core.vgrid, &params);
    times.trace_ms = start.elapsed().as_secs_f32() * 1e3;

    // 3. R-grid.
    let start = std::time::Instant::now();
    let base = grid::accumulate_sorted(&photons, layout.cell_count());
    let rgrid = RGrid::new(layout, base, 6);
    times.rgrid_ms = start.elapsed().as_secs_f32() * 1e3;

    // 4. SH field.
    let start = std::time::Instant::now();
    let field_params = FieldParams {
        directions: settings.sh_directions,
        max_distance: DISTANCE_CELLS * layout.cell,
        filter_levels: settings.filter_levels,
    };
    let field = ShField::build(&core.vgrid, &rgrid, snapshot.environment.as_deref(), &field_params);
    times.field_ms = start.elapsed().as_secs_f32() * 1e3;

    let activity = PhotonGridActivity {
        dims: layout.dims,
        boundary_v_cells: core.vgrid.boundary_cells(),
        boundary_sh_cells: core.vgrid.sh_boundary.iter().filter(|b| **b).count(),
        probes: field.coefficients.len(),
        inside: field.inside,
        photons: photons.len(),
        stats,
        times,
        ..default()
    };
    PreparedField { field: Some((layout, field)), occupancy: Arc::new(core.vgrid.occupancy_words()), activity }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        let presets = [PhotonGridSettings::LOW, PhotonGridSettings::MEDIUM, PhotonGridSettings::HIGH];
        for preset in &presets {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
        }
        assert!(presets.windows(2).all(|w| w[0].resolution < w[1].resolution
            && w[0].photons < w[1].photons
            && w[0].sh_directions < w[1].sh_directions));
        assert_eq!(PhotonGridSettings::default(), PhotonGridSettings::MEDIUM);
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = PhotonGridSettings { resolution: 0, photons: u32::MAX, r_max: f32::NAN, intensity: -1.0, ..default() };
        let (clean, bad) = s.sanitized();
        let names: Vec<_> = bad.iter().map(|b| b.0).collect();
        assert_eq!(names, ["resolution", "photons", "r_max", "intensity"]);
        assert_eq!((clean.resolution, clean.photons, clean.r_max, clean.intensity), (4, 4_194_304, 1.75, 0.0));
    }
}
