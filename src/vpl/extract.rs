//! Main world: settings validation and the VPL walks (only when their inputs change); and extraction.

use std::sync::Arc;

use bevy::prelude::*;
use bevy::app::SubApp;
use bevy::render::{Extract, ExtractSchedule};

use super::{VplSettings, VplVisibility};
use crate::settings::GiSettings;
use super::generate::{
    EmissionGuide, IsmPoint, PilotHits, Vpl, VplPaths, WalkSettings, automatic_bound, ism_positions, ism_samples, pilot_hits, surface_area,
    traced_shadow_maps, traced_shadow_maps_update,
};
use crate::scene::changes::InstanceRecord;
use crate::background::BackgroundJob;
use crate::camera::{DiffuseGi, GiDebugView, GiMethod};
use crate::emitters::{EmitterSamples, GpuEmitter};
use crate::ssbc::SsbcRequest;
use crate::light::GiLight;
use crate::scene::SceneSnapshot;

/// Scene points per VPL's splat run: the point set holds this many runs, so that neighbouring VPLs
/// splat different points (Ritschel et al. 2008 give every ISM its own subset).
pub const POINT_RUNS: u32 = 16;
/// The largest point set, whatever `ism_points` asks (16 MiB of `vec4`s).
pub const MAX_POINTS: u32 = 1 << 20;

/// The VPLs and the shadow-map point set, shared by every VPL camera; rebuilt only when the lights, the
/// geometry or the generation settings change, in the background ([`crate::background`]): the set
/// shown is the last one finished (usually the previous frame's inputs). Empty while no camera uses the
/// method.
#[derive(Resource, Default, Clone, Debug)]
pub struct VplSet {
    /// Bumped whenever `vpls` change (the shadow maps are rebuilt then).
    pub generation: u64,
    pub vpls: Arc<Vec<Vpl>>,
    /// Bumped whenever `points` change.
    pub points_generation: u64,
    pub points: Arc<Vec<IsmPoint>>,
    /// The settings of the first VPL camera (sanitised). Only `light_paths`, `bounces`, `seed` and
    /// `ism_points` are baked into the set; their values the set was made with are those of the last
    /// finished walk.
    pub settings: VplSettings,
    /// The automatic `b` for this set ([`automatic_bound`]), 1/m².
    pub automatic_bound: f32,
    /// Total surface area of the scene, m² (each shadow map's points share it).
    pub surface_area: f32,
    /// [`VplVisibility::Traced`](super::VplVisibility): the ray-traced shadow maps of `vpls` (side,
    /// then `side²` words per VPL, see [`traced_shadow_maps`](super::generate::traced_shadow_maps)). The
    /// GPU splats imperfect ones while these are missing or stale.
    pub shadow_maps: Option<(u32, Arc<Vec<u32>>)>,
    /// Whether the set is not yet the one of the scene as it is now (a walk runs or is due).
    pub busy: bool,
    /// How long the last walk that changed the set took on its background thread (pilot rays, VPLs,
    /// points and traced shadow maps, whichever it redid), milliseconds.
    pub last_walk_ms: f32,
    /// What the last walk that changed the VPLs redid: the light paths walked (of all, after meshes
    /// moved: those whose rays ran through them) and the traced shadow-map texels traced (the kept
    /// VPLs' texels whose rays pass through what moved, and every texel of the new VPLs).
    pub last_redone: VplRedone,
}

/// What one walk redid ([`VplSet::last_redone`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VplRedone {
    pub paths: usize,
    pub paths_total: usize,
    pub texels: usize,
    pub texels_total: usize,
}

/// The main-world side of the walks: the running walk and the caches it keeps between runs.
#[derive(Resource, Default)]
pub struct VplWalks {
    job: BackgroundJob<WalkKey, Walked>,
    /// `None` while a walk holds them.
    caches: Option<Box<WalkCaches>>,
    /// The lights' pilot rays (a copy of the caches'), from which the main thread draws the guides
    /// every frame: they follow the cameras.
    pilots: Option<((u64, u64, Vec<Entity>), Arc<Vec<PilotHits>>)>,
    /// Walks finished, and frames since the last one started (the method's [`MethodStatus`](crate::method::MethodStatus)).
    finished: u64,
    frames_since_start: u32,
}

