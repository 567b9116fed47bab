//! Geometry a Radiance Hints volume knows about its scene, voxelised on the CPU from the
//! [`SceneSnapshot`] whenever the geometry or the volume changes:
//!
//! * **Albedo volume** (§6's optional extension): the mean diffuse albedo of the surfaces in each hint's
//!   cell, so that extra bounces are reflected with the colour of nearby surfaces instead of white
//!   (Eq. 10). Every triangle is covered with stratified points (about four per cell it spans), each adding
//!   `albedo × area`; empty cells take the mean of their non-empty neighbours (three dilation passes), then
//!   the scene's mean albedo, so trilinear lookups beside surfaces stay stable.
//! * **Hint validity**: whether a hint lies outside solid geometry. From each hint, rays in 32 directions
//!   find the nearest surface; a hint that sees the back of most surfaces is inside something (a box, a
//!   thick wall) and is excluded from interpolation, so light it picks up through the solid does not leak
//!   onto the solid's faces.
//! * **Occupancy**: one bit per voxel of a grid [`OCCUPANCY_FACTOR`]× finer than the hints, set where a
//!   triangle overlaps the voxel (Akenine-Möller's separating-axis test, so thin walls are closed). The
//!   injection tests each RSM sample's path to its receiver against it, and the extra bounces march it to
//!   find the surface each direction sees.
//!
//! Cost: O(triangles × voxels each overlaps) plus 32 BVH rays per hint, once per geometry change.

use bevy::math::{Mat4, UVec3, Vec3, Vec4};

use crate::scene::SceneSnapshot;

/// Occupancy voxels per hint cell along each axis.
pub const OCCUPANCY_FACTOR: u32 = 4;
/// Largest occupancy grid along an axis.
pub const MAX_OCCUPANCY_RESOLUTION: u32 = 256;
/// Directions cast from each hint to decide whether it lies inside solid geometry.
pub const VALIDITY_RAYS: u32 = 32;

/// Everything [`voxelize`] computes for one volume.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeometryVoxels {
    /// Per hint: mean albedo (rgb) and validity (a: 1 outside solids, 0 inside).
    pub albedo_validity: Vec<Vec4>,
    pub occupancy_resolution: UVec3,
    /// One bit per occupancy voxel, x fastest, 32 voxels per word.
    pub occupancy: Vec<u32>,
}

/// The occupancy grid resolution for a hint grid.
pub fn occupancy_resolution(hints: UVec3) -> UVec3 {
    (hints * OCCUPANCY_FACTOR).min(UVec3::splat(MAX_OCCUPANCY_RESOLUTION))
}

/// Voxelises `snapshot` into the volume `world_from_local` (the unit cube) with `resolution` hints.
pub fn voxelize(snapshot: &SceneSnapshot, world_from_local: Mat4, resolution: UVec3) -> GeometryVoxels {
    let res = resolution.max(UVec3::ONE);
    let local_from_world = world_from_local.inverse();
    let mut albedo = voxelize_albedo(snapshot, local_from_world, res);
    let validity = hint_validity(snapshot, world_from_local, res);
    for (a, v) in albedo.iter_mut().zip(validity) {
        a.w = v;
    }
    let occupancy_resolution = occupancy_resolution(res);
    GeometryVoxels {
        albedo_validity: albedo,
        occupancy: voxelize_occupancy(snapshot, local_from_world, occupancy_resolution),
        occupancy_resolution,
    }
}

fn cell_index(c: UVec3, res: UVec3) -> usize {
    (c.x + res.x * (c.y + res.y * c.z)) as usize
}

