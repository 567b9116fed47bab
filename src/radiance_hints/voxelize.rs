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
//! Cost: O(triangles × voxels each overlaps) plus 32 BVH rays per hint for a full voxelisation (a new
//! volume, resolution or transform). When meshes move, [`voxelize_update`] redoes only the cells their old
//! and new bounds touch (plus one cell around), so one moving mesh costs what its bounds cover.

pub use crate::scene::triangle_box_overlap;
use bevy::math::{IVec3, Mat4, UVec3, Vec3, Vec4};

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
    /// Per hint cell: `Σ albedo × area` (rgb) and `Σ area` (a), in cell units, before dilation; kept so that
    /// [`voxelize_update`] can redo only the cells a change touches.
    pub albedo_sums: Vec<Vec4>,
    /// What may differ from the previous voxelisation of the same volume: what the reconstruction's
    /// visibility masks must redo.
    pub changed: VoxelChange,
}

/// The part of a volume's voxels a voxelisation changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VoxelChange {
    /// A full voxelisation: anything may have changed.
    #[default]
    All,
    /// Only occupancy bits, and the validity of hints, inside this inclusive box of occupancy voxels.
    Voxels(UVec3, UVec3),
    /// Nothing.
    Nothing,
    /// The volume moved by whole cells ([`voxelize_scrolled`]): occupancy voxel `v` now holds what voxel
    /// `v + shift` held before; what came into the box and the voxels within a cell of the old and new
    /// faces are new.
    Scrolled(IVec3),
}

/// The occupancy grid resolution for a hint grid.
pub fn occupancy_resolution(hints: UVec3) -> UVec3 {
    (hints * OCCUPANCY_FACTOR).min(UVec3::splat(MAX_OCCUPANCY_RESOLUTION))
}

/// An inclusive box of cells.
type CellBox = (UVec3, UVec3);

/// Voxelises `snapshot` into the volume `world_from_local` (the unit cube) with `resolution` hints.
pub fn voxelize(snapshot: &SceneSnapshot, world_from_local: Mat4, resolution: UVec3) -> GeometryVoxels {
    let res = resolution.max(UVec3::ONE);
    let local_from_world = world_from_local.inverse();
    let all = (UVec3::ZERO, res - 1);
    let mut sums = vec![Vec4::ZERO; (res.x * res.y * res.z) as usize];
    albedo_sums(snapshot, local_from_world, res, all, &mut sums);
    let mut albedo = finish_albedo(&sums, res);
    let validity = hint_validity(snapshot, world_from_local, res);
    for (a, v) in albedo.iter_mut().zip(validity) {
        a.w = v;
    }
    let occupancy_resolution = occupancy_resolution(res);
    let words = ((occupancy_resolution.x * occupancy_resolution.y * occupancy_resolution.z) as usize).div_ceil(32);
    let mut occupancy = vec![0u32; words];
    occupancy_bits(snapshot, local_from_world, occupancy_resolution, (UVec3::ZERO, occupancy_resolution - 1), &mut occupancy);
    GeometryVoxels { albedo_validity: albedo, occupancy, occupancy_resolution, albedo_sums: sums, changed: VoxelChange::All }
}

