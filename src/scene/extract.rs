//! Keeps [`SceneSnapshot`] in step with the main world, rebuilding only what changed.

use bevy::asset::AssetId;
use bevy::camera::visibility::VisibilitySystems;
use bevy::light::{DirectionalLight, PointLight, SpotLight};
use bevy::mesh::{Indices, PrimitiveTopology, VertexAttributeValues};
use bevy::pbr::{MeshMaterial3d, StandardMaterial};
use bevy::platform::collections::{HashMap, HashSet};
use bevy::prelude::*;
use bevy::transform::TransformSystems;

use std::sync::Arc;

use bevy::math::Affine3A;
use bevy::mesh::skinning::{SkinnedMesh, SkinnedMeshInverseBindposes};
use bevy::mesh::UvChannel;

use super::{
    CulledFace, Environment, InputTriangle, MeshGeometry, MetallicTexture, SceneSnapshot, SnapshotLight, SnapshotLightEntry,
    SnapshotMaterial, SnapshotTexture, TextureRef,
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
        app.init_resource::<SnapshotTimings>()
            .init_resource::<crate::MainThreadCost>()
            .init_resource::<crate::DiffuseGiWarnings>()
            .add_systems(
            PostUpdate,
            (
                // Apps without meshes, materials or images (no renderer) have no geometry to snapshot.
                update_snapshot_geometry.run_if(
                    resource_exists::<Assets<Mesh>>
                        .and_then(resource_exists::<Assets<StandardMaterial>>)
                        .and_then(resource_exists::<Assets<Image>>),
                ),
                update_snapshot_lights,
                update_snapshot_environment.run_if(resource_exists::<Assets<Image>>),
            )
                .in_set(SceneSnapshotSystems::Update)
                .after(TransformSystems::Propagate)
                .after(VisibilitySystems::VisibilityPropagate)
                .run_if(resource_exists::<SceneSnapshot>),
        );
    }
}

/// What the snapshot was built from, so that a change costs what changed: local-space geometry per mesh
/// asset, material and texture slots per asset, and what every instance was made of.
#[derive(Default)]
pub(crate) struct SnapshotCache {
    meshes: HashMap<AssetId<Mesh>, Arc<MeshGeometry>>,
    materials: HashMap<AssetId<StandardMaterial>, u32>,
    textures: HashMap<AssetId<Image>, u32>,
    /// Images whose texture slot holds the white placeholder because they are not loaded yet.
    missing_textures: HashSet<AssetId<Image>>,
    /// Per instance: its mesh and material assets.
    instances: HashMap<Entity, (AssetId<Mesh>, Option<AssetId<StandardMaterial>>)>,
    /// Mesh entities waiting for their mesh or material asset.
    waiting: HashSet<Entity>,
    warned_extracted: bool,
    warned_textures: HashSet<AssetId<Image>>,
    /// The snapshot generation this cache describes.
    generation: u64,
}

type MeshEntity<'a> = (
    Entity,
    &'a Mesh3d,
    Option<&'a MeshMaterial3d<StandardMaterial>>,
    &'a GlobalTransform,
    &'a InheritedVisibility,
    Option<&'a SkinnedMesh>,
);

type ChangedMesh = Or<(
    Changed<Mesh3d>,
    Changed<GlobalTransform>,
    Changed<MeshMaterial3d<StandardMaterial>>,
    Changed<InheritedVisibility>,
    Changed<SkinnedMesh>,
)>;

/// Main-thread cost of the last geometry update, for reports.
#[derive(Resource, Default, Clone, Copy, Debug)]
pub struct SnapshotTimings {
    /// Milliseconds the last frame's geometry update took (0 when nothing changed).
    pub geometry_ms: f32,
    /// Instances updated in that frame.
    pub instances_updated: u32,
    /// Mesh entities or textures the snapshot still waits for (it is incomplete while this is non-zero).
    pub waiting: u32,
}

