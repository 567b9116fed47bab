//! A CPU snapshot of the world: triangles, diffuse colours, emission, lights and a BVH.
//!
//! The path tracer ([`crate::reference`]) and, later, the VPL random walks and the radiosity solver work on
//! this snapshot rather than on Bevy's render world, so that every method and the ground truth see *the same
//! scene*: the meshes with their transforms, each [`StandardMaterial`](bevy::pbr::StandardMaterial)'s diffuse
//! colour (`base_color × (1 − metallic)`, with the base-colour and metallic-roughness textures through the
//! UV channel and `uv_transform` Bevy uses), its emission, and the directional, point and spot lights in
//! Bevy's units.
//!
//! # Cost
//! [`SceneSnapshotPlugin`] keeps the [`SceneSnapshot`] resource current. Nothing is done unless that resource
//! exists (insert it, or let a method that needs it insert it). A change costs what changed:
//!
//! * Each mesh asset's triangles and BVH are built once, in local space ([`MeshGeometry`]), and shared by
//!   every entity that shows the mesh. A moved entity only replaces its [`SnapshotInstance`]'s transform;
//!   [`SceneSnapshot::commit`] then rebuilds the top-level BVH over instance bounds, O(instances). Skinned
//!   meshes are re-posed (O(their vertices)) in frames where one of their joints moved.
//! * Materials and textures are re-read only when their asset changes; a texture that loads after its
//!   material gets a white placeholder first and its texels when it arrives.
//! * Lights are re-read only when a light changed.
//!
//! Each commit bumps [`SceneSnapshot::geometry_generation`] and records [`SceneSnapshot::last_change`]: the
//! world-space boxes that changed and whether global triangle indices moved
//! ([`SceneSnapshot::layout_generation`]). Consumers one generation behind update only what those boxes
//! touch (RSM faces and vertex ranges, voxels, ISM points); others rebuild. [`SnapshotTimings`] reports the
//! main-thread milliseconds of the last update (measured in `docs/dynamic.md`: a 1 280-triangle mesh moving
//! in a 500 k-triangle scene costs a fraction of a millisecond and does not grow with the scene).
//!
//! # Data layout
//! Per mesh, triangles are stored in BVH order (obvhs' CWBVH, an 8-wide compressed BVH built with PLOC),
//! with a parallel array of [`TriangleAttributes`], in the mesh's local space. Rays are transformed into each
//! instance's space during the top-level traversal. Global triangle indices run instance by instance
//! (instances sorted by key, the entity's bits); [`SceneSnapshot::triangle`] and
//! [`SceneSnapshot::attributes`] return world-space data, in metres.
//!
//! # Known issues
//! Morph targets are not applied (a morphed mesh is in its base shape); block-compressed textures cannot be
//! read on the CPU and are white; alpha-blended materials are opaque to rays.

pub mod changes;
pub mod environment;
pub(crate) mod extract;

use std::sync::Arc;

use bevy::math::{Affine3A, Mat3, Vec2, Vec3};
use bevy::prelude::{Entity, Resource};
use obvhs::{
    BvhBuildParams,
    aabb::Aabb,
    cwbvh::{CwBvh, builder::{build_cwbvh, build_cwbvh_from_tris}},
    ray::{Ray, RayHit},
    triangle::Triangle as BvhTriangle,
};
use obvhs_glam::Vec3A;

pub use environment::Environment;
pub use extract::{SceneSnapshotPlugin, SceneSnapshotSystems, SnapshotTimings, mesh_local_triangles, mesh_triangles, skinned_triangles};


/// Per-triangle data the BVH does not hold, in world space (see [`SceneSnapshot::attributes`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleAttributes {
    /// Index into [`SceneSnapshot::materials`].
    pub material: u32,
    /// Unit geometric normal, `(v1 − v0) × (v2 − v0)` normalised (counter-clockwise front face).
    pub geometric_normal: Vec3,
    /// Vertex normals in world space (unit length), or the geometric normal three times.
    pub normals: [Vec3; 3],
    /// Texture coordinates of UV channel 0, or zero when the mesh has none.
    pub uvs: [Vec2; 3],
    /// Texture coordinates of UV channel 1 (`Mesh::ATTRIBUTE_UV_1`), or channel 0 when the mesh has none.
    pub uvs_1: [Vec2; 3],
    /// Area in m².
    pub area: f32,
}

/// The diffuse part of a material, as the GI methods and the tracer see it.
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotMaterial {
    /// Linear diffuse reflectance: `base_color × (1 − metallic) × (1 − transmission)`.
    pub diffuse: Vec3,
    /// Emitted radiance in cd/m² (before exposure), already divided by the exposure where Bevy's
    /// `emissive.alpha` asks for exposure-independent emission (see [`SnapshotMaterial::emission`]).
    pub emissive: Vec3,
    /// `emissive.alpha` of the [`StandardMaterial`](bevy::pbr::StandardMaterial): 1 = physical emission,
    /// 0 = the displayed value ignores exposure.
    pub emissive_exposure_weight: f32,
    /// The base-colour texture (multiplies `diffuse`, and its alpha the opacity).
    pub base_color_texture: Option<TextureRef>,
    /// The metallic-roughness texture (metallic in its blue channel), with the material's metallic factor
    /// and its diffuse colour before metallic (`base_color × (1 − transmission)`): where present, the diffuse
    /// reflectance is `base × texture_rgb × (1 − metallic × metallic_texture.b)` instead of `diffuse × texture`.
    pub metallic_texture: Option<MetallicTexture>,
    /// `AlphaMode::Mask(cutoff)`: surfaces whose opacity (`base_color.a × texture.a`) is below the cutoff let
    /// rays through, as Bevy discards those fragments. `None` for every other alpha mode (treated as opaque).
    pub alpha_cutoff: Option<f32>,
    /// `base_color.a` of the material (only read with `alpha_cutoff`).
    pub base_alpha: f32,
    /// Perceptual roughness in `[0, 1]`; only the Burley model of Bevy's direct light uses it.
    pub perceptual_roughness: f32,
    /// Which face Bevy's rasteriser culls (the material's `cull_mode`). Camera rays of the tracer skip
    /// culled faces, so the tracer sees what the game shows; light transport treats every surface as
    /// two-sided, as physical surfaces are.
    pub culled_face: CulledFace,
}

/// The face a material's rasteriser culls, by winding (counter-clockwise = front).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CulledFace {
    #[default]
    None,
    Back,
    Front,
}

impl SnapshotMaterial {
    /// A grey Lambertian material, used for meshes without a `StandardMaterial`.
    pub const DEFAULT_GREY: Self = Self {
        diffuse: Vec3::splat(0.5),
        emissive: Vec3::ZERO,
        emissive_exposure_weight: 1.0,
        base_color_texture: None,
        metallic_texture: None,
        alpha_cutoff: None,
        base_alpha: 1.0,
        perceptual_roughness: 1.0,
        culled_face: CulledFace::None,
    };

    /// Emitted radiance in cd/m² for a camera with exposure multiplier `exposure`, matching Bevy's
    /// `emissive.rgb * mix(1, exposure, emissive.a)` once the tracer multiplies everything by `exposure`.
    pub fn emission(&self, exposure: f32) -> Vec3 {
        let w = self.emissive_exposure_weight;
        let scale = w + (1.0 - w) / exposure.max(f32::MIN_POSITIVE);
        self.emissive * scale
    }
}