/// What a walk keeps between runs.
#[derive(Default)]
struct WalkCaches {
    vpl_key: Option<VplKey>,
    points_key: Option<(u64, u32)>,
    /// Where the points sit (triangle and barycentrics), by layout generation, count and seed.
    samples: Option<((u64, u32, u32), Arc<Vec<super::generate::IsmSample>>)>,
    /// The lights' pilot rays, and what they were traced from.
    pilots: Option<((u64, u64, Vec<Entity>), Arc<Vec<PilotHits>>)>,
    /// The last light paths (with the records [`VplPaths::rewalk`] reads) and their VPLs, and the
    /// instances and layout generation they were walked in.
    paths: VplPaths,
    instances: Vec<InstanceRecord<()>>,
    layout: u64,
    /// The last traced shadow maps, and what they were made for (the VPLs' key and the side).
    maps: Option<Arc<Vec<u32>>>,
    maps_key: Option<(VplKey, u32)>,
}

#[derive(Clone, Debug, PartialEq)]
struct VplKey {
    geometry: u64,
    lights: u64,
    gi_lights: Vec<Entity>,
    /// The emissive surfaces' samples ([`EmitterSamples::generation`]).
    emitters: u64,
    walk: WalkSettings,
    /// The guides the paths were drawn from (they change when a camera crosses to another side of a
    /// surface the lights reach, not with every camera move).
    guides: Vec<EmissionGuide>,
}

/// The inputs of one walk: the VPLs' and the points'.
#[derive(Clone, Debug, PartialEq)]
struct WalkKey {
    vpls: VplKey,
    layout: u64,
    points: u32,
    /// The side of the traced shadow maps, or `None` for imperfect ones.
    maps: Option<u32>,
}

/// What a walk hands back.
struct Walked {
    caches: Box<WalkCaches>,
    /// New VPLs with the scene's surface area, when they were redone.
    vpls: Option<(Arc<Vec<Vpl>>, f32)>,
    /// New points, when they were redone.
    points: Option<Vec<IsmPoint>>,
    /// New traced shadow maps (or none, for imperfect ones), when they were redone.
    maps: Option<Option<(u32, Arc<Vec<u32>>)>>,
    /// What it redid.
    redone: VplRedone,
    /// The walk's time on its thread, milliseconds.
    ms: f32,
}

/// The settings of the first active camera that uses the VPL method, if any.
pub(crate) fn first_vpl_camera<'a>(
    cameras: impl Iterator<Item = (Entity, &'a Camera, &'a DiffuseGi, Option<&'a VplSettings>)>,
) -> Option<VplSettings> {
    cameras
        .filter(|(_, camera, gi, _)| camera.is_active && gi.enabled && gi.method == GiMethod::Vpl)
        .min_by_key(|(entity, ..)| *entity)
        .map(|(.., settings)| settings.cloned().unwrap_or_default().sanitized().0)
}

