//! Main world: validation, albedo voxelisation, IrradianceVolume export entities; and extraction to the
//! render world.

use std::sync::Arc;

use bevy::asset::RenderAssetUsages;
use bevy::image::ImageSampler;
use bevy::light::{IrradianceVolume, LightProbe};
use bevy::platform::collections::HashSet;
use bevy::prelude::*;
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat, TextureUsages};
use bevy::render::Extract;

use super::settings::RadianceHintsVolume;
use super::voxelize::{GeometryVoxels, voxelize, voxelize_update};
use crate::camera::{DiffuseGi, GiMethod, GiOutput};
use crate::light::GiLight;
use crate::rsm::RsmFocus;
use crate::scene::SceneSnapshot;

/// The voxelised scene of a [`RadianceHintsVolume`] (albedo, hint validity, occupancy; see
/// [`super::voxelize`]), redone when geometry or the volume changes.
#[derive(Component, Clone, Debug)]
pub struct RhGeometryVoxels {
    /// Bumped at every voxelisation.
    pub generation: u64,
    /// What it was voxelised from: snapshot geometry generation, transform, resolution.
    key: (u64, [u32; 16], UVec3),
    pub data: Arc<GeometryVoxels>,
}

/// How far apart the surfaces in a [`RadianceHintsVolume`] are: their mean chord
/// ([`SceneSnapshot::mean_chord`], [`MEAN_CHORD_RAYS`] rays), which keeps the adaptive grid's cells in
/// proportion to the scene whatever its units ([`GridSizing`](super::GridSizing)). Measured with the
/// voxels, once per layout of the snapshot and placement of the volume; a new value within 20 % of the
/// last is not taken (a volume that moves does not re-size its grid for noise).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct RhMeanChord {
    /// Metres; `None` when no surface overlaps the volume (or every ray left the scene).
    pub metres: Option<f32>,
    /// The snapshot's layout generation and the volume's transform it was measured for.
    key: (u64, [u32; 16]),
}

/// Rays [`RhMeanChord`] traces: 0.5–0.9 ms on the main thread (per layout change or volume move) on the
/// standard scenes and room_0, plus O(triangles in the volume) for its area table; within 2.4 % of the
/// value of 16× as many rays on the standard scenes (5.7 % on room_0, well inside the 20 % hysteresis).
pub const MEAN_CHORD_RAYS: u32 = 2048;

impl RhMeanChord {
    /// The chord of a volume with `world_from_local` in `snapshot`, reusing `last` where it still holds.
    fn measure(last: Option<&RhMeanChord>, snapshot: &SceneSnapshot, world_from_local: Mat4) -> RhMeanChord {
        let key = (snapshot.layout_generation, world_from_local.to_cols_array().map(f32::to_bits));
        if let Some(last) = last.filter(|l| l.key == key) {
            return *last;
        }
        let (lo, hi) = volume_world_bounds(world_from_local);
        let metres = snapshot.mean_chord(lo, hi, MEAN_CHORD_RAYS);
        let metres = match (last.and_then(|l| l.metres), metres) {
            (Some(old), Some(new)) if (new / old - 1.0).abs() < 0.2 => Some(old),
            (_, new) => new,
        };
        RhMeanChord { metres, key }
    }
}

/// The world-space bounds of a volume's box (its unit cube under `world_from_local`).
fn volume_world_bounds(world_from_local: Mat4) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for i in 0..8 {
        let corner = Vec3::new(
            if i & 1 == 0 { -0.5 } else { 0.5 },
            if i & 2 == 0 { -0.5 } else { 0.5 },
            if i & 4 == 0 { -0.5 } else { 0.5 },
        );
        let p = world_from_local.transform_point3(corner);
        (lo, hi) = (lo.min(p), hi.max(p));
    }
    (lo, hi)
}

/// The Bevy [`IrradianceVolume`] image a volume writes when a camera asks for
/// [`GiOutput::IrradianceVolume`]; the probe is a child entity carrying this same handle.
#[derive(Component, Clone, Debug)]
pub struct RhIrradianceExport {
    pub image: Handle<Image>,
    pub probe: Entity,
    resolution: UVec3,
}