/// How a material reads one of its textures: which texture, through which UV channel and with which
/// `uv_transform` (`KHR_texture_transform`, applied as Bevy's `StandardMaterial::uv_transform`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`SceneSnapshot::textures`].
    pub texture: u32,
    /// 0 for `ATTRIBUTE_UV_0`, 1 for `ATTRIBUTE_UV_1`.
    pub channel: u8,
    pub uv_transform: bevy::math::Affine2,
}

impl TextureRef {
    /// The texture's UVs of triangle `attributes` at barycentrics `(u, v)` of vertices 1 and 2.
    pub fn uv(&self, attributes: &TriangleAttributes, u: f32, v: f32) -> Vec2 {
        let uvs = if self.channel == 1 { &attributes.uvs_1 } else { &attributes.uvs };
        let uv = uvs[0] * (1.0 - u - v) + uvs[1] * u + uvs[2] * v;
        self.uv_transform.transform_point2(uv)
    }
}

/// See [`SnapshotMaterial::metallic_texture`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetallicTexture {
    pub texture: TextureRef,
    pub metallic: f32,
    pub base: Vec3,
}

impl SnapshotMaterial {
    /// Diffuse reflectance and opacity at barycentrics `(u, v)` of a triangle with this material.
    pub fn diffuse_at(&self, textures: &[SnapshotTexture], attributes: &TriangleAttributes, u: f32, v: f32) -> Vec3 {
        let sample = |r: &TextureRef| textures.get(r.texture as usize).map(|t| t.sample(r.uv(attributes, u, v)));
        let base_texel = self.base_color_texture.as_ref().and_then(sample).map_or(Vec3::ONE, |t| t.truncate());
        match &self.metallic_texture {
            Some(m) => {
                let metal = sample(&m.texture).map_or(1.0, |t| t.z) * m.metallic;
                m.base * base_texel * (1.0 - metal).clamp(0.0, 1.0)
            }
            None => self.diffuse * base_texel,
        }
    }

    /// Whether rays pass through this material at barycentrics `(u, v)` (an alpha-masked cut-out).
    pub fn cut_out(&self, textures: &[SnapshotTexture], attributes: &TriangleAttributes, u: f32, v: f32) -> bool {
        let Some(cutoff) = self.alpha_cutoff else {
            return false;
        };
        let alpha = self
            .base_color_texture
            .as_ref()
            .and_then(|r| textures.get(r.texture as usize).map(|t| t.sample(r.uv(attributes, u, v)).w))
            .unwrap_or(1.0);
        self.base_alpha * alpha < cutoff
    }
}

/// A linear RGBA texture, sampled bilinearly with repeat wrapping.
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotTexture {
    pub width: u32,
    pub height: u32,
    /// Linear RGB texels with alpha, row-major; shared, so that copying the snapshot for a background
    /// task copies no texels.
    pub texels: Arc<[bevy::math::Vec4]>,
}

impl SnapshotTexture {
    /// A 1×1 white texture: the placeholder for an image not loaded (or not readable) yet.
    pub fn white() -> Self {
        Self { width: 1, height: 1, texels: Arc::new([bevy::math::Vec4::ONE]) }
    }

    /// Bilinear sample at `uv` with repeat wrapping (glTF's default sampler).
    pub fn sample(&self, uv: Vec2) -> bevy::math::Vec4 {
        if self.texels.is_empty() {
            return bevy::math::Vec4::ONE;
        }
        let (w, h) = (self.width as i64, self.height as i64);
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let texel = |xi: i64, yi: i64| {
            let xi = xi.rem_euclid(w) as usize;
            let yi = yi.rem_euclid(h) as usize;
            self.texels[yi * self.width as usize + xi]
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        let top = texel(x0, y0).lerp(texel(x0 + 1, y0), fx);
        let bottom = texel(x0, y0 + 1).lerp(texel(x0 + 1, y0 + 1), fx);
        top.lerp(bottom, fy)
    }
}

/// A light, in Bevy's units, with Bevy's falloff.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SnapshotLight {
    /// Illuminance `color × illuminance` in lux on a surface facing the light.
    Directional {
        /// Unit direction the light travels in (Bevy's `Transform::forward()`).
        direction: Vec3,
        illuminance: Vec3,
    },
    /// Luminous intensity `color × lumens / 4π` in candela, with Bevy's smooth range window.
    Point {
        position: Vec3,
        intensity: Vec3,
        /// `1 / range²`.
        inverse_range_squared: f32,
    },
    /// A point light limited to a cone, with Bevy's cone falloff
    /// `saturate(cos_angle · spot_scale + spot_offset)²`.
    Spot {
        position: Vec3,
        /// Unit direction of the cone axis.
        direction: Vec3,
        intensity: Vec3,
        inverse_range_squared: f32,
        /// `1 / max(cos(inner) − cos(outer), 1e-4)`.
        spot_scale: f32,
        /// `−cos(outer) · spot_scale`.
        spot_offset: f32,
    },
}

/// Bevy's range window: `saturate(1 − (d²/r²)²)²` (`getRangeFalloff` in `pbr_lighting.wgsl`).
#[inline]
pub fn range_falloff(distance_squared: f32, inverse_range_squared: f32) -> f32 {
    let factor = distance_squared * inverse_range_squared;
    let smooth = (1.0 - factor * factor).clamp(0.0, 1.0);
    smooth * smooth
}

impl SnapshotLight {
    /// Bevy's spot cone parameters for inner and outer half-angles in radians.
    pub fn spot_scale_offset(inner_angle: f32, outer_angle: f32) -> (f32, f32) {
        let cos_outer = outer_angle.cos();
        let scale = 1.0 / (inner_angle.cos() - cos_outer).max(1e-4);
        (scale, -cos_outer * scale)
    }

    /// For a shading point `p`: the unit direction towards the light, the distance to it (infinite for a
    /// directional light) and the irradiance it delivers on a surface facing it, in lux (before the
    /// cosine at the receiver and before visibility).
    pub fn incident(&self, p: Vec3) -> Option<(Vec3, f32, Vec3)> {
        match *self {
            SnapshotLight::Directional { direction, illuminance } => {
                Some((-direction, f32::INFINITY, illuminance))
            }
            SnapshotLight::Point { position, intensity, inverse_range_squared } => {
                let to_light = position - p;
                let d2 = to_light.length_squared();
                if d2 <= 0.0 || !d2.is_finite() {
                    return None;
                }
                let d = d2.sqrt();
                let e = intensity * range_falloff(d2, inverse_range_squared) / d2.max(1e-4);
                Some((to_light / d, d, e))
            }
            SnapshotLight::Spot {
                position,
                direction,
                intensity,
                inverse_range_squared,
                spot_scale,
                spot_offset,
            } => {
                let to_light = position - p;
                let d2 = to_light.length_squared();
                if d2 <= 0.0 || !d2.is_finite() {
                    return None;
                }
                let d = d2.sqrt();
                let l = to_light / d;
                let cd = (-l).dot(direction);
                let cone = (cd * spot_scale + spot_offset).clamp(0.0, 1.0);
                let cone = cone * cone;
                if cone <= 0.0 {
                    return None;
                }
                let e = intensity * cone * range_falloff(d2, inverse_range_squared) / d2.max(1e-4);
                Some((l, d, e))
            }
        }
    }
}

