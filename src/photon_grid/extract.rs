//! Main world: the background preparation (V-grid, photons, R-grid, SH field) of the photon grid and the
//! field it hands the frame, extracted to the render world as [`PhotonGridOutput`].

use std::sync::Arc;

use bevy::diagnostic::DiagnosticPath;
use bevy::prelude::*;
use bevy::render::extract_resource::ExtractResource;
use bevy::render::renderer::{RenderAdapter, RenderDevice, RenderQueue};

use super::field_gpu::{FieldGpu, FieldPipeline};
use super::settings::FieldDevice;
use super::PhotonGridSettings;
use super::grid::{self, FieldParams, GridLayout, PhotonPaths, PhotonStats, ProbeRays, RGrid, ShField, TraceParams, VGrid};
use super::prepare::PhotonGridUniform;
use crate::background::{self, BackgroundJob, Blend, CpuJob, CpuMethodParams, JobKey, MethodUse};
use crate::camera::GiMethod;
use crate::method::GpuCapabilities;
use crate::scene::{SceneSnapshot, SnapshotLight};

/// The field the frame gathers from. Extracted to the render world.
#[derive(Resource, Clone, Debug, Default, ExtractResource)]
pub struct PhotonGridOutput {
    /// Bumped whenever the output changes (a blend step or a gather setting changes only `grid`).
    pub generation: u64,
    /// Bumped whenever the buffers below change (a new field).
    pub field_generation: u64,
    /// The grid and the gather settings; `blend` is the new field's weight while it blends in.
    pub grid: PhotonGridUniform,
    /// Per SH cell: its probe, or `u32::MAX`.
    pub cell_probe: Arc<Vec<u32>>,
    /// Nine `vec4`s per probe: radiance SH (rgb, cd/m² before exposure) and distance SH (a, metres).
    pub coefficients: Arc<Vec<Vec4>>,
    /// Where the blend starts, at the same probes as `coefficients` (the previous field; the new one at
    /// probes the previous field lacked). The gather reads `mix(from, coefficients, grid.blend)`.
    pub from_coefficients: Arc<Vec<Vec4>>,
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
    /// Photon paths traced by the last update: all of them after a change of the lights or the
    /// settings, only those whose rays ran through what moved after a mesh moved.
    pub paths_traced: usize,
    /// Probe rays of the field (every probe's, those dropped inside solid geometry too), and those the
    /// last update marched through the V-grid (the others kept where they met it).
    pub rays: usize,
    pub rays_marched: usize,
    /// Bytes the preparation keeps to redo only what a change touches: the photon paths' points and
    /// balances, and where each probe ray met the V-grid.
    pub kept_bytes: usize,
    /// The stages of the last update, ms (zero for one that did not run).
    pub times: PhotonGridTimes,
    /// Whether the last update built its SH field on the GPU ([`PhotonGridSettings::field_device`]).
    pub field_on_gpu: bool,
    /// The last field's time per probe ray on each device, what [`FieldDevice::Auto`] chooses by.
    pub field_timings: FieldTimings,
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
    /// The photon paths of the last preparation, and what they were traced from.
    paths: PhotonPaths,
    trace_key: Option<TraceKey>,
    /// Where the probe rays of the last field met the V-grid.
    rays: ProbeRays,
    /// The instances the paths and rays were made in, by key (the snapshot's order).
    instances: Vec<InstanceRecord>,
    /// The snapshot's layout generation then: instances added or removed, or the whole snapshot
    /// touched, redo every path and ray.
    layout_generation: u64,
    /// Whether a mesh moved (or changed) between two preparations: from then on the paths' records and
    /// the probe rays are kept (`PhotonGridActivity::kept_bytes`); a scene where nothing moves does not
    /// hold them.
    keep_records: bool,
    /// The last field made (shared with the one shown): the next preparation starts its blend from it.
    last_field: Option<(GridLayout, Arc<Vec<u32>>, Arc<Vec<Vec4>>)>,
}