#[expect(clippy::too_many_arguments, reason = "a system reading every input of the snapshot")]
fn update_snapshot_geometry(
    mut snapshot: ResMut<SceneSnapshot>,
    mut cache: Local<SnapshotCache>,
    mut timings: ResMut<SnapshotTimings>,
    mut cost: ResMut<crate::MainThreadCost>,
    all: Query<MeshEntity>,
    changed: Query<Entity, (With<Mesh3d>, ChangedMesh)>,
    skinned: Query<(Entity, &SkinnedMesh)>,
    joints: Query<Ref<GlobalTransform>>,
    mut removed: RemovedComponents<Mesh3d>,
    mut mesh_events: MessageReader<AssetEvent<Mesh>>,
    mut material_events: MessageReader<AssetEvent<StandardMaterial>>,
    mut image_events: MessageReader<AssetEvent<Image>>,
    assets: SnapshotAssets,
    (mut warned, mut warnings): (Local<BadInputWarned>, ResMut<crate::DiffuseGiWarnings>),
) {
    let start = std::time::Instant::now();
    let cache = &mut *cache;
    let mut warn_bad = |message: String| crate::gi_warning(&mut warnings, message);
    let mut dirty: HashSet<Entity> = HashSet::default();
    // A new (or replaced, or externally edited) snapshot is built from scratch.
    if snapshot.is_added() || snapshot.geometry_generation != cache.generation || cache.generation == 0 {
        *cache = SnapshotCache { warned_extracted: cache.warned_extracted, ..default() };
        for key in snapshot.instances().iter().map(|i| i.key).collect::<Vec<_>>() {
            snapshot.remove_instance(key);
        }
        snapshot.materials = vec![SnapshotMaterial::DEFAULT_GREY];
        snapshot.textures.clear();
        dirty.extend(all.iter().map(|(e, ..)| e));
        // Even an empty world bumps the generation once, so that consumers see a built snapshot.
        snapshot.touch_all();
    }
    dirty.extend(changed.iter());
    dirty.extend(cache.waiting.iter().copied());
    // Skinned meshes follow their joints.
    for (entity, skin) in &skinned {
        if skin.joints.iter().any(|&j| joints.get(j).is_ok_and(|t| t.is_changed())) {
            dirty.insert(entity);
        }
    }
    for entity in removed.read() {
        if cache.instances.remove(&entity).is_some() {
            snapshot.remove_instance(entity.to_bits());
        }
        cache.waiting.remove(&entity);
    }

    // Mesh assets: drop the cached geometry and redo the instances that use it.
    for event in mesh_events.read() {
        let id = event_id(event);
        if cache.meshes.remove(&id).is_some() || matches!(event, AssetEvent::Added { .. } | AssetEvent::LoadedWithDependencies { .. }) {
            dirty.extend(cache.instances.iter().filter(|(_, (m, _))| *m == id).map(|(e, _)| *e));
        }
    }
    // Images: re-decode into the same slot, then refresh the materials that read them.
    let mut refreshed_images: HashSet<AssetId<Image>> = HashSet::default();
    for event in image_events.read() {
        let id = event_id(event);
        if let Some(&slot) = cache.textures.get(&id) {
            let texture = assets.images.get(id).and_then(|image| decode_texture(image, id, &mut cache.warned_textures));
            // Waiting only while the image is not loaded; an unreadable one stays white (warned once).
            if assets.images.get(id).is_some() {
                cache.missing_textures.remove(&id);
            } else {
                cache.missing_textures.insert(id);
            }
            snapshot.textures[slot as usize] = texture.unwrap_or_else(SnapshotTexture::white);
            refreshed_images.insert(id);
        }
    }
    // Materials: re-read in place.
    let mut refreshed_materials: HashSet<AssetId<StandardMaterial>> = HashSet::default();
    for event in material_events.read() {
        let id = event_id(event);
        if cache.materials.contains_key(&id) {
            refreshed_materials.insert(id);
        }
    }
    if !refreshed_images.is_empty() {
        for (&id, _) in cache.materials.iter() {
            if let Some(m) = assets.materials.get(id)
                && material_images(m).any(|h| refreshed_images.contains(&h))
            {
                refreshed_materials.insert(id);
            }
        }
    }
    for id in &refreshed_materials {
        let slot = cache.materials[id];
        if let Some(m) = assets.materials.get(*id) {
            if let Some(fields) = non_finite_fields(m)
                && warned.materials.insert(*id)
            {
                warn_bad(non_finite_material_message(*id, &fields));
            }
            let material = material_with_textures(m, &mut snapshot, cache, &assets);
            snapshot.materials[slot as usize] = material;
        }
        for (entity, (_, material)) in cache.instances.iter() {
            if *material == Some(*id) && !dirty.contains(entity) {
                snapshot.touch_instance(entity.to_bits());
            }
        }
    }

    let mut updated = 0u32;
    for entity in dirty {
        updated += 1;
        cache.waiting.remove(&entity);
        let Ok((_, mesh3d, material3d, transform, visibility, skin)) = all.get(entity) else {
            if cache.instances.remove(&entity).is_some() {
                snapshot.remove_instance(entity.to_bits());
            }
            continue;
        };
        if !visibility.get() {
            if cache.instances.remove(&entity).is_some() {
                snapshot.remove_instance(entity.to_bits());
            }
            continue;
        }
        let key = entity.to_bits();
        // Material slot (0 is the default grey for meshes without a StandardMaterial).
        let material = match material3d {
            Some(m) => match cache.materials.get(&m.id()) {
                Some(&slot) => slot,
                None => {
                    let Some(standard) = assets.materials.get(m.id()) else {
                        cache.waiting.insert(entity);
                        continue;
                    };
                    if let Some(fields) = non_finite_fields(standard)
                        && warned.materials.insert(m.id())
                    {
                        warn_bad(non_finite_material_message(m.id(), &fields));
                    }
                    let material = material_with_textures(standard, &mut snapshot, cache, &assets);
                    snapshot.materials.push(material);
                    let slot = snapshot.materials.len() as u32 - 1;
                    cache.materials.insert(m.id(), slot);
                    slot
                }
            },
            None => 0,
        };
        let Some(mesh) = assets.meshes.get(mesh3d.id()) else {
            cache.waiting.insert(entity);
            continue;
        };
        let assets_key = (mesh3d.id(), material3d.map(|m| m.id()));
        // Skinned meshes: the current pose in world space, one geometry per entity.
        if let Some(skin) = skin {
            match skinned_triangles(mesh, skin, &assets.bindposes, &joints) {
                Ok(Some(tris)) => {
                    snapshot.set_instance(key, Arc::new(MeshGeometry::new(tris)), Affine3A::IDENTITY, material);
                    cache.instances.insert(entity, assets_key);
                    continue;
                }
                Ok(None) => {
                    cache.waiting.insert(entity);
                    continue;
                }
                Err(e) => {
                    warn_left_out(&mut cache.warned_extracted, &e);
                    continue;
                }
            }
        }
        let world_from_local = transform.affine();
        if !world_from_local.is_finite() {
            // NaN or infinite: no light can bounce off it (a zero or mirrored scale is fine: a hidden or
            // flipped mesh).
            if warned.transforms.insert(entity) {
                warn_bad(format!(
                    "bevy_diffuse_gi: mesh entity {entity} has a non-finite transform; it takes no part in the \
                     bounced light until its transform is finite again"
                ));
            }
            if cache.instances.remove(&entity).is_some() {
                snapshot.remove_instance(entity.to_bits());
            }
            continue;
        }
        if cache.instances.get(&entity) == Some(&assets_key) && cache.meshes.contains_key(&mesh3d.id()) {
            // Only moved (or re-shown): the cheap path.
            if snapshot.instance(key).is_some_and(|i| i.material == material) {
                snapshot.set_instance_transform(key, world_from_local);
                continue;
            }
        }
        let geometry = match cache.meshes.get(&mesh3d.id()) {
            Some(g) => g.clone(),
            None => match mesh_local_triangles(mesh) {
                Ok(tris) => {
                    let g = Arc::new(MeshGeometry::new(tris));
                    cache.meshes.insert(mesh3d.id(), g.clone());
                    g
                }
                Err(e) => {
                    warn_left_out(&mut cache.warned_extracted, &e);
                    continue;
                }
            },
        };
        snapshot.set_instance(key, geometry, world_from_local, material);
        cache.instances.insert(entity, assets_key);
    }
    snapshot.commit();
    cache.generation = snapshot.geometry_generation;
    if updated > 0 || !refreshed_materials.is_empty() {
        timings.geometry_ms = start.elapsed().as_secs_f32() * 1000.0;
    } else {
        timings.geometry_ms = 0.0;
    }
    timings.instances_updated = updated;
    cost.snapshot_ms = timings.geometry_ms;
    timings.waiting = (cache.waiting.len() + cache.missing_textures.len()) as u32;
}