/// A light with the entity it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnapshotLightEntry {
    pub entity: Entity,
    pub light: SnapshotLight,
    /// Whether Bevy renders a shadow map for it. The tracer always tests visibility (it is the ground
    /// truth); this is kept so that reports can flag lights that leak in Bevy's own direct lighting.
    pub shadows_enabled: bool,
}

/// A ray hit against the snapshot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneHit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Index into [`SceneSnapshot::attributes`] (BVH order).
    pub triangle: u32,
    /// Barycentric coordinates of the hit for vertices 1 and 2.
    pub barycentrics: Vec2,
}

/// Triangles of one mesh in its own (local) space with their BVH: the bottom level of the snapshot's
/// two-level BVH. Built once per mesh asset (and pose, for skinned meshes) and shared by every instance.
#[derive(Default)]
pub struct MeshGeometry {
    /// Triangles in BVH order.
    triangles: Vec<BvhTriangle>,
    /// Attributes of `triangles` in local space (material unused), same order.
    attributes: Vec<TriangleAttributes>,
    bvh: Option<CwBvh>,
    bounds: Option<(Vec3, Vec3)>,
    /// [`MeshGeometry::open_sides`] of every triangle, made on first use.
    open_sides: std::sync::OnceLock<Vec<u8>>,
}

impl std::fmt::Debug for MeshGeometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshGeometry").field("triangles", &self.triangles.len()).finish()
    }
}

impl MeshGeometry {
    /// Builds the geometry from local-space triangles (their `material` is ignored). Degenerate triangles
    /// (zero area or non-finite vertices) are dropped.
    pub fn new(triangles: impl IntoIterator<Item = InputTriangle>) -> Self {
        let mut tris = Vec::new();
        let mut attributes = Vec::new();
        for t in triangles {
            let [a, b, c] = t.positions;
            if !(a.is_finite() && b.is_finite() && c.is_finite()) {
                continue;
            }
            let cross = (b - a).cross(c - a);
            let area = 0.5 * cross.length();
            if area <= 1e-12 || !area.is_finite() {
                continue;
            }
            let n = cross.normalize();
            let normals = t
                .normals
                .filter(|ns| ns.iter().all(|v| v.is_finite() && v.length_squared() > 1e-12))
                .map(|ns| ns.map(Vec3::normalize))
                .unwrap_or([n; 3]);
            let uvs = t.uvs.unwrap_or([Vec2::ZERO; 3]);
            tris.push(BvhTriangle { v0: to_bvh(a), v1: to_bvh(b), v2: to_bvh(c) });
            attributes.push(TriangleAttributes {
                material: 0,
                geometric_normal: n,
                normals,
                uvs,
                uvs_1: t.uvs_1.unwrap_or(uvs),
                area,
            });
        }
        if tris.is_empty() {
            return Self::default();
        }
        let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Default::default());
        // Store triangles in BVH order so that leaves read contiguous memory.
        let triangles: Vec<BvhTriangle> = bvh.primitive_indices.iter().map(|&i| tris[i as usize]).collect();
        let attributes = bvh.primitive_indices.iter().map(|&i| attributes[i as usize]).collect();
        let mut bvh = bvh;
        bvh.primitive_indices = (0..triangles.len() as u32).collect();
        let mut points = triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]);
        let first = points.next().unwrap();
        let (lo, hi) = points.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v)));
        Self {
            triangles,
            attributes,
            bvh: Some(bvh),
            bounds: Some((from_bvh(lo), from_bvh(hi))),
            open_sides: Default::default(),
        }
    }

    /// Which faces of triangle `i` (BVH order) look into open space rather than into this closed mesh:
    /// [`OPEN_FRONT`] (the side its geometric normal points to) and [`OPEN_BACK`] bits. The inside faces of
    /// a closed box are not open: light they emit never leaves the box. A face is closed when most of five
    /// rays leaving it (along its normal and tilted 45° four ways) first meet the back of another triangle
    /// of the mesh; a single sheet, an open shell and a mesh with inverted winding keep both sides open.
    /// Computed for all triangles on the first call (ten rays each through the mesh's own BVH, spread over
    /// the cores) and kept: once per mesh asset, and only for meshes something asks about (emissive ones).
    pub fn open_sides(&self, i: usize) -> u8 {
        self.open_sides.get_or_init(|| self.find_open_sides()).get(i).copied().unwrap_or(OPEN_FRONT | OPEN_BACK)
    }

    fn find_open_sides(&self) -> Vec<u8> {
        let Some((bvh, (lo, hi))) = self.bvh.as_ref().zip(self.bounds) else {
            return Vec::new();
        };
        let epsilon = ((hi - lo).length() * 1e-4).max(1e-6);
        let back_hit = |origin: Vec3, direction: Vec3| {
            let ray = bvh_ray(origin, direction, 0.0, f32::INFINITY);
            let mut hit = RayHit::none();
            bvh.ray_traverse(ray, &mut hit, |r, id| intersect_triangle(&self.triangles[id], r).map_or(f32::INFINITY, |(t, _, _)| t))
                && self.attributes[hit.primitive_id as usize].geometric_normal.dot(direction) > 0.0
        };
        let tilt = std::f32::consts::FRAC_1_SQRT_2;
        use rayon::prelude::*;
        self.triangles
            .par_iter()
            .zip(&self.attributes)
            .map(|(t, a)| {
                let centre = from_bvh(t.v0 + t.v1 + t.v2) / 3.0;
                let n = a.geometric_normal;
                let (u, v) = n.any_orthonormal_pair();
                let mut open = 0;
                for (bit, side) in [(OPEN_FRONT, n), (OPEN_BACK, -n)] {
                    let origin = centre + side * epsilon;
                    let directions = [side, (side + u) * tilt, (side - u) * tilt, (side + v) * tilt, (side - v) * tilt];
                    let closed = directions.iter().filter(|&&d| back_hit(origin, d)).count();
                    if closed < 3 {
                        open |= bit;
                    }
                }
                open
            })
            .collect()
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Local-space bounds, `None` when empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }
}

/// [`MeshGeometry::open_sides`]: the front face (along the geometric normal) looks into open space.
pub const OPEN_FRONT: u8 = 1;
/// [`MeshGeometry::open_sides`]: the back face looks into open space.
pub const OPEN_BACK: u8 = 2;

/// One mesh entity in the snapshot: shared local geometry, a transform and a material.
#[derive(Clone, Debug)]
pub struct SnapshotInstance {
    /// Orders instances and identifies them across updates (the entity's bits for ECS meshes).
    pub key: u64,
    pub geometry: Arc<MeshGeometry>,
    pub material: u32,
    world_from_local: Affine3A,
    /// `world_from_local⁻¹` in obvhs' glam, for rays.
    local_from_world_bvh: obvhs_glam::Affine3A,
    normal_matrix: Mat3,
    /// A mirroring transform: world triangles swap vertices 1 and 2 to keep the front face in front.
    mirrored: bool,
    /// World-space bounds.
    pub bounds: (Vec3, Vec3),
    /// Global index of the instance's first triangle.
    first_triangle: u32,
    /// The [`SceneSnapshot::geometry_generation`] that last changed this instance.
    pub version: u64,
}

