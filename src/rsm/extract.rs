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

/// The scene geometry the RSMs rasterise, extracted only when the snapshot's geometry changes.
#[derive(Resource, Default)]
pub struct ExtractedGiGeometry {
    /// The snapshot generation `vertices` was built from.
    pub generation: u64,
    /// New vertex data waiting to be uploaded (`None` once uploaded or when unchanged).
    pub pending: Option<Vec<RsmVertex>>,
    /// World-space bounds of the scene.
    pub bounds: Option<(Vec3, Vec3)>,
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

pub(crate) fn extract_gi_geometry(
    snapshot: Extract<Option<Res<SceneSnapshot>>>,
    mut geometry: ResMut<ExtractedGiGeometry>,
) {
    let Some(snapshot) = snapshot.as_ref() else {
        return;
    };
    if snapshot.geometry_generation == geometry.generation {
        return;
    }
    let mut vertices = Vec::with_capacity(snapshot.triangle_count() * 3);
    for i in 0..snapshot.triangle_count() as u32 {
        let positions = snapshot.triangle(i);
        let normal = snapshot.attributes[i as usize].geometric_normal.to_array();
        let albedo = snapshot.triangle_albedo(i).to_array();
        for p in positions {
            vertices.push(RsmVertex {
                position: p.to_array(),
                normal,
                albedo,
            });
        }
    }
    geometry.generation = snapshot.geometry_generation;
    geometry.pending = Some(vertices);
    geometry.bounds = snapshot.bounds();
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
