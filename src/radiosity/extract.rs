//! Main world: the background solve (elements, links, lighting) and the element mesh with its light that
//! it hands the frame, extracted to the render world as [`RadiosityOutput`].

use std::sync::Arc;

use bevy::diagnostic::DiagnosticPath;
use bevy::math::Affine3A;
use bevy::prelude::*;
use bevy::render::extract_resource::ExtractResource;
use rayon::prelude::*;

use super::RadiositySettings;
use super::prepare::RadiosityVertex;
use super::solver::{Elements, PatchTriangle, RadiosityPatch, RadiositySolver, StageTimes};
use crate::background::{self, Blend, CpuJob, CpuMethodParams, JobKey, MethodUse};
use crate::camera::GiMethod;
use crate::scene::SceneSnapshot;

/// The solution the frame draws: the element mesh with its light. Extracted to the render world.
#[derive(Resource, Clone, Debug, Default, ExtractResource)]
pub struct RadiosityOutput {
    /// Bumped whenever the vertices or triangles change.
    pub generation: u64,
    pub vertices: Arc<Vec<RadiosityVertex>>,
    /// Three vertex indices per triangle.
    pub indices: Arc<Vec<u32>>,
}

/// What the last radiosity solve did, for the panel, the tools and the tests.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct RadiosityActivity {
    /// Surface elements (vertices after subdivision) and hierarchy nodes.
    pub elements: usize,
    pub nodes: usize,
    /// The stages of the last solve, ms of the background task (the paper's Table 1 rows); zero for a
    /// stage that did not run.
    pub times: StageTimes,
    /// Solves finished so far (background tasks that recomputed anything).
    pub solves: u64,
    /// Solves that derived the links kept among the still meshes from the links at hand (a mesh started
    /// moving: only the bins that saw it relinked), and solves that had to make them from scratch (a
    /// full linking's cost).
    pub kept_links_derived: u64,
    pub kept_links_made: u64,
    /// Solves that stopped after deriving or making those links because the meshes had moved on
    /// ([`RadiosityWork::Superseded`]).
    pub superseded: u64,
    /// What the last finished solve redid.
    pub last: RadiosityWork,
    /// Whether the light shown is not yet the solution of the scene as it is now: a solve is running
    /// or due, or a new solution is still being blended in.
    pub busy: bool,
    /// Whether a result is drawn: false from the method's activation until its first background
    /// result arrives (the frame shows no bounced light from it until then).
    pub ready: bool,
    /// Frames since the last solve was started from the scene as it was then (0 while none ran).
    pub frames_since_start: u32,
    /// MiB the links of the scene's elements would need, when that is over
    /// [`max_link_memory_mib`](RadiositySettings::max_link_memory_mib) and nothing was solved.
    pub over_budget_mib: Option<u64>,
}

/// How much of the solution a solve recomputed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RadiosityWork {
    /// Nothing changed.
    #[default]
    Reused,
    /// Only the lighting (lights, settings of the illumination).
    Illumination,
    /// Moved instances: elements moved and refitted, their links redone (the others' kept), lighting redone.
    Refit,
    /// New elements (meshes added, removed or re-meshed; element settings), links and lighting.
    Rebuild,
    /// New elements whose links would need more memory than allowed: nothing solved, no light.
    OverBudget,
    /// The first solve of a move made the links kept among the still meshes, and the meshes had moved on
    /// meanwhile: it stopped there (no push-down, no light) and the next solve, from the newest poses,
    /// reuses those links instead of finishing a solution that was already stale.
    Superseded,
}