impl SnapshotInstance {
    /// `None` when the geometry is empty or the transform is not invertible.
    fn new(key: u64, geometry: Arc<MeshGeometry>, world_from_local: Affine3A, material: u32) -> Option<Self> {
        let (lo, hi) = geometry.bounds?;
        let det = world_from_local.matrix3.determinant();
        if !(det.is_finite() && det.abs() > 1e-18 && world_from_local.translation.is_finite()) {
            return None;
        }
        let local_from_world = world_from_local.inverse();
        let local_from_world_bvh = obvhs_glam::Affine3A::from_cols_array(&local_from_world.to_cols_array());
        let mut bounds = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for i in 0..8 {
            let corner = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let p = world_from_local.transform_point3(corner);
            bounds = (bounds.0.min(p), bounds.1.max(p));
        }
        Some(Self {
            key,
            normal_matrix: Mat3::from(world_from_local.matrix3).inverse().transpose(),
            mirrored: det < 0.0,
            geometry,
            material,
            world_from_local,
            local_from_world_bvh,
            bounds,
            first_triangle: 0,
            version: 0,
        })
    }

    pub fn world_from_local(&self) -> Affine3A {
        self.world_from_local
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.geometry.triangles.len()
    }

    /// World-space vertices of local triangle `i`.
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        let t = &self.geometry.triangles[i];
        let m = &self.world_from_local;
        let [a, b, c] = [t.v0, t.v1, t.v2].map(|v| m.transform_point3(from_bvh(v)));
        if self.mirrored { [a, c, b] } else { [a, b, c] }
    }

    /// World-space attributes of local triangle `i`. UVs and normals keep the local vertex order, which is
    /// the order of [`SceneHit::barycentrics`].
    pub fn attributes(&self, i: usize) -> TriangleAttributes {
        let a = &self.geometry.attributes[i];
        let (geometric_normal, normals) = self.world_normals(i);
        TriangleAttributes {
            material: self.material,
            geometric_normal,
            normals,
            uvs: a.uvs,
            uvs_1: a.uvs_1,
            area: triangle_area(&self.triangle(i)),
        }
    }

    /// [`MeshGeometry::open_sides`] of local triangle `i`; the front is the side of its world geometric
    /// normal ([`SnapshotInstance::triangle`]'s winding), mirrored or not.
    pub fn open_sides(&self, i: usize) -> u8 {
        self.geometry.open_sides(i)
    }

    /// World-space unit geometric and vertex normals of local triangle `i` (what a hit needs, without the
    /// vertices and area of [`SnapshotInstance::attributes`]).
    pub fn world_normals(&self, i: usize) -> (Vec3, [Vec3; 3]) {
        let a = &self.geometry.attributes[i];
        let n = |v: Vec3| (self.normal_matrix * v).try_normalize().unwrap_or(v);
        (n(a.geometric_normal), a.normals.map(n))
    }

    fn local_ray(&self, ray: &Ray) -> Ray {
        let origin = self.local_from_world_bvh.transform_point3a(ray.origin);
        let direction = self.local_from_world_bvh.transform_vector3a(ray.direction) + Vec3A::ZERO;
        Ray::new(origin, direction, ray.tmin, ray.tmax)
    }
}

/// Area of a triangle, m².
#[inline]
pub fn triangle_area([a, b, c]: &[Vec3; 3]) -> f32 {
    0.5 * (*b - *a).cross(*c - *a).length()
}

/// What the last [`SceneSnapshot::commit`] changed, for consumers that update incrementally.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeometryChange {
    /// World-space bounds of everything that changed: old and new bounds of moved, added, removed or
    /// re-materialed instances.
    pub dirty: Vec<(Vec3, Vec3)>,
    /// Whether instances were added or removed or changed their triangle count (global triangle indices
    /// moved), as opposed to moving or changing material in place.
    pub layout_changed: bool,
}

/// The CPU snapshot of the world. See the [module docs](self).
///
/// Cloning it is cheap (O(instances + materials + lights)): mesh geometry, texels and the environment
/// are shared behind `Arc`s. The CPU methods clone it to hand their background tasks a frozen copy of
/// the world ([`crate::background`]).
#[derive(Resource, Default, Clone)]
pub struct SceneSnapshot {
    /// Instances sorted by key.
    instances: Vec<SnapshotInstance>,
    /// Top level of the two-level BVH, over instance bounds.
    tlas: Option<CwBvh>,
    pub materials: Vec<SnapshotMaterial>,
    pub textures: Vec<SnapshotTexture>,
    pub lights: Vec<SnapshotLightEntry>,
    bounds: Option<(Vec3, Vec3)>,
    triangle_count: usize,
    /// Changes since the last commit.
    pending: GeometryChange,
    pending_any: bool,
    /// What the last commit changed (from `geometry_generation − 1` to `geometry_generation`).
    pub last_change: GeometryChange,
    /// Bumped every time the triangles or materials change.
    pub geometry_generation: u64,
    /// Bumped whenever the global triangle indices change (instances added, removed or resized).
    pub layout_generation: u64,
    /// Bumped every time the lights are re-read.
    pub light_generation: u64,
    /// The environment light of the first active GI camera with a readable `EnvironmentMapLight`
    /// ([`Environment`]); `None` for none. Escaping paths of the tracer and radiosity's empty bins see it.
    pub environment: Option<Arc<Environment>>,
    /// Bumped every time [`environment`](Self::environment) changes.
    pub environment_generation: u64,
}

/// Below this many instances the top-level BVH is built without obvhs' reinsertion pass, so that the
/// build never leaves the calling thread.
///
/// The top level is rebuilt on the main thread by every [`SceneSnapshot::commit`] that moved an
/// instance. obvhs' reinsertion pass runs on rayon's global pool whatever the input's size, and called
/// from the main thread each of its parallel loops waits until a pool thread is scheduled: measured in
/// `dynamic` with one mesh moving, a commit of 12 instances took 1.2–7.7 ms while the photon grid's or the
/// VPLs' background work kept both cores busy (and microseconds without it), the worst main-thread
/// frames of those methods. Below 2 000 instances the rest of the build (PLOC, the sort: rayon joins only
/// above 2 000 elements) runs on the calling thread, and a top level that small gains little from
/// reinsertion.
const TLAS_SEQUENTIAL_BELOW: usize = 2000;

/// obvhs' build parameters for a top level over `instances` instances ([`TLAS_SEQUENTIAL_BELOW`]).
fn tlas_build_params(instances: usize) -> BvhBuildParams {
    let medium = BvhBuildParams::medium_build();
    if instances < TLAS_SEQUENTIAL_BELOW {
        BvhBuildParams { reinsertion_batch_ratio: 0.0, post_collapse_reinsertion_batch_ratio_multiplier: 0.0, ..medium }
    } else {
        medium
    }
}