/// `previous` brought up to date after geometry changed inside the world-space boxes `dirty`: only the
/// cells those boxes touch are voxelised again (the albedo dilation, O(cells), runs over the whole grid).
/// Albedo and occupancy equal [`voxelize`] of the new scene when `previous` was voxelised from the old
/// one; validity is redone for the hints in the boxes only (a solid that moved can only put
/// hints inside itself there), so a far hint whose validity rays the change shades keeps its old value.
pub fn voxelize_update(
    snapshot: &SceneSnapshot,
    world_from_local: Mat4,
    resolution: UVec3,
    previous: &GeometryVoxels,
    dirty: &[(Vec3, Vec3)],
) -> GeometryVoxels {
    let res = resolution.max(UVec3::ONE);
    let local_from_world = world_from_local.inverse();
    let occupancy_res = occupancy_resolution(res);
    if previous.albedo_sums.len() != (res.x * res.y * res.z) as usize || previous.occupancy_resolution != occupancy_res {
        return voxelize(snapshot, world_from_local, res);
    }
    let mut out = previous.clone();
    out.changed = VoxelChange::Nothing;
    let mut validity_boxes = Vec::new();
    for &(lo, hi) in dirty {
        if let Some(cells) = cell_box(local_from_world, res, lo, hi, 1) {
            for z in cells.0.z..=cells.1.z {
                for y in cells.0.y..=cells.1.y {
                    for x in cells.0.x..=cells.1.x {
                        out.albedo_sums[cell_index(UVec3::new(x, y, z), res)] = Vec4::ZERO;
                    }
                }
            }
            albedo_sums(snapshot, local_from_world, res, cells, &mut out.albedo_sums);
            // Validity changes in the hint cells the box touches, occupancy in the voxels; both in voxels.
            let scale = occupancy_res.as_vec3() / res.as_vec3();
            let a = (cells.0.as_vec3() * scale).floor().as_uvec3();
            let b = (((cells.1 + 1).as_vec3() * scale).ceil().as_uvec3()).min(occupancy_res) - 1;
            out.changed = match out.changed {
                VoxelChange::Voxels(lo, hi) => VoxelChange::Voxels(lo.min(a), hi.max(b)),
                _ => VoxelChange::Voxels(a, b),
            };
        }
        // Validity: only hints inside the box can have been put inside (or let out of) the moved solid.
        if let Some(cells) = cell_box(local_from_world, res, lo, hi, 0) {
            validity_boxes.push(cells);
        }
        if let Some(voxels) = cell_box(local_from_world, occupancy_res, lo, hi, 1) {
            for z in voxels.0.z..=voxels.1.z {
                for y in voxels.0.y..=voxels.1.y {
                    for x in voxels.0.x..=voxels.1.x {
                        let i = cell_index(UVec3::new(x, y, z), occupancy_res);
                        out.occupancy[i / 32] &= !(1 << (i % 32));
                    }
                }
            }
            occupancy_bits(snapshot, local_from_world, occupancy_res, voxels, &mut out.occupancy);
        }
    }
    let validity: Vec<f32> = previous.albedo_validity.iter().map(|a| a.w).collect();
    let mut albedo = finish_albedo(&out.albedo_sums, res);
    for (a, v) in albedo.iter_mut().zip(validity) {
        a.w = v;
    }
    for cells in validity_boxes {
        for z in cells.0.z..=cells.1.z {
            for y in cells.0.y..=cells.1.y {
                for x in cells.0.x..=cells.1.x {
                    let c = UVec3::new(x, y, z);
                    albedo[cell_index(c, res)].w = hint_valid(snapshot, world_from_local, res, c);
                }
            }
        }
    }
    out.albedo_validity = albedo;
    out
}

/// How many hint cells a volume moved from `old` to `new` (both world-from-unit-cube), when that is all
/// that changed: the same axes and size, and a translation by a whole number of cells along each axis of
/// a `res` grid (as a [`RadianceHintsCascade`](super::RadianceHintsCascade) level moves, snapped to its
/// cells). `None` otherwise.
pub fn scroll_shift(old: Mat4, new: Mat4, res: UVec3) -> Option<IVec3> {
    let same_axes = (0..3).all(|i| old.col(i).abs_diff_eq(new.col(i), 1e-5 * old.col(i).length().max(1e-6)));
    if !same_axes || old.determinant().abs() < 1e-12 {
        return None;
    }
    let moved = old.inverse().transform_vector3((new.col(3) - old.col(3)).truncate()) * res.as_vec3();
    let shift = moved.round();
    ((moved - shift).abs().max_element() < 1e-3 && shift != Vec3::ZERO).then(|| shift.as_ivec3())
}

