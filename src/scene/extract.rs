//! Keeps [`SceneSnapshot`] in step with the main world, rebuilding only what changed.

use bevy::asset::AssetId;
use bevy::camera::visibility::VisibilitySystems;
use bevy::light::{DirectionalLight, PointLight, SpotLight};
use bevy::mesh::{Indices, PrimitiveTopology, VertexAttributeValues};
use bevy::pbr::{MeshMaterial3d, StandardMaterial};
use bevy::platform::collections::{HashMap, HashSet};
use bevy::prelude::*;
use bevy::transform::TransformSystems;

use super::{
    CulledFace, InputTriangle, SceneSnapshot, SnapshotLight, SnapshotLightEntry, SnapshotMaterial, SnapshotTexture,
};

/// Maintains the [`SceneSnapshot`] resource when it exists. Added by [`crate::DiffuseGiPlugin`].
pub struct SceneSnapshotPlugin;

/// The systems that update [`SceneSnapshot`], in `PostUpdate` after transform and visibility propagation.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SceneSnapshotSystems {
    Update,
}

impl Plugin for SceneSnapshotPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(
            PostUpdate,
            (
                // Apps without meshes, materials or images (no renderer) have no geometry to snapshot.
                update_snapshot_geometry.run_if(
                    resource_exists::<Assets<Mesh>>
                        .and_then(resource_exists::<Assets<StandardMaterial>>)
                        .and_then(resource_exists::<Assets<Image>>),
                ),
                update_snapshot_lights,
            )
                .in_set(SceneSnapshotSystems::Update)
                .after(TransformSystems::Propagate)
                .after(VisibilitySystems::VisibilityPropagate)
                .run_if(resource_exists::<SceneSnapshot>),
        );
    }
}

/// Asset ids the current snapshot was built from (including meshes and images not loaded yet), so that
/// asset events about unrelated assets (render targets, UI textures) do not trigger a rebuild.
#[derive(Default)]
struct UsedAssets {
    meshes: HashSet<AssetId<Mesh>>,
    materials: HashSet<AssetId<StandardMaterial>>,
    images: HashSet<AssetId<Image>>,
    warned_extracted: bool,
}

type MeshEntity<'a> = (
    &'a Mesh3d,
    Option<&'a MeshMaterial3d<StandardMaterial>>,
    &'a GlobalTransform,
    &'a InheritedVisibility,
);

#[expect(clippy::too_many_arguments, reason = "a system reading every input of the snapshot")]
fn update_snapshot_geometry(
    mut snapshot: ResMut<SceneSnapshot>,
    mut used: Local<UsedAssets>,
    entities: Query<MeshEntity>,
    changed: Query<
        (),
        (
            With<Mesh3d>,
            Or<(
                Changed<Mesh3d>,
                Changed<GlobalTransform>,
                Changed<MeshMaterial3d<StandardMaterial>>,
                Changed<InheritedVisibility>,
            )>,
        ),
    >,
    mut removed: RemovedComponents<Mesh3d>,
    mut mesh_events: MessageReader<AssetEvent<Mesh>>,
    mut material_events: MessageReader<AssetEvent<StandardMaterial>>,
    mut image_events: MessageReader<AssetEvent<Image>>,
    meshes: Res<Assets<Mesh>>,
    materials: Res<Assets<StandardMaterial>>,
    images: Res<Assets<Image>>,
) {
    let entity_changed = !changed.is_empty() || removed.read().count() > 0;
    let mesh_changed = mesh_events.read().any(|e| used.meshes.contains(&event_id(e)));
    let material_changed = material_events.read().any(|e| used.materials.contains(&event_id(e)));
    let image_changed = image_events.read().any(|e| used.images.contains(&event_id(e)));
    if !(snapshot.is_added() || entity_changed || mesh_changed || material_changed || image_changed) {
        return;
    }

    let mut next_used = UsedAssets {
        warned_extracted: used.warned_extracted,
        ..default()
    };
    let mut material_index: HashMap<AssetId<StandardMaterial>, u32> = HashMap::default();
    let mut texture_index: HashMap<AssetId<Image>, Option<u32>> = HashMap::default();
    let mut snapshot_materials = vec![SnapshotMaterial::DEFAULT_GREY];
    let mut textures = Vec::new();
    let mut triangles = Vec::new();

    for (mesh3d, material3d, transform, visibility) in &entities {
        if !visibility.get() {
            continue;
        }
        next_used.meshes.insert(mesh3d.id());
        let material = match material3d {
            Some(m) => {
                next_used.materials.insert(m.id());
                match material_index.get(&m.id()) {
                    Some(&i) => i,
                    None => {
                        let Some(standard) = materials.get(m.id()) else {
                            // Not loaded yet: skip the mesh; its asset event triggers a rebuild.
                            continue;
                        };
                        let texture = standard.base_color_texture.as_ref().and_then(|handle| {
                            next_used.images.insert(handle.id());
                            *texture_index.entry(handle.id()).or_insert_with(|| {
                                let texture = images.get(handle.id()).and_then(texture_from_image)?;
                                textures.push(texture);
                                Some(textures.len() as u32 - 1)
                            })
                        });
                        snapshot_materials.push(material_from_standard(standard, texture));
                        let i = snapshot_materials.len() as u32 - 1;
                        material_index.insert(m.id(), i);
                        i
                    }
                }
            }
            None => 0,
        };
        let Some(mesh) = meshes.get(mesh3d.id()) else {
            continue;
        };
        match mesh_triangles(mesh, transform, material) {
            Ok(tris) => triangles.extend(tris),
            Err(e) => {
                if !used.warned_extracted {
                    warn!(
                        "bevy_diffuse_gi: a mesh is left out of the scene snapshot (used by the path tracer and \
                         CPU-side GI): {e}. Keep `RenderAssetUsages::MAIN_WORLD` on meshes that should take part."
                    );
                    used.warned_extracted = true;
                    next_used.warned_extracted = true;
                }
            }
        }
    }

    snapshot.set_geometry(triangles, snapshot_materials);
    *used = next_used;
}

