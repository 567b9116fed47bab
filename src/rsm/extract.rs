//! Main world → render world: the snapshot's triangles (only when they change) and the GI lights.

use bevy::light::{DirectionalLight, PointLight, SpotLight};
use bevy::prelude::*;
use bevy::render::Extract;
use bytemuck::{Pod, Zeroable};

use crate::light::GiLight;
use crate::scene::{SceneSnapshot, SnapshotLight, extract::snapshot_light};

/// One vertex of the RSM geometry: world position, face normal, diffuse albedo (per triangle).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RsmVertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub albedo: [f32; 3],
}

/// The scene geometry the RSMs rasterise, extracted only when the snapshot's geometry changes, and then
/// only for the instances that changed.
#[derive(Resource, Default)]
pub struct ExtractedGiGeometry {
    /// The snapshot generation the extracted vertices are at.
    pub generation: u64,
    /// The snapshot's layout generation they are at (instances, triangle counts).
    pub layout_generation: u64,
    /// Every vertex, waiting to be uploaded (after a layout change or on the first extraction).
    pub pending: Option<Vec<RsmVertex>>,
    /// Vertex ranges to overwrite in place: `(first vertex, vertices)` (instances that moved or changed
    /// material).
    pub pending_ranges: Vec<(u32, Vec<RsmVertex>)>,
    /// World-space boxes where geometry changed since the RSMs were last prepared; `None` = everywhere.
    pub dirty: Option<Vec<(Vec3, Vec3)>>,
    /// World-space bounds of the scene.
    pub bounds: Option<(Vec3, Vec3)>,
    /// The instances that changed within the last [`MOVING_HOLD_FRAMES`] frames, as vertex ranges
    /// sorted by their first vertex. A face that sees only their change is redrawn from a copy of itself
    /// without them plus a draw of them alone (`RsmAtlas::static_layers`), not from every triangle.
    pub moving: Vec<MovingRange>,
    /// Bumped whenever [`moving`](Self::moving) gains or loses a range, or the vertices are uploaded anew:
    /// a face drawn without the moving ranges is valid only for the generation it was drawn at.
    pub moving_generation: u64,
    /// Frames extracted so far (the clock of [`MovingRange::last_changed`]).
    pub frame: u64,
}

/// How many frames an instance stays in [`ExtractedGiGeometry::moving`] after its last change: a mesh
/// moving every frame, or every few frames, stays in it; one moved once leaves it after a second at 60 fps.
pub const MOVING_HOLD_FRAMES: u64 = 60;

/// The vertices of one recently changed instance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MovingRange {
    pub first: u32,
    pub count: u32,
    /// [`ExtractedGiGeometry::frame`] of its last change.
    pub last_changed: u64,
}

impl ExtractedGiGeometry {
    /// Records that the vertices `first..first + count` changed this frame.
    fn touch(&mut self, first: u32, count: u32) {
        let frame = self.frame;
        match self.moving.binary_search_by_key(&first, |m| m.first) {
            Ok(i) if self.moving[i].count == count => self.moving[i].last_changed = frame,
            Ok(i) => {
                self.moving[i] = MovingRange { first, count, last_changed: frame };
                self.moving_generation += 1;
            }
            Err(i) => {
                self.moving.insert(i, MovingRange { first, count, last_changed: frame });
                self.moving_generation += 1;
            }
        }
    }

    /// Drops the ranges that have been still for [`MOVING_HOLD_FRAMES`].
    fn age(&mut self) {
        self.frame += 1;
        let frame = self.frame;
        let before = self.moving.len();
        self.moving.retain(|m| frame - m.last_changed <= MOVING_HOLD_FRAMES);
        if self.moving.len() != before {
            self.moving_generation += 1;
        }
    }
}

/// The RSM vertices of one instance (its triangles in global order).
fn instance_vertices(snapshot: &SceneSnapshot, instance: &crate::scene::SnapshotInstance, out: &mut Vec<RsmVertex>) {
    let Some(range) = snapshot.instance_triangles(instance.key) else {
        return;
    };
    for (local, global) in range.enumerate() {
        let normal = instance.attributes(local).geometric_normal.to_array();
        let albedo = snapshot.triangle_albedo(global).to_array();
        for p in instance.triangle(local) {
            out.push(RsmVertex { position: p.to_array(), normal, albedo });
        }
    }
}