/// Keeps the VPLs (and the point set) current while a camera uses the method, without waiting for
/// them: takes a finished walk, and starts the next when the lights, the geometry, the guides or the
/// settings changed since the last one began.
pub(crate) fn update_vpls(
    mut commands: Commands,
    mut set: ResMut<VplSet>,
    mut walks: ResMut<VplWalks>,
    snapshot: Option<Res<SceneSnapshot>>,
    cameras: Query<(Entity, &Camera, &DiffuseGi, Option<&VplSettings>, &GlobalTransform)>,
    (gi_lights, emitters): (Query<Entity, With<GiLight>>, Option<Res<EmitterSamples>>),
    (mut cost, status): (ResMut<crate::MainThreadCost>, Res<crate::method::GiMethodStatus>),
) {
    let start = std::time::Instant::now();
    cost.vpl_ms = 0.0;
    let Some(settings) = first_vpl_camera(cameras.iter().map(|(e, c, gi, s, _)| (e, c, gi, s))) else {
        if walks.caches.is_some() || walks.job.is_running() || !set.vpls.is_empty() {
            *walks = VplWalks::default();
            *set = VplSet { generation: set.generation + 1, points_generation: set.points_generation + 1, ..default() };
        }
        return;
    };
    // The snapshot holds the geometry the paths cross and the emissive surfaces they may start on.
    let Some(snapshot) = snapshot else {
        commands.init_resource::<SceneSnapshot>();
        return;
    };
    let walks = &mut *walks;

    // 1. A finished walk: its VPLs and points replace the set's.
    if let Some((_, walked)) = walks.job.poll() {
        walks.finished += 1;
        let Walked { caches, vpls, points, maps, redone, ms } = walked;
        if vpls.is_some() || points.is_some() || maps.is_some() {
            set.last_walk_ms = ms;
        }
        if vpls.is_some() {
            set.last_redone = redone;
        }
        walks.pilots = caches.pilots.clone();
        walks.caches = Some(caches);
        if let Some((vpls, area)) = vpls {
            set.surface_area = area;
            set.automatic_bound = automatic_bound(vpls.len(), area);
            set.vpls = vpls;
            set.generation += 1;
        }
        if let Some(maps) = maps {
            set.shadow_maps = maps;
            set.generation += 1;
        }
        if let Some(points) = points {
            set.points = Arc::new(points);
            set.points_generation += 1;
            // New points: the shadow maps must be splatted again.
            set.generation += 1;
        }
    }

    // 2. What the set should be made from now.
    let mut lights: Vec<Entity> = gi_lights.iter().collect();
    lights.sort();
    let walk = WalkSettings { paths: settings.light_paths, bounces: settings.bounces, seed: settings.seed };
    let positions: Vec<Vec3> = cameras
        .iter()
        .filter(|(_, camera, gi, ..)| camera.is_active && gi.enabled && gi.method == GiMethod::Vpl)
        .map(|(.., transform)| transform.translation())
        .collect();
    // The guides follow the cameras over the lights' pilot rays: those of the last walk, for the same
    // GI lights (a walk after a change of geometry or lights traces new ones, and the guides drawn from
    // them start the next; guided paths are weighted by 1/pdf, so slightly stale guides bias nothing).
    let guides: Vec<EmissionGuide> = walks
        .pilots
        .as_ref()
        .filter(|((_, _, pilot_lights), _)| *pilot_lights == lights)
        .map(|(_, hits)| hits.iter().map(|h| EmissionGuide::from_pilots(h, &positions)).collect())
        .unwrap_or_default();
    let count = (settings.ism_points.saturating_mul(POINT_RUNS)).min(MAX_POINTS);
    let key = WalkKey {
        vpls: VplKey {
            geometry: snapshot.geometry_generation,
            lights: snapshot.light_generation,
            gi_lights: lights,
            emitters: emitters.as_ref().map_or(0, |e| e.generation),
            walk,
            guides,
        },
        layout: snapshot.layout_generation,
        points: count,
        maps: (settings.visibility == VplVisibility::Traced).then(|| super::prepare::ism_side(settings.ism_resolution)),
    };
    walks.frames_since_start += 1;
    if walks.job.wants(&key) {
        walks.frames_since_start = 0;
        let mut caches = walks.caches.take().unwrap_or_default();
        let snapshot = snapshot.clone();
        let walk_key = key.clone();
        let emitters = emitters.as_ref().map(|e| e.samples.clone()).unwrap_or_default();
        walks.job.start(key.clone(), move || {
            let started = std::time::Instant::now();
            let (vpls, points, maps, redone) = walk_scene(&mut caches, &snapshot, &emitters, &walk_key, &positions);
            Walked { caches, vpls, points, maps, redone, ms: started.elapsed().as_secs_f32() * 1000.0 }
        });
    }
    // Only the shadow maps' size and kind are baked into the set; gather and SSBC fields are per view.
    if set.settings.ism_resolution != settings.ism_resolution || set.settings.visibility != settings.visibility {
        set.generation += 1;
    }
    set.settings = settings;
    set.busy = !walks.job.is_current(&key);
    status.set_background(GiMethod::Vpl, !set.vpls.is_empty(), set.busy, walks.frames_since_start, walks.finished);
    cost.vpl_ms = start.elapsed().as_secs_f32() * 1000.0;
}