/// The bad inputs the snapshot has warned about (once each, for the app's lifetime).
#[derive(Default)]
pub(crate) struct BadInputWarned {
    transforms: HashSet<Entity>,
    materials: HashSet<AssetId<StandardMaterial>>,
}

/// The names of `m`'s non-finite values, if any.
fn non_finite_fields(m: &StandardMaterial) -> Option<Vec<&'static str>> {
    let base = m.base_color.to_linear();
    let checks = [
        ("base_color", base.red.is_finite() && base.green.is_finite() && base.blue.is_finite() && base.alpha.is_finite()),
        ("emissive", m.emissive.red.is_finite() && m.emissive.green.is_finite() && m.emissive.blue.is_finite() && m.emissive.alpha.is_finite()),
        ("metallic", m.metallic.is_finite()),
        ("perceptual_roughness", m.perceptual_roughness.is_finite()),
        ("specular_transmission", m.specular_transmission.is_finite()),
        ("diffuse_transmission", m.diffuse_transmission.is_finite()),
    ];
    let bad: Vec<&'static str> = checks.iter().filter(|(_, ok)| !ok).map(|(name, _)| *name).collect();
    (!bad.is_empty()).then_some(bad)
}

fn non_finite_material_message(id: AssetId<StandardMaterial>, fields: &[&str]) -> String {
    format!(
        "bevy_diffuse_gi: StandardMaterial {id:?} has non-finite {}; the bounced light reads each as its \
         neutral value (no colour, no emission)",
        fields.join(", ")
    )
}

/// The asset collections the snapshot reads.
#[derive(bevy::ecs::system::SystemParam)]
pub(crate) struct SnapshotAssets<'w> {
    meshes: Res<'w, Assets<Mesh>>,
    materials: Res<'w, Assets<StandardMaterial>>,
    images: Res<'w, Assets<Image>>,
    bindposes: Option<Res<'w, Assets<SkinnedMeshInverseBindposes>>>,
}

fn warn_left_out(warned: &mut bool, e: &str) {
    if !*warned {
        warn!(
            "bevy_diffuse_gi: a mesh is left out of the scene snapshot (used by the path tracer and CPU-side GI): \
             {e}. Keep `RenderAssetUsages::MAIN_WORLD` on meshes that should take part."
        );
        *warned = true;
    }
}

/// The images a material reads.
fn material_images(m: &StandardMaterial) -> impl Iterator<Item = AssetId<Image>> + '_ {
    [m.base_color_texture.as_ref(), m.metallic_roughness_texture.as_ref()].into_iter().flatten().map(|h| h.id())
}