/// Per cell: mean albedo (rgb) and the surface area in the cell relative to one cell face (a, ≤ 1).
pub fn voxelize_albedo(snapshot: &SceneSnapshot, local_from_world: Mat4, resolution: UVec3) -> Vec<Vec4> {
    let res = resolution.max(UVec3::ONE);
    let cells = (res.x * res.y * res.z) as usize;
    let mut sum = vec![Vec4::ZERO; cells];
    let to_grid = |p: Vec3| (local_from_world.transform_point3(p) + 0.5) * res.as_vec3();
    let mut scene_sum = Vec4::ZERO;

    for t in 0..snapshot.triangle_count() as u32 {
        let [a, b, c] = snapshot.triangle(t).map(to_grid);
        let area = 0.5 * (b - a).cross(c - a).length();
        if !area.is_finite() || area <= 0.0 {
            continue;
        }
        let albedo = snapshot.triangle_albedo(t);
        scene_sum += (albedo * area).extend(area);
        // About four points per cell of area, stratified over the triangle.
        let side = ((area * 4.0).sqrt().ceil() as u32).clamp(1, 16);
        let weight = area / (side * side) as f32;
        for i in 0..side {
            for j in 0..side {
                // Cell (i, j) of a side×side grid over the unit square, folded into the triangle.
                let (mut u, mut v) = ((i as f32 + 0.5) / side as f32, (j as f32 + 0.5) / side as f32);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p = a + (b - a) * u + (c - a) * v;
                if p.cmplt(Vec3::ZERO).any() || p.cmpge(res.as_vec3()).any() {
                    continue;
                }
                sum[cell_index(p.as_uvec3().min(res - 1), res)] += (albedo * weight).extend(weight);
            }
        }
    }

    let mut out: Vec<Vec4> = sum
        .iter()
        .map(|s| if s.w > 0.0 { (s.truncate() / s.w).extend(s.w.min(1.0)) } else { Vec4::ZERO })
        .collect();
    // Dilate into empty cells (alpha stays 0: no surface there).
    for _ in 0..3 {
        let previous = out.clone();
        for z in 0..res.z {
            for y in 0..res.y {
                for x in 0..res.x {
                    let c = UVec3::new(x, y, z);
                    if previous[cell_index(c, res)].truncate() != Vec3::ZERO {
                        continue;
                    }
                    let mut acc = Vec3::ZERO;
                    let mut count = 0.0;
                    for d in [UVec3::X, UVec3::Y, UVec3::Z] {
                        for neighbour in [c.checked_sub(d), Some(c + d)].into_iter().flatten() {
                            if neighbour.cmplt(res).all() {
                                let v = previous[cell_index(neighbour, res)].truncate();
                                if v != Vec3::ZERO {
                                    acc += v;
                                    count += 1.0;
                                }
                            }
                        }
                    }
                    if count > 0.0 {
                        out[cell_index(c, res)] = (acc / count).extend(0.0);
                    }
                }
            }
        }
    }
    let fallback = if scene_sum.w > 0.0 { scene_sum.truncate() / scene_sum.w } else { Vec3::splat(0.5) };
    for v in &mut out {
        if v.truncate() == Vec3::ZERO {
            *v = fallback.extend(0.0);
        }
    }
    out
}

/// Per hint: 1 when it lies outside solid geometry, 0 when most directions first meet the back of a
/// surface (the hint is inside a box or a thick wall).
pub fn hint_validity(snapshot: &SceneSnapshot, world_from_local: Mat4, resolution: UVec3) -> Vec<f32> {
    use crate::sampling::uniform_sphere;
    use bevy::math::Vec2;
    let res = resolution.max(UVec3::ONE);
    // Fixed, well-spread directions (a Fibonacci-like lattice over the sphere).
    let directions: Vec<Vec3> = (0..VALIDITY_RAYS)
        .map(|i| {
            let u = Vec2::new((i as f32 + 0.5) / VALIDITY_RAYS as f32, (i as f32 * 0.618_034).fract());
            uniform_sphere(u)
        })
        .collect();
    let mut out = Vec::with_capacity((res.x * res.y * res.z) as usize);
    for z in 0..res.z {
        for y in 0..res.y {
            for x in 0..res.x {
                let local = (UVec3::new(x, y, z).as_vec3() + 0.5) / res.as_vec3() - 0.5;
                let p = world_from_local.transform_point3(local);
                let mut back = 0;
                let mut hits = 0;
                for &d in &directions {
                    if let Some(hit) = snapshot.intersect(p, d, 0.0, f32::INFINITY) {
                        hits += 1;
                        if snapshot.attributes(hit.triangle).geometric_normal.dot(d) > 0.0 {
                            back += 1;
                        }
                    }
                }
                // Inside: most of the rays that hit anything hit a back face, and most rays hit.
                let inside = hits * 2 > VALIDITY_RAYS && back * 2 > hits;
                out.push(if inside { 0.0 } else { 1.0 });
            }
        }
    }
    out
}

