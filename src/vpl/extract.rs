//! Main world: settings validation and the VPL walks (only when their inputs change); and extraction.

use std::sync::Arc;

use bevy::prelude::*;
use bevy::render::Extract;

use super::VplSettings;
use crate::settings::GiSettings;
use super::generate::{
    EmissionGuide, IsmPoint, PilotHits, Vpl, WalkSettings, automatic_bound, generate_vpls, ism_positions, ism_samples, pilot_hits, surface_area,
};
use crate::camera::{DiffuseGi, GiDebugView, GiMethod};
use crate::ssbc::SsbcRequest;
use crate::light::GiLight;
use crate::scene::SceneSnapshot;

/// Scene points per VPL's splat run: the point set holds this many runs, so that neighbouring VPLs
/// splat different points (Ritschel et al. 2008 give every ISM its own subset).
pub const POINT_RUNS: u32 = 16;
/// The largest point set, whatever `ism_points` asks (16 MiB of `vec4`s).
pub const MAX_POINTS: u32 = 1 << 20;

/// The VPLs and the shadow-map point set, shared by every VPL camera; rebuilt only when the lights, the
/// geometry or the generation settings change. Empty while no camera uses the method.
#[derive(Resource, Default, Clone, Debug)]
pub struct VplSet {
    /// Bumped whenever `vpls` change (the shadow maps are rebuilt then).
    pub generation: u64,
    pub vpls: Arc<Vec<Vpl>>,
    /// Bumped whenever `points` change.
    pub points_generation: u64,
    pub points: Arc<Vec<IsmPoint>>,
    /// The settings the set was generated with (sanitised; the first VPL camera's).
    pub settings: VplSettings,
    /// The automatic `b` for this set ([`automatic_bound`]), 1/m².
    pub automatic_bound: f32,
    /// Total surface area of the scene, m² (each shadow map's points share it).
    pub surface_area: f32,
    key: Option<VplKey>,
    points_key: Option<(u64, u32)>,
    /// Where the points sit (triangle and barycentrics), by layout generation, count and seed.
    samples: Option<((u64, u32, u32), Arc<Vec<super::generate::IsmSample>>)>,
    /// The lights' pilot rays, and what they were traced from.
    pilots: Option<((u64, u64, Vec<Entity>), Vec<PilotHits>)>,
}

#[derive(Clone, Debug, PartialEq)]
struct VplKey {
    geometry: u64,
    lights: u64,
    gi_lights: Vec<Entity>,
    walk: WalkSettings,
    /// The guides the paths were drawn from (they change when a camera crosses to another side of a
    /// surface the lights reach, not with every camera move).
    guides: Vec<EmissionGuide>,
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

/// Regenerates the VPLs (and the point set) when the lights, the geometry or the settings changed, and
/// only while a camera uses the method.
pub(crate) fn update_vpls(
    mut commands: Commands,
    mut set: ResMut<VplSet>,
    snapshot: Option<Res<SceneSnapshot>>,
    cameras: Query<(Entity, &Camera, &DiffuseGi, Option<&VplSettings>, &GlobalTransform)>,
    gi_lights: Query<Entity, With<GiLight>>,
    mut cost: ResMut<crate::MainThreadCost>,
) {
    let start = std::time::Instant::now();
    cost.vpl_ms = 0.0;
    let Some(settings) = first_vpl_camera(cameras.iter().map(|(e, c, gi, s, _)| (e, c, gi, s))) else {
        if set.key.is_some() {
            *set = VplSet { generation: set.generation + 1, points_generation: set.points_generation + 1, ..default() };
        }
        return;
    };
    let Some(snapshot) = snapshot else {
        if !gi_lights.is_empty() {
            commands.init_resource::<SceneSnapshot>();
        }
        return;
    };
    let mut lights: Vec<Entity> = gi_lights.iter().collect();
    lights.sort();
    let walk = WalkSettings { paths: settings.light_paths, bounces: settings.bounces, seed: settings.seed };
    let sources: Vec<_> =
        snapshot.lights.iter().filter(|l| lights.binary_search(&l.entity).is_ok()).map(|l| l.light).collect();
    // Pilot rays per light, once per light and geometry; the guides from them follow the cameras.
    let pilot_key = (snapshot.geometry_generation, snapshot.light_generation, lights.clone());
    if set.pilots.as_ref().is_none_or(|(k, _)| *k != pilot_key) {
        let hits = sources.iter().map(|l| pilot_hits(&snapshot, l)).collect();
        set.pilots = Some((pilot_key, hits));
    }
    let positions: Vec<Vec3> = cameras
        .iter()
        .filter(|(_, camera, gi, ..)| camera.is_active && gi.enabled && gi.method == GiMethod::Vpl)
        .map(|(.., transform)| transform.translation())
        .collect();
    let guides: Vec<EmissionGuide> = set
        .pilots
        .as_ref()
        .map(|(_, hits)| hits.iter().map(|h| EmissionGuide::from_pilots(h, &positions)).collect())
        .unwrap_or_default();
    let key = VplKey {
        geometry: snapshot.geometry_generation,
        lights: snapshot.light_generation,
        gi_lights: lights,
        walk,
        guides,
    };
    if set.key.as_ref() != Some(&key) {
        let vpls = generate_vpls(&snapshot, &sources, Some(&key.guides), walk);
        set.surface_area = surface_area(&snapshot);
        set.automatic_bound = automatic_bound(vpls.len(), set.surface_area);
        set.vpls = Arc::new(vpls);
        set.generation += 1;
        set.key = Some(key);
    }
    let count = (settings.ism_points.saturating_mul(POINT_RUNS)).min(MAX_POINTS);
    // New points after a layout change (O(triangles)); after moves only, the same points follow their
    // triangles (O(points)).
    let samples_key = (snapshot.layout_generation, count, settings.seed);
    if set.samples.as_ref().is_none_or(|(k, _)| *k != samples_key) {
        set.samples = Some((samples_key, Arc::new(ism_samples(&snapshot, count, settings.seed))));
    }
    let points_key = (snapshot.geometry_generation, count);
    if set.points_key != Some(points_key) {
        let samples = set.samples.as_ref().map(|(_, s)| s.clone()).unwrap_or_default();
        set.points = Arc::new(ism_positions(&snapshot, &samples));
        set.points_generation += 1;
        set.points_key = Some(points_key);
        // New points: the shadow maps must be splatted again.
        set.generation += 1;
    }
    // Only the shadow maps' size is baked into the set; gather and SSBC fields are per view.
    if set.settings.ism_resolution != settings.ism_resolution {
        set.generation += 1;
    }
    set.settings = settings;
    cost.vpl_ms = start.elapsed().as_secs_f32() * 1000.0;
}

/// The VPL set in the render world (the `Arc`s are shared, not copied).
#[derive(Resource, Default, Clone, Debug)]
pub struct ExtractedVplSet(pub VplSet);

pub(crate) fn extract_vpl_set(set: Extract<Res<VplSet>>, mut extracted: ResMut<ExtractedVplSet>) {
    if extracted.0.generation != set.generation || extracted.0.points_generation != set.points_generation {
        extracted.0 = set.clone();
    }
}

/// The camera's [`VplSettings`] in the render world (sanitised), for VPL cameras.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ExtractedVplSettings(pub VplSettings);

/// Copies each VPL camera's settings into the render world, and asks the frame's SSBC pass for the
/// compensation (unless the settings or the debug view want the clamped light alone).
pub(crate) fn extract_vpl_cameras(
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
                bound: super::render::effective_bound(s.geometry_bound, set.automatic_bound),
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
        entity.insert(ExtractedVplSettings(s));
    }
}