/// The snapshot material of `m`, with texture slots allocated (white until the image loads).
fn material_with_textures(
    m: &StandardMaterial,
    snapshot: &mut SceneSnapshot,
    cache: &mut SnapshotCache,
    assets: &SnapshotAssets,
) -> SnapshotMaterial {
    let mut slot = |handle: &Handle<Image>| -> u32 {
        let id = handle.id();
        if let Some(&slot) = cache.textures.get(&id) {
            return slot;
        }
        let texture = assets.images.get(id).and_then(|image| decode_texture(image, id, &mut cache.warned_textures));
        if assets.images.get(id).is_none() {
            cache.missing_textures.insert(id);
        }
        snapshot.textures.push(texture.unwrap_or_else(SnapshotTexture::white));
        let slot = snapshot.textures.len() as u32 - 1;
        cache.textures.insert(id, slot);
        slot
    };
    let channel = |c: &UvChannel| if matches!(c, UvChannel::Uv1) { 1 } else { 0 };
    let base = m.base_color_texture.as_ref().map(|h| TextureRef {
        texture: slot(h),
        channel: channel(&m.base_color_channel),
        uv_transform: m.uv_transform,
    });
    let metallic = m.metallic_roughness_texture.as_ref().map(|h| TextureRef {
        texture: slot(h),
        channel: channel(&m.metallic_roughness_channel),
        uv_transform: m.uv_transform,
    });
    material_from_standard_textured(m, base, metallic)
}

fn decode_texture(image: &Image, id: AssetId<Image>, warned: &mut HashSet<AssetId<Image>>) -> Option<SnapshotTexture> {
    let texture = texture_from_image(image);
    if texture.is_none() && image.data.is_some() && warned.insert(id) {
        warn!(
            "bevy_diffuse_gi: texture {id:?} ({:?}) cannot be read on the CPU; the scene snapshot (path tracer, \
             RSM and voxel albedo) uses white for it",
            image.texture_descriptor.format
        );
    }
    texture
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
/// (1 − diffuse_transmission)`, and the emission (no textures).
pub(crate) fn material_from_standard(m: &StandardMaterial) -> SnapshotMaterial {
    material_from_standard_textured(m, None, None)
}

/// [`material_from_standard`] with the material's base-colour and metallic-roughness texture slots.
pub(crate) fn material_from_standard_textured(
    m: &StandardMaterial,
    base_color_texture: Option<TextureRef>,
    metallic_roughness_texture: Option<TextureRef>,
) -> SnapshotMaterial {
    let base = m.base_color.to_linear();
    let finite01 = |v: f32, fallback: f32| if v.is_finite() { v.clamp(0.0, 1.0) } else { fallback };
    let transmission_keep = finite01((1.0 - m.specular_transmission) * (1.0 - m.diffuse_transmission), 1.0);
    let metallic = finite01(m.metallic, 0.0);
    let sanitize = |v: Vec3| if v.is_finite() { v.max(Vec3::ZERO) } else { Vec3::ZERO };
    let base_rgb = sanitize(Vec3::new(base.red, base.green, base.blue) * transmission_keep);
    let emissive = Vec3::new(m.emissive.red, m.emissive.green, m.emissive.blue);
    SnapshotMaterial {
        diffuse: base_rgb * (1.0 - metallic),
        emissive: sanitize(emissive),
        emissive_exposure_weight: finite01(m.emissive.alpha, 1.0),
        base_color_texture,
        metallic_texture: metallic_roughness_texture.map(|texture| MetallicTexture { texture, metallic, base: base_rgb }),
        alpha_cutoff: match m.alpha_mode {
            AlphaMode::Mask(cutoff) if cutoff.is_finite() => Some(cutoff),
            _ => None,
        },
        base_alpha: finite01(base.alpha, 1.0),
        perceptual_roughness: finite01(m.perceptual_roughness, 1.0),
        culled_face: match m.cull_mode {
            Some(bevy::render::render_resource::Face::Back) => CulledFace::Back,
            Some(bevy::render::render_resource::Face::Front) => CulledFace::Front,
            None => CulledFace::None,
        },
    }
}

/// Decodes a 2D image into linear RGBA texels (sRGB formats are linearised by `get_color_at`). Only the
/// first layer of an array or cube texture is read; block-compressed formats give `None`.
pub(crate) fn texture_from_image(image: &Image) -> Option<SnapshotTexture> {
    let size = image.size();
    if size.x == 0 || size.y == 0 || image.data.is_none() {
        return None;
    }
    let mut texels = Vec::with_capacity((size.x * size.y) as usize);
    for y in 0..size.y {
        for x in 0..size.x {
            let c = image.get_color_at(x, y).ok()?.to_linear();
            texels.push(Vec4::new(c.red, c.green, c.blue, c.alpha));
        }
    }
    Some(SnapshotTexture {
        width: size.x,
        height: size.y,
        texels: texels.into(),
    })
}

/// The triangles of a mesh in its local space, as vertex-index triples (strips unrolled). Only triangle
/// lists and strips contribute.
struct MeshCorners<'a> {
    positions: &'a [[f32; 3]],
    normals: Option<&'a [[f32; 3]]>,
    uvs: Option<&'a [[f32; 2]]>,
    uvs_1: Option<&'a [[f32; 2]]>,
    corners: Vec<[usize; 3]>,
}

