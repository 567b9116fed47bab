//! A CPU snapshot of the world: triangles, diffuse colours, emission, lights and a BVH.
//!
//! The path tracer ([`crate::reference`]) and, later, the VPL random walks and the radiosity solver work on
//! this snapshot rather than on Bevy's render world, so that every method and the ground truth see *the same
//! scene*: the meshes with their transforms, each [`StandardMaterial`](bevy::pbr::StandardMaterial)'s diffuse
//! colour (`base_color × (1 − metallic)`, times its base-colour texture where the mesh has UVs), its emission,
//! and the directional, point and spot lights in Bevy's units.
//!
//! # Cost
//! [`SceneSnapshotPlugin`] keeps the [`SceneSnapshot`] resource current. Nothing is done unless that resource
//! exists (insert it, or let a method that needs it insert it). Geometry (triangles and the BVH) is rebuilt
//! only in frames where a mesh entity, a mesh asset, a material or an image changed; lights are re-read
//! only when a light changed. Each rebuild bumps [`SceneSnapshot::geometry_generation`] or
//! [`SceneSnapshot::light_generation`], so consumers can tell whether their caches are stale.
//!
//! # Data layout
//! Triangles are stored in BVH order (obvhs' CWBVH, an 8-wide compressed BVH built with PLOC), with a
//! parallel array of [`TriangleAttributes`]. Positions are in world space, metres.

pub(crate) mod extract;

use bevy::math::{Vec2, Vec3};
use bevy::prelude::{Entity, Resource};
use obvhs::{
    BvhBuildParams,
    cwbvh::{CwBvh, builder::build_cwbvh_from_tris},
    ray::{Ray, RayHit},
    triangle::Triangle as BvhTriangle,
};
use obvhs_glam::Vec3A;

pub use extract::{SceneSnapshotPlugin, SceneSnapshotSystems, mesh_triangles};


/// Per-triangle data the BVH does not hold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleAttributes {
    /// Index into [`SceneSnapshot::materials`].
    pub material: u32,
    /// Unit geometric normal, `(v1 − v0) × (v2 − v0)` normalised (counter-clockwise front face).
    pub geometric_normal: Vec3,
    /// Vertex normals in world space (unit length), or the geometric normal three times.
    pub normals: [Vec3; 3],
    /// Texture coordinates, or zero when the mesh has none.
    pub uvs: [Vec2; 3],
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
    /// Index into [`SceneSnapshot::textures`] of the base-colour texture.
    pub base_color_texture: Option<u32>,
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

/// A linear RGB texture, sampled bilinearly with repeat wrapping.
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotTexture {
    pub width: u32,
    pub height: u32,
    /// Linear RGB texels, row-major.
    pub texels: Vec<Vec3>,
}

impl SnapshotTexture {
    /// Bilinear sample at `uv` with repeat wrapping (glTF's default sampler).
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        if self.texels.is_empty() {
            return Vec3::ONE;
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

/// The CPU snapshot of the world. See the [module docs](self).
#[derive(Resource, Default)]
pub struct SceneSnapshot {
    /// Triangles in BVH order.
    triangles: Vec<BvhTriangle>,
    /// Attributes of `triangles`, same order.
    pub attributes: Vec<TriangleAttributes>,
    pub materials: Vec<SnapshotMaterial>,
    pub textures: Vec<SnapshotTexture>,
    pub lights: Vec<SnapshotLightEntry>,
    bvh: Option<CwBvh>,
    /// Bumped every time the triangles or materials are rebuilt.
    pub geometry_generation: u64,
    /// Bumped every time the lights are re-read.
    pub light_generation: u64,
}

/// A triangle given to [`SceneSnapshot::build`], in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputTriangle {
    pub positions: [Vec3; 3],
    /// Vertex normals; `None` uses the geometric normal.
    pub normals: Option<[Vec3; 3]>,
    pub uvs: Option<[Vec2; 3]>,
    pub material: u32,
}

impl InputTriangle {
    /// A flat triangle without UVs.
    pub fn flat(positions: [Vec3; 3], material: u32) -> Self {
        Self { positions, normals: None, uvs: None, material }
    }
}

impl std::fmt::Debug for SceneSnapshot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneSnapshot")
            .field("triangles", &self.triangles.len())
            .field("materials", &self.materials.len())
            .field("textures", &self.textures.len())
            .field("lights", &self.lights)
            .field("geometry_generation", &self.geometry_generation)
            .field("light_generation", &self.light_generation)
            .finish()
    }
}