fn event_id<A: Asset>(event: &AssetEvent<A>) -> AssetId<A> {
    match *event {
        AssetEvent::Added { id }
        | AssetEvent::Modified { id }
        | AssetEvent::Removed { id }
        | AssetEvent::Unused { id }
        | AssetEvent::LoadedWithDependencies { id } => id,
    }
}

/// The diffuse colour Bevy shades with: `base_color × (1 − metallic) × (1 − specular_transmission) ×
/// (1 − diffuse_transmission)`, and the emission.
pub(crate) fn material_from_standard(m: &StandardMaterial, texture: Option<u32>) -> SnapshotMaterial {
    let base = m.base_color.to_linear();
    let keep = (1.0 - m.metallic) * (1.0 - m.specular_transmission) * (1.0 - m.diffuse_transmission);
    let keep = if keep.is_finite() { keep.clamp(0.0, 1.0) } else { 1.0 };
    let diffuse = Vec3::new(base.red, base.green, base.blue) * keep;
    let emissive = Vec3::new(m.emissive.red, m.emissive.green, m.emissive.blue);
    let sanitize = |v: Vec3| if v.is_finite() { v.max(Vec3::ZERO) } else { Vec3::ZERO };
    SnapshotMaterial {
        diffuse: sanitize(diffuse),
        emissive: sanitize(emissive),
        emissive_exposure_weight: if m.emissive.alpha.is_finite() { m.emissive.alpha.clamp(0.0, 1.0) } else { 1.0 },
        base_color_texture: texture,
        perceptual_roughness: if m.perceptual_roughness.is_finite() { m.perceptual_roughness.clamp(0.0, 1.0) } else { 1.0 },
        culled_face: match m.cull_mode {
            Some(bevy::render::render_resource::Face::Back) => CulledFace::Back,
            Some(bevy::render::render_resource::Face::Front) => CulledFace::Front,
            None => CulledFace::None,
        },
    }
}

/// Decodes a 2D image into linear RGB texels (sRGB formats are linearised by `get_color_at`).
fn texture_from_image(image: &Image) -> Option<SnapshotTexture> {
    let size = image.size();
    if size.x == 0 || size.y == 0 || image.data.is_none() {
        return None;
    }
    let mut texels = Vec::with_capacity((size.x * size.y) as usize);
    for y in 0..size.y {
        for x in 0..size.x {
            let c = image.get_color_at(x, y).ok()?.to_linear();
            texels.push(Vec3::new(c.red, c.green, c.blue));
        }
    }
    Some(SnapshotTexture {
        width: size.x,
        height: size.y,
        texels,
    })
}