fn mesh_corners(mesh: &Mesh) -> Result<Option<MeshCorners<'_>>, String> {
    let topology = mesh.primitive_topology();
    if !matches!(topology, PrimitiveTopology::TriangleList | PrimitiveTopology::TriangleStrip) {
        return Ok(None);
    }
    let positions = match mesh.try_attribute_option(Mesh::ATTRIBUTE_POSITION).map_err(|e| e.to_string())? {
        Some(VertexAttributeValues::Float32x3(p)) => p.as_slice(),
        Some(_) => return Err("positions are not Float32x3".into()),
        None => return Ok(None),
    };
    let normals = match mesh.try_attribute_option(Mesh::ATTRIBUTE_NORMAL).map_err(|e| e.to_string())? {
        Some(VertexAttributeValues::Float32x3(n)) if n.len() == positions.len() => Some(n.as_slice()),
        _ => None,
    };
    let uv = |attribute| -> Result<Option<&[[f32; 2]]>, String> {
        Ok(match mesh.try_attribute_option(attribute).map_err(|e| e.to_string())? {
            Some(VertexAttributeValues::Float32x2(uv)) if uv.len() == positions.len() => Some(uv.as_slice()),
            _ => None,
        })
    };
    let (uvs, uvs_1) = (uv(Mesh::ATTRIBUTE_UV_0)?, uv(Mesh::ATTRIBUTE_UV_1)?);
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
    let corners = corners.into_iter().filter(|c| c.iter().all(|&i| i < positions.len())).collect();
    Ok(Some(MeshCorners { positions, normals, uvs, uvs_1, corners }))
}

/// Local-space triangles of a mesh (material 0). Fails when the mesh's vertex data lives only in the
/// render world (`RenderAssetUsages::RENDER_WORLD`).
pub fn mesh_local_triangles(mesh: &Mesh) -> Result<Vec<InputTriangle>, String> {
    let Some(m) = mesh_corners(mesh)? else {
        return Ok(Vec::new());
    };
    let v3 = |a: &[[f32; 3]], c: [usize; 3]| c.map(|i| Vec3::from_array(a[i]));
    let v2 = |a: &[[f32; 2]], c: [usize; 3]| c.map(|i| Vec2::from_array(a[i]));
    Ok(m.corners
        .iter()
        .map(|&c| InputTriangle {
            positions: v3(m.positions, c),
            normals: m.normals.map(|n| v3(n, c)),
            uvs: m.uvs.map(|uv| v2(uv, c)),
            uvs_1: m.uvs_1.map(|uv| v2(uv, c)),
            material: 0,
        })
        .collect())
}

/// World-space triangles of a mesh. Only triangle lists and strips contribute. Fails when the mesh's
/// vertex data lives only in the render world (`RenderAssetUsages::RENDER_WORLD`).
pub fn mesh_triangles(
    mesh: &Mesh,
    transform: &GlobalTransform,
    material: u32,
) -> Result<Vec<InputTriangle>, String> {
    let affine = transform.affine();
    let normal_matrix = Mat3::from(affine.matrix3).inverse().transpose();
    let flip = affine.matrix3.determinant() < 0.0;
    Ok(mesh_local_triangles(mesh)?
        .into_iter()
        .map(|mut t| {
            t.positions = t.positions.map(|p| affine.transform_point3(p));
            t.normals = t.normals.map(|n| n.map(|v| normal_matrix * v));
            t.material = material;
            if flip {
                // A mirroring transform turns counter-clockwise into clockwise: keep the front face in front.
                t.positions.swap(1, 2);
                if let Some(n) = t.normals.as_mut() {
                    n.swap(1, 2);
                }
                if let Some(uv) = t.uvs.as_mut() {
                    uv.swap(1, 2);
                }
                if let Some(uv) = t.uvs_1.as_mut() {
                    uv.swap(1, 2);
                }
            }
            t
        })
        .collect())
}