/// What every photon path depends on besides the geometry: a change of any re-traces them all.
#[derive(Clone, Debug, PartialEq)]
struct TraceKey {
    layout: GridLayout,
    lights: Vec<SnapshotLight>,
    environment: u64,
    exposure: u32,
    photons: u32,
    max_reflections: u32,
}

/// An instance as a preparation saw it: key, version, world bounds and whether its material emits.
type InstanceRecord = crate::scene::changes::InstanceRecord<bool>;

/// The instances of `snapshot` as [`PhotonGridCore::instances`] keeps them.
fn instance_table(snapshot: &SceneSnapshot, exposure: f32) -> Vec<InstanceRecord> {
    crate::scene::changes::instance_records(snapshot, |i| {
        snapshot.materials.get(i.material as usize).is_some_and(|m| m.emission(exposure).max_element() > 0.0)
    })
}

/// The world boxes that changed between two instance tables (the old and new bounds of every instance
/// moved, re-materialed, added or removed), and whether one of those instances emits light.
fn changed_boxes(old: &[InstanceRecord], new: &[InstanceRecord]) -> (Vec<(Vec3, Vec3)>, bool) {
    let changed = crate::scene::changes::changed_boxes(old, new);
    (changed.iter().map(|&(bounds, _)| bounds).collect(), changed.iter().any(|&(_, emits)| emits))
}

/// The main-world state: the grids (in a background task while one runs), the running preparation and
/// the field shown.
#[derive(Resource, Default)]
pub struct PhotonGridState {
    job: CpuJob<PhotonGridSettings, PhotonGridCore, Prepared>,
    shown: Option<ShownField>,
    /// A new field that arrived while the shown one was still blending in: it waits for that blend to
    /// end (at most [`BLEND_FRAMES`](background::BLEND_FRAMES) − 1 frames), and then starts from the
    /// start the background laid out from the field it replaces, so that the main thread never mixes
    /// fields itself.
    pending: Option<(NewField, Arc<Vec<u32>>)>,
    /// The start of the waiting field's blend, laid out in the background from the shown field's end
    /// when that field replaced another waiting one (whose start it had been laid out from, and which
    /// was never shown): the main thread never mixes fields itself.
    pending_start: BackgroundJob<(), Vec<Vec4>>,
    /// The GPU's SH-field pass, made when a setting first asks for it; `None` before, and without a
    /// render device.
    field_gpu: Option<FieldGpu>,
    /// Whether the GPU's field failed once (warned once; the CPU builds it from then on).
    field_gpu_failed: bool,
    /// The last field's time per probe ray on each device.
    field_timings: FieldTimings,
}

/// Everything the preparation depends on: the scene and the settings it reads (not the gather-only
/// ones).
type FieldKey = JobKey<PhotonGridSettings>;

/// Milliseconds per probe ray of the last SH field built on the CPU and on the GPU (`None`: none yet).
/// After a move the CPU marches only the rays near it, so its time per ray is then that of a partial
/// field: what a field costs it in that regime.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FieldTimings {
    pub cpu: Option<f32>,
    pub gpu: Option<f32>,
}

impl FieldTimings {
    /// Where [`FieldDevice::Auto`] builds the next field on a hardware GPU: on the GPU first, on the
    /// CPU once to compare, then on whichever built its last field faster per ray.
    pub fn auto_on_gpu(&self) -> bool {
        match (self.cpu, self.gpu) {
            (_, None) => true,
            (None, Some(_)) => false,
            (Some(cpu), Some(gpu)) => gpu <= cpu,
        }
    }
}

/// What a background preparation hands back (its grids go back to the state).
struct Prepared {
    /// `None` for an empty scene.
    field: Option<NewField>,
    occupancy: Arc<Vec<u32>>,
    activity: PhotonGridActivity,
    /// Why the GPU could not build the field it was asked to build (the CPU built it).
    field_gpu_error: Option<String>,
}