fn to_bvh(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
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

#[inline(always)]
fn intersect_t(tri: &BvhTriangle, ray: &Ray) -> f32 {
    intersect_triangle(tri, ray).map_or(f32::INFINITY, |(t, _, _)| t)
}

impl SceneSnapshot {
    /// Builds a snapshot from world-space triangles, materials and lights. Degenerate triangles (zero
    /// area or non-finite vertices) are dropped; material indices out of range use the last material, or
    /// [`SnapshotMaterial::DEFAULT_GREY`] when there is none.
    pub fn build(
        triangles: impl IntoIterator<Item = InputTriangle>,
        mut materials: Vec<SnapshotMaterial>,
        textures: Vec<SnapshotTexture>,
        lights: Vec<SnapshotLightEntry>,
    ) -> Self {
        let mut snapshot = Self {
            lights,
            textures,
            ..Self::default()
        };
        if materials.is_empty() {
            materials.push(SnapshotMaterial::DEFAULT_GREY);
        }
        snapshot.set_geometry(triangles, materials);
        snapshot
    }

    /// Replaces the geometry and materials, rebuilding the BVH.
    pub fn set_geometry(&mut self, triangles: impl IntoIterator<Item = InputTriangle>, materials: Vec<SnapshotMaterial>) {
        let material_count = materials.len().max(1) as u32;
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
            tris.push(BvhTriangle {
                v0: to_bvh(a),
                v1: to_bvh(b),
                v2: to_bvh(c),
            });
            attributes.push(TriangleAttributes {
                material: t.material.min(material_count - 1),
                geometric_normal: n,
                normals,
                uvs: t.uvs.unwrap_or([Vec2::ZERO; 3]),
                area,
            });
        }

        self.bvh = None;
        if !tris.is_empty() {
            let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Default::default());
            // Store triangles in BVH order so that leaves read contiguous memory.
            self.triangles = bvh.primitive_indices.iter().map(|&i| tris[i as usize]).collect();
            self.attributes = bvh.primitive_indices.iter().map(|&i| attributes[i as usize]).collect();
            let mut bvh = bvh;
            bvh.primitive_indices = (0..self.triangles.len() as u32).collect();
            self.bvh = Some(bvh);
        } else {
            self.triangles.clear();
            self.attributes.clear();
        }
        self.materials = if materials.is_empty() {
            vec![SnapshotMaterial::DEFAULT_GREY]
        } else {
            materials
        };
        self.geometry_generation += 1;
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// World-space vertices of triangle `i` (BVH order).
    pub fn triangle(&self, i: u32) -> [Vec3; 3] {
        let t = &self.triangles[i as usize];
        [t.v0, t.v1, t.v2].map(|v| Vec3::new(v.x, v.y, v.z))
    }

    /// The axis-aligned bounds of all triangles, or `None` for an empty scene.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut iter = self.triangles.iter().flat_map(|t| [t.v0, t.v1, t.v2]);
        let first = iter.next()?;
        let (lo, hi) = iter.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v)));
        Some((Vec3::new(lo.x, lo.y, lo.z), Vec3::new(hi.x, hi.y, hi.z)))
    }

    /// The closest hit along `origin + t · direction` for `t ∈ [t_min, t_max]`. `direction` must be unit
    /// length for `t` to be a distance.
    pub fn intersect(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Option<SceneHit> {
        let bvh = self.bvh.as_ref()?;
        let ray = bvh_ray(origin, direction, t_min, t_max);
        let mut hit = RayHit::none();
        if !bvh.ray_traverse(ray, &mut hit, |ray, id| intersect_t(&self.triangles[id], ray)) {
            return None;
        }
        let tri = &self.triangles[hit.primitive_id as usize];
        // Recompute the barycentrics of the closest triangle only (the traversal needs just `t`).
        let (t, u, v) = intersect_triangle(tri, &Ray::new(ray.origin, ray.direction, t_min, f32::INFINITY))?;
        Some(SceneHit {
            t,
            triangle: hit.primitive_id,
            barycentrics: Vec2::new(u, v),
        })
    }

    /// Like [`SceneSnapshot::intersect`], but skipping faces the rasteriser culls (see
    /// [`SnapshotMaterial::culled_face`]): what a camera ray sees in Bevy.
    pub fn intersect_visible(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Option<SceneHit> {
        let bvh = self.bvh.as_ref()?;
        let ray = bvh_ray(origin, direction, t_min, t_max);
        let mut hit = RayHit::none();
        let culled = |id: usize| {
            let a = &self.attributes[id];
            let facing = a.geometric_normal.dot(direction);
            match self.materials[a.material as usize].culled_face {
                CulledFace::None => false,
                CulledFace::Back => facing > 0.0,
                CulledFace::Front => facing < 0.0,
            }
        };
        if !bvh.ray_traverse(ray, &mut hit, |ray, id| {
            if culled(id) { f32::INFINITY } else { intersect_t(&self.triangles[id], ray) }
        }) {
            return None;
        }
        let tri = &self.triangles[hit.primitive_id as usize];
        let (t, u, v) = intersect_triangle(tri, &Ray::new(ray.origin, ray.direction, t_min, f32::INFINITY))?;
        Some(SceneHit {
            t,
            triangle: hit.primitive_id,
            barycentrics: Vec2::new(u, v),
        })
    }

    /// Whether anything blocks the open segment `origin + t · direction`, `t ∈ (t_min, t_max)`.
    pub fn occluded(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        // Written so that NaN bounds are rejected too.
        if t_max.partial_cmp(&t_min) != Some(std::cmp::Ordering::Greater) {
            return false;
        }
        let ray = bvh_ray(origin, direction, t_min, t_max);
        !bvh.ray_traverse_miss(ray, |ray, id| intersect_t(&self.triangles[id], ray))
    }

    /// The mean diffuse albedo of triangle `i`: its material's diffuse colour times the mean of its
    /// base-colour texture at the corners, edge midpoints and centroid. The GI methods' low-frequency
    /// inputs (RSM albedo, albedo volumes) use this per-triangle colour.
    pub fn triangle_albedo(&self, i: u32) -> Vec3 {
        let attributes = &self.attributes[i as usize];
        let material = &self.materials[attributes.material as usize];
        let Some(texture) = material.base_color_texture.and_then(|t| self.textures.get(t as usize)) else {
            return material.diffuse;
        };
        let [a, b, c] = attributes.uvs;
        let points = [a, b, c, (a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5, (a + b + c) / 3.0];
        material.diffuse * (points.iter().map(|uv| texture.sample(*uv)).sum::<Vec3>() / points.len() as f32)
    }

    /// Surface data at a hit: position, unit shading normal, unit geometric normal, diffuse reflectance
    /// and the material.
    pub fn surface(&self, origin: Vec3, direction: Vec3, hit: &SceneHit) -> SurfacePoint<'_> {
        let attributes = &self.attributes[hit.triangle as usize];
        let material = &self.materials[attributes.material as usize];
        let (u, v) = (hit.barycentrics.x, hit.barycentrics.y);
        let w = 1.0 - u - v;
        let normal = (attributes.normals[0] * w + attributes.normals[1] * u + attributes.normals[2] * v)
            .try_normalize()
            .unwrap_or(attributes.geometric_normal);
        let mut diffuse = material.diffuse;
        if let Some(texture) = material.base_color_texture.and_then(|t| self.textures.get(t as usize)) {
            let uv = attributes.uvs[0] * w + attributes.uvs[1] * u + attributes.uvs[2] * v;
            diffuse *= texture.sample(uv);
        }
        SurfacePoint {
            position: origin + direction * hit.t,
            normal,
            geometric_normal: attributes.geometric_normal,
            diffuse,
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
            texels: vec![Vec3::ZERO, Vec3::ONE],
        };
        assert_eq!(t.sample(Vec2::new(0.25, 0.5)), Vec3::ZERO);
        assert_eq!(t.sample(Vec2::new(0.75, 0.5)), Vec3::ONE);
        assert!((t.sample(Vec2::new(0.5, 0.5)) - Vec3::splat(0.5)).length() < 1e-6);
        assert!((t.sample(Vec2::new(1.0, 0.5)) - Vec3::splat(0.5)).length() < 1e-6);
    }
}