/// World-space triangles of a skinned mesh in its current pose, the way Bevy's skinning shader places
/// them: each vertex is `Σ weightᵢ · joint_worldᵢ · inverse_bindposeᵢ · position` (the entity's own
/// transform is not used). `Ok(None)` while the bind poses or a joint are not available yet.
pub fn skinned_triangles(
    mesh: &Mesh,
    skin: &SkinnedMesh,
    bindposes: &Option<Res<Assets<SkinnedMeshInverseBindposes>>>,
    joints: &Query<Ref<GlobalTransform>>,
) -> Result<Option<Vec<InputTriangle>>, String> {
    let Some(inverse) = bindposes.as_ref().and_then(|b| b.get(&skin.inverse_bindposes)) else {
        return Ok(None);
    };
    let mut matrices = Vec::with_capacity(skin.joints.len());
    for (k, &joint) in skin.joints.iter().enumerate() {
        let Ok(t) = joints.get(joint) else {
            return Ok(None);
        };
        matrices.push(t.to_matrix() * inverse.get(k).copied().unwrap_or(Mat4::IDENTITY));
    }
    let Some(m) = mesh_corners(mesh)? else {
        return Ok(Some(Vec::new()));
    };
    let (Some(VertexAttributeValues::Uint16x4(indices)), Some(VertexAttributeValues::Float32x4(weights))) = (
        mesh.try_attribute_option(Mesh::ATTRIBUTE_JOINT_INDEX).map_err(|e| e.to_string())?,
        mesh.try_attribute_option(Mesh::ATTRIBUTE_JOINT_WEIGHT).map_err(|e| e.to_string())?,
    ) else {
        return Err("a SkinnedMesh without Uint16x4 joint indices and Float32x4 joint weights".into());
    };
    let skin_matrix = |v: usize| -> Mat4 {
        let (Some(i), Some(w)) = (indices.get(v), weights.get(v)) else {
            return Mat4::IDENTITY;
        };
        let mut sum = Mat4::ZERO;
        for k in 0..4 {
            sum += matrices.get(i[k] as usize).copied().unwrap_or(Mat4::IDENTITY) * w[k];
        }
        sum
    };
    let skinned: Vec<Mat4> = (0..m.positions.len()).map(skin_matrix).collect();
    let v2 = |a: &[[f32; 2]], c: [usize; 3]| c.map(|i| Vec2::from_array(a[i]));
    Ok(Some(
        m.corners
            .iter()
            .map(|&c| InputTriangle {
                positions: c.map(|i| skinned[i].transform_point3(Vec3::from_array(m.positions[i]))),
                normals: m.normals.map(|n| {
                    c.map(|i| Mat3::from_mat4(skinned[i]).inverse().transpose() * Vec3::from_array(n[i]))
                }),
                uvs: m.uvs.map(|uv| v2(uv, c)),
                uvs_1: m.uvs_1.map(|uv| v2(uv, c)),
                material: 0,
            })
            .collect(),
    ))
}

type LightEntity<'a> = (
    Entity,
    &'a GlobalTransform,
    Option<&'a InheritedVisibility>,
    Option<&'a DirectionalLight>,
    Option<&'a PointLight>,
    Option<&'a SpotLight>,
);

#[expect(clippy::too_many_arguments, reason = "a system reading every kind of light and its removals")]
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
    gi_lights: Query<(), With<crate::light::GiLight>>,
    (mut warned, mut warnings): (Local<HashSet<(Entity, u8)>>, ResMut<crate::DiffuseGiWarnings>),
) {
    let removed = removed_directional.read().count() + removed_point.read().count() + removed_spot.read().count();
    if !(snapshot.is_added() || !changed.is_empty() || removed > 0) {
        return;
    }
    let mut warn_once = |entity: Entity, kind: u8, message: String| {
        if warned.insert((entity, kind)) {
            crate::gi_warning(&mut warnings, message);
        }
    };
    snapshot.lights = lights
        .iter()
        .filter(|(_, _, visibility, ..)| visibility.is_none_or(|v| v.get()))
        .filter_map(|(entity, transform, _, directional, point, spot)| {
            let entry = snapshot_light(transform, directional, point, spot);
            let gi = gi_lights.contains(entity);
            match &entry {
                None if gi => warn_once(
                    entity,
                    0,
                    format!(
                        "bevy_diffuse_gi: GI light {entity} has a non-finite transform, colour or intensity; \
                         it adds no bounced light until they are finite again"
                    ),
                ),
                Some((_, false)) if gi => warn_once(
                    entity,
                    1,
                    format!(
                        "bevy_diffuse_gi: GI light {entity} casts no shadows (`shadow_maps_enabled: false`): \
                         its direct light goes through walls that its bounced light respects"
                    ),
                ),
                _ => {}
            }
            entry.map(|(light, shadows_enabled)| SnapshotLightEntry { entity, light, shadows_enabled })
        })
        .collect();
    snapshot.light_generation += 1;
}

/// What [`SceneSnapshot::environment`] was read from: the image, Bevy's intensity and rotation.
type EnvironmentKey = (AssetId<Image>, u32, [u32; 4]);