/// A triangle given to [`SceneSnapshot::build`] (world space) or [`MeshGeometry::new`] (local space).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputTriangle {
    pub positions: [Vec3; 3],
    /// Vertex normals; `None` uses the geometric normal.
    pub normals: Option<[Vec3; 3]>,
    pub uvs: Option<[Vec2; 3]>,
    /// UV channel 1; `None` uses channel 0.
    pub uvs_1: Option<[Vec2; 3]>,
    pub material: u32,
}

impl InputTriangle {
    /// A flat triangle without UVs.
    pub fn flat(positions: [Vec3; 3], material: u32) -> Self {
        Self { positions, normals: None, uvs: None, uvs_1: None, material }
    }
}

impl std::fmt::Debug for SceneSnapshot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneSnapshot")
            .field("instances", &self.instances.len())
            .field("triangles", &self.triangle_count)
            .field("materials", &self.materials.len())
            .field("textures", &self.textures.len())
            .field("lights", &self.lights)
            .field("geometry_generation", &self.geometry_generation)
            .field("light_generation", &self.light_generation)
            .field("environment", &self.environment.as_ref().map(|e| e.face_size()))
            .finish()
    }
}

fn to_bvh(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

fn from_bvh(v: Vec3A) -> Vec3 {
    Vec3::new(v.x, v.y, v.z)
}

/// A ray for obvhs. Adding `+0.0` turns `−0.0` components into `+0.0`: obvhs takes the sign of a zero
/// direction component from `signum` (negative for `−0.0`) in one place and from a comparison in another,
/// and axis-aligned rays with negative zeros then miss everything.
fn bvh_ray(origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Ray {
    Ray::new(to_bvh(origin), to_bvh(direction + Vec3::ZERO), t_min, t_max)
}

/// Möller–Trumbore ray/triangle intersection returning `(t, u, v)` with `u`, `v` the barycentrics of
/// vertices 1 and 2. Edges are inclusive (`−0.0` counts as inside), so a ray through the edge shared by two
/// triangles hits at least one of them; obvhs' own test rejects `−0.0` and lets such rays through.
#[inline(always)]
fn intersect_triangle(tri: &BvhTriangle, ray: &Ray) -> Option<(f32, f32, f32)> {
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let p = ray.direction.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = ray.origin - tri.v0;
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.direction.dot(q) * inv_det;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = e2.dot(q) * inv_det;
    (t >= ray.tmin && t <= ray.tmax).then_some((t, u, v))
}

/// Which faces a traversal ignores.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Faces {
    /// Light transport: every surface is two-sided.
    All,
    /// Camera rays: skip what the rasteriser culls.
    Visible,
}

impl SceneSnapshot {
    /// Builds a snapshot from world-space triangles, materials and lights (one instance with an identity
    /// transform per material index in use). Degenerate triangles (zero area or non-finite vertices) are
    /// dropped; material indices out of range use the last material, or [`SnapshotMaterial::DEFAULT_GREY`]
    /// when there is none.
    pub fn build(
        triangles: impl IntoIterator<Item = InputTriangle>,
        materials: Vec<SnapshotMaterial>,
        textures: Vec<SnapshotTexture>,
        lights: Vec<SnapshotLightEntry>,
    ) -> Self {
        let mut snapshot = Self { lights, textures, ..Self::default() };
        snapshot.set_geometry(triangles, materials);
        snapshot
    }

    /// Replaces the geometry and materials with world-space triangles: one identity-transform instance
    /// per material (keys are the material indices).
    pub fn set_geometry(&mut self, triangles: impl IntoIterator<Item = InputTriangle>, mut materials: Vec<SnapshotMaterial>) {
        if materials.is_empty() {
            materials.push(SnapshotMaterial::DEFAULT_GREY);
        }
        let last = materials.len() as u32 - 1;
        let mut by_material: std::collections::BTreeMap<u32, Vec<InputTriangle>> = Default::default();
        for t in triangles {
            by_material.entry(t.material.min(last)).or_default().push(t);
        }
        for key in self.instances.iter().map(|i| i.key).collect::<Vec<_>>() {
            self.remove_instance(key);
        }
        self.materials = materials;
        for (material, tris) in by_material {
            let geometry = Arc::new(MeshGeometry::new(tris));
            self.set_instance(material as u64, geometry, Affine3A::IDENTITY, material);
        }
        self.commit();
    }

    /// Adds the instance `key`, or replaces its geometry, transform and material. Takes effect at the next
    /// [`SceneSnapshot::commit`]. Empty geometry or a singular transform removes the instance.
    pub fn set_instance(&mut self, key: u64, geometry: Arc<MeshGeometry>, world_from_local: Affine3A, material: u32) {
        let material = material.min(self.materials.len().max(1) as u32 - 1);
        let Some(mut instance) = SnapshotInstance::new(key, geometry, world_from_local, material) else {
            self.remove_instance(key);
            return;
        };
        self.pending_any = true;
        instance.version = self.geometry_generation + 1;
        self.pending.dirty.push(instance.bounds);
        match self.instances.binary_search_by_key(&key, |i| i.key) {
            Ok(i) => {
                let old = &self.instances[i];
                self.pending.dirty.push(old.bounds);
                if old.triangle_count() != instance.triangle_count() {
                    self.pending.layout_changed = true;
                }
                self.instances[i] = instance;
            }
            Err(i) => {
                self.pending.layout_changed = true;
                self.instances.insert(i, instance);
            }
        }
    }

    /// Moves instance `key` (no-op when absent or unchanged).
    pub fn set_instance_transform(&mut self, key: u64, world_from_local: Affine3A) {
        let Some(i) = self.instance_index(key) else {
            return;
        };
        let old = &self.instances[i];
        if old.world_from_local == world_from_local {
            return;
        }
        let (geometry, material) = (old.geometry.clone(), old.material);
        self.set_instance(key, geometry, world_from_local, material);
    }

    /// Marks instance `key` changed in place (its material's contents changed).
    pub fn touch_instance(&mut self, key: u64) {
        if let Some(i) = self.instance_index(key) {
            self.pending_any = true;
            self.pending.dirty.push(self.instances[i].bounds);
            self.instances[i].version = self.geometry_generation + 1;
        }
    }

    /// Marks the whole snapshot changed at the next commit (consumers rebuild everything).
    pub fn touch_all(&mut self) {
        self.pending_any = true;
        self.pending.layout_changed = true;
        if let Some(b) = self.bounds {
            self.pending.dirty.push(b);
        }
    }

    /// Removes instance `key` at the next commit (no-op when absent).
    pub fn remove_instance(&mut self, key: u64) {
        if let Some(i) = self.instance_index(key) {
            let old = self.instances.remove(i);
            self.pending.dirty.push(old.bounds);
            self.pending.layout_changed = true;
            self.pending_any = true;
        }
    }

    fn instance_index(&self, key: u64) -> Option<usize> {
        self.instances.binary_search_by_key(&key, |i| i.key).ok()
    }

    /// The instance `key`, if present.
    pub fn instance(&self, key: u64) -> Option<&SnapshotInstance> {
        self.instance_index(key).map(|i| &self.instances[i])
    }

    /// Every instance, by key.
    pub fn instances(&self) -> &[SnapshotInstance] {
        &self.instances
    }

    /// Whether changes wait for [`SceneSnapshot::commit`].
    pub fn has_pending_changes(&self) -> bool {
        self.pending_any
    }

    /// Applies the pending instance changes: rebuilds the top-level BVH over instance bounds (the meshes'
    /// own BVHs are kept), bumps [`SceneSnapshot::geometry_generation`] and records
    /// [`SceneSnapshot::last_change`]. Costs O(instances · log instances); does nothing without changes.
    pub fn commit(&mut self) {
        if !self.pending_any {
            return;
        }
        self.pending_any = false;
        self.last_change = std::mem::take(&mut self.pending);
        self.geometry_generation += 1;
        if self.last_change.layout_changed {
            self.layout_generation += 1;
        }
        let mut first = 0u32;
        for instance in &mut self.instances {
            instance.first_triangle = first;
            first += instance.triangle_count() as u32;
        }
        self.triangle_count = first as usize;
        self.bounds = self
            .instances
            .iter()
            .map(|i| i.bounds)
            .reduce(|(lo, hi), (l, h)| (lo.min(l), hi.max(h)));
        self.tlas = (!self.instances.is_empty()).then(|| {
            let boxes: Vec<Aabb> = self
                .instances
                .iter()
                .map(|i| {
                    // A little padding keeps flat instances (a single wall) from slipping through.
                    let pad = ((i.bounds.1 - i.bounds.0).max_element() * 1e-5).max(1e-6);
                    Aabb::new(to_bvh(i.bounds.0 - pad), to_bvh(i.bounds.1 + pad))
                })
                .collect();
            build_cwbvh(&boxes, tlas_build_params(boxes.len()), &mut Default::default())
        });
        if self.materials.is_empty() {
            self.materials.push(SnapshotMaterial::DEFAULT_GREY);
        }
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangle_count
    }

    /// The instance holding global triangle `i` and the triangle's index inside it.
    pub fn locate(&self, i: u32) -> (&SnapshotInstance, usize) {
        let k = self.instances.partition_point(|inst| inst.first_triangle <= i) - 1;
        let instance = &self.instances[k];
        (instance, (i - instance.first_triangle) as usize)
    }

    /// World-space vertices of global triangle `i`.
    pub fn triangle(&self, i: u32) -> [Vec3; 3] {
        let (instance, local) = self.locate(i);
        instance.triangle(local)
    }

    /// World-space attributes of global triangle `i`.
    pub fn attributes(&self, i: u32) -> TriangleAttributes {
        let (instance, local) = self.locate(i);
        instance.attributes(local)
    }

    /// World-space unit geometric normal of global triangle `i`.
    pub fn geometric_normal(&self, i: u32) -> Vec3 {
        let (instance, local) = self.locate(i);
        instance.world_normals(local).0
    }

    /// Every triangle's global index, world vertices and material, instance by instance.
    pub fn triangles(&self) -> impl Iterator<Item = (u32, [Vec3; 3])> + '_ {
        self.instances.iter().flat_map(|inst| {
            (0..inst.triangle_count()).map(move |k| (inst.first_triangle + k as u32, inst.triangle(k)))
        })
    }

    /// The mean distance between the surfaces in the box `lo..hi`: the mean length of `rays`
    /// cosine-distributed rays, from points spread by area over the surfaces that overlap the box (on
    /// both sides), to the next surface; rays that leave the scene do not count. For a closed convex room
    /// it is Cauchy's mean chord `4V/A`; furniture, columns and walls between rooms shorten it. A length
    /// of the geometry's own: it scales with the scene, whatever its units. `None` without surfaces there,
    /// or when every ray leaves. O(triangles in the box + rays · log triangles); the same answer for the
    /// same scene (a fixed quasi-random sequence).
    pub fn mean_chord(&self, lo: Vec3, hi: Vec3, rays: u32) -> Option<f32> {
        let triangles: Vec<[Vec3; 3]> = self.triangles_overlapping(lo, hi).map(|(_, t)| t).collect();
        let mut cdf = Vec::with_capacity(triangles.len());
        let mut total = 0.0f64;
        for t in &triangles {
            total += triangle_area(t).max(0.0) as f64;
            cdf.push(total);
        }
        if triangles.is_empty() || total.is_nan() || total <= 0.0 || rays == 0 {
            return None;
        }
        let stream = crate::sampling::SobolStream::new(0xC0DE, 0x0C4D);
        let epsilon = self.ray_epsilon();
        let (mut sum, mut hits) = (0.0f64, 0u32);
        for i in 0..rays {
            let u = stream.vertex_4d(i, 0);
            let target = (i as f64 + 0.5) / rays as f64 * total;
            let [a, b, c] = triangles[cdf.partition_point(|x| *x < target).min(triangles.len() - 1)];
            let Vec2 { x: s, y: r } = crate::sampling::uniform_triangle(Vec2::new(u[0], u[1]));
            let side = if u[2] < 0.5 { 1.0 } else { -1.0 };
            let n = (b - a).cross(c - a).normalize_or_zero() * side;
            if n == Vec3::ZERO {
                continue;
            }
            let v = stream.vertex_4d(i, 1);
            let direction = crate::sampling::cosine_hemisphere(n, Vec2::new(v[0], v[1]));
            if let Some(hit) = self.intersect(a + (b - a) * s + (c - a) * r + n * epsilon, direction, 0.0, f32::INFINITY) {
                sum += hit.t as f64;
                hits += 1;
            }
        }
        (hits > 0).then(|| (sum / hits as f64) as f32)
    }

    /// Global indices and world vertices of the triangles whose bounds overlap the box `lo..hi`.
    pub fn triangles_overlapping(&self, lo: Vec3, hi: Vec3) -> impl Iterator<Item = (u32, [Vec3; 3])> + '_ {
        self.instances
            .iter()
            .filter(move |inst| inst.bounds.0.cmple(hi).all() && inst.bounds.1.cmpge(lo).all())
            .flat_map(move |inst| {
                (0..inst.triangle_count()).filter_map(move |k| {
                    let t = inst.triangle(k);
                    let (tl, th) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
                    (tl.cmple(hi).all() && th.cmpge(lo).all()).then_some((inst.first_triangle + k as u32, t))
                })
            })
    }

    /// Global index range of the instance `key`'s triangles.
    pub fn instance_triangles(&self, key: u64) -> Option<std::ops::Range<u32>> {
        let inst = self.instance(key)?;
        Some(inst.first_triangle..inst.first_triangle + inst.triangle_count() as u32)
    }

    /// The axis-aligned bounds of all triangles, or `None` for an empty scene.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// How far a ray leaving a surface starts from it: 10⁻⁴ of the scene's diagonal (at least 10⁻⁶ m;
    /// 10⁻⁴ m for an empty scene), so that rays do not hit the surface they leave at any scale.
    pub fn ray_epsilon(&self) -> f32 {
        self.bounds.map_or(1e-4, |(lo, hi)| ((hi - lo).length() * 1e-4).max(1e-6))
    }

    /// Closest hit over the two-level BVH.
    fn traverse(&self, ray: Ray, faces: Faces) -> Option<SceneHit> {
        let tlas = self.tlas.as_ref()?;
        let mut hit = RayHit::none();
        let mut best: Option<(usize, u32, f32, f32)> = None;
        tlas.ray_traverse(ray, &mut hit, |ray, id| {
            let k = tlas.primitive_indices[id] as usize;
            let inst = &self.instances[k];
            let Some(bvh) = inst.geometry.bvh.as_ref() else {
                return f32::INFINITY;
            };
            let local = inst.local_ray(ray);
            let material = &self.materials[inst.material as usize];
            let culled = faces == Faces::Visible && material.culled_face != CulledFace::None;
            let masked = material.alpha_cutoff.is_some();
            let mut local_hit = RayHit::none();
            let mut uv = (0.0, 0.0);
            let found = bvh.ray_traverse(local, &mut local_hit, |r, id| {
                let Some((t, u, v)) = intersect_triangle(&inst.geometry.triangles[id], r) else {
                    return f32::INFINITY;
                };
                if culled {
                    let facing = inst.geometry.attributes[id].geometric_normal.dot(from_bvh(r.direction));
                    let skip = match material.culled_face {
                        CulledFace::Back => facing > 0.0,
                        CulledFace::Front => facing < 0.0,
                        CulledFace::None => false,
                    };
                    if skip {
                        return f32::INFINITY;
                    }
                }
                if masked && material.cut_out(&self.textures, &inst.geometry.attributes[id], u, v) {
                    return f32::INFINITY;
                }
                if t < r.tmax {
                    uv = (u, v);
                }
                t
            });
            if found {
                best = Some((k, local_hit.primitive_id, uv.0, uv.1));
                local_hit.t
            } else {
                f32::INFINITY
            }
        });
        let (k, local, u, v) = best?;
        Some(SceneHit {
            t: hit.t,
            triangle: self.instances[k].first_triangle + local,
            barycentrics: Vec2::new(u, v),
        })
    }

    /// The closest hit along `origin + t · direction` for `t ∈ [t_min, t_max]`. `direction` must be unit
    /// length for `t` to be a distance.
    pub fn intersect(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Option<SceneHit> {
        self.traverse(bvh_ray(origin, direction, t_min, t_max), Faces::All)
    }

    /// Like [`SceneSnapshot::intersect`], but skipping faces the rasteriser culls (see
    /// [`SnapshotMaterial::culled_face`]): what a camera ray sees in Bevy.
    pub fn intersect_visible(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Option<SceneHit> {
        self.traverse(bvh_ray(origin, direction, t_min, t_max), Faces::Visible)
    }

    /// Whether anything blocks the open segment `origin + t · direction`, `t ∈ (t_min, t_max)`.
    pub fn occluded(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> bool {
        let Some(tlas) = self.tlas.as_ref() else {
            return false;
        };
        // Written so that NaN bounds are rejected too.
        if t_max.partial_cmp(&t_min) != Some(std::cmp::Ordering::Greater) {
            return false;
        }
        let ray = bvh_ray(origin, direction, t_min, t_max);
        !tlas.ray_traverse_miss(ray, |ray, id| {
            let inst = &self.instances[tlas.primitive_indices[id] as usize];
            let Some(bvh) = inst.geometry.bvh.as_ref() else {
                return f32::INFINITY;
            };
            let material = &self.materials[inst.material as usize];
            let masked = material.alpha_cutoff.is_some();
            let blocked = !bvh.ray_traverse_miss(inst.local_ray(ray), |r, id| match intersect_triangle(&inst.geometry.triangles[id], r) {
                Some((_, u, v)) if masked && material.cut_out(&self.textures, &inst.geometry.attributes[id], u, v) => f32::INFINITY,
                Some((t, _, _)) => t,
                None => f32::INFINITY,
            });
            if blocked { ray.tmin } else { f32::INFINITY }
        })
    }

    /// The mean diffuse albedo of triangle `i`: its material's diffuse reflectance at the corners, edge
    /// midpoints and centroid. The GI methods' low-frequency inputs (RSM albedo, albedo volumes) use this
    /// per-triangle colour.
    pub fn triangle_albedo(&self, i: u32) -> Vec3 {
        let (instance, local) = self.locate(i);
        let attributes = &instance.geometry.attributes[local];
        let material = &self.materials[instance.material as usize];
        if material.base_color_texture.is_none() && material.metallic_texture.is_none() {
            return material.diffuse;
        }
        const POINTS: [(f32, f32); 7] =
            [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5), (1.0 / 3.0, 1.0 / 3.0)];
        POINTS.iter().map(|&(u, v)| material.diffuse_at(&self.textures, attributes, u, v)).sum::<Vec3>() / 7.0
    }

    /// Surface data at a hit: position, unit shading normal, unit geometric normal, diffuse reflectance
    /// and the material.
    pub fn surface(&self, origin: Vec3, direction: Vec3, hit: &SceneHit) -> SurfacePoint<'_> {
        let (instance, local) = self.locate(hit.triangle);
        let (geometric_normal, normals) = instance.world_normals(local);
        let material = &self.materials[instance.material as usize];
        let (u, v) = (hit.barycentrics.x, hit.barycentrics.y);
        let w = 1.0 - u - v;
        let normal = (normals[0] * w + normals[1] * u + normals[2] * v).try_normalize().unwrap_or(geometric_normal);
        SurfacePoint {
            position: origin + direction * hit.t,
            normal,
            geometric_normal,
            diffuse: material.diffuse_at(&self.textures, &instance.geometry.attributes[local], u, v),
            material,
        }
    }
}