/// A new field, ready to draw: its probes' coefficients flattened, and where its blend starts when the
/// field before it had the same grid (made in the background, so that the main thread only swaps
/// `Arc`s).
struct NewField {
    layout: GridLayout,
    cell_probe: Arc<Vec<u32>>,
    to: Arc<Vec<Vec4>>,
    /// The previous field at this field's probes (this field's values where it had none).
    from: Option<Arc<Vec<Vec4>>>,
}

/// The field drawn, blending from the previous one (on the GPU: the gather mixes the two buffers).
struct ShownField {
    layout: GridLayout,
    cell_probe: Arc<Vec<u32>>,
    occupancy: Arc<Vec<u32>>,
    /// Nine coefficients per probe: where the blend starts (the previous field at the same cells) and
    /// where it ends.
    from: Arc<Vec<Vec4>>,
    to: Arc<Vec<Vec4>>,
    blend: Blend,
    /// The gather settings last drawn with.
    drawn: Option<PhotonGridSettings>,
    /// Whether the buffers changed since the output was last written.
    new_buffers: bool,
}

/// Distances of the SH distance field are clamped to this many SH cells: the gather's visibility only
/// needs what lies within its reach, and a far distance (a ray into the sky) blurs into the near ones.
pub const DISTANCE_CELLS: f32 = 4.0;

pub const DIAGNOSTIC_VOXELIZE: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_voxelize");
pub const DIAGNOSTIC_TRACE: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_trace");
pub const DIAGNOSTIC_RGRID: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_rgrid");
pub const DIAGNOSTIC_FIELD: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/photon_field");