/// `previous`, the voxels of the same volume before it moved by `shift` hint cells ([`scroll_shift`]),
/// scrolled to where the volume is now: the cells both boxes hold are copied and only those that came
/// into the box are voxelised (a cascade level crossing one cell redoes one slab, not the grid). The
/// result equals [`voxelize`] at the new place up to rounding at cell boundaries. `None` when the move
/// is not a whole number of occupancy voxels (a grid whose occupancy is capped at
/// [`MAX_OCCUPANCY_RESOLUTION`]) or spans the grid: voxelise it whole instead.
pub fn voxelize_scrolled(
    snapshot: &SceneSnapshot,
    world_from_local: Mat4,
    resolution: UVec3,
    previous: &GeometryVoxels,
    shift: IVec3,
) -> Option<GeometryVoxels> {
    let res = resolution.max(UVec3::ONE);
    let occupancy_res = occupancy_resolution(res);
    let cells = (res.x * res.y * res.z) as usize;
    if previous.albedo_sums.len() != cells
        || previous.occupancy_resolution != occupancy_res
        || occupancy_res != res * OCCUPANCY_FACTOR
        || shift.abs().cmpge(res.as_ivec3()).any()
    {
        return None;
    }
    let local_from_world = world_from_local.inverse();
    // New cell c holds what old cell c + shift held.
    let mut sums = vec![Vec4::ZERO; cells];
    let mut validity = vec![0.0f32; cells];
    for (i, o) in shifted_cells(res, shift) {
        sums[i] = previous.albedo_sums[o];
        validity[i] = previous.albedo_validity[o].w;
    }
    let mut occupancy = vec![0u32; previous.occupancy.len()];
    for (i, o) in shifted_cells(occupancy_res, shift * OCCUPANCY_FACTOR as i32) {
        if previous.occupancy[o / 32] & (1 << (o % 32)) != 0 {
            occupancy[i / 32] |= 1 << (i % 32);
        }
    }
    // The slabs that came into the box, one per axis it moved along (they may share corner cells:
    // each box is cleared before it is summed, so a cell is never counted twice).
    let world_from_local = local_from_world.inverse();
    for axis in 0..3 {
        let s = shift[axis];
        if s == 0 {
            continue;
        }
        let (mut lo, mut hi) = (UVec3::ZERO, res - 1);
        if s > 0 {
            lo[axis] = res[axis] - s as u32;
        } else {
            hi[axis] = (-s) as u32 - 1;
        }
        for z in lo.z..=hi.z {
            for y in lo.y..=hi.y {
                for x in lo.x..=hi.x {
                    let c = UVec3::new(x, y, z);
                    sums[cell_index(c, res)] = Vec4::ZERO;
                    validity[cell_index(c, res)] = hint_valid(snapshot, world_from_local, res, c);
                }
            }
        }
        albedo_sums(snapshot, local_from_world, res, (lo, hi), &mut sums);
        let voxels = (lo * OCCUPANCY_FACTOR, (hi + 1) * OCCUPANCY_FACTOR - 1);
        occupancy_bits(snapshot, local_from_world, occupancy_res, voxels, &mut occupancy);
    }
    let mut albedo = finish_albedo(&sums, res);
    for (a, v) in albedo.iter_mut().zip(validity) {
        a.w = v;
    }
    Some(GeometryVoxels {
        albedo_validity: albedo,
        occupancy,
        occupancy_resolution: occupancy_res,
        albedo_sums: sums,
        changed: VoxelChange::Scrolled(shift * OCCUPANCY_FACTOR as i32),
    })
}

/// For a `res` grid moved by `shift` cells: (index now, index before) of every cell that was in the grid
/// before the move (cell c now is cell c + shift before).
fn shifted_cells(res: UVec3, shift: IVec3) -> impl Iterator<Item = (usize, usize)> {
    (0..res.z).flat_map(move |z| (0..res.y).flat_map(move |y| (0..res.x).map(move |x| UVec3::new(x, y, z)))).filter_map(
        move |c| {
            let old = c.as_ivec3() + shift;
            (old.cmpge(IVec3::ZERO).all() && old.cmplt(res.as_ivec3()).all())
                .then(|| (cell_index(c, res), cell_index(old.as_uvec3(), res)))
        },
    )
}