/// The solver and what it was built from: the state a background solve takes and hands back.
#[derive(Default)]
pub struct RadiosityCore {
    pub solver: RadiositySolver,
    /// Per snapshot instance: key, version and `world_from_local` the elements were made with, and their
    /// element range.
    instances: Vec<(u64, u64, Affine3A, std::ops::Range<usize>)>,
    /// Each instance's own elements by key, with the instance version they were made from: a rebuild
    /// re-makes only the instances whose version changed.
    cache: bevy::platform::collections::HashMap<u64, (u64, Arc<Elements>)>,
    /// What the elements were built from: layout generation, element size and exposure (bits; the
    /// emission of `emissive.alpha < 1` materials depends on it).
    elements_key: Option<(u64, u32, u32)>,
    /// What the links were built from: geometry generation, bins and subdivision threshold (bits).
    links_key: Option<(u64, u32, u32)>,
    /// What the lighting was computed from.
    lighting_key: Option<SolveKey>,
    /// The link memory needed and allowed when that was last warned about.
    warned_budget: Option<(u64, u64)>,
    /// MiB of links the last solve would have needed, when that was over the budget.
    over_budget_mib: Option<u64>,
    /// The last solve stopped after its links ([`RadiosityWork::Superseded`]): the next one finishes
    /// whatever happens meanwhile, so that meshes that keep starting to move cannot hold the light back.
    superseded_last: bool,
}

/// The main-world state: the solver (in a background task while one runs), the running solve and the
/// solution shown.
#[derive(Resource, Default)]
pub struct RadiosityState {
    job: CpuJob<RadiositySettings, RadiosityCore, Solution>,
    shown: Option<Shown>,
}

/// Everything a solve depends on: the scene and the settings that change the solution (not
/// `intensity`, which only scales what is drawn).
type SolveKey = JobKey<RadiositySettings>;

/// What a background solve hands back.
struct Solution {
    work: RadiosityWork,
    over_budget_mib: Option<u64>,
    times: StageTimes,
    /// Elements and hierarchy nodes of the solver.
    elements: usize,
    nodes: usize,
    /// Gathered irradiance per element, lux (empty when nothing was recomputed).
    gathered: Vec<Vec3>,
    /// The drawn element vertices, world space, as solved.
    vertices: Vec<Vec3>,
    indices: Arc<Vec<u32>>,
    /// Per instance: key, `world_from_local` as solved and element range, so that the drawn elements
    /// follow instances that move on while the next solve runs.
    instances: Vec<(u64, Affine3A, std::ops::Range<usize>)>,
}

/// The solution drawn, blending from the previous one.
struct Shown {
    from: Vec<Vec3>,
    to: Vec<Vec3>,
    blend: Blend,
    vertices: Vec<Vec3>,
    indices: Arc<Vec<u32>>,
    instances: Vec<(u64, Affine3A, std::ops::Range<usize>)>,
    /// The snapshot generation and intensity last drawn with.
    drawn: Option<(u64, u32)>,
}

/// Milliseconds of the solve's stages in the background task, in Bevy's diagnostics (a measurement per
/// solve).
pub const DIAGNOSTIC_UPDATE_ELEMENTS: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_update_elements");
pub const DIAGNOSTIC_LINKS: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_links");
pub const DIAGNOSTIC_REFINE_PUSH: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_refine_push");
pub const DIAGNOSTIC_ILLUMINATION: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_illumination");


/// The elements of one snapshot instance: its triangles in world space with their colours at the
/// corners, welded and cut at `max_edge` metres.
fn instance_elements(snapshot: &SceneSnapshot, instance: &crate::scene::SnapshotInstance, exposure: f32, max_edge: f32) -> Elements {
    let material = snapshot.materials.get(instance.material as usize);
    let emission = material.map_or(Vec3::ZERO, |m| m.emission(exposure));
    let emission = if emission.is_finite() { emission.max(Vec3::ZERO) } else { Vec3::ZERO };
    let mirrored = instance.world_from_local().matrix3.determinant() < 0.0;
    let triangles = (0..instance.triangle_count())
        .map(|i| {
            let positions = instance.triangle(i);
            let attributes = instance.attributes(i);
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)];
            let mut albedo =
                corners.map(|(u, v)| material.map_or(Vec3::splat(0.5), |m| m.diffuse_at(&snapshot.textures, &attributes, u, v)));
            let mut normals = attributes.normals;
            // `triangle` swaps vertices 1 and 2 of a mirrored instance; its attributes keep the local
            // order.
            if mirrored {
                albedo.swap(1, 2);
                normals.swap(1, 2);
            }
            PatchTriangle { positions, normals, albedo, emission }
        })
        .collect();
    let mut elements = Elements::default();
    elements.add_patch(&RadiosityPatch { triangles }, max_edge);
    elements
}