pub(crate) fn extract_gi_geometry(
    snapshot: Extract<Option<Res<SceneSnapshot>>>,
    mut geometry: ResMut<ExtractedGiGeometry>,
) {
    geometry.age();
    let Some(snapshot) = snapshot.as_ref() else {
        return;
    };
    if snapshot.geometry_generation == geometry.generation {
        return;
    }
    let incremental = geometry.generation > 0
        && snapshot.geometry_generation == geometry.generation + 1
        && snapshot.layout_generation == geometry.layout_generation
        && !snapshot.last_change.layout_changed;
    if incremental {
        // Only the instances this generation changed.
        for instance in snapshot.instances().iter().filter(|i| i.version == snapshot.geometry_generation) {
            let Some(range) = snapshot.instance_triangles(instance.key) else {
                continue;
            };
            let mut vertices = Vec::with_capacity(instance.triangle_count() * 3);
            instance_vertices(snapshot, instance, &mut vertices);
            geometry.touch(range.start * 3, vertices.len() as u32);
            geometry.pending_ranges.push((range.start * 3, vertices));
        }
        if let Some(dirty) = geometry.dirty.as_mut() {
            dirty.extend(snapshot.last_change.dirty.iter().copied());
        }
    } else {
        let mut vertices = Vec::with_capacity(snapshot.triangle_count() * 3);
        for instance in snapshot.instances() {
            instance_vertices(snapshot, instance, &mut vertices);
        }
        geometry.pending = Some(vertices);
        geometry.pending_ranges.clear();
        geometry.dirty = None;
        geometry.moving.clear();
        geometry.moving_generation += 1;
    }
    geometry.generation = snapshot.geometry_generation;
    geometry.layout_generation = snapshot.layout_generation;
    geometry.bounds = snapshot.bounds();
}

/// A GI light as the RSM passes see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtractedGiLight {
    pub entity: Entity,
    pub light: SnapshotLight,
    /// Validated [`GiLight::rsm_resolution`].
    pub resolution: u32,
}

/// Every visible light carrying a [`GiLight`], in a stable order.
#[derive(Resource, Default, Clone, Debug, PartialEq)]
pub struct ExtractedGiLights {
    pub lights: Vec<ExtractedGiLight>,
}

type GiLightQuery<'a> = (
    Entity,
    &'a GiLight,
    &'a GlobalTransform,
    Option<&'a InheritedVisibility>,
    Option<&'a DirectionalLight>,
    Option<&'a PointLight>,
    Option<&'a SpotLight>,
);

pub(crate) fn extract_gi_lights(
    lights: Extract<Query<GiLightQuery, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>>>,
    mut extracted: ResMut<ExtractedGiLights>,
) {
    let mut next: Vec<ExtractedGiLight> = lights
        .iter()
        .filter(|(.., visibility, _, _, _)| visibility.is_none_or(|v| v.get()))
        .filter_map(|(entity, gi, transform, _, directional, point, spot)| {
            let (light, _) = snapshot_light(transform, directional, point, spot)?;
            Some(ExtractedGiLight {
                entity,
                light,
                resolution: gi.rsm_resolution.clamp(GiLight::MIN_RSM_RESOLUTION, GiLight::MAX_RSM_RESOLUTION),
            })
        })
        .collect();
    next.sort_by_key(|l| l.entity);
    if next != extracted.lights {
        extracted.lights = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_instance_stays_moving_while_it_changes_and_leaves_after_the_hold() {
        let mut g = ExtractedGiGeometry::default();
        g.age();
        g.touch(30, 6);
        g.touch(0, 3);
        assert_eq!(g.moving.iter().map(|m| (m.first, m.count)).collect::<Vec<_>>(), vec![(0, 3), (30, 6)]);
        let generation = g.moving_generation;
        // Changing again every frame keeps the set (and its generation).
        for _ in 0..2 * MOVING_HOLD_FRAMES {
            g.age();
            g.touch(30, 6);
        }
        assert_eq!(g.moving.iter().map(|m| m.first).collect::<Vec<_>>(), vec![30]);
        assert_eq!(g.moving_generation, generation + 1, "only the still instance's leaving bumps the generation");
        // Still for the hold: it leaves.
        for _ in 0..MOVING_HOLD_FRAMES {
            g.age();
        }
        assert_eq!(g.moving.len(), 1);
        g.age();
        assert!(g.moving.is_empty());
        assert_eq!(g.moving_generation, generation + 2);
    }
}