/// A shaded point on a surface.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint<'a> {
    pub position: Vec3,
    /// Interpolated vertex normal (not flipped towards the viewer).
    pub normal: Vec3,
    /// Face normal (not flipped towards the viewer).
    pub geometric_normal: Vec3,
    /// Diffuse reflectance, texture applied.
    pub diffuse: Vec3,
    pub material: &'a SnapshotMaterial,
}

/// Whether the triangle `tri` overlaps the box `centre ± half` (Akenine-Möller, "Fast 3D Triangle-Box
/// Overlap Testing", 2001: the 13 separating axes).
pub fn triangle_box_overlap(centre: Vec3, half: Vec3, tri: [Vec3; 3]) -> bool {
    let v = tri.map(|p| p - centre);
    let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    let axes_separate = |axis: Vec3| {
        if axis.length_squared() < 1e-20 {
            return false;
        }
        let p = v.map(|q| q.dot(axis));
        let r = half.x * axis.x.abs() + half.y * axis.y.abs() + half.z * axis.z.abs();
        p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r
    };
    // The nine edge × box-axis cross products.
    for edge in e {
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            if axes_separate(edge.cross(axis)) {
                return false;
            }
        }
    }
    // The box's own axes.
    for k in 0..3 {
        let (lo, hi) = (v[0][k].min(v[1][k]).min(v[2][k]), v[0][k].max(v[1][k]).max(v[2][k]));
        if lo > half[k] || hi < -half[k] {
            return false;
        }
    }
    // The triangle's plane.
    !axes_separate(e[0].cross(e[1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_quad_z0() -> Vec<InputTriangle> {
        let (a, b, c, d) = (
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        );
        vec![InputTriangle::flat([a, b, c], 0), InputTriangle::flat([a, c, d], 0)]
    }

    #[test]
    fn ray_hits_quad_at_the_right_distance_and_misses_outside() {
        let scene = SceneSnapshot::build(unit_quad_z0(), vec![], vec![], vec![]);
        assert_eq!(scene.triangle_count(), 2);
        let hit = scene
            .intersect(Vec3::new(0.3, 0.2, 5.0), Vec3::NEG_Z, 0.0, f32::INFINITY)
            .expect("hit");
        assert!((hit.t - 5.0).abs() < 1e-5);
        let p = scene.surface(Vec3::new(0.3, 0.2, 5.0), Vec3::NEG_Z, &hit);
        assert!((p.position - Vec3::new(0.3, 0.2, 0.0)).length() < 1e-5);
        assert!((p.geometric_normal - Vec3::Z).length() < 1e-6);
        assert!(scene.intersect(Vec3::new(1.5, 0.0, 5.0), Vec3::NEG_Z, 0.0, f32::INFINITY).is_none());
        assert!(scene.occluded(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z, 0.0, 10.0));
        assert!(!scene.occluded(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z, 0.0, 4.0));
    }

    #[test]
    fn rays_through_a_shared_edge_still_hit() {
        // The quad's diagonal runs through the origin; a ray straight down it must not slip through.
        let scene = SceneSnapshot::build(unit_quad_z0(), vec![], vec![], vec![]);
        let hit = scene.intersect(Vec3::new(0.0, 0.0, 1.0), Vec3::NEG_Z, 0.0, f32::INFINITY).expect("hit");
        assert!((hit.t - 1.0).abs() < 1e-6);
        let (u, v) = (hit.barycentrics.x, hit.barycentrics.y);
        assert!((0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v) && u + v <= 1.0 + 1e-6);
        assert!(scene.occluded(Vec3::new(0.0, 0.0, 1.0), Vec3::NEG_Z, 0.0, f32::INFINITY));
    }

    #[test]
    fn negative_zero_direction_components_do_not_lose_hits() {
        let scene = SceneSnapshot::build(unit_quad_z0(), vec![], vec![], vec![]);
        let o = Vec3::new(0.3, 0.2, 1.0);
        let d = Vec3::new(-0.0, -0.0, -1.0);
        assert!(scene.intersect(o, d, 0.0, f32::INFINITY).is_some());
        assert!(scene.occluded(o, d, 0.0, f32::INFINITY));
    }

    #[test]
    fn mirrored_and_inside_out_instances_are_hit_and_leave_the_rest_alone() {
        let mut scene = SceneSnapshot { materials: vec![SnapshotMaterial::DEFAULT_GREY], ..Default::default() };
        let quad = Arc::new(MeshGeometry::new(unit_quad_z0()));
        // A floor (the quad turned to face +y) and, above it, the quad mirrored and inside out.
        let floor = Affine3A::from_rotation_x(-std::f32::consts::FRAC_PI_2) * Affine3A::from_scale(Vec3::splat(4.0));
        scene.set_instance(1, quad.clone(), floor, 0);
        scene.set_instance(2, quad.clone(), Affine3A::from_translation(Vec3::new(0.0, 1.0, 0.0)) * Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0)), 0);
        scene.set_instance(3, quad, Affine3A::from_translation(Vec3::new(2.5, 1.0, 0.0)) * Affine3A::from_scale(Vec3::splat(-1.0)), 0);
        scene.commit();
        // The floor is hit everywhere away from the others.
        for x in [-3.0f32, -2.0, 3.5] {
            let hit = scene.intersect(Vec3::new(x, 2.0, 0.5), Vec3::NEG_Y, 0.0, f32::INFINITY).expect("the floor");
            assert!((hit.t - 2.0).abs() < 1e-4, "x = {x}: t = {}", hit.t);
        }
        // The mirrored quads are hit where they are, and their normals are unit and finite.
        for origin in [Vec3::new(0.0, 1.5, 0.0), Vec3::new(2.5, 1.5, 0.0)] {
            let hit = scene.intersect(origin - Vec3::Z * 2.0, Vec3::Z, 0.0, f32::INFINITY).expect("the mirrored quad");
            assert!((hit.t - 2.0).abs() < 1e-4, "{origin}: t = {}", hit.t);
            let n = scene.geometric_normal(hit.triangle);
            assert!(n.is_finite() && (n.length() - 1.0).abs() < 1e-4, "{n}");
        }
    }

    #[test]
    fn camera_rays_skip_culled_back_faces() {
        let material = SnapshotMaterial {
            culled_face: CulledFace::Back,
            ..SnapshotMaterial::DEFAULT_GREY
        };
        let scene = SceneSnapshot::build(unit_quad_z0(), vec![material], vec![], vec![]);
        // The quad faces +z: seen from the front it is hit, from behind a camera ray passes through...
        assert!(scene.intersect_visible(Vec3::new(0.2, 0.1, 1.0), Vec3::NEG_Z, 0.0, f32::INFINITY).is_some());
        assert!(scene.intersect_visible(Vec3::new(0.2, 0.1, -1.0), Vec3::Z, 0.0, f32::INFINITY).is_none());
        // ...while light transport still sees both sides.
        assert!(scene.intersect(Vec3::new(0.2, 0.1, -1.0), Vec3::Z, 0.0, f32::INFINITY).is_some());
    }

    #[test]
    fn degenerate_and_non_finite_triangles_are_dropped() {
        let mut tris = unit_quad_z0();
        tris.push(InputTriangle::flat([Vec3::ZERO, Vec3::X, Vec3::X * 2.0], 0));
        tris.push(InputTriangle::flat([Vec3::NAN, Vec3::X, Vec3::Y], 0));
        let scene = SceneSnapshot::build(tris, vec![], vec![], vec![]);
        assert_eq!(scene.triangle_count(), 2);
        assert_eq!(scene.bounds(), Some((Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0))));
    }

    #[test]
    fn spot_cone_matches_bevy_formula() {
        let (scale, offset) = SnapshotLight::spot_scale_offset(0.5, 0.5);
        let light = SnapshotLight::Spot {
            position: Vec3::ZERO,
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(100.0),
            inverse_range_squared: 0.0,
            spot_scale: scale,
            spot_offset: offset,
        };
        // On the axis at 2 m: 100 cd / 4 m² = 25 lux.
        let (l, d, e) = light.incident(Vec3::new(0.0, -2.0, 0.0)).unwrap();
        assert!((l - Vec3::Y).length() < 1e-6 && (d - 2.0).abs() < 1e-6);
        assert!((e.x - 25.0).abs() < 1e-3);
        // Outside the 0.5 rad cone: nothing.
        assert!(light.incident(Vec3::new(2.0, -2.0, 0.0)).is_none());
    }

    #[test]
    fn texture_sampling_is_bilinear_and_wraps() {
        let t = SnapshotTexture {
            width: 2,
            height: 1,
            texels: Arc::new([bevy::math::Vec4::ZERO, bevy::math::Vec4::ONE]),
        };
        assert_eq!(t.sample(Vec2::new(0.25, 0.5)), bevy::math::Vec4::ZERO);
        assert_eq!(t.sample(Vec2::new(0.75, 0.5)), bevy::math::Vec4::ONE);
        assert!((t.sample(Vec2::new(0.5, 0.5)) - bevy::math::Vec4::splat(0.5)).length() < 1e-6);
        assert!((t.sample(Vec2::new(1.0, 0.5)) - bevy::math::Vec4::splat(0.5)).length() < 1e-6);
    }
}