/// Warns once per light about an RSM resolution it does not get (the volume's own settings are checked
/// by the shared [`crate::settings::validate_settings`]).
pub(crate) fn validate_lights(
    lights: Query<(Entity, &GiLight), Changed<GiLight>>,
    mut warned: Local<HashSet<Entity>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    for (entity, light) in &lights {
        let r = light.rsm_resolution;
        if !(GiLight::MIN_RSM_RESOLUTION..=GiLight::MAX_RSM_RESOLUTION).contains(&r) && warned.insert(entity) {
            crate::gi_warning(
                &mut warnings,
                format!(
                    "bevy_diffuse_gi: GiLight on {entity}: rsm_resolution {r} is outside {}..={}, clamped",
                    GiLight::MIN_RSM_RESOLUTION,
                    GiLight::MAX_RSM_RESOLUTION
                ),
            );
        }
    }
}

/// Warns once per volume with a degenerate or non-finite transform.
pub(crate) fn validate_transforms(
    volumes: Query<(Entity, &GlobalTransform), (With<RadianceHintsVolume>, Changed<GlobalTransform>)>,
    mut warned: Local<HashSet<Entity>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    for (entity, transform) in &volumes {
        let m = transform.to_matrix();
        if !(m.is_finite() && m.determinant().abs() > 1e-12) && warned.insert(entity) {
            crate::gi_warning(
                &mut warnings,
                format!(
                    "bevy_diffuse_gi: RadianceHintsVolume on {entity} has a degenerate or non-finite transform; \
                     using a 1 m cube at the origin"
                ),
            );
        }
    }
}

/// The world-from-unit-cube matrix of a volume, with a degenerate or non-finite transform replaced by a
/// 1 m cube at the origin ([`validate_transforms`] warns about it).
pub(crate) fn volume_matrix(transform: &GlobalTransform) -> Mat4 {
    let m = transform.to_matrix();
    if m.is_finite() && m.determinant().abs() > 1e-12 { m } else { Mat4::IDENTITY }
}

/// Inserts the scene snapshot (the RSMs rasterise it, the volumes are voxelised from it, and the emissive
/// surfaces are sampled from it) as soon as a GI light or a volume exists.
pub(crate) fn ensure_snapshot(
    mut commands: Commands,
    snapshot: Option<Res<SceneSnapshot>>,
    lights: Query<(), With<GiLight>>,
    volumes: Query<(), With<RadianceHintsVolume>>,
) {
    if snapshot.is_none() && !(lights.is_empty() && volumes.is_empty()) {
        commands.init_resource::<SceneSnapshot>();
    }
}

/// What a volume's voxels were made from: the snapshot's geometry generation, the volume's transform
/// (bits) and its hint resolution.
type VoxelKey = (u64, [u32; 16], UVec3);

/// Recent geometry changes of the snapshot, by generation: the boxes each commit changed. Voxels made a
/// few generations ago (a background voxelisation finishes while the scene moves on) are brought up to
/// date from the boxes in between, in proportion to what changed, instead of being voxelised again.
#[derive(Resource, Default)]
pub struct RhVoxelChanges {
    by_generation: std::collections::VecDeque<(u64, Vec<(Vec3, Vec3)>)>,
}

/// Generations [`RhVoxelChanges`] keeps: 17 s of continuous change at 60 frames a second (a background
/// voxelisation that takes longer than that under continuous change is started again).
const KEPT_CHANGES: usize = 1024;

impl RhVoxelChanges {
    fn record(&mut self, snapshot: &SceneSnapshot) {
        let generation = snapshot.geometry_generation;
        if self.by_generation.back().is_some_and(|(g, _)| *g == generation) {
            return;
        }
        self.by_generation.push_back((generation, snapshot.last_change.dirty.clone()));
        while self.by_generation.len() > KEPT_CHANGES {
            self.by_generation.pop_front();
        }
    }

    /// Every box changed after generation `from` up to `to`, or `None` when a generation in between
    /// is not kept.
    fn since(&self, from: u64, to: u64) -> Option<Vec<(Vec3, Vec3)>> {
        let mut boxes = Vec::new();
        let mut seen = 0;
        for (_, dirty) in self.by_generation.iter().filter(|(g, _)| *g > from && *g <= to) {
            boxes.extend_from_slice(dirty);
            seen += 1;
        }
        (seen == to - from).then_some(boxes)
    }
}