/// Reads the environment light of the first active GI camera (by camera order; any camera where there
/// is no GI camera) that has an `EnvironmentMapLight`, when it or its image changes. An image that cannot be read is reported once,
/// by path, and leaves no environment.
fn update_snapshot_environment(
    mut snapshot: ResMut<SceneSnapshot>,
    cameras: Query<(&Camera, Option<&crate::camera::DiffuseGi>, &bevy::light::EnvironmentMapLight)>,
    images: Res<Assets<Image>>,
    assets: Option<Res<AssetServer>>,
    mut events: MessageReader<AssetEvent<Image>>,
    mut read: Local<Option<EnvironmentKey>>,
    mut warned: Local<HashSet<AssetId<Image>>>,
) {
    // GI cameras first; without one (the tracer's own camera), any active camera.
    let light = cameras
        .iter()
        .filter(|(camera, gi, _)| camera.is_active && gi.is_none_or(|gi| gi.enabled))
        .min_by_key(|(camera, gi, _)| (gi.is_none(), camera.order))
        .map(|(_, _, light)| light)
        .filter(|light| light.intensity > 0.0);
    let key = light.map(|l| {
        let r = l.rotation;
        (l.specular_map.id(), l.intensity.to_bits(), [r.x.to_bits(), r.y.to_bits(), r.z.to_bits(), r.w.to_bits()])
    });
    let modified = key.is_some_and(|(id, ..)| {
        events.read().any(|e| matches!(e, AssetEvent::Modified { id: m } | AssetEvent::LoadedWithDependencies { id: m } if *m == id))
    });
    // A new snapshot starts without an environment, whatever this system read into the last one.
    if key == *read && !modified && !snapshot.is_added() {
        return;
    }
    let Some(light) = light else {
        *read = None;
        if snapshot.environment.take().is_some() {
            snapshot.environment_generation += 1;
        }
        return;
    };
    let Some(image) = images.get(&light.specular_map) else {
        // Not loaded yet: try again next frame.
        return;
    };
    *read = key;
    let environment = match Environment::from_image(image, light.intensity, light.rotation) {
        Ok(e) => Some(Arc::new(e)),
        Err(why) => {
            if warned.insert(light.specular_map.id()) {
                let name = assets
                    .as_ref()
                    .and_then(|a| a.get_path(light.specular_map.id()))
                    .map_or_else(|| format!("{:?}", light.specular_map.id()), |p| p.to_string());
                warn!("diffuse_gi: the environment map {name} is not used for bounced light: {why}");
            }
            None
        }
    };
    snapshot.environment = environment;
    snapshot.environment_generation += 1;
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
    if !(position.is_finite() && forward.is_finite()) {
        return None;
    }
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

#[cfg(test)]
mod incremental_tests {
    use super::*;
    use crate::scene::SceneSnapshot;

    /// An app with the snapshot plugin and the assets it reads, no renderer.
    pub(super) fn app() -> App {
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, AssetPlugin::default(), TransformPlugin, SceneSnapshotPlugin))
            .init_asset::<Mesh>()
            .init_asset::<StandardMaterial>()
            .init_asset::<Image>()
            .init_asset::<SkinnedMeshInverseBindposes>()
            .init_resource::<SceneSnapshot>();
        app
    }

    fn spawn(app: &mut App, mesh: &Handle<Mesh>, material: &Handle<StandardMaterial>, at: Vec3) -> Entity {
        app.world_mut()
            .spawn((
                Mesh3d(mesh.clone()),
                MeshMaterial3d(material.clone()),
                Transform::from_translation(at).with_rotation(Quat::from_rotation_y(at.x)),
                InheritedVisibility::VISIBLE,
            ))
            .id()
    }

    /// Every triangle, its attributes and the hits of a fixed fan of rays.
    fn fingerprint(s: &SceneSnapshot) -> (Vec<([Vec3; 3], TriangleAttributesKey)>, Vec<Option<(u32, i64)>>) {
        let triangles = (0..s.triangle_count() as u32)
            .map(|i| {
                let a = s.attributes(i);
                (s.triangle(i), (s.materials[a.material as usize].diffuse.to_array().map(f32::to_bits), a.geometric_normal.to_array().map(|v| (v * 1e4).round() as i64)))
            })
            .collect();
        let mut hits = Vec::new();
        for i in 0..200 {
            let d = crate::sampling::uniform_sphere(bevy::math::Vec2::new((i as f32 + 0.5) / 200.0, (i as f32 * 0.618_034).fract()));
            let hit = s.intersect(Vec3::new(0.1, 0.5, 0.2), d, 0.0, f32::INFINITY);
            hits.push(hit.map(|h| (h.triangle, (h.t * 1e4).round() as i64)));
        }
        (triangles, hits)
    }

    type TriangleAttributesKey = ([u32; 3], [i64; 3]);

    #[test]
    fn incremental_snapshot_equals_a_full_rebuild() {
        let mut app = app();
        let (cube, sphere, red, white) = {
            let world = app.world_mut();
            let mut meshes = world.resource_mut::<Assets<Mesh>>();
            let cube = meshes.add(Cuboid::new(1.0, 0.5, 0.8));
            let sphere = meshes.add(Sphere::new(0.4).mesh().ico(2).unwrap());
            let mut materials = world.resource_mut::<Assets<StandardMaterial>>();
            let red = materials.add(StandardMaterial::from(Color::srgb(0.8, 0.1, 0.1)));
            let white = materials.add(StandardMaterial::from(Color::WHITE));
            (cube, sphere, red, white)
        };
        let mut entities: Vec<Entity> = (0..6)
            .map(|i| {
                let (mesh, material) = if i % 2 == 0 { (&cube, &red) } else { (&sphere, &white) };
                spawn(&mut app, mesh, material, Vec3::new(i as f32 - 2.5, 0.3 * i as f32, 1.5))
            })
            .collect();
        app.update();
        let first = app.world().resource::<SceneSnapshot>().layout_generation;
        for step in 0..8 {
            let world = app.world_mut();
            // Move two, re-material one, add one, remove one.
            for &e in entities.iter().take(2) {
                world.get_mut::<Transform>(e).unwrap().translation += Vec3::new(0.3, -0.1, 0.2 * step as f32);
            }
            if step == 3 {
                world.entity_mut(entities[2]).insert(MeshMaterial3d(white.clone()));
            }
            if step % 3 == 1 {
                let e = entities.remove(step % entities.len());
                world.despawn(e);
            }
            if step % 2 == 0 {
                let e = spawn(&mut app, &sphere, &red, Vec3::new(-1.0 + step as f32 * 0.4, 1.0, -1.0));
                entities.push(e);
            }
            app.update();
        }
        let snapshot = app.world().resource::<SceneSnapshot>();
        assert!(snapshot.layout_generation > first, "adds and removals change the layout");
        let incremental = fingerprint(snapshot);
        assert!(incremental.1.iter().any(Option::is_some), "the rays must hit something");

        // A fresh snapshot of the same world is built from scratch.
        app.world_mut().insert_resource(SceneSnapshot::default());
        app.update();
        let full = fingerprint(app.world().resource::<SceneSnapshot>());
        assert_eq!(incremental.0.len(), full.0.len());
        assert_eq!(incremental, full);
    }

    #[test]
    fn moving_one_mesh_updates_only_its_instance() {
        let mut app = app();
        let (cube, grey) = {
            let world = app.world_mut();
            let cube = world.resource_mut::<Assets<Mesh>>().add(Cuboid::default());
            let grey = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial::default());
            (cube, grey)
        };
        let entities: Vec<Entity> = (0..5).map(|i| spawn(&mut app, &cube, &grey, Vec3::X * i as f32 * 2.0)).collect();
        app.update();
        let layout = app.world().resource::<SceneSnapshot>().layout_generation;
        app.world_mut().get_mut::<Transform>(entities[3]).unwrap().translation.y += 1.0;
        app.update();
        let s = app.world().resource::<SceneSnapshot>();
        assert_eq!(s.layout_generation, layout, "a move keeps the layout");
        assert!(!s.last_change.layout_changed);
        let changed: Vec<u64> = s.instances().iter().filter(|i| i.version == s.geometry_generation).map(|i| i.key).collect();
        assert_eq!(changed, vec![entities[3].to_bits()]);
        // Old and new bounds are dirty.
        assert_eq!(s.last_change.dirty.len(), 2);
        assert_eq!(app.world().resource::<SnapshotTimings>().instances_updated, 1);
    }
}