/// Keeps the field current for the first active photon-grid camera, without waiting for it: takes a
/// finished background preparation (V-grid when geometry changed; photons, R-grid and SH field), starts
/// the next when the scene or a preparation setting changed since the last one began, and writes the
/// output (blending a new field in; gather-only settings are applied here, with no preparation).
pub(super) fn update_photon_grid(
    mut params: CpuMethodParams<PhotonGridSettings>,
    mut state: ResMut<PhotonGridState>,
    mut output: ResMut<PhotonGridOutput>,
    mut activity: ResMut<PhotonGridActivity>,
    gpu: Option<(Res<RenderDevice>, Res<RenderQueue>, Res<RenderAdapter>, Res<FieldPipeline>)>,
) {
    params.cost.photon_grid_ms = 0.0;
    let (settings, scene) = match params.method_use(GiMethod::PhotonGrid) {
        MethodUse::On { settings, scene } => (settings, scene),
        MethodUse::Waiting => return,
        MethodUse::Off => {
            if state.shown.take().is_some() || state.job.is_active() {
                state.pending = None;
                state.pending_start.reset();
                state.job.reset();
                *output = PhotonGridOutput { generation: output.generation + 1, ..default() };
                (activity.busy, activity.ready) = (false, false);
            }
            return;
        }
    };
    let frame_start = std::time::Instant::now();
    let snapshot = params.snapshot.as_deref().expect("a method in use has a snapshot");
    let key = FieldKey { scene, settings: settings.preparation() };
    let state = &mut *state;

    // 1. A finished preparation: its grids come back, its field is blended in.
    if let Some(prepared) = state.job.poll() {
        let Prepared { field, occupancy, activity: done, field_gpu_error } = prepared;
        if let Some(error) = field_gpu_error
            && !std::mem::replace(&mut state.field_gpu_failed, true)
        {
            warn!("PhotonGridSettings::field_device: the GPU cannot build the SH field ({error}); it is built on the CPU");
        }
        if done.rays > 0 && done.times.field_ms > 0.0 {
            let per_ray = done.times.field_ms / done.rays as f32;
            *(if done.field_on_gpu { &mut state.field_timings.gpu } else { &mut state.field_timings.cpu }) = Some(per_ray);
        }
        let t = done.times;
        background::record_stages(
            &mut params.diagnostics,
            &[(&DIAGNOSTIC_VOXELIZE, t.voxelize_ms), (&DIAGNOSTIC_TRACE, t.trace_ms), (&DIAGNOSTIC_RGRID, t.rgrid_ms), (&DIAGNOSTIC_FIELD, t.field_ms)],
        );
        *activity = PhotonGridActivity {
            updates: activity.updates + 1,
            frames_since_start: activity.frames_since_start,
            field_timings: state.field_timings,
            ..done
        };
        state.arrive(field, occupancy);
        if state.shown.is_none() {
            let (generation, field_generation) = (output.generation + 1, output.field_generation + 1);
            *output = PhotonGridOutput { generation, field_generation, ..default() };
        }
    }

    // 2. The scene or a preparation setting changed since the last preparation began: start the next.
    if state.job.wants(&key) {
        let snapshot = snapshot.clone();
        let on_gpu = match settings.field_device {
            FieldDevice::Cpu => false,
            FieldDevice::Gpu => true,
            FieldDevice::Auto => gpu.as_ref().is_some_and(|(_, _, adapter, _)| {
                adapter.get_info().device_type != wgpu_types::DeviceType::Cpu && state.field_timings.auto_on_gpu()
            }),
        };
        if on_gpu && state.field_gpu.is_none() {
            state.field_gpu = gpu.as_ref().map(|(device, queue, adapter, pipeline)| {
                let capabilities = GpuCapabilities { limits: device.limits(), flags: adapter.get_downlevel_capabilities().flags };
                FieldGpu::new((**device).clone(), (**queue).clone(), capabilities, (**pipeline).clone())
            });
            if state.field_gpu.is_none() && !std::mem::replace(&mut state.field_gpu_failed, true) {
                warn!("PhotonGridSettings::field_device: no render device to build the SH field on; it is built on the CPU");
            }
        }
        let field_gpu = state.field_gpu.clone().filter(|_| on_gpu && !state.field_gpu_failed);
        state.job.start(&key, move |core, key| prepare(core, &snapshot, key, field_gpu.as_ref()));
        activity.frames_since_start = 0;
    } else {
        activity.frames_since_start += 1;
    }

    // 3. Write the output when the field, the blend or a gather setting changed (a waiting field
    //    starts once the blend before it ended).
    state.start_waiting();
    if let Some(shown) = &mut state.shown {
        let weight = shown.blend.advance();
        if weight.is_some() || shown.drawn.as_ref() != Some(&settings) || shown.new_buffers {
            shown.drawn = Some(settings.clone());
            let layout = shown.layout;
            let generation = output.generation + 1;
            let field_generation = output.field_generation + u64::from(std::mem::take(&mut shown.new_buffers));
            *output = PhotonGridOutput {
                generation,
                field_generation,
                grid: PhotonGridUniform {
                    origin: layout.origin,
                    cell_size: layout.cell,
                    dims: layout.dims,
                    r_max: settings.r_max * layout.cell,
                    intensity: settings.intensity,
                    gather_samples: settings.gather_samples,
                    obscurance_distance: settings.obscurance_distance,
                    probes: (shown.to.len() / 9) as u32,
                    blend: shown.blend.weight(),
                },
                cell_probe: shown.cell_probe.clone(),
                coefficients: shown.to.clone(),
                from_coefficients: shown.from.clone(),
                occupancy: shown.occupancy.clone(),
            };
        }
    }
    activity.busy = state.job.is_stale(&key) || state.pending.is_some() || state.shown.as_ref().is_some_and(|s| !s.blend.is_done());
    activity.ready = state.shown.is_some();
    params.status.set_background(GiMethod::PhotonGrid, activity.ready, activity.busy, activity.frames_since_start, activity.updates);
    params.cost.photon_grid_ms = frame_start.elapsed().as_secs_f32() * 1e3;
}