/// The cells of a `res` grid over the volume that the world box `lo..hi` touches, grown by `margin`.
fn cell_box(local_from_world: Mat4, res: UVec3, lo: Vec3, hi: Vec3, margin: u32) -> Option<CellBox> {
    let (mut a, mut b) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for i in 0..8 {
        let p = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let g = (local_from_world.transform_point3(p) + 0.5) * res.as_vec3();
        (a, b) = (a.min(g), b.max(g));
    }
    if !(a.is_finite() && b.is_finite()) {
        return None;
    }
    let a = (a.floor() - margin as f32).max(Vec3::ZERO);
    let b = (b.floor() + margin as f32).min(res.as_vec3() - 1.0);
    if a.cmpgt(b).any() {
        return None;
    }
    Some((a.as_uvec3(), b.as_uvec3()))
}

/// The world-space bounds of a box of cells of a `res` grid.
fn world_box(world_from_local: Mat4, res: UVec3, cells: CellBox) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for i in 0..8 {
        let g = Vec3::new(
            if i & 1 == 0 { cells.0.x as f32 } else { cells.1.x as f32 + 1.0 },
            if i & 2 == 0 { cells.0.y as f32 } else { cells.1.y as f32 + 1.0 },
            if i & 4 == 0 { cells.0.z as f32 } else { cells.1.z as f32 + 1.0 },
        );
        let p = world_from_local.transform_point3(g / res.as_vec3() - 0.5);
        (lo, hi) = (lo.min(p), hi.max(p));
    }
    let pad = (hi - lo).max_element() * 1e-4;
    (lo - pad, hi + pad)
}

fn cell_index(c: UVec3, res: UVec3) -> usize {
    (c.x + res.x * (c.y + res.y * c.z)) as usize
}

fn in_box(c: UVec3, cells: CellBox) -> bool {
    c.cmpge(cells.0).all() && c.cmple(cells.1).all()
}

/// Adds `albedo × area` of the stratified points of every triangle that land in `cells` to `sums`.
fn albedo_sums(snapshot: &SceneSnapshot, local_from_world: Mat4, res: UVec3, cells: CellBox, sums: &mut [Vec4]) {
    let world_from_local = local_from_world.inverse();
    let (lo, hi) = world_box(world_from_local, res, cells);
    let to_grid = |p: Vec3| (local_from_world.transform_point3(p) + 0.5) * res.as_vec3();
    for (t, tri) in snapshot.triangles_overlapping(lo, hi) {
        let [a, b, c] = tri.map(to_grid);
        let area = 0.5 * (b - a).cross(c - a).length();
        if !area.is_finite() || area <= 0.0 {
            continue;
        }
        let albedo = snapshot.triangle_albedo(t);
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
                let cell = p.as_uvec3().min(res - 1);
                if in_box(cell, cells) {
                    sums[cell_index(cell, res)] += (albedo * weight).extend(weight);
                }
            }
        }
    }
}

/// Per cell: mean albedo (rgb) and the surface area in the cell relative to one cell face (a, ≤ 1), from
/// [`GeometryVoxels::albedo_sums`]; empty cells take their neighbours' mean (three dilation passes), then
/// the volume's mean albedo.
fn finish_albedo(sums: &[Vec4], res: UVec3) -> Vec<Vec4> {
    let mut out: Vec<Vec4> = sums
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
    let total: Vec4 = sums.iter().copied().sum();
    let fallback = if total.w > 0.0 { total.truncate() / total.w } else { Vec3::splat(0.5) };
    for v in &mut out {
        if v.truncate() == Vec3::ZERO {
            *v = fallback.extend(0.0);
        }
    }
    out
}