/// The volumes' full voxelisations running in the background (a first one, a new resolution, a move
/// that is not by whole cells): tens of milliseconds to seconds, which a frame must not wait for.
#[derive(Resource, Default)]
pub struct RhVoxelJobs {
    jobs: bevy::platform::collections::HashMap<Entity, crate::background::BackgroundJob<VoxelKey, GeometryVoxels>>,
    /// Full voxelisations finished, and frames since the last one started.
    finished: u64,
    frames_since_start: u32,
}

/// Keeps every volume's voxels current without the main thread voxelising: a geometry change
/// re-voxelises the cells it touched (in the background, in proportion to the change, from the volume's
/// voxels, which it keeps until the update arrives a frame or two later), a move by whole cells scrolls
/// (voxelising the slab that came in, on the main thread); anything else (the first voxels, a new
/// resolution, another move) is voxelised in full in the background, the volume keeping its previous
/// voxels, transform and resolution meanwhile ([`extract_volumes`]).
pub(crate) fn update_geometry_voxels(
    mut commands: Commands,
    snapshot: Option<Res<SceneSnapshot>>,
    volumes: Query<(Entity, &RadianceHintsVolume, &GlobalTransform, Option<&RhGeometryVoxels>, Option<&RhMeanChord>)>,
    cameras: Query<(&Camera, &DiffuseGi)>,
    (mut changes, mut jobs): (ResMut<RhVoxelChanges>, ResMut<RhVoxelJobs>),
    mut cost: ResMut<crate::MainThreadCost>,
    status: Res<crate::method::GiMethodStatus>,
) {
    let start = std::time::Instant::now();
    let Some(snapshot) = snapshot else {
        return;
    };
    changes.record(&snapshot);
    let jobs = &mut *jobs;
    jobs.jobs.retain(|entity, _| volumes.contains(*entity));
    jobs.frames_since_start += 1;
    let mut worked = false;
    let mut busy = false;
    for (entity, volume, transform, voxels, last_chord) in &volumes {
        let matrix = volume_matrix(transform);
        // Only an adaptive grid follows the scene's chord.
        let chord = matches!(volume.sizing, super::GridSizing::Adaptive { .. })
            .then(|| RhMeanChord::measure(last_chord, &snapshot, matrix));
        if let Some(chord) = chord.filter(|c| Some(c) != last_chord) {
            commands.entity(entity).insert(chord);
        }
        let settings = volume.effective(matrix, chord.and_then(|c| c.metres));
        let key: VoxelKey = (snapshot.geometry_generation, matrix.to_cols_array().map(f32::to_bits), settings.resolution);
        let job = jobs.jobs.entry(entity).or_default();
        // A finished full voxelisation is the newest base; the volume's own voxels otherwise.
        let finished = job.poll();
        jobs.finished += finished.is_some() as u64;
        if voxels.is_some_and(|v| v.key == key) {
            // Current already (a result that arrives late is dropped).
            continue;
        }
        let from_job = finished.is_some();
        // A background update of the cells some geometry changes touched, made from the volume's own
        // voxels: what it changed is relative to those, which the render world has.
        let update = finished.as_ref().is_some_and(|(_, d)| d.changed != super::voxelize::VoxelChange::All);
        let base = finished.map(|(k, data)| (k, Arc::new(data))).or_else(|| voxels.map(|v| (v.key, v.data.clone())));
        // From the base to the scene as it is: the same volume some geometry changes later is updated in
        // the cells those changes touched, in the background from the volume's own voxels (the volume
        // keeps them meanwhile); the same volume moved by whole cells (a cascade level following its
        // camera) scrolls, voxelising only the slab that came in.
        let (mut wait, mut started) = (false, false);
        let brought = base.as_ref().and_then(|(k, d)| {
            if *k == key || update {
                // A finished full voxelisation of the scene as it is (new everywhere already), or a
                // finished update (what changes came after it go into the next one).
                return Some(d.clone());
            }
            let mut data = if k.1 == key.1 && k.2 == key.2 && k.0 < key.0 {
                let dirty = changes.since(k.0, key.0)?;
                if !from_job {
                    wait = true;
                    if job.wants(&key) {
                        let (snapshot, base, resolution) = (snapshot.clone(), d.clone(), settings.resolution);
                        job.start(key, move || voxelize_update(&snapshot, matrix, resolution, &base, &dirty));
                        started = true;
                    }
                    return None;
                }
                voxelize_update(&snapshot, matrix, settings.resolution, d, &dirty)
            } else if k.0 == key.0 && k.2 == key.2 {
                let old = Mat4::from_cols_array(&k.1.map(f32::from_bits));
                let shift = super::voxelize::scroll_shift(old, matrix, settings.resolution)?;
                super::voxelize::voxelize_scrolled(&snapshot, matrix, settings.resolution, d, shift)?
            } else {
                return None;
            };
            // The render world has not seen a background result: its voxels are new everywhere.
            if from_job {
                data.changed = super::voxelize::VoxelChange::All;
            }
            Some(Arc::new(data))
        });
        if started {
            jobs.frames_since_start = 0;
        }
        if wait {
            // An update runs: the volume keeps its voxels until it arrives.
            busy = true;
            continue;
        }
        let inserted_key = if update { base.as_ref().map_or(key, |(k, _)| *k) } else { key };
        let (inserted_key, data) = match (brought, base) {
            (Some(data), _) => (inserted_key, data),
            // Nothing to bring up to date from: voxelise it all in the background (once the running
            // one, if any, has finished); the volume keeps what it has meanwhile, or shows a finished
            // older voxelisation (new everywhere, as made).
            (None, base) => {
                busy = true;
                if job.wants(&key) {
                    let snapshot = snapshot.clone();
                    let resolution = settings.resolution;
                    job.start(key, move || voxelize(&snapshot, matrix, resolution));
                    jobs.frames_since_start = 0;
                }
                match base.filter(|_| from_job) {
                    Some(finished) => finished,
                    None => continue,
                }
            }
        };
        worked = true;
        commands.entity(entity).insert(RhGeometryVoxels { generation: voxels.map_or(1, |v| v.generation + 1), key: inserted_key, data });
    }
    cost.voxels_ms = if worked { start.elapsed().as_secs_f32() * 1000.0 } else { 0.0 };
    let used = cameras.iter().any(|(c, gi)| c.is_active && gi.enabled && gi.method == GiMethod::RadianceHints);
    if used {
        status.set_busy(GiMethod::RadianceHints, busy, jobs.frames_since_start, jobs.finished);
    }
}