/// Direct irradiance (lux) from the GI lights at each element, with a shadow ray each.
fn direct_irradiance(snapshot: &SceneSnapshot, elements: &Elements, gi_lights: &[Entity]) -> Vec<Vec3> {
    let epsilon = snapshot.ray_epsilon();
    let lights: Vec<_> = snapshot.lights.iter().filter(|l| gi_lights.contains(&l.entity)).map(|l| l.light).collect();
    (0..elements.len())
        .into_par_iter()
        .map(|e| {
            let (p, n) = (elements.positions[e], elements.normals[e]);
            let origin = p + n * epsilon;
            let mut sum = Vec3::ZERO;
            for light in &lights {
                let Some((l, distance, irradiance)) = light.incident(origin) else {
                    continue;
                };
                let cos = n.dot(l);
                if cos > 0.0 && !snapshot.occluded(origin, l, epsilon, distance - epsilon) {
                    sum += irradiance * cos;
                }
            }
            if sum.is_finite() { sum } else { Vec3::ZERO }
        })
        .collect()
}

/// Keeps the radiosity solution current for the first active radiosity camera, without waiting for it:
/// takes a finished background solve, starts the next when the scene or the settings changed since the
/// last one began, and draws the solution shown (blending a new one in, following moved instances).
pub(super) fn update_radiosity(
    mut params: CpuMethodParams<RadiositySettings>,
    mut state: ResMut<RadiosityState>,
    mut output: ResMut<RadiosityOutput>,
    mut activity: ResMut<RadiosityActivity>,
) {
    params.cost.radiosity_ms = 0.0;
    let frame_start = std::time::Instant::now();
    let (settings, scene) = match params.method_use(GiMethod::Radiosity) {
        MethodUse::On { settings, scene } => (settings, scene),
        MethodUse::Waiting => return,
        MethodUse::Off => {
            if state.shown.take().is_some() || state.job.is_active() {
                state.job.reset();
                *output = RadiosityOutput { generation: output.generation + 1, ..default() };
                (activity.busy, activity.ready) = (false, false);
            }
            return;
        }
    };
    let snapshot = params.snapshot.as_deref().expect("a method in use has a snapshot");
    let key = SolveKey { scene, settings: RadiositySettings { intensity: 1.0, ..settings.clone() } };
    let state = &mut *state;

    // 1. A finished solve: its solver comes back, its solution is blended in.
    if let Some(solution) = state.job.poll() {
        let Solution { work, over_budget_mib, times, elements, nodes, gathered, vertices, indices, instances } = solution;
        *activity = RadiosityActivity {
            elements,
            nodes,
            times,
            over_budget_mib,
            solves: activity.solves + !matches!(work, RadiosityWork::Reused | RadiosityWork::Superseded) as u64,
            kept_links_derived: activity.kept_links_derived + times.kept_bins_relinked.is_some() as u64,
            kept_links_made: activity.kept_links_made + times.kept_links_made as u64,
            superseded: activity.superseded + (work == RadiosityWork::Superseded) as u64,
            last: work,
            ..activity.clone()
        };
        background::record_stages(
            &mut params.diagnostics,
            &[
                (&DIAGNOSTIC_UPDATE_ELEMENTS, times.update_elements_ms),
                (&DIAGNOSTIC_LINKS, times.create_links_ms),
                (&DIAGNOSTIC_REFINE_PUSH, times.refine_push_ms),
                (&DIAGNOSTIC_ILLUMINATION, times.illumination_ms),
            ],
        );
        if work == RadiosityWork::OverBudget {
            // Not solved: no light, and nothing to redraw each frame while meshes move (a scene this
            // large rebuilt its elements' zero light on the main thread every frame, 1.7 ms).
            if state.shown.take().is_some() {
                *output = RadiosityOutput { generation: output.generation + 1, ..default() };
            }
        } else if !matches!(work, RadiosityWork::Reused | RadiosityWork::Superseded) {
            // Blend from what is on screen when the elements are the same ones; otherwise show it whole.
            let from = state.shown.as_ref().filter(|s| s.to.len() == gathered.len()).map(|s| s.current());
            let blend = if from.is_some() { Blend::start() } else { Blend::DONE };
            let from = from.unwrap_or_else(|| gathered.clone());
            state.shown = Some(Shown { from, to: gathered, blend, vertices, indices, instances, drawn: None });
        }
    }

    // 2. The scene or the settings changed since the last solve began: start the next one (a solve
    // still running on older inputs is told, see `RadiosityWork::Superseded`).
    state.job.supersede_if_stale(&key);
    if state.job.wants(&key) {
        let snapshot = snapshot.clone();
        state.job.start_supersedable(&key, move |core, key, superseded| {
            let (work, times, gathered) = solve(core, &snapshot, key, superseded);
            debug!(
                "Radiosity solve ({work:?}): elements {:.1} ms, links {:.1} ms ({} bins; kept links derived by relinking {:?} bins), \
                 push-down {:.1} ms ({} leaves, {} of them in part), light {:.1} ms; full links kept {:.1} MiB",
                times.update_elements_ms,
                times.create_links_ms,
                times.links,
                times.kept_bins_relinked,
                times.refine_push_ms,
                times.leaves_pushed,
                times.leaves_updated,
                times.illumination_ms,
                core.solver.full_links_bytes() as f64 / f64::from(1 << 20)
            );
            let elements = &core.solver.elements;
            Solution {
                work,
                over_budget_mib: core.over_budget_mib,
                times,
                elements: elements.len(),
                nodes: core.solver.hierarchy.nodes.len(),
                gathered,
                vertices: elements.vertices.clone(),
                indices: Arc::new(elements.triangles.iter().flatten().copied().collect()),
                instances: core.instances.iter().map(|(key, _, transform, range)| (*key, *transform, range.clone())).collect(),
            }
        });
        activity.frames_since_start = 0;
    } else {
        activity.frames_since_start += 1;
    }

    // 3. Draw the shown solution when it, the intensity or an instance's transform changed.
    if let Some(shown) = &mut state.shown {
        let weight = shown.blend.advance();
        let drawn = Some((snapshot.geometry_generation, settings.intensity.to_bits()));
        if weight.is_some() || shown.drawn != drawn {
            shown.follow(snapshot);
            shown.drawn = drawn;
            let scale = settings.intensity / std::f32::consts::PI;
            let vertices = shown
                .current()
                .into_iter()
                .zip(&shown.vertices)
                .map(|(irradiance, position)| RadiosityVertex {
                    position: position.extend(1.0),
                    irradiance: (irradiance * scale).extend(0.0),
                })
                .collect();
            let generation = output.generation + 1;
            *output = RadiosityOutput { generation, vertices: Arc::new(vertices), indices: shown.indices.clone() };
        }
    }
    activity.busy = state.job.is_stale(&key) || state.shown.as_ref().is_some_and(|s| !s.blend.is_done());
    // A scene over the link budget has its (empty) result too.
    activity.ready = state.shown.is_some() || activity.over_budget_mib.is_some();
    params.status.set_background(GiMethod::Radiosity, activity.ready, activity.busy, activity.frames_since_start, activity.solves);
    params.cost.radiosity_ms = frame_start.elapsed().as_secs_f32() * 1e3;
}

