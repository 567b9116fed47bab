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

/// Re-voxelises every volume whose geometry, transform or resolution changed.
pub(crate) fn update_geometry_voxels(
    mut commands: Commands,
    snapshot: Option<Res<SceneSnapshot>>,
    volumes: Query<(Entity, &RadianceHintsVolume, &GlobalTransform, Option<&RhGeometryVoxels>, Option<&RhMeanChord>)>,
    mut cost: ResMut<crate::MainThreadCost>,
) {
    let start = std::time::Instant::now();
    let Some(snapshot) = snapshot else {
        return;
    };
    let mut worked = false;
    for (entity, volume, transform, voxels, last_chord) in &volumes {
        let matrix = volume_matrix(transform);
        // Only an adaptive grid follows the scene's chord.
        let chord = matches!(volume.sizing, super::GridSizing::Adaptive { .. })
            .then(|| RhMeanChord::measure(last_chord, &snapshot, matrix));
        if let Some(chord) = chord.filter(|c| Some(c) != last_chord) {
            commands.entity(entity).insert(chord);
        }
        let settings = volume.effective(matrix, chord.and_then(|c| c.metres));
        let key = (
            snapshot.geometry_generation,
            matrix.to_cols_array().map(f32::to_bits),
            settings.resolution,
        );
        if voxels.is_some_and(|v| v.key == key) {
            continue;
        }
        // The same volume one geometry change later: redo only the cells the change touched. The same
        // volume moved by whole cells (a cascade level following its camera): scroll, voxelising only
        // the slab that came in.
        let data = match voxels {
            Some(v) if v.key.1 == key.1 && v.key.2 == key.2 && v.key.0 + 1 == key.0 => {
                voxelize_update(&snapshot, matrix, settings.resolution, &v.data, &snapshot.last_change.dirty)
            }
            Some(v) if v.key.0 == key.0 && v.key.2 == key.2 => {
                let old = Mat4::from_cols_array(&v.key.1.map(f32::from_bits));
                super::voxelize::scroll_shift(old, matrix, settings.resolution)
                    .and_then(|shift| super::voxelize::voxelize_scrolled(&snapshot, matrix, settings.resolution, &v.data, shift))
                    .unwrap_or_else(|| voxelize(&snapshot, matrix, settings.resolution))
            }
            _ => voxelize(&snapshot, matrix, settings.resolution),
        };
        worked = true;
        commands.entity(entity).insert(RhGeometryVoxels {
            generation: voxels.map_or(1, |v| v.generation + 1),
            key,
            data: Arc::new(data),
        });
    }
    cost.voxels_ms = if worked { start.elapsed().as_secs_f32() * 1000.0 } else { 0.0 };
}

/// Creates (or removes) the IrradianceVolume probes of every volume, depending on whether an active
/// [`DiffuseGi`] camera asks for [`GiOutput::IrradianceVolume`].
pub(crate) fn manage_irradiance_exports(
    mut commands: Commands,
    cameras: Query<(&Camera, &DiffuseGi)>,
    volumes: Query<(Entity, &RadianceHintsVolume, &GlobalTransform, Option<&RhIrradianceExport>, Option<&RhMeanChord>)>,
    images: Option<ResMut<Assets<Image>>>,
) {
    let Some(mut images) = images else {
        return;
    };
    let wanted = cameras.iter().any(|(camera, gi)| {
        camera.is_active && gi.enabled && gi.method == GiMethod::RadianceHints && gi.output == GiOutput::IrradianceVolume
    });
    for (entity, volume, transform, export, chord) in &volumes {
        let resolution = volume.effective(volume_matrix(transform), chord.and_then(|c| c.metres)).resolution;
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
    &'a GlobalTransform,
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
    for (entity, volume, transform, visibility, voxels, export, chord) in &volumes {
        if visibility.is_some_and(|v| !v.get()) {
            continue;
        }
        let world_from_local = volume_matrix(transform);
        let settings = volume.effective(world_from_local, chord.and_then(|c| c.metres));
        let (lo, hi) = volume_world_bounds(world_from_local);
        bounds = Some(bounds.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
        extracted.volumes.push(ExtractedRhVolume {
            entity,
            voxels: voxels.map(|v| (v.generation, v.data.clone())),
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