/// Creates (or removes) the IrradianceVolume probes of every volume, depending on whether an active
/// [`DiffuseGi`] camera asks for [`GiOutput::IrradianceVolume`].
pub(crate) fn manage_irradiance_exports(
    mut commands: Commands,
    cameras: Query<(&Camera, &DiffuseGi)>,
    volumes: Query<(Entity, &RadianceHintsVolume, &GlobalTransform, Option<&RhIrradianceExport>, Option<&RhMeanChord>, Option<&RhGeometryVoxels>)>,
    images: Option<ResMut<Assets<Image>>>,
) {
    let Some(mut images) = images else {
        return;
    };
    let wanted = cameras.iter().any(|(camera, gi)| {
        camera.is_active && gi.enabled && gi.method == GiMethod::RadianceHints && gi.output == GiOutput::IrradianceVolume
    });
    for (entity, volume, transform, export, chord, voxels) in &volumes {
        // The resolution the volume runs with: its voxels' (see `extract_volumes`).
        let resolution = voxels.map_or_else(|| volume.effective(volume_matrix(transform), chord.and_then(|c| c.metres)).resolution, |v| v.key.2);
        match (wanted, export) {
            (true, Some(e)) if e.resolution == resolution => {}
            (true, existing) => {
                if let Some(e) = existing {
                    commands.entity(e.probe).despawn();
                }
                let mut image = Image::new_uninit(
                    Extent3d {
                        width: resolution.x,
                        height: 2 * resolution.y,
                        depth_or_array_layers: 3 * resolution.z,
                    },
                    TextureDimension::D3,
                    TextureFormat::Rgba16Float,
                    RenderAssetUsages::RENDER_WORLD,
                );
                image.texture_descriptor.usage |= TextureUsages::STORAGE_BINDING;
                image.sampler = ImageSampler::linear();
                let image = images.add(image);
                // A child with an identity transform: the probe covers exactly the volume's box.
                let probe = commands
                    .spawn((
                        LightProbe::new(),
                        IrradianceVolume {
                            voxels: image.clone(),
                            intensity: 1.0,
                            affects_lightmapped_meshes: true,
                        },
                        Transform::IDENTITY,
                        ChildOf(entity),
                    ))
                    .id();
                commands.entity(entity).insert(RhIrradianceExport { image, probe, resolution });
            }
            (false, Some(e)) => {
                commands.entity(e.probe).despawn();
                commands.entity(entity).remove::<RhIrradianceExport>();
            }
            (false, None) => {}
        }
    }
}