/// One walk, on a background task: the lights' pilot rays when the geometry or the lights changed, the
/// guides from them for the cameras at `viewers`, the VPLs when their inputs changed, the point samples
/// after a layout change (O(triangles)) and the points after any geometry change (after moves only, the
/// same samples follow their triangles: O(points)), and the traced shadow maps when the VPLs or their
/// side changed (O(VPLs × side²) rays).
///
/// When only meshes moved since the last walk (same instances, lights, emitters, guides and settings),
/// only the paths whose rays ran through their old or new bounds are walked again
/// ([`VplPaths::rewalk`]), and only the shadow-map texels whose rays pass through those bounds, or
/// belong to a new VPL, are traced ([`traced_shadow_maps_update`]): the same VPLs and maps as a walk from
/// scratch, at the cost of what the move touches.
#[expect(clippy::type_complexity, reason = "what changed, each part optional")]
fn walk_scene(
    caches: &mut WalkCaches,
    snapshot: &SceneSnapshot,
    emitters: &[GpuEmitter],
    key: &WalkKey,
    viewers: &[Vec3],
) -> (Option<(Arc<Vec<Vpl>>, f32)>, Option<Vec<IsmPoint>>, Option<Option<(u32, Arc<Vec<u32>>)>>, VplRedone) {
    let VplKey { geometry, lights, gi_lights, walk, .. } = &key.vpls;
    let sources: Vec<_> =
        snapshot.lights.iter().filter(|l| gi_lights.binary_search(&l.entity).is_ok()).map(|l| l.light).collect();
    let pilot_key = (*geometry, *lights, gi_lights.clone());
    if caches.pilots.as_ref().is_none_or(|(k, _)| *k != pilot_key) {
        let hits = sources.iter().map(|l| pilot_hits(snapshot, l)).collect();
        caches.pilots = Some((pilot_key, Arc::new(hits)));
    }
    // The guides of this scene's pilots (the main thread's, in the key, may be a walk old: they only
    // decide when to walk again).
    let guides = caches.pilots.as_ref().map(|(_, hits)| hits.iter().map(|h| EmissionGuide::from_pilots(h, viewers)).collect());
    let vpl_key = VplKey { guides: guides.unwrap_or_default(), ..key.vpls.clone() };
    let instances = crate::scene::changes::instance_records(snapshot, |_| ());
    let mut vpls = None;
    let mut redone = VplRedone::default();
    // With the VPLs' other inputs the same and the same instances, the boxes of the meshes that moved.
    let moved: Option<Vec<(Vec3, Vec3)>> = caches
        .vpl_key
        .as_ref()
        .filter(|old| VplKey { geometry: vpl_key.geometry, ..(*old).clone() } == vpl_key && caches.layout == key.layout)
        .map(|_| crate::scene::changes::changed_boxes(&caches.instances, &instances).into_iter().map(|(b, _)| b).collect());
    // The last maps were traced for the VPLs this walk starts from.
    let old_maps_side = caches.maps_key.as_ref().filter(|(k, _)| Some(k) == caches.vpl_key.as_ref()).map(|(_, side)| *side);
    let mut origin = None;
    if caches.vpl_key.as_ref() != Some(&vpl_key) {
        let guides = Some(vpl_key.guides.as_slice());
        let rewalked = match &moved {
            Some(boxes) => caches.paths.rewalk(snapshot, &sources, emitters, guides, *walk, boxes),
            None => {
                caches.paths = VplPaths::walk(snapshot, &sources, emitters, guides, *walk);
                None
            }
        };
        redone.paths = rewalked.as_ref().map_or(caches.paths.len(), |(_, walked)| *walked);
        redone.paths_total = caches.paths.len();
        origin = rewalked.map(|(origin, _)| origin);
        vpls = Some((Arc::new(caches.paths.vpls.clone()), surface_area(snapshot)));
        caches.vpl_key = Some(vpl_key.clone());
    }
    (caches.instances, caches.layout) = (instances, key.layout);
    let maps_key = key.maps.map(|side| (vpl_key, side));
    let mut maps = None;
    if caches.maps_key != maps_key {
        caches.maps = key.maps.map(|side| {
            let texels = caches.paths.vpls.len() * (side * side) as usize;
            redone.texels_total = texels;
            // The last maps were traced for the VPLs this walk started from, at this side.
            let previous = caches.maps.as_ref().filter(|_| old_maps_side == Some(side));
            Arc::new(match (previous, &origin, &moved) {
                (Some(old), Some(origin), Some(boxes)) => {
                    let (maps, traced) = traced_shadow_maps_update(snapshot, &caches.paths.vpls, side, old, origin, boxes);
                    redone.texels = traced;
                    maps
                }
                _ => {
                    redone.texels = texels;
                    traced_shadow_maps(snapshot, &caches.paths.vpls, side)
                }
            })
        });
        maps = Some(key.maps.zip(caches.maps.clone()));
        caches.maps_key = maps_key;
    }
    let samples_key = (key.layout, key.points, walk.seed);
    if caches.samples.as_ref().is_none_or(|(k, _)| *k != samples_key) {
        caches.samples = Some((samples_key, Arc::new(ism_samples(snapshot, key.points, walk.seed))));
    }
    let mut points = None;
    let points_key = (*geometry, key.points);
    if caches.points_key != Some(points_key) {
        let samples = caches.samples.as_ref().map(|(_, s)| s.clone()).unwrap_or_default();
        points = Some(ism_positions(snapshot, &samples));
        caches.points_key = Some(points_key);
    }
    (vpls, points, maps, redone)
}