/// Conservative surface voxelisation: a bit per voxel of the grid `resolution` over the unit cube, set
/// where a triangle overlaps the voxel.
pub fn voxelize_occupancy(snapshot: &SceneSnapshot, local_from_world: Mat4, resolution: UVec3) -> Vec<u32> {
    let res = resolution.max(UVec3::ONE);
    let words = ((res.x * res.y * res.z) as usize).div_ceil(32);
    let mut bits = vec![0u32; words];
    let to_grid = |p: Vec3| (local_from_world.transform_point3(p) + 0.5) * res.as_vec3();
    for t in 0..snapshot.triangle_count() as u32 {
        let tri = snapshot.triangle(t).map(to_grid);
        let lo = tri[0].min(tri[1]).min(tri[2]).floor().max(Vec3::ZERO);
        let hi = tri[0].max(tri[1]).max(tri[2]).floor().min(res.as_vec3() - 1.0);
        if lo.cmpgt(hi).any() {
            continue;
        }
        let (lo, hi) = (lo.as_uvec3(), hi.as_uvec3());
        for z in lo.z..=hi.z {
            for y in lo.y..=hi.y {
                for x in lo.x..=hi.x {
                    let centre = UVec3::new(x, y, z).as_vec3() + 0.5;
                    if triangle_box_overlap(centre, Vec3::splat(0.5), tri) {
                        let i = cell_index(UVec3::new(x, y, z), res);
                        bits[i / 32] |= 1 << (i % 32);
                    }
                }
            }
        }
    }
    bits
}