/// World-space triangles of a mesh. Only triangle lists and strips contribute. Fails when the mesh's
/// vertex data lives only in the render world (`RenderAssetUsages::RENDER_WORLD`).
pub fn mesh_triangles(
    mesh: &Mesh,
    transform: &GlobalTransform,
    material: u32,
) -> Result<Vec<InputTriangle>, String> {
    let topology = mesh.primitive_topology();
    if !matches!(topology, PrimitiveTopology::TriangleList | PrimitiveTopology::TriangleStrip) {
        return Ok(Vec::new());
    }
    let positions = match mesh.try_attribute_option(Mesh::ATTRIBUTE_POSITION).map_err(|e| e.to_string())? {
        Some(VertexAttributeValues::Float32x3(p)) => p,
        Some(_) => return Err("positions are not Float32x3".into()),
        None => return Ok(Vec::new()),
    };
    let normals = match mesh.try_attribute_option(Mesh::ATTRIBUTE_NORMAL).map_err(|e| e.to_string())? {
        Some(VertexAttributeValues::Float32x3(n)) if n.len() == positions.len() => Some(n),
        _ => None,
    };
    let uvs = match mesh.try_attribute_option(Mesh::ATTRIBUTE_UV_0).map_err(|e| e.to_string())? {
        Some(VertexAttributeValues::Float32x2(uv)) if uv.len() == positions.len() => Some(uv),
        _ => None,
    };
    let indices: Vec<usize> = match mesh.try_indices_option().map_err(|e| e.to_string())? {
        Some(Indices::U16(i)) => i.iter().map(|&v| v as usize).collect(),
        Some(Indices::U32(i)) => i.iter().map(|&v| v as usize).collect(),
        None => (0..positions.len()).collect(),
    };
    let corners: Vec<[usize; 3]> = match topology {
        PrimitiveTopology::TriangleList => indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        _ => (2..indices.len())
            .map(|k| {
                // Strips alternate winding.
                if k % 2 == 0 {
                    [indices[k - 2], indices[k - 1], indices[k]]
                } else {
                    [indices[k - 1], indices[k - 2], indices[k]]
                }
            })
            .collect(),
    };

    let affine = transform.affine();
    let normal_matrix = Mat3::from(affine.matrix3).inverse().transpose();
    let flip = affine.matrix3.determinant() < 0.0;
    let mut out = Vec::with_capacity(corners.len());
    for mut c in corners {
        if c.iter().any(|&i| i >= positions.len()) {
            continue;
        }
        if flip {
            // A mirroring transform turns counter-clockwise into clockwise: keep the front face in front.
            c.swap(1, 2);
        }
        let p = c.map(|i| affine.transform_point3(Vec3::from_array(positions[i])));
        out.push(InputTriangle {
            positions: p,
            normals: normals.map(|n| c.map(|i| normal_matrix * Vec3::from_array(n[i]))),
            uvs: uvs.map(|uv| c.map(|i| Vec2::from_array(uv[i]))),
            material,
        });
    }
    Ok(out)
}

type LightEntity<'a> = (
    Entity,
    &'a GlobalTransform,
    Option<&'a InheritedVisibility>,
    Option<&'a DirectionalLight>,
    Option<&'a PointLight>,
    Option<&'a SpotLight>,
);

fn update_snapshot_lights(
    mut snapshot: ResMut<SceneSnapshot>,
    lights: Query<LightEntity, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>>,
    changed: Query<
        (),
        Or<(
            Changed<DirectionalLight>,
            Changed<PointLight>,
            Changed<SpotLight>,
            (Changed<GlobalTransform>, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>),
            (Changed<InheritedVisibility>, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>),
        )>,
    >,
    mut removed_directional: RemovedComponents<DirectionalLight>,
    mut removed_point: RemovedComponents<PointLight>,
    mut removed_spot: RemovedComponents<SpotLight>,
) {
    let removed = removed_directional.read().count() + removed_point.read().count() + removed_spot.read().count();
    if !(snapshot.is_added() || !changed.is_empty() || removed > 0) {
        return;
    }
    snapshot.lights = lights
        .iter()
        .filter(|(_, _, visibility, ..)| visibility.is_none_or(|v| v.get()))
        .filter_map(|(entity, transform, _, directional, point, spot)| {
            snapshot_light(transform, directional, point, spot).map(|(light, shadows_enabled)| SnapshotLightEntry {
                entity,
                light,
                shadows_enabled,
            })
        })
        .collect();
    snapshot.light_generation += 1;
}