#[cfg(test)]
mod skinning_tests {
    use super::*;
    use bevy::asset::RenderAssetUsages;
    use bevy::mesh::VertexAttributeValues;

    /// A 1 m × 2 m vertical strip, its top vertices bound to joint 1, its bottom ones to joint 0.
    fn strip() -> Mesh {
        let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 0.0]];
        let joints = vec![[0u16, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0]];
        let weights = vec![[1.0f32, 0.0, 0.0, 0.0]; 4];
        Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::default())
            .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
            .with_inserted_attribute(Mesh::ATTRIBUTE_JOINT_INDEX, VertexAttributeValues::Uint16x4(joints))
            .with_inserted_attribute(Mesh::ATTRIBUTE_JOINT_WEIGHT, weights)
            .with_inserted_indices(Indices::U32(vec![0, 1, 2, 0, 2, 3]))
    }

    #[test]
    fn a_skinned_mesh_enters_the_snapshot_in_its_current_pose() {
        let mut app = super::incremental_tests::app();
        let world = app.world_mut();
        let mesh = world.resource_mut::<Assets<Mesh>>().add(strip());
        // Joint 1 sits at y = 2 in the bind pose.
        let bindposes = world
            .resource_mut::<Assets<SkinnedMeshInverseBindposes>>()
            .add(SkinnedMeshInverseBindposes::from(vec![Mat4::IDENTITY, Mat4::from_translation(Vec3::new(0.0, -2.0, 0.0))]));
        let root = world.spawn(Transform::IDENTITY).id();
        let tip = world.spawn(Transform::from_xyz(0.0, 2.0, 0.0)).id();
        world.spawn((
            Mesh3d(mesh),
            Transform::from_xyz(5.0, 0.0, 0.0), // ignored by skinning, as in Bevy
            InheritedVisibility::VISIBLE,
            SkinnedMesh { inverse_bindposes: bindposes, joints: vec![root, tip] },
        ));
        app.update();
        let top = |app: &App| {
            let s = app.world().resource::<SceneSnapshot>();
            s.triangles().flat_map(|(_, t)| t).fold(f32::NEG_INFINITY, |m, p| m.max(p.y))
        };
        assert!((top(&app) - 2.0).abs() < 1e-5, "bind pose: top at {}", top(&app));
        // Raise the tip joint by a metre: the top edge follows, the bottom stays.
        app.world_mut().get_mut::<Transform>(tip).unwrap().translation.y = 3.0;
        app.update();
        assert!((top(&app) - 3.0).abs() < 1e-5, "posed: top at {}", top(&app));
        let s = app.world().resource::<SceneSnapshot>();
        let bottom = s.triangles().flat_map(|(_, t)| t).fold(f32::INFINITY, |m, p| m.min(p.y));
        assert!(bottom.abs() < 1e-5);
        assert_eq!(s.triangle_count(), 2);
    }
}