impl Shown {
    /// The irradiance per element on screen now.
    fn current(&self) -> Vec<Vec3> {
        self.blend.mix(&self.from, &self.to, Vec3::lerp)
    }

    /// Moves the drawn elements of instances whose transform changed since they were solved, so that the
    /// light drawn on a moving mesh stays on it until the next solution arrives: O(the moved elements).
    fn follow(&mut self, snapshot: &SceneSnapshot) {
        for (key, solved, range) in &mut self.instances {
            let Some(instance) = snapshot.instance(*key) else {
                continue;
            };
            let now = instance.world_from_local();
            if now == *solved {
                continue;
            }
            let change = now * solved.inverse();
            if !change.is_finite() {
                continue;
            }
            for v in &mut self.vertices[range.clone()] {
                *v = change.transform_point3(*v);
            }
            *solved = now;
        }
    }
}

/// One solve, on a background task: elements, links and lighting, each only when what it depends on
/// changed since `core` last solved. Returns what it redid, the stage times and the gathered irradiance
/// per element (empty when nothing was redone).
fn solve(core: &mut RadiosityCore, snapshot: &SceneSnapshot, key: &SolveKey, superseded: &background::Superseded) -> (RadiosityWork, StageTimes, Vec<Vec3>) {
    let settings = &key.settings;
    let exposure = key.scene.exposure();
    let params = settings.params();
    let diagonal = snapshot.bounds().map_or(1.0, |(lo, hi)| (hi - lo).length()).max(1e-6);
    let mut work = RadiosityWork::Reused;
    let mut times = StageTimes::default();
    let may_stop = !std::mem::take(&mut core.superseded_last);

    // 1. Elements: rebuilt on a new layout or element size, moved with instances otherwise.
    let elements_key = Some((snapshot.layout_generation, settings.element_size.to_bits(), key.scene.exposure));
    let moved = core.links_key.is_none_or(|k| k.0 != snapshot.geometry_generation);
    // The element ranges of the instances that moved since the links were made (None: rebuild).
    let moved_ranges = (core.elements_key == elements_key && moved).then(|| move_instances(core, snapshot)).flatten();
    if core.elements_key != elements_key || (moved && moved_ranges.is_none()) {
        let start = std::time::Instant::now();
        // The cached elements were cut at another size or carry another exposure's emission.
        let made_as = (settings.element_size.to_bits(), key.scene.exposure);
        if core.elements_key.is_none_or(|k| (k.1, k.2) != made_as) {
            core.cache.clear();
        }
        // Only the instances that changed are re-made (a deforming mesh costs its own elements).
        let max_edge = settings.element_size * diagonal;
        let cache = &core.cache;
        let per_instance: Vec<(u64, u64, Arc<Elements>)> = snapshot
            .instances()
            .par_iter()
            .map(|instance| {
                let reuse = cache.get(&instance.key).filter(|(version, _)| *version == instance.version);
                let elements = reuse.map_or_else(|| Arc::new(instance_elements(snapshot, instance, exposure, max_edge)), |(_, e)| e.clone());
                (instance.key, instance.version, elements)
            })
            .collect();
        let mut elements = Elements::default();
        core.instances.clear();
        core.cache.clear();
        for ((key, version, part), instance) in per_instance.into_iter().zip(snapshot.instances()) {
            let first = elements.len();
            elements.append(&part);
            core.instances.push((key, version, instance.world_from_local(), first..elements.len()));
            core.cache.insert(key, (version, part));
        }
        core.solver = RadiositySolver::new(elements);
        core.elements_key = elements_key;
        core.links_key = None;
        times.update_elements_ms = start.elapsed().as_secs_f32() * 1e3;
        work = RadiosityWork::Rebuild;
    } else if moved {
        let start = std::time::Instant::now();
        core.solver.hierarchy.refit(&core.solver.elements);
        times.update_elements_ms = start.elapsed().as_secs_f32() * 1e3;
        work = RadiosityWork::Refit;
    }

    // 2. Links, whenever any geometry changed, within the memory allowed.
    core.over_budget_mib = None;
    let budget = u64::from(settings.max_link_memory_mib) << 20;
    let needed = core.solver.link_bytes(settings.bins, false);
    if needed > budget {
        if core.warned_budget != Some((needed, budget)) {
            warn!(
                "Radiosity: the scene's {} elements need {} MiB of links with 6 × {b} × {b} bins, more than \
                 RadiositySettings::max_link_memory_mib ({} MiB); not solved (no bounced light). Raise element_size, \
                 lower bins or raise max_link_memory_mib.",
                core.solver.elements.len(),
                needed >> 20,
                settings.max_link_memory_mib,
                b = settings.bins
            );
            core.warned_budget = Some((needed, budget));
        }
        core.solver.forget_links();
        (core.links_key, core.lighting_key) = (None, None);
        core.over_budget_mib = Some(needed >> 20);
        return (RadiosityWork::OverBudget, times, Vec::new());
    }
    let links_key = Some((snapshot.geometry_generation, settings.bins, settings.subdivision_threshold.to_bits()));
    if core.links_key != links_key {
        let keep = core.solver.link_bytes(settings.bins, true) <= budget;
        // The links of a still scene kept (their filled bins) for the first move: less than the kept links.
        core.solver.keep_full_links = keep;
        match (&moved_ranges, work) {
            // Moved instances: keep the links among the rest (§4's update for deforming meshes).
            (Some(ranges), RadiosityWork::Refit) if keep => {
                let moving = core.solver.moving_segments(|e| ranges.iter().any(|r| r.contains(&e)));
                // The kept links were derived or made (a move's first solve, seconds with many meshes)
                // and the meshes moved on meanwhile: linking the moving meshes, the push-down and the
                // light of these poses would be stale on arrival. Stop there; the links stay stale
                // (`links_key` is not set), so the next solve relinks the moving meshes at their newest
                // poses over the kept links, and its push-down covers what this relink changed.
                let stopped = core.solver.relink_unless(&params, &moving, || may_stop && superseded.is_set());
                let solver_times = core.solver.times;
                let derived = solver_times.kept_bins_relinked.is_some() || solver_times.kept_links_made;
                if stopped || (derived && superseded.is_set() && may_stop) {
                    core.superseded_last = true;
                    let times = StageTimes { update_elements_ms: times.update_elements_ms, ..solver_times };
                    return (RadiosityWork::Superseded, times, Vec::new());
                }
            }
            // New elements (a new solver), new bins or threshold: every link anew.
            _ => core.solver.create_links(&params),
        }
        core.solver.refine_and_push();
        // The link stages as the solver reported them; the elements and the light are timed here.
        times = StageTimes {
            update_elements_ms: times.update_elements_ms,
            illumination_ms: times.illumination_ms,
            bounces_run: times.bounces_run,
            ..core.solver.times
        };
        core.links_key = links_key;
        core.lighting_key = None;
        if work == RadiosityWork::Reused {
            work = RadiosityWork::Refit;
        }
    }

    // 3. Lighting.
    if core.lighting_key.as_ref() == Some(key) {
        return (work, times, Vec::new());
    }
    let start = std::time::Instant::now();
    core.solver.environment = match (snapshot.environment.as_deref(), core.solver.bins.as_ref()) {
        // The camera's environment map (plus the constant sky), averaged over each world-aligned bin
        // with about two samples per environment texel across a bin.
        (Some(environment), Some(bins)) => {
            let samples = (2 * environment.face_size()).div_ceil(bins.n).clamp(2, 16);
            bins.average(samples, |d| environment.radiance(d) + settings.sky)
        }
        _ => Vec::new(),
    };
    let direct = direct_irradiance(snapshot, &core.solver.elements, &key.scene.gi_lights);
    core.solver.illuminate(&direct, &params);
    times.illumination_ms = start.elapsed().as_secs_f32() * 1e3;
    times.bounces_run = core.solver.times.bounces_run;
    core.lighting_key = Some(key.clone());
    if work == RadiosityWork::Reused {
        work = RadiosityWork::Illumination;
    }
    (work, times, core.solver.gathered.clone())
}