impl PhotonGridState {
    /// A finished preparation's field (`None`: an empty scene). While the shown field still blends in,
    /// the new one waits for its end. When one already waits, the new one replaces it; its start was
    /// laid out from the waiting field, never shown, so it is laid out again, in the background, from
    /// where the shown field's blend ends.
    fn arrive(&mut self, field: Option<NewField>, occupancy: Arc<Vec<u32>>) {
        let waiting = self.pending.is_some();
        let waits = |shown: &ShownField, field: &NewField| {
            (!shown.blend.is_done() || waiting) && field.from.is_some() && shown.layout == field.layout && shown.cell_probe.len() == field.cell_probe.len()
        };
        match (field, self.shown.take()) {
            (Some(mut field), Some(shown)) if waits(&shown, &field) => {
                if waiting {
                    let (cell_probe, to) = (field.cell_probe.clone(), field.to.clone());
                    let (old_cell_probe, old) = (shown.cell_probe.clone(), shown.to.clone());
                    self.pending_start.start((), move || blend_start(&cell_probe, &to, &old_cell_probe, &old));
                    field.from = None;
                }
                self.pending = Some((field, occupancy));
                self.shown = Some(shown);
            }
            (field, shown) => {
                self.pending = None;
                self.pending_start.reset();
                self.shown = field.map(|field| ShownField::after(shown, field, occupancy));
            }
        }
    }

    /// Shows the waiting field once the shown one's blend ended and its start is laid out (a start still
    /// being laid out holds the shown field a frame or two more).
    fn start_waiting(&mut self) {
        if !self.shown.as_ref().is_some_and(|shown| shown.blend.is_done()) || self.pending.is_none() {
            return;
        }
        if let Some(((), from)) = self.pending_start.poll()
            && let Some((field, _)) = self.pending.as_mut()
        {
            field.from = Some(Arc::new(from));
        }
        if !self.pending_start.is_running()
            && let Some((field, occupancy)) = self.pending.take()
        {
            self.shown = Some(ShownField::after(self.shown.take(), field, occupancy));
        }
    }
}

impl ShownField {
    /// The new field, blending from `previous` (same grid only). The start of the blend was made in the
    /// background from the last field; only when `previous` was still blending in (a preparation
    /// shorter than the blend) is it made here, from what `previous` shows now.
    fn after(previous: Option<Self>, field: NewField, occupancy: Arc<Vec<u32>>) -> Self {
        let NewField { layout, cell_probe, to, from } = field;
        let previous = previous.filter(|p| p.layout == layout && p.cell_probe.len() == cell_probe.len());
        let (from, blend) = match (previous, from) {
            (Some(previous), Some(from)) if previous.blend.is_done() => (from, Blend::start()),
            (Some(previous), _) => {
                let old = previous.blend.mix(&previous.from, &previous.to, Vec4::lerp);
                (Arc::new(blend_start(&cell_probe, &to, &previous.cell_probe, &old)), Blend::start())
            }
            (None, _) => (to.clone(), Blend::DONE),
        };
        Self { layout, cell_probe, occupancy, from, to, blend, drawn: None, new_buffers: true }
    }
}

/// `to`'s probes with the values `old` had at the same cells (`to`'s own where `old` had no probe).
fn blend_start(cell_probe: &[u32], to: &[Vec4], old_cell_probe: &[u32], old: &[Vec4]) -> Vec<Vec4> {
    let mut from = to.to_vec();
    for (&new, &was) in cell_probe.iter().zip(old_cell_probe) {
        if new != u32::MAX && was != u32::MAX {
            let (new, was) = (new as usize * 9, was as usize * 9);
            from[new..new + 9].copy_from_slice(&old[was..was + 9]);
        }
    }
    from
}