/// A volume as the render world sees it.
#[derive(Clone, Debug)]
pub struct ExtractedRhVolume {
    pub entity: Entity,
    pub settings: RadianceHintsVolume,
    pub world_from_local: Mat4,
    /// The voxelised scene and its generation, once voxelised.
    pub voxels: Option<(u64, Arc<GeometryVoxels>)>,
    pub export: Option<Handle<Image>>,
}

/// Every active [`RadianceHintsVolume`], in a stable order.
#[derive(Resource, Default)]
pub struct ExtractedRhVolumes {
    pub volumes: Vec<ExtractedRhVolume>,
}

type VolumeQuery<'a> = (
    Entity,
    &'a RadianceHintsVolume,
    Option<&'a InheritedVisibility>,
    Option<&'a RhGeometryVoxels>,
    Option<&'a RhIrradianceExport>,
    Option<&'a RhMeanChord>,
);

/// Extracts the volumes, but only while an active camera uses Radiance Hints (for its composite or its
/// `IrradianceVolume` export): otherwise the method costs nothing, and its GPU state is dropped.
pub(crate) fn extract_volumes(
    volumes: Extract<Query<VolumeQuery>>,
    cameras: Extract<Query<(&Camera, &DiffuseGi)>>,
    mut extracted: ResMut<ExtractedRhVolumes>,
    mut focus: ResMut<RsmFocus>,
) {
    extracted.volumes.clear();
    let used = cameras
        .iter()
        .any(|(camera, gi)| camera.is_active && gi.enabled && gi.method == GiMethod::RadianceHints);
    if !used {
        let next = RsmFocus { bounds: None, volumes_need: false, ..*focus };
        if *focus != next {
            *focus = next;
        }
        return;
    }
    let mut bounds: Option<(Vec3, Vec3)> = None;
    for (entity, volume, visibility, voxels, export, chord) in &volumes {
        if visibility.is_some_and(|v| !v.get()) {
            continue;
        }
        // A volume runs with the transform and resolution its voxels were made for: while a new
        // voxelisation runs in the background, the previous field stays where it was; a volume without
        // voxels yet is not drawn.
        let Some(voxels) = voxels else {
            continue;
        };
        let world_from_local = Mat4::from_cols_array(&voxels.key.1.map(f32::from_bits));
        let mut settings = volume.effective(world_from_local, chord.and_then(|c| c.metres));
        settings.resolution = voxels.key.2;
        let (lo, hi) = volume_world_bounds(world_from_local);
        bounds = Some(bounds.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
        extracted.volumes.push(ExtractedRhVolume {
            entity,
            voxels: Some((voxels.generation, voxels.data.clone())),
            settings,
            world_from_local,
            export: export.map(|e| e.image.clone()),
        });
    }
    extracted.volumes.sort_by_key(|v| v.entity);
    let next = RsmFocus { bounds, volumes_need: !extracted.volumes.is_empty(), ..*focus };
    if *focus != next {
        *focus = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_changes_since_a_generation_are_the_boxes_in_between_or_none_when_one_is_gone() {
        let b = |x: f32| (Vec3::splat(x), Vec3::splat(x + 1.0));
        let changes = RhVoxelChanges { by_generation: [(3, vec![b(3.0)]), (4, vec![b(4.0)]), (5, vec![b(5.0), b(5.5)])].into() };
        assert_eq!(changes.since(3, 5), Some(vec![b(4.0), b(5.0), b(5.5)]));
        assert_eq!(changes.since(4, 4), Some(vec![]));
        // Generation 2 was not kept (or the scene moved on past what is kept): voxelise anew.
        assert_eq!(changes.since(1, 5), None);
        assert_eq!(changes.since(3, 6), None);
    }
}