/// The CPU twin of `first_hit` in `shaders/radiance_hints/rh_occupancy.wgsl`: walks the voxels the segment
/// `a → b` (occupancy-grid coordinates) passes through, skipping the one containing `a`, and returns the
/// fraction of the segment where it enters an occupied voxel, or `None`.
pub fn first_hit(occupancy: &[u32], res: UVec3, a: Vec3, b: Vec3, skip_end: f32) -> Option<f32> {
    let delta = b - a;
    let len = delta.length();
    if len < 1e-5 {
        return None;
    }
    let d = delta / len;
    let mut v = a.floor().as_ivec3();
    let step = d.signum().as_ivec3();
    let inv = Vec3::ONE / d.abs().max(Vec3::splat(1e-8));
    let frac = a - a.floor();
    let mut t_max = Vec3::select(d.cmplt(Vec3::ZERO), frac, Vec3::ONE - frac) * inv;
    t_max = Vec3::select(d.abs().cmplt(Vec3::splat(1e-8)), Vec3::splat(3.0e38), t_max);
    let limit = len - skip_end;
    let occupied = |v: bevy::math::IVec3| {
        if v.cmplt(bevy::math::IVec3::ZERO).any() || v.cmpge(res.as_ivec3()).any() {
            return false;
        }
        let i = cell_index(v.as_uvec3(), res);
        occupancy[i / 32] & (1 << (i % 32)) != 0
    };
    for _ in 0..(res.x + res.y + res.z + 2) {
        let t;
        if t_max.x < t_max.y && t_max.x < t_max.z {
            t = t_max.x;
            t_max.x += inv.x;
            v.x += step.x;
        } else if t_max.y < t_max.z {
            t = t_max.y;
            t_max.y += inv.y;
            v.y += step.y;
        } else {
            t = t_max.z;
            t_max.z += inv.z;
            v.z += step.z;
        }
        if t >= limit {
            return None;
        }
        if occupied(v) {
            return Some(t / len);
        }
    }
    None
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
    use crate::scene::{InputTriangle, SnapshotMaterial};

    fn wall(x: f32, material: u32) -> Vec<InputTriangle> {
        let q = [
            Vec3::new(x, -1.0, -1.0),
            Vec3::new(x, 1.0, -1.0),
            Vec3::new(x, 1.0, 1.0),
            Vec3::new(x, -1.0, 1.0),
        ];
        vec![InputTriangle::flat([q[0], q[1], q[2]], material), InputTriangle::flat([q[0], q[2], q[3]], material)]
    }

    fn bit(bits: &[u32], c: UVec3, res: UVec3) -> bool {
        let i = cell_index(c, res);
        bits[i / 32] & (1 << (i % 32)) != 0
    }

    #[test]
    fn cells_take_the_colour_of_their_surfaces_and_empty_cells_are_filled() {
        let red = SnapshotMaterial { diffuse: Vec3::new(0.8, 0.1, 0.1), ..SnapshotMaterial::DEFAULT_GREY };
        let green = SnapshotMaterial { diffuse: Vec3::new(0.1, 0.7, 0.1), ..SnapshotMaterial::DEFAULT_GREY };
        let mut tris = wall(-0.9, 0);
        tris.extend(wall(0.9, 1));
        let scene = SceneSnapshot::build(tris, vec![red.clone(), green.clone()], vec![], vec![]);
        // A 2 m cube volume at the origin, 4 cells per axis.
        let local_from_world = Mat4::from_scale(Vec3::splat(2.0)).inverse();
        let v = voxelize_albedo(&scene, local_from_world, UVec3::splat(4));
        let at = |x: u32, y: u32, z: u32| v[(x + 4 * (y + 4 * z)) as usize];
        assert!((at(0, 1, 2).truncate() - red.diffuse).length() < 1e-5);
        assert!(at(0, 1, 2).w > 0.5);
        assert!((at(3, 2, 1).truncate() - green.diffuse).length() < 1e-5);
        // The middle cells hold no surface: dilated colour, zero coverage.
        let middle = at(1, 1, 1);
        assert_eq!(middle.w, 0.0);
        assert!((middle.truncate() - red.diffuse).length() < 1e-5, "{middle}");
        assert!(v.iter().all(|c| c.is_finite() && c.truncate() != Vec3::ZERO));
    }

    #[test]
    fn triangle_box_overlap_matches_simple_cases() {
        let tri = [Vec3::new(-1.0, 0.2, -1.0), Vec3::new(1.0, 0.2, -1.0), Vec3::new(0.0, 0.2, 1.0)];
        assert!(triangle_box_overlap(Vec3::ZERO, Vec3::splat(0.5), tri));
        // Plane above the box.
        assert!(!triangle_box_overlap(Vec3::new(0.0, -0.5, 0.0), Vec3::splat(0.25), tri));
        // Beside the triangle's edge, within its bounding box: only an edge axis separates.
        let thin = [Vec3::ZERO, Vec3::new(4.0, 0.0, 0.0), Vec3::new(0.0, 4.0, 0.0)];
        assert!(!triangle_box_overlap(Vec3::new(3.0, 3.0, 0.0), Vec3::splat(0.4), thin));
        assert!(triangle_box_overlap(Vec3::new(1.0, 1.0, 0.0), Vec3::splat(0.4), thin));
    }

    #[test]
    fn a_thin_diagonal_wall_is_watertight_in_the_occupancy() {
        // A wall at x = z through the origin: every straight line from one side to the other must cross an
        // occupied voxel when walked through face-adjacent voxels.
        let q = [
            Vec3::new(-1.0, -1.0, -1.0),
            Vec3::new(1.0, -1.0, 1.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(-1.0, 1.0, -1.0),
        ];
        let tris = vec![InputTriangle::flat([q[0], q[1], q[2]], 0), InputTriangle::flat([q[0], q[2], q[3]], 0)];
        let scene = SceneSnapshot::build(tris, vec![], vec![], vec![]);
        let res = UVec3::splat(16);
        let bits = voxelize_occupancy(&scene, Mat4::from_scale(Vec3::splat(2.0)).inverse(), res);
        // Along z at fixed (x, y), the voxels go from x > z to x < z: one of them must be occupied.
        for x in 0..16 {
            for y in 0..16 {
                assert!((0..16).any(|z| bit(&bits, UVec3::new(x, y, z), res)), "gap at x={x} y={y}");
            }
        }
        // Far from the wall, nothing.
        assert!(!bit(&bits, UVec3::new(15, 8, 0), res));
    }

    #[test]
    fn cellar_walls_block_every_path_between_the_rooms() {
        use crate::scenes::cellar::cellar_boxes;
        let mut tris = Vec::new();
        for (lo, hi, _) in cellar_boxes() {
            let mesh = bevy::mesh::Mesh::from(bevy::math::primitives::Cuboid::from_corners(lo, hi));
            let t = bevy::prelude::GlobalTransform::from_translation((lo + hi) * 0.5);
            tris.extend(crate::scene::mesh_triangles(&mesh, &t, 0).unwrap());
        }
        let scene = SceneSnapshot::build(tris, vec![], vec![], vec![]);
        let (lo, hi) = scene.bounds().unwrap();
        let world_from_local = Mat4::from_scale_rotation_translation((hi - lo) * 1.002, Default::default(), (lo + hi) * 0.5);
        let hints = crate::radiance_hints::RadianceHintsVolume::MEDIUM.with_cubic_cells(hi - lo).resolution;
        let res = occupancy_resolution(hints);
        let bits = voxelize_occupancy(&scene, world_from_local.inverse(), res);
        let grid = |p: Vec3| (world_from_local.inverse().transform_point3(p) + 0.5) * res.as_vec3();
        // From room B to room A across the dividing wall (x ∈ [−0.1, 0.1]), at every height and depth
        // away from the door (z ∈ [−1.6, −0.8]).
        for y in [0.05f32, 0.5, 1.0, 2.0, 2.3, 2.45] {
            for z in [-1.9f32, -0.6, 0.0, 0.7, 1.9] {
                let a = grid(Vec3::new(0.35, y, z));
                let b = grid(Vec3::new(-0.35, y + 0.1, z - 0.05));
                assert!(first_hit(&bits, res, a, b, 0.0).is_some(), "leak at y={y} z={z}");
            }
        }
        // Through the door, nothing.
        assert!(first_hit(&bits, res, grid(Vec3::new(0.8, 1.0, -1.2)), grid(Vec3::new(-0.8, 1.0, -1.2)), 0.0).is_none());
    }

    #[test]
    fn hints_inside_a_closed_box_are_invalid() {
        let mesh = bevy::mesh::Mesh::from(bevy::math::primitives::Cuboid::new(1.0, 1.0, 1.0));
        let tris = crate::scene::mesh_triangles(&mesh, &bevy::prelude::GlobalTransform::IDENTITY, 0).unwrap();
        let scene = SceneSnapshot::build(tris, vec![], vec![], vec![]);
        // A 3 m volume with 3 hints per axis: the centre hint is inside the 1 m box, the corners are not.
        let v = hint_validity(&scene, Mat4::from_scale(Vec3::splat(3.0)), UVec3::splat(3));
        assert_eq!(v[13], 0.0);
        assert_eq!(v[0], 1.0);
        assert_eq!(v.iter().filter(|x| **x == 0.0).count(), 1);
    }
}