/// One preparation, on a background task: the V-grid (only when geometry or the resolution changed
/// since `core` was built), photons, R-grid and SH field.
fn prepare(core: &mut PhotonGridCore, snapshot: &SceneSnapshot, key: &FieldKey, field_gpu: Option<&FieldGpu>) -> Prepared {
    let settings = &key.settings;
    let exposure = key.scene.exposure();
    let mut times = PhotonGridTimes::default();
    let Some((lo, hi)) = snapshot.bounds() else {
        return Prepared { field: None, occupancy: Arc::default(), activity: PhotonGridActivity::default(), field_gpu_error: None };
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

    // What changed since the paths and the probe rays were made: the boxes of the instances that
    // moved or changed (`None` before the first preparation).
    let instances = instance_table(snapshot, exposure);
    let comparable = !core.instances.is_empty() && core.layout_generation == snapshot.layout_generation;
    let changed = comparable.then(|| changed_boxes(&core.instances, &instances));
    (core.instances, core.layout_generation) = (instances, snapshot.layout_generation);
    core.keep_records |= changed.as_ref().is_some_and(|(boxes, _)| !boxes.is_empty());

    // 2. Photons: only the paths that ran through what changed, when only meshes that do not emit
    //    changed; all of them otherwise.
    let start = std::time::Instant::now();
    let gi_lights: Vec<_> = snapshot.lights.iter().filter(|l| key.scene.gi_lights.contains(&l.entity)).map(|l| l.light).collect();
    let params = TraceParams { photons: settings.photons, max_reflections: settings.max_reflections, seed: 0x9e37_79b9, exposure };
    let trace_key = TraceKey {
        layout,
        lights: gi_lights.clone(),
        environment: snapshot.environment_generation,
        exposure: exposure.to_bits(),
        photons: settings.photons,
        max_reflections: settings.max_reflections,
    };
    let environment = snapshot.environment.as_deref();
    let paths_traced = match &changed {
        Some((boxes, false)) if core.trace_key.as_ref() == Some(&trace_key) => {
            core.paths.retrace(snapshot, &gi_lights, environment, &core.vgrid, &params, boxes)
        }
        _ => {
            core.paths = PhotonPaths::trace(snapshot, &gi_lights, environment, &core.vgrid, &params);
            core.trace_key = Some(trace_key);
            params.photons as usize
        }
    };
    if !core.keep_records {
        core.paths.forget_paths();
    }
    let (photons, stats) = (&core.paths.photons, core.paths.stats);
    times.trace_ms = start.elapsed().as_secs_f32() * 1e3;

    // 3. R-grid.
    let start = std::time::Instant::now();
    let base = grid::accumulate_sorted(photons, layout.cell_count());
    let rgrid = RGrid::new(layout, base, 6);
    times.rgrid_ms = start.elapsed().as_secs_f32() * 1e3;

    // 4. SH field.
    let start = std::time::Instant::now();
    let field_params = FieldParams {
        directions: settings.sh_directions,
        max_distance: DISTANCE_CELLS * layout.cell,
        filter_levels: settings.filter_levels,
    };
    let changed_geometry = changed.as_ref().map(|(boxes, _)| boxes.as_slice());
    // On the GPU every ray is marched (no rays kept); on the CPU, after a move, only those near it.
    let on_gpu = field_gpu.map(|gpu| gpu.build(&core.vgrid, &rgrid, environment, &field_params));
    let field_gpu_error = on_gpu.as_ref().and_then(|r| r.as_ref().err().cloned());
    let field_on_gpu = matches!(on_gpu, Some(Ok(_)));
    let (field, marched) = match on_gpu {
        Some(Ok(field)) => {
            core.rays = ProbeRays::default();
            (field, None)
        }
        _ => {
            let (field, marched) = ShField::build_reusing(&core.vgrid, &rgrid, environment, &field_params, &mut core.rays, changed_geometry);
            (field, Some(marched))
        }
    };
    let rays = (field.coefficients.len() + field.inside as usize) * settings.sh_directions as usize;
    if !core.keep_records {
        core.rays = ProbeRays::default();
    }
    times.field_ms = start.elapsed().as_secs_f32() * 1e3;

    let activity = PhotonGridActivity {
        dims: layout.dims,
        boundary_v_cells: core.vgrid.boundary_cells(),
        boundary_sh_cells: core.vgrid.sh_boundary.iter().filter(|b| **b).count(),
        probes: field.coefficients.len(),
        inside: field.inside,
        photons: photons.len(),
        stats,
        paths_traced,
        rays,
        rays_marched: marched.unwrap_or(rays),
        kept_bytes: core.paths.bytes() + core.rays.bytes(),
        times,
        field_on_gpu,
        ..default()
    };
    // The field flattened, and where its blend starts: the last field at the same cells.
    let cell_probe = Arc::new(field.cell_probe);
    let to: Arc<Vec<Vec4>> = Arc::new(field.coefficients.iter().flatten().copied().collect());
    let from = core
        .last_field
        .as_ref()
        .filter(|(l, old_cells, _)| *l == layout && old_cells.len() == cell_probe.len())
        .map(|(_, old_cells, old)| Arc::new(blend_start(&cell_probe, &to, old_cells, old)));
    core.last_field = Some((layout, cell_probe.clone(), to.clone()));
    let field = NewField { layout, cell_probe, to, from };
    Prepared { field: Some(field), occupancy: Arc::new(core.vgrid.occupancy_words()), activity, field_gpu_error }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A field over two cells, a probe each, every coefficient `value`; its blend start `from`.
    fn field(value: f32, from: Option<f32>) -> NewField {
        let coefficients = |v: f32| Arc::new(vec![Vec4::splat(v); 18]);
        NewField {
            layout: GridLayout { origin: Vec3::ZERO, cell: 1.0, dims: UVec3::new(2, 1, 1) },
            cell_probe: Arc::new(vec![0, 1]),
            to: coefficients(value),
            from: from.map(coefficients),
        }
    }

    /// Fields that arrive faster than they blend in: the second waits for the first's blend; a third
    /// replaces it, and starts from where the shown blend ended (not from the waiting field, which was
    /// never shown), laid out by a background task, not on the main thread.
    #[test]
    fn auto_tries_the_gpu_then_the_cpu_then_keeps_the_faster() {
        let t = |cpu, gpu| FieldTimings { cpu, gpu };
        assert!(t(None, None).auto_on_gpu(), "the first field on the GPU");
        assert!(!t(None, Some(0.01)).auto_on_gpu(), "the second on the CPU, to compare");
        assert!(t(Some(0.5), Some(0.01)).auto_on_gpu());
        assert!(!t(Some(0.4), Some(0.6)).auto_on_gpu(), "the CPU where it measured faster");
        // Only a missing GPU measurement sends it back to the GPU.
        assert!(t(Some(0.4), None).auto_on_gpu());
    }

    #[test]
    fn a_field_replacing_a_waiting_one_starts_where_the_shown_blend_ends() {
        let occupancy = Arc::new(Vec::new());
        let mut state = PhotonGridState::default();
        state.arrive(Some(field(1.0, None)), occupancy.clone());
        assert!(state.shown.as_ref().expect("shown").blend.is_done(), "the first field is shown whole");
        state.arrive(Some(field(2.0, Some(1.0))), occupancy.clone());
        let shown = state.shown.as_ref().expect("shown");
        assert!(!shown.blend.is_done() && shown.from[0] == Vec4::splat(1.0) && shown.to[0] == Vec4::splat(2.0));
        // The next one waits; the one after replaces it, its start laid out in the background.
        state.arrive(Some(field(3.0, Some(2.0))), occupancy.clone());
        assert!(state.pending.is_some() && !state.pending_start.is_running(), "its start was laid out with it");
        state.arrive(Some(field(4.0, Some(3.0))), occupancy.clone());
        assert!(state.pending_start.is_running(), "its start is laid out again, from the shown field");
        assert_eq!(state.pending.as_ref().map(|(f, _)| f.to[0]), Some(Vec4::splat(4.0)));
        // The shown field blends to its end, then the waiting one starts once its start is ready.
        while !state.shown.as_ref().expect("shown").blend.is_done() {
            state.start_waiting();
            assert!(state.pending.is_some(), "the waiting field waits for the blend before it");
            state.shown.as_mut().expect("shown").blend.advance();
        }
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while state.pending.is_some() && std::time::Instant::now() < deadline {
            state.start_waiting();
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let shown = state.shown.as_ref().expect("shown");
        assert!(state.pending.is_none(), "the waiting field started");
        assert!(!shown.blend.is_done());
        assert!(shown.from.iter().all(|c| *c == Vec4::splat(2.0)), "it starts where the shown blend ended: {:?}", shown.from[0]);
        assert!(shown.to.iter().all(|c| *c == Vec4::splat(4.0)));
    }
}