/// The VPL set in the render world (the `Arc`s are shared, not copied).
#[derive(Resource, Default, Clone, Debug)]
pub struct ExtractedVplSet(pub VplSet);

fn extract_vpl_set(set: Extract<Res<VplSet>>, mut extracted: ResMut<ExtractedVplSet>) {
    if extracted.0.generation != set.generation || extracted.0.points_generation != set.points_generation {
        extracted.0 = set.clone();
    }
}

/// The camera's [`VplSettings`] in the render world (sanitised), for VPL cameras.
pub type ExtractedVplSettings = crate::method::ExtractedSettings<VplSettings>;

/// Copies each VPL camera's settings into the render world, and asks the frame's SSBC pass for the
/// compensation (unless the settings or the debug view want the clamped light alone).
fn extract_vpl_cameras(
    mut commands: Commands,
    cameras: Extract<Query<(bevy::render::sync_world::RenderEntity, &DiffuseGi, Option<&VplSettings>)>>,
    set: Extract<Res<VplSet>>,
) {
    for (entity, gi, settings) in &cameras {
        let Ok(mut entity) = commands.get_entity(entity) else {
            continue;
        };
        if gi.method != GiMethod::Vpl {
            entity.remove::<(ExtractedVplSettings, SsbcRequest)>();
            continue;
        }
        let s = settings.cloned().unwrap_or_default().sanitized().0;
        let wanted = s.ssbc_steps > 0 && gi.debug_view != GiDebugView::VplClampedOnly && gi.debug_view != GiDebugView::VplPositions;
        if wanted {
            entity.insert(SsbcRequest {
                steps: s.ssbc_steps,
                bound: super::prepare::effective_bound(s.geometry_bound, set.automatic_bound),
                solid_angle: s.ssbc_solid_angle,
                discontinuity_solid_angle: s.ssbc_discontinuity_solid_angle,
                levels: s.ssbc_levels,
                blur: s.ssbc_blur,
                intensity: s.intensity,
                replace: gi.debug_view == GiDebugView::VplCompensationOnly,
            });
        } else {
            entity.remove::<SsbcRequest>();
        }
        entity.insert(crate::method::ExtractedSettings(s));
    }
}

/// The main-world systems: the walks, after the snapshot and the emitter samples they read.
pub(super) fn add_main_systems(app: &mut App) {
    app.init_resource::<VplSet>().init_resource::<VplWalks>().add_systems(
        PostUpdate,
        update_vpls.after(crate::scene::SceneSnapshotSystems::Update).after(crate::emitters::update_emitters),
    );
}

/// The extraction of the set and of each VPL camera's settings.
pub(super) fn add_extract_systems(render_app: &mut SubApp) {
    render_app.add_systems(ExtractSchedule, (extract_vpl_set, extract_vpl_cameras));
}