/// Per cell: mean albedo (rgb) and the surface area in the cell relative to one cell face (a, ≤ 1).
pub fn voxelize_albedo(snapshot: &SceneSnapshot, local_from_world: Mat4, resolution: UVec3) -> Vec<Vec4> {
    let res = resolution.max(UVec3::ONE);
    let mut sums = vec![Vec4::ZERO; (res.x * res.y * res.z) as usize];
    albedo_sums(snapshot, local_from_world, res, (UVec3::ZERO, res - 1), &mut sums);
    finish_albedo(&sums, res)
}

fn validity_directions() -> Vec<Vec3> {
    use crate::sampling::uniform_sphere;
    use bevy::math::Vec2;
    // Fixed, well-spread directions (a Fibonacci-like lattice over the sphere).
    (0..VALIDITY_RAYS)
        .map(|i| uniform_sphere(Vec2::new((i as f32 + 0.5) / VALIDITY_RAYS as f32, (i as f32 * 0.618_034).fract())))
        .collect()
}

/// 1 when hint `c` lies outside solid geometry, 0 when most directions first meet the back of a surface.
fn hint_valid(snapshot: &SceneSnapshot, world_from_local: Mat4, res: UVec3, c: UVec3) -> f32 {
    thread_local! {
        static DIRECTIONS: Vec<Vec3> = validity_directions();
    }
    let local = (c.as_vec3() + 0.5) / res.as_vec3() - 0.5;
    let p = world_from_local.transform_point3(local);
    let (mut back, mut hits) = (0, 0);
    DIRECTIONS.with(|directions| {
        for &d in directions {
            if let Some(hit) = snapshot.intersect(p, d, 0.0, f32::INFINITY) {
                hits += 1;
                if snapshot.geometric_normal(hit.triangle).dot(d) > 0.0 {
                    back += 1;
                }
            }
        }
    });
    // Inside: most of the rays that hit anything hit a back face, and most rays hit.
    let inside = hits * 2 > VALIDITY_RAYS && back * 2 > hits;
    if inside {
        return 0.0;
    }
    // How far the hint's free space reaches along each cell axis, up to half a cell: a surface closer
    // than that (a wall 4 cm from the hint) bounds where the injection may put its receivers.
    let mut free = [FREE_STEPS; 6];
    for (side, extent) in free.iter_mut().enumerate() {
        let mut axis = Vec3::ZERO;
        axis[side / 2] = if side % 2 == 0 { -0.5 } else { 0.5 };
        let half = world_from_local.transform_vector3(axis / res.as_vec3());
        let length = half.length();
        if length <= 0.0 {
            continue;
        }
        if let Some(hit) = snapshot.intersect(p, half / length, 0.0, length) {
            // Rounded down, and a hundredth of a half cell short of the surface.
            *extent = ((hit.t / length - 0.01).max(0.0) * FREE_STEPS as f32).floor() as u32;
        }
    }
    encode_free_extents(free)
}

/// Bits per side of a hint's free extent (see [`encode_free_extents`]); `RH_FREE_BITS` in WGSL.
pub const FREE_BITS: u32 = 3;
/// Steps of a hint's free extent per half cell; `RH_FREE_STEPS` in WGSL.
pub const FREE_STEPS: u32 = (1 << FREE_BITS) - 1;
/// The bit that marks a validity value carrying free extents (after the six sides' bits);
/// `RH_FREE_MARKER_BIT` in WGSL.
pub const FREE_MARKER_BIT: u32 = 6 * FREE_BITS;
const FREE_MARKER: u32 = 1 << FREE_MARKER_BIT;

/// A valid hint's validity value: `1 + m · 2⁻²³` with `m` the six free extents (−x, +x, −y, +y, −z, +z;
/// 0–[`FREE_STEPS`] steps of half a cell each) in [`FREE_BITS`] bits apiece plus a marker bit, so that the
/// value stays in `[1, 2)` and every test of validity (`≥ 0.5`) still holds. `rh_types.wgsl`'s
/// `free_extents` decodes it, with these constants as shader defs.
pub fn encode_free_extents(free: [u32; 6]) -> f32 {
    let bits = free.iter().enumerate().fold(FREE_MARKER, |m, (i, &e)| m | (e.min(FREE_STEPS) << (FREE_BITS * i as u32)));
    f32::from_bits(1.0f32.to_bits() | bits)
}