/// Converts a Bevy light to the snapshot's units: lux for directional lights, candela (`lumens / 4π`,
/// Bevy's convention for point *and* spot lights) otherwise.
pub(crate) fn snapshot_light(
    transform: &GlobalTransform,
    directional: Option<&DirectionalLight>,
    point: Option<&PointLight>,
    spot: Option<&SpotLight>,
) -> Option<(SnapshotLight, bool)> {
    let rgb = |c: Color| {
        let l = c.to_linear();
        Vec3::new(l.red, l.green, l.blue)
    };
    let finite = |v: Vec3| v.is_finite().then_some(v.max(Vec3::ZERO));
    let inverse_range_squared = |range: f32| {
        if range.is_finite() && range > 0.0 { 1.0 / (range * range) } else { 0.0 }
    };
    let position = transform.translation();
    let forward = transform.forward().as_vec3();
    if let Some(d) = directional {
        let illuminance = finite(rgb(d.color) * d.illuminance)?;
        return Some((SnapshotLight::Directional { direction: forward, illuminance }, d.shadow_maps_enabled));
    }
    if let Some(s) = spot {
        let intensity = finite(rgb(s.color) * s.intensity / (4.0 * std::f32::consts::PI))?;
        let outer = s.outer_angle.clamp(0.0, std::f32::consts::FRAC_PI_2);
        let inner = s.inner_angle.clamp(0.0, outer);
        let (spot_scale, spot_offset) = SnapshotLight::spot_scale_offset(inner, outer);
        return Some((
            SnapshotLight::Spot {
                position,
                direction: forward,
                intensity,
                inverse_range_squared: inverse_range_squared(s.range),
                spot_scale,
                spot_offset,
            },
            s.shadow_maps_enabled,
        ));
    }
    if let Some(p) = point {
        let intensity = finite(rgb(p.color) * p.intensity / (4.0 * std::f32::consts::PI))?;
        return Some((
            SnapshotLight::Point {
                position,
                intensity,
                inverse_range_squared: inverse_range_squared(p.range),
            },
            p.shadow_maps_enabled,
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::asset::RenderAssetUsages;

    #[test]
    fn cuboid_mesh_becomes_twelve_outward_triangles() {
        let mesh = Mesh::from(Cuboid::new(2.0, 2.0, 2.0));
        let transform = GlobalTransform::from(Transform::from_xyz(0.0, 1.0, 0.0));
        let tris = mesh_triangles(&mesh, &transform, 3).unwrap();
        assert_eq!(tris.len(), 12);
        for t in &tris {
            let [a, b, c] = t.positions;
            let n = (b - a).cross(c - a).normalize();
            let centre = (a + b + c) / 3.0 - Vec3::new(0.0, 1.0, 0.0);
            assert!(n.dot(centre) > 0.0, "face normal {n} points inward");
            assert_eq!(t.material, 3);
        }
    }

    #[test]
    fn mirrored_transform_keeps_outward_winding() {
        let mesh = Mesh::from(Cuboid::new(2.0, 2.0, 2.0));
        let transform = GlobalTransform::from(Transform::from_scale(Vec3::new(-1.0, 1.0, 1.0)));
        for t in mesh_triangles(&mesh, &transform, 0).unwrap() {
            let [a, b, c] = t.positions;
            let n = (b - a).cross(c - a);
            assert!(n.dot((a + b + c) / 3.0) > 0.0);
        }
    }

    #[test]
    fn render_world_only_mesh_is_an_error_not_a_panic() {
        let mut mesh = Mesh::from(Cuboid::default());
        mesh.asset_usage = RenderAssetUsages::RENDER_WORLD;
        // Simulate extraction: the data is taken away from the main world.
        let taken = mesh.take_gpu_data();
        assert!(taken.is_ok());
        assert!(mesh_triangles(&mesh, &GlobalTransform::IDENTITY, 0).is_err());
    }

    #[test]
    fn light_units_follow_bevy() {
        let t = GlobalTransform::from(Transform::from_xyz(0.0, 2.0, 0.0).looking_at(Vec3::ZERO, Vec3::Z));
        let spot = SpotLight {
            intensity: 4.0 * std::f32::consts::PI * 100.0,
            color: Color::WHITE,
            ..default()
        };
        let (light, _) = snapshot_light(&t, None, None, Some(&spot)).unwrap();
        match light {
            SnapshotLight::Spot { intensity, direction, .. } => {
                assert!((intensity - Vec3::splat(100.0)).abs().max_element() < 1e-3);
                assert!((direction - Vec3::NEG_Y).length() < 1e-6);
            }
            other => panic!("expected a spot light, got {other:?}"),
        }
        let nan = PointLight {
            intensity: f32::NAN,
            ..default()
        };
        assert!(snapshot_light(&t, None, Some(&nan), None).is_none());
    }
}