/// Moves the elements of instances whose transform changed (same instances, same meshes) by the
/// change of their transform, and returns their element ranges. Returns `None` when the snapshot's
/// instances are not those the elements were made from (then everything is rebuilt).
fn move_instances(core: &mut RadiosityCore, snapshot: &SceneSnapshot) -> Option<Vec<std::ops::Range<usize>>> {
    let instances = snapshot.instances();
    if instances.len() != core.instances.len() {
        return None;
    }
    let mut moved = Vec::new();
    let elements = &mut core.solver.elements;
    for (instance, (key, version, transform, range)) in instances.iter().zip(core.instances.iter_mut()) {
        if instance.key != *key {
            return None;
        }
        if instance.version == *version {
            continue;
        }
        let now = instance.world_from_local();
        let change = now * transform.inverse();
        // A new version in place without a move is a new material or texture: rebuild.
        if !change.is_finite() || now == *transform {
            return None;
        }
        let normal_matrix = Mat3::from(change.matrix3).inverse().transpose();
        for e in range.clone() {
            elements.positions[e] = change.transform_point3(elements.positions[e]);
            elements.vertices[e] = change.transform_point3(elements.vertices[e]);
            elements.normals[e] = (normal_matrix * elements.normals[e]).normalize_or(elements.normals[e]);
        }
        (*version, *transform) = (instance.version, now);
        moved.push(range.clone());
    }
    Some(moved)
}