/// The six free extents of a validity value of [`encode_free_extents`] (all full for a plain 1).
pub fn decode_free_extents(validity: f32) -> [u32; 6] {
    let bits = validity.to_bits() & 0x7f_ffff;
    if validity < 1.0 || bits & FREE_MARKER == 0 {
        return [FREE_STEPS; 6];
    }
    std::array::from_fn(|i| (bits >> (FREE_BITS * i as u32)) & FREE_STEPS)
}

/// Per hint: 1 when it lies outside solid geometry, 0 when most directions first meet the back of a
/// surface (the hint is inside a box or a thick wall).
pub fn hint_validity(snapshot: &SceneSnapshot, world_from_local: Mat4, resolution: UVec3) -> Vec<f32> {
    let res = resolution.max(UVec3::ONE);
    let mut out = Vec::with_capacity((res.x * res.y * res.z) as usize);
    for z in 0..res.z {
        for y in 0..res.y {
            for x in 0..res.x {
                out.push(hint_valid(snapshot, world_from_local, res, UVec3::new(x, y, z)));
            }
        }
    }
    out
}

/// Sets the bits of the voxels in `voxels` that a triangle overlaps.
fn occupancy_bits(snapshot: &SceneSnapshot, local_from_world: Mat4, res: UVec3, voxels: CellBox, bits: &mut [u32]) {
    let (lo_w, hi_w) = world_box(local_from_world.inverse(), res, voxels);
    let to_grid = |p: Vec3| (local_from_world.transform_point3(p) + 0.5) * res.as_vec3();
    for (_, tri) in snapshot.triangles_overlapping(lo_w, hi_w) {
        let tri = tri.map(to_grid);
        let lo = tri[0].min(tri[1]).min(tri[2]).floor().max(voxels.0.as_vec3());
        let hi = tri[0].max(tri[1]).max(tri[2]).floor().min(voxels.1.as_vec3());
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
}

/// Conservative surface voxelisation: a bit per voxel of the grid `resolution` over the unit cube, set
/// where a triangle overlaps the voxel.
pub fn voxelize_occupancy(snapshot: &SceneSnapshot, local_from_world: Mat4, resolution: UVec3) -> Vec<u32> {
    let res = resolution.max(UVec3::ONE);
    let words = ((res.x * res.y * res.z) as usize).div_ceil(32);
    let mut bits = vec![0u32; words];
    occupancy_bits(snapshot, local_from_world, res, (UVec3::ZERO, res - 1), &mut bits);
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
    let mut walk = crate::voxels::VoxelWalk::new(a, delta / len);
    let limit = len - skip_end;
    let occupied = |v: bevy::math::IVec3| {
        if v.cmplt(bevy::math::IVec3::ZERO).any() || v.cmpge(res.as_ivec3()).any() {
            return false;
        }
        let i = cell_index(v.as_uvec3(), res);
        occupancy[i / 32] & (1 << (i % 32)) != 0
    };
    for _ in 0..(res.x + res.y + res.z + 2) {
        let t = walk.advance();
        if t >= limit {
            return None;
        }
        if occupied(walk.voxel()) {
            return Some(t / len);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    #[test]
    fn free_extents_round_trip_and_stay_valid() {
        for free in [[0, 7, 3, 3, 1, 6], [7; 6], [0; 6]] {
            let v = super::encode_free_extents(free);
            assert!((1.0..2.0).contains(&v), "{v}");
            assert_eq!(super::decode_free_extents(v), free);
        }
        assert_eq!(super::decode_free_extents(1.0), [super::FREE_STEPS; 6]);
    }

    #[test]
    fn a_hint_beside_a_wall_keeps_its_receivers_on_its_side() {
        // cellar: the dividing wall spans x ∈ [−0.1, 0.1]. A 0.4 m cell centred 5 cm from its face.
        let scene = crate::scenes::cellar_snapshot();
        let world_from_local = Mat4::from_scale_rotation_translation(Vec3::splat(0.4), bevy::math::Quat::IDENTITY, Vec3::new(0.15, 1.2, 1.0));
        let v = super::hint_valid(&scene, world_from_local, UVec3::ONE, UVec3::ZERO);
        let free = super::decode_free_extents(v);
        // 5 cm of a 20 cm half cell towards the wall (−x): 1 step of 7 (rounded down); free elsewhere.
        assert_eq!(free, [1, 7, 7, 7, 7, 7], "{v}");
    }

    use super::*;
    use crate::scene::{InputTriangle, SnapshotMaterial};

    /// Two grey walls at x = ±1.9 and two red 0.6 m cubes (instances 100 and 101) at `cubes`.
    fn walls_and_cubes(cubes: [Vec3; 2]) -> crate::scene::SceneSnapshot {
        use crate::scene::{MeshGeometry, SceneSnapshot};
        use bevy::math::Affine3A;
        use std::sync::Arc;
        let cube = Arc::new(MeshGeometry::new(
            crate::scene::mesh_local_triangles(&bevy::prelude::Mesh::from(bevy::prelude::Cuboid::new(0.6, 0.6, 0.6))).unwrap(),
        ));
        let red = SnapshotMaterial { diffuse: Vec3::new(0.8, 0.1, 0.1), ..SnapshotMaterial::DEFAULT_GREY };
        let mut scene = SceneSnapshot::build(wall(-1.9, 0).into_iter().chain(wall(1.9, 0)), vec![SnapshotMaterial::DEFAULT_GREY, red], vec![], vec![]);
        scene.set_instance(100, cube.clone(), Affine3A::from_translation(cubes[0]), 1);
        scene.set_instance(101, cube, Affine3A::from_translation(cubes[1]), 1);
        scene.commit();
        scene
    }

    #[test]
    fn a_volume_scrolled_by_whole_cells_equals_a_full_voxelisation_there() {
        // Off the cell boundaries, so that rounding at a boundary cannot decide a bit.
        let scene = walls_and_cubes([Vec3::new(-0.83, 0.07, 0.11), Vec3::new(0.93, 0.53, 0.29)]);
        let res = UVec3::new(8, 6, 8);
        let size = Vec3::new(4.0, 3.0, 4.0);
        let cell = size / res.as_vec3();
        let at = |centre: Vec3| Mat4::from_scale_rotation_translation(size, bevy::math::Quat::IDENTITY, centre);
        let before = voxelize(&scene, at(Vec3::new(0.01, 0.02, 0.03)), res);
        for shift in [IVec3::new(1, 0, 0), IVec3::new(-2, 0, 1), IVec3::new(1, -1, -3)] {
            let old = at(Vec3::new(0.01, 0.02, 0.03));
            let new = at(Vec3::new(0.01, 0.02, 0.03) + shift.as_vec3() * cell);
            assert_eq!(scroll_shift(old, new, res), Some(shift));
            let scrolled = voxelize_scrolled(&scene, new, res, &before, shift).expect("a whole-cell move scrolls");
            let full = voxelize(&scene, new, res);
            let differing = (0..full.occupancy.len() * 32).filter(|&i| (scrolled.occupancy[i / 32] ^ full.occupancy[i / 32]) & (1 << (i % 32)) != 0).count();
            assert_eq!(differing, 0, "shift {shift}: {differing} occupancy bits differ");
            for (a, b) in scrolled.albedo_validity.iter().zip(&full.albedo_validity) {
                assert!((*a - *b).abs().max_element() < 1e-3, "shift {shift}: {a} vs {b}");
            }
        }
        // Not a whole number of cells, a turn or a new size: no scroll.
        let old = at(Vec3::ZERO);
        assert_eq!(scroll_shift(old, at(Vec3::new(0.3 * cell.x, 0.0, 0.0)), res), None);
        assert_eq!(scroll_shift(old, old, res), None);
        assert_eq!(scroll_shift(old, Mat4::from_scale(size * 1.5), res), None);
        assert_eq!(scroll_shift(old, Mat4::from_rotation_y(0.3) * old, res), None);
        // A move across the whole grid is voxelised afresh.
        assert!(voxelize_scrolled(&scene, at(Vec3::X * 9.0 * cell.x), res, &before, IVec3::new(9, 0, 0)).is_none());
    }

    #[test]
    fn an_update_after_a_move_equals_a_full_voxelisation() {
        use bevy::math::Affine3A;
        let mut scene = walls_and_cubes([Vec3::new(-0.8, 0.0, 0.0), Vec3::new(0.9, 0.5, 0.3)]);
        let volume = Mat4::from_scale(Vec3::splat(4.0));
        let res = UVec3::splat(8);
        let before = voxelize(&scene, volume, res);
        scene.set_instance_transform(100, Affine3A::from_translation(Vec3::new(0.2, -0.7, 0.4)));
        scene.commit();
        let updated = voxelize_update(&scene, volume, res, &before, &scene.last_change.dirty);
        let full = voxelize(&scene, volume, res);
        assert_ne!(before.occupancy, full.occupancy, "the move must change something");
        assert_eq!(updated.occupancy, full.occupancy);
        for (a, b) in updated.albedo_validity.iter().zip(&full.albedo_validity) {
            assert!((a.truncate() - b.truncate()).abs().max_element() < 1e-4, "{a} vs {b}");
        }
        // Validity is redone near the change only; a far hint whose rays the moved box now shades may differ.
        let differing = updated.albedo_validity.iter().zip(&full.albedo_validity).filter(|(a, b)| a.w != b.w).count();
        assert!(differing * 50 <= full.albedo_validity.len(), "{differing} hints differ in validity");
        // The change it reports covers every occupancy voxel and every hint's voxels that differ, and not
        // the whole grid.
        let VoxelChange::Voxels(lo, hi) = updated.changed else {
            panic!("an incremental update reports a box, not {:?}", updated.changed);
        };
        let occ = full.occupancy_resolution;
        let inside = |v: UVec3| v.cmpge(lo).all() && v.cmple(hi).all();
        for z in 0..occ.z {
            for y in 0..occ.y {
                for x in 0..occ.x {
                    let v = UVec3::new(x, y, z);
                    if bit(&before.occupancy, v, occ) != bit(&updated.occupancy, v, occ) {
                        assert!(inside(v), "voxel {v} changed outside the reported box {lo}..={hi}");
                    }
                }
            }
        }
        for (i, (a, b)) in before.albedo_validity.iter().zip(&updated.albedo_validity).enumerate() {
            if a.w != b.w {
                let c = UVec3::new(i as u32 % res.x, (i as u32 / res.x) % res.y, i as u32 / (res.x * res.y));
                assert!(inside(c * OCCUPANCY_FACTOR) && inside(c * OCCUPANCY_FACTOR + OCCUPANCY_FACTOR - 1), "hint {c}");
            }
        }
        let (size, all) = ((hi - lo + 1).as_vec3(), occ.as_vec3());
        assert!(size.x * size.y * size.z < 0.8 * all.x * all.y * all.z, "the box {lo}..={hi} is most of the grid");
        assert_eq!(full.changed, VoxelChange::All);
        let unchanged = voxelize_update(&scene, volume, res, &updated, &[]);
        assert_eq!(unchanged.changed, VoxelChange::Nothing);
    }

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
        assert!(v[0] >= 0.5);
        // Nothing within half a cell of the corner hint: free all round.
        assert_eq!(decode_free_extents(v[0]), [FREE_STEPS; 6]);
        assert_eq!(v.iter().filter(|x| **x == 0.0).count(), 1);
    }
}
