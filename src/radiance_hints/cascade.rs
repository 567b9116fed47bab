//! [`RadianceHintsCascade`]: nested Radiance Hints volumes that follow a camera, for worlds larger than
//! one volume (the "multiple RH volumes … sampled in a hierarchical manner" of the paper's §8, organised as
//! the clipmaps of cascaded light propagation volumes and probe systems).
//!
//! Level `k` is a [`RadianceHintsVolume`] of `extent × scale^k` metres with the same hint counts, so each
//! level's cells are `scale` times the previous level's. Every level is centred on the camera, snapped to
//! its own cell size: its hints stay on a fixed world lattice, and the level moves (and recomputes) only
//! when the camera crosses one of its cells — the coarse levels rarely. Each finer level lies inside the
//! next coarser one and fades in over [`NESTED_BLEND_CELLS`](super::prepare::NESTED_BLEND_CELLS) cells
//! inside its box, drawn over the coarser field, so the light changes smoothly across level boundaries.
//!
//! # Cost
//! Each level costs what a volume of its hint count costs (memory, updates, voxelisation); the
//! per-pixel reconstruction runs once per level that covers the pixel. A still camera in a still scene
//! updates nothing. A level that moves pays for one slab of voxels on the CPU, a copy of its field, a
//! copy of its reconstruction masks with those within a cell of its faces recomputed (about 10 ms instead
//! of 25 for 64³ voxels on lavapipe), and the amortised updates while the camera keeps moving.

use bevy::prelude::*;

use super::settings::{GridSizing, RadianceHintsVolume};

/// Nested Radiance Hints volumes centred on this camera (see the [module docs](self)).
///
/// ```no_run
/// # use bevy::prelude::*;
/// # use bevy_diffuse_gi::prelude::*;
/// # use bevy_diffuse_gi::radiance_hints::RadianceHintsCascade;
/// # fn setup(mut commands: Commands) {
/// commands.spawn((Camera3d::default(), DiffuseGi::default(), RadianceHintsCascade::default()));
/// # }
/// ```
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
pub struct RadianceHintsCascade {
    /// Nested levels. Default 3. Valid range 1–6. Cost: one volume each.
    pub levels: u32,
    /// Size of the innermost level's box in metres. Default 12 × 6 × 12. Valid range 0.1–10 000 per
    /// axis.
    pub extent: Vec3,
    /// Each level's box (and cells) is this many times the previous level's. Default 2. Valid range 1.5–8.
    pub scale: f32,
    /// The settings of every level. Its grid is fixed ([`GridSizing::Fixed`]): every level has
    /// `settings.resolution` hints. Default [`RadianceHintsVolume::MEDIUM`] with 24 × 12 × 24 hints (cells
    /// of 0.5 m, 1 m and 2 m at the default extent).
    pub settings: RadianceHintsVolume,
}

impl Default for RadianceHintsCascade {
    fn default() -> Self {
        Self {
            levels: 3,
            extent: Vec3::new(12.0, 6.0, 12.0),
            scale: 2.0,
            settings: RadianceHintsVolume {
                sizing: GridSizing::Fixed,
                resolution: UVec3::new(24, 12, 24),
                ..RadianceHintsVolume::MEDIUM
            },
        }
    }
}

impl RadianceHintsCascade {
    /// The box (centre, size) of level `k` for a camera at `camera`: centred on the camera, snapped to
    /// the level's cells.
    pub fn level_box(&self, k: u32, camera: Vec3) -> (Vec3, Vec3) {
        let scale = if self.scale.is_finite() { self.scale.clamp(1.5, 8.0) } else { 2.0 };
        let extent = sanitize_extent(self.extent) * scale.powi(k.min(5) as i32);
        let cell = extent / self.settings.resolution.max(UVec3::splat(2)).as_vec3();
        let camera = if camera.is_finite() { camera } else { Vec3::ZERO };
        ((camera / cell).round() * cell, extent)
    }
}

fn sanitize_extent(extent: Vec3) -> Vec3 {
    if extent.is_finite() { extent.clamp(Vec3::splat(0.1), Vec3::splat(10_000.0)) } else { Vec3::new(12.0, 6.0, 12.0) }
}

/// Warns once per camera about cascade settings outside their documented ranges (they are clamped).
pub(crate) fn validate_cascades(
    cascades: Query<(Entity, &RadianceHintsCascade), Changed<RadianceHintsCascade>>,
    mut warned: Local<bevy::platform::collections::HashSet<(Entity, &'static str)>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    for (entity, cascade) in &cascades {
        let extent_ok = cascade.extent.is_finite()
            && cascade.extent.cmpge(Vec3::splat(0.1)).all()
            && cascade.extent.cmple(Vec3::splat(10_000.0)).all();
        for (field, ok) in [
            ("levels", (1..=6).contains(&cascade.levels)),
            ("scale", (1.5..=8.0).contains(&cascade.scale)),
            ("extent", extent_ok),
        ] {
            if !ok && warned.insert((entity, field)) {
                crate::gi_warning(
                    &mut warnings,
                    format!("bevy_diffuse_gi: RadianceHintsCascade on {entity}: invalid `{field}`, clamped to its range"),
                );
            }
        }
    }
}

/// A volume spawned by a [`RadianceHintsCascade`]: level `level` of `camera`'s cascade.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct CascadeLevel {
    pub camera: Entity,
    pub level: u32,
}

/// Spawns, moves and removes the cascades' volumes. Runs in `PostUpdate` before transform propagation,
/// from the cameras' last propagated positions (a level moves a cell at a time, so a frame's lag is
/// invisible).
pub(crate) fn update_cascades(
    mut commands: Commands,
    cameras: Query<(Entity, &RadianceHintsCascade, &GlobalTransform)>,
    mut levels: Query<(Entity, &CascadeLevel, &mut RadianceHintsVolume, &mut Transform)>,
) {
    let mut present = Vec::new();
    for (entity, level, mut volume, mut transform) in &mut levels {
        let Ok((_, cascade, camera)) = cameras.get(level.camera) else {
            commands.entity(entity).despawn();
            continue;
        };
        if level.level >= cascade.levels.clamp(1, 6) {
            commands.entity(entity).despawn();
            continue;
        }
        let (centre, size) = cascade.level_box(level.level, camera.translation());
        let next = Transform::from_translation(centre).with_scale(size);
        if *transform != next {
            *transform = next;
        }
        let settings = RadianceHintsVolume { sizing: GridSizing::Fixed, ..cascade.settings.clone() };
        if *volume != settings {
            *volume = settings;
        }
        present.push((level.camera, level.level));
    }
    for (camera_entity, cascade, camera) in &cameras {
        for k in 0..cascade.levels.clamp(1, 6) {
            if present.contains(&(camera_entity, k)) {
                continue;
            }
            let (centre, size) = cascade.level_box(k, camera.translation());
            commands.spawn((
                RadianceHintsVolume { sizing: GridSizing::Fixed, ..cascade.settings.clone() },
                Transform::from_translation(centre).with_scale(size),
                CascadeLevel { camera: camera_entity, level: k },
                Name::new(format!("RH cascade level {k}")),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_nest_snap_to_their_cells_and_move_a_cell_at_a_time() {
        let cascade = RadianceHintsCascade::default();
        let camera = Vec3::new(3.3, 1.7, -8.1);
        let (c0, s0) = cascade.level_box(0, camera);
        let (c1, s1) = cascade.level_box(1, camera);
        assert_eq!(s1, 2.0 * s0);
        let cell0 = s0 / cascade.settings.resolution.as_vec3();
        // Snapped: the centre is a whole number of cells, within half a cell of the camera.
        let steps = c0 / cell0;
        assert!((steps - steps.round()).abs().max_element() < 1e-4);
        assert!(((c0 - camera) / cell0).abs().max_element() <= 0.5 + 1e-4);
        // Level 0 lies inside level 1, with room for the blend band.
        assert!(((c0 - c1).abs() + s0 / 2.0).cmplt(s1 / 2.0).all());
        // A small camera move keeps the boxes; crossing a cell moves level 0 by exactly one cell.
        assert_eq!(cascade.level_box(0, camera + Vec3::X * 0.1 * cell0.x).0, c0);
        let moved = cascade.level_box(0, camera + Vec3::X * cell0.x).0;
        assert!((moved - c0 - Vec3::X * cell0.x).abs().max_element() < 1e-4);
        // Bad input does not produce bad boxes.
        let (c, s) = RadianceHintsCascade { extent: Vec3::NAN, scale: f32::NAN, ..cascade.clone() }.level_box(2, Vec3::INFINITY);
        assert!(c.is_finite() && s.is_finite() && s.min_element() > 0.0);
    }
}
