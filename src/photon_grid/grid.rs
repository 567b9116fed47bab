//! The preparation stage of the photon grid (Chang, Park & Ihm, §3) on the CPU: the V-grid and SH-grid
//! (§3.1), photon tracing into the global photon list (§3.2), the multilevel R-grid by sorting, flagging,
//! scanning and per-cell accumulation (§3.3, Fig. 3) and the spherical-harmonics field of incoming
//! radiance and distance at the SH-grid's boundary cells and their 26 neighbours (§3.4). The final gather
//! (§4) has a CPU twin here, [`ShField::irradiance`], for the tests; the GPU's is
//! `shaders/photon_grid/gather.wgsl`. See the [module docs](super) for the algorithm and its departures.

use std::f32::consts::PI;

use bevy::math::{IVec3, UVec3, Vec2, Vec3, Vec4};
use rand::RngExt;
use rayon::prelude::*;

use crate::sampling::{cosine_hemisphere, fibonacci_sphere, orthonormal_basis, rng_for, uniform2, uniform_sphere};
use crate::scene::changes::segment_meets_box;
use crate::scene::environment::Environment;
use crate::scene::{OPEN_BACK, OPEN_FRONT, SceneSnapshot, SnapshotLight, range_falloff, triangle_area, triangle_box_overlap};
use crate::sh::{COSINE_LOBE, band, basis};

/// V-grid cells per SH-grid cell along each axis (§3.1: 4 × 4 × 4 V-cells merge into one SH cell).
pub const V_PER_SH: u32 = 4;

/// The six directional faces of a cell: `+x, −x, +y, −y, +z, −z`.
pub const FACES: usize = 6;

/// Where the grids lie: a box of `dims` cubic SH-grid cells of side `cell` from `origin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridLayout {
    pub origin: Vec3,
    /// SH-grid cell side, metres.
    pub cell: f32,
    /// SH-grid cells per axis.
    pub dims: UVec3,
}

impl GridLayout {
    /// The layout over the box `lo..hi` with `resolution` cells along its longest side (cubic cells),
    /// padded by a cell on every side, so that surfaces on the box's faces lie inside and a box whose
    /// sides are whole cells has its walls on cell boundaries (not through the probes at cell centres).
    pub fn fit(lo: Vec3, hi: Vec3, resolution: u32) -> Self {
        let resolution = resolution.max(1);
        let extent = (hi - lo).max(Vec3::splat(1e-3));
        let cell = extent.max_element() / resolution as f32;
        let padded = extent + 2.0 * cell;
        let dims = (padded / cell).ceil().as_uvec3().max(UVec3::ONE);
        let centre = (lo + hi) * 0.5;
        Self { origin: centre - dims.as_vec3() * cell * 0.5, cell, dims }
    }

    pub fn cell_count(&self) -> usize {
        (self.dims.x * self.dims.y * self.dims.z) as usize
    }

    /// V-grid cells per axis.
    pub fn v_dims(&self) -> UVec3 {
        self.dims * V_PER_SH
    }

    /// V-grid cell side, metres.
    pub fn v_cell(&self) -> f32 {
        self.cell / V_PER_SH as f32
    }

    /// Linear index of SH cell `c`.
    pub fn index(&self, c: UVec3) -> usize {
        ((c.z * self.dims.y + c.y) * self.dims.x + c.x) as usize
    }

    /// The SH cell of a linear index.
    pub fn coords(&self, i: usize) -> UVec3 {
        let i = i as u32;
        UVec3::new(i % self.dims.x, (i / self.dims.x) % self.dims.y, i / (self.dims.x * self.dims.y))
    }

    /// The SH cell containing `p`, if inside.
    pub fn cell_of(&self, p: Vec3) -> Option<UVec3> {
        let c = ((p - self.origin) / self.cell).floor();
        (c.is_finite() && c.cmpge(Vec3::ZERO).all() && c.cmplt(self.dims.as_vec3()).all()).then(|| c.as_uvec3())
    }

    /// World centre of SH cell `c`.
    pub fn centre(&self, c: UVec3) -> Vec3 {
        self.origin + (c.as_vec3() + 0.5) * self.cell
    }

    /// Linear index of V-cell `v`.
    pub fn v_index(&self, v: UVec3) -> u32 {
        let d = self.v_dims();
        (v.z * d.y + v.y) * d.x + v.x
    }

    /// The V-cell of a linear index.
    pub fn v_coords(&self, i: u32) -> UVec3 {
        let d = self.v_dims();
        UVec3::new(i % d.x, (i / d.x) % d.y, i / (d.x * d.y))
    }

    /// How far around a changed box what the photons and probe rays read can have changed: a stored
    /// photon's SH cell and faces, the SH cells a probe ray skips or walks (one SH cell), and the
    /// V-cells a triangle marks beyond its own box (one V-cell).
    pub fn change_margin(&self) -> f32 {
        self.cell + self.v_cell()
    }
}

/// How far (in V-cells) beyond a cell a triangle still marks it.
const BOUNDARY_MARGIN: f32 = 1e-3;

/// One boundary cell of the V-grid: the area-weighted sum of the unit normals of the triangles that
/// overlap it (§3.1) and their area (each triangle's area is shared equally among the cells it overlaps).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VCell {
    pub normal_sum: Vec3,
    pub area: f32,
}

/// The V-grid (a bit per cell, set on boundary cells, and each boundary cell's [`VCell`]) and the SH-grid
/// built from it by merging 4 × 4 × 4 cells (§3.1).
#[derive(Clone, Debug, Default)]
pub struct VGrid {
    pub layout: Option<GridLayout>,
    bits: Vec<u64>,
    /// Boundary cells sorted by linear V-grid index.
    cells: Vec<(u32, VCell)>,
    /// Per SH cell: whether one of its V-cells is a boundary cell.
    pub sh_boundary: Vec<bool>,
}

impl VGrid {
    /// Surface voxelisation of every triangle of `snapshot` into the grid `layout` (a conservative
    /// triangle–box overlap per cell of the triangle's bounding box).
    pub fn build(snapshot: &SceneSnapshot, layout: GridLayout) -> Self {
        let v_dims = layout.v_dims();
        let v_cell = layout.v_cell();
        let triangles: Vec<[Vec3; 3]> = snapshot.triangles().map(|(_, t)| t).collect();
        let mut entries: Vec<(u32, VCell)> = triangles
            .par_iter()
            .flat_map_iter(|tri| {
                let area = triangle_area(tri);
                let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
                let local = tri.map(|p| (p - layout.origin) / v_cell);
                let lo = (local[0].min(local[1]).min(local[2]) - BOUNDARY_MARGIN).floor().max(Vec3::ZERO);
                let hi = (local[0].max(local[1]).max(local[2]) + BOUNDARY_MARGIN).floor().min(v_dims.as_vec3() - 1.0);
                let mut hits = Vec::new();
                if area.is_finite() && area > 0.0 && normal != Vec3::ZERO && lo.cmple(hi).all() {
                    let (lo, hi) = (lo.as_uvec3(), hi.as_uvec3());
                    for z in lo.z..=hi.z {
                        for y in lo.y..=hi.y {
                            for x in lo.x..=hi.x {
                                let c = UVec3::new(x, y, z);
                                // Slightly larger than the cell, so that a surface on a cell boundary marks
                                // the cells on both sides whatever the rounding: photons are stored on
                                // the side they leave from, and a ray must stop in that cell.
                                if triangle_box_overlap(c.as_vec3() + 0.5, Vec3::splat(0.5 + BOUNDARY_MARGIN), local) {
                                    hits.push(layout.v_index(c));
                                }
                            }
                        }
                    }
                }
                let share = area / hits.len().max(1) as f32;
                hits.into_iter().map(move |i| (i, VCell { normal_sum: normal * share, area: share }))
            })
            .collect();
        entries.par_sort_unstable_by_key(|e| e.0);
        let mut cells: Vec<(u32, VCell)> = Vec::new();
        for (i, c) in entries {
            match cells.last_mut() {
                Some((j, sum)) if *j == i => {
                    sum.normal_sum += c.normal_sum;
                    sum.area += c.area;
                }
                _ => cells.push((i, c)),
            }
        }
        let total = (v_dims.x * v_dims.y * v_dims.z) as usize;
        let mut bits = vec![0u64; total.div_ceil(64)];
        let mut sh_boundary = vec![false; layout.cell_count()];
        for &(i, _) in &cells {
            bits[i as usize / 64] |= 1 << (i % 64);
            sh_boundary[layout.index(layout.v_coords(i) / V_PER_SH)] = true;
        }
        Self { layout: Some(layout), bits, cells, sh_boundary }
    }

    /// The boundary V-cells, sorted by linear index, with their data (for the GPU's field).
    pub(super) fn boundary_data(&self) -> &[(u32, VCell)] {
        &self.cells
    }

    /// Boundary V-cells.
    pub fn boundary_cells(&self) -> usize {
        self.cells.len()
    }

    /// Whether V-cell `v` is a boundary cell (false outside the grid).
    pub fn occupied(&self, v: IVec3) -> bool {
        let Some(layout) = self.layout else { return false };
        let d = layout.v_dims().as_ivec3();
        if v.cmplt(IVec3::ZERO).any() || v.cmpge(d).any() {
            return false;
        }
        let i = layout.v_index(v.as_uvec3()) as usize;
        self.bits[i / 64] & (1 << (i % 64)) != 0
    }

    /// The data of boundary cell `v`.
    pub fn cell(&self, v: UVec3) -> Option<VCell> {
        let i = self.layout?.v_index(v);
        self.cells.binary_search_by_key(&i, |e| e.0).ok().map(|k| self.cells[k].1)
    }

    /// The faces of the SH cell around `p` that a surface facing `p` hides: walking from `p`'s V-cell
    /// towards each face along its axis, a boundary V-cell whose normal faces back (or whose normals
    /// cancel: both faces of a thin wall) blocks it. A floor photon beside a wall thinner than the cell
    /// then lights the cell's faces on its own side only, and a room does not see the next room's floor
    /// through the wall (§3.3's faces carry the light of everything in the cell otherwise).
    pub fn blocked_faces(&self, p: Vec3) -> u8 {
        let Some(layout) = self.layout else { return 0 };
        let v = ((p - layout.origin) / layout.v_cell()).floor();
        if !v.is_finite() || v.cmplt(Vec3::ZERO).any() || v.cmpge(layout.v_dims().as_vec3()).any() {
            return 0;
        }
        let v = v.as_ivec3();
        let per = V_PER_SH as i32;
        let sh = v / per;
        let mut blocked = 0u8;
        for face in 0..FACES {
            let axis = face / 2;
            let step = if face % 2 == 0 { 1 } else { -1 };
            let e = Vec3::AXES[axis] * step as f32;
            let mut w = v;
            loop {
                w[axis] += step;
                if w[axis].div_euclid(per) != sh[axis] {
                    break;
                }
                if !self.occupied(w) {
                    continue;
                }
                let Some(cell) = self.cell(w.as_uvec3()) else { continue };
                let coherent = cell.normal_sum.length() > 0.5 * cell.area;
                if !coherent || cell.normal_sum.normalize().dot(e) < -0.5 {
                    blocked |= 1 << face;
                    break;
                }
            }
        }
        blocked
    }

    /// Whether a boundary V-cell lies strictly between the cells of the world points `a` and `b` (the
    /// gather's visibility test from a surface point to a probe; the CPU twin of `segment_blocked` in
    /// `shaders/photon_grid/gather.wgsl`).
    pub fn segment_blocked(&self, a: Vec3, b: Vec3) -> bool {
        let Some(layout) = self.layout else { return false };
        let (a, b) = ((a - layout.origin) / layout.v_cell(), (b - layout.origin) / layout.v_cell());
        let delta = b - a;
        let len = delta.length();
        if len < 1e-5 || !len.is_finite() {
            return false;
        }
        let end = b.floor().as_ivec3();
        let mut walk = crate::voxels::VoxelWalk::new(a, delta / len);
        for _ in 0..(len.ceil() as i32 * 3 + 3) {
            if walk.advance() >= len {
                return false;
            }
            let v = walk.voxel();
            if v == end {
                return false;
            }
            if self.occupied(v) {
                return true;
            }
        }
        false
    }

    /// The occupancy bits as 32-bit words (bit `i % 32` of word `i / 32` for V-cell `i`), for the GPU.
    pub fn occupancy_words(&self) -> Vec<u32> {
        self.bits.iter().flat_map(|w| [*w as u32, (*w >> 32) as u32]).collect()
    }

    /// Walks the V-grid from `origin` (world) along the unit `direction`: the first boundary cell and the
    /// distance at which the ray enters it, or `None` when it leaves the grid. The two-level traversal of
    /// §3.4.2: whole SH cells without a boundary V-cell are crossed in one step.
    pub fn march(&self, origin: Vec3, direction: Vec3) -> Option<(UVec3, f32)> {
        let layout = self.layout?;
        let v_cell = layout.v_cell();
        let a = (origin - layout.origin) / v_cell;
        let d = direction;
        let mut walk = crate::voxels::VoxelWalk::new(a, d);
        let dims = layout.v_dims().as_ivec3();
        let per = V_PER_SH as i32;
        for _ in 0..(4 * (dims.x + dims.y + dims.z) + 8) {
            let v = walk.voxel();
            if v.cmplt(IVec3::ZERO).any() || v.cmpge(dims).any() {
                return None;
            }
            let sh = v / per;
            if !self.sh_boundary[layout.index(sh.as_uvec3())] {
                // An SH cell without surfaces is crossed in one step (the two-level traversal).
                let lo = (sh * per).as_vec3();
                let mut t_exit = f32::INFINITY;
                for k in 0..3 {
                    if d[k] > 1e-8 {
                        t_exit = t_exit.min((lo[k] + per as f32 - a[k]) / d[k]);
                    } else if d[k] < -1e-8 {
                        t_exit = t_exit.min((lo[k] - a[k]) / d[k]);
                    }
                }
                if !t_exit.is_finite() {
                    return None;
                }
                walk.restart(t_exit.max(walk.t()) + 1e-4);
                continue;
            }
            if self.occupied(v) {
                return Some((v.as_uvec3(), walk.t() * v_cell));
            }
            walk.advance();
        }
        None
    }
}

/// One entry of the global photon list (§3.2): the SH cell it was stored in, its outgoing (reflected)
/// direction and the flux it leaves with, lumens per channel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Photon {
    pub cell: u32,
    pub direction: Vec3,
    pub power: Vec3,
    /// Faces of its cell (bit `f` for face `f`) that a surface facing the photon hides from it: its flux
    /// does not go out through them (see [`VGrid::blocked_faces`]).
    pub blocked: u8,
}

/// Where the emitted flux went, lumens per channel (expected values: a surface absorbs `(1 − ρ)` of what
/// reaches it, whatever the Russian roulette drew), for the conservation test and the panel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhotonStats {
    /// Flux leaving the light sources (including emission stored at emissive surfaces).
    pub emitted: Vec3,
    /// Absorbed by surfaces.
    pub absorbed: Vec3,
    /// Left the scene without hitting anything.
    pub escaped: Vec3,
    /// Reflected at the last stored reflection and not traced further.
    pub truncated: Vec3,
    /// Photons emitted and photons stored.
    pub paths: u32,
    pub stored: u32,
}

/// What photon tracing needs besides the snapshot.
#[derive(Clone, Copy, Debug)]
pub struct TraceParams {
    /// Photons emitted over all sources.
    pub photons: u32,
    /// Stored reflections per path (the paper keeps four).
    pub max_reflections: u32,
    pub seed: u64,
    /// Exposure of the camera (for `emissive.alpha < 1` materials).
    pub exposure: f32,
}

/// A source of photons with its emitted flux (lumens per channel).
enum Source<'a> {
    Light(SnapshotLight),
    /// An emissive triangle (snapshot index) and its open faces ([`crate::scene::MeshGeometry::open_sides`]).
    Emitter(u32, u8),
    /// The environment map and its mean radiance.
    Environment(&'a Environment, Vec3),
}

fn luminance_sum(v: Vec3) -> f32 {
    let s = v.x + v.y + v.z;
    if s.is_finite() { s.max(0.0) } else { 0.0 }
}

/// Traces `params.photons` photons from `lights`, the snapshot's emissive triangles and its environment
/// (§3.2): each hit on a surface reflects by Russian roulette on the diffuse albedo, and a reflected
/// photon is stored with its outgoing direction, the flux it leaves with and the SH cell of the hit; up
/// to `max_reflections` stored reflections per path. Emissive surfaces also store their emission at the
/// point it leaves, so that the R-grid holds their radiance too. Photons outside `layout` are traced but
/// not stored.
pub fn trace_photons(
    snapshot: &SceneSnapshot,
    lights: &[SnapshotLight],
    environment: Option<&Environment>,
    vgrid: &VGrid,
    params: &TraceParams,
) -> (Vec<Photon>, PhotonStats) {
    let paths = PhotonPaths::trace(snapshot, lights, environment, vgrid, params);
    (paths.photons, paths.stats)
}

/// The photon list kept path by path, with where each path went, so that a later trace can redo only
/// the paths a change touches ([`PhotonPaths::retrace`]). Path `k` draws its random numbers from its own
/// stream (`rng_for(seed, k)`), so a path traced again in an unchanged scene is the same path.
#[derive(Clone, Debug, Default)]
pub struct PhotonPaths {
    /// Every stored photon, path after path (what [`trace_photons`] returns).
    pub photons: Vec<Photon>,
    /// Where each path's photons start in `photons` (one more entry than paths).
    photon_offsets: Vec<u32>,
    /// The points each path's rays ran between: its origin, then the end of every ray it traced (the
    /// surface hit, or a point beyond the scene for a ray that left it).
    points: Vec<Vec3>,
    /// Where each path's points start in `points` (one more entry than paths).
    point_offsets: Vec<u32>,
    /// Each path's flux balance (`paths` and `stored` as counts).
    path_stats: Vec<PhotonStats>,
    /// The sum of `path_stats`.
    pub stats: PhotonStats,
}

/// One traced path: its photons, ray end points and flux balance.
#[derive(Default)]
struct TracedPath {
    photons: Vec<Photon>,
    points: Vec<Vec3>,
    stats: PhotonStats,
}

/// The photon sources of a scene and their flux, with each photon's source (§3.2's emission).
struct Sources<'a> {
    sources: Vec<(Source<'a>, Vec3)>,
    cumulative: Vec<f32>,
    counts: Vec<u32>,
    photons: u32,
    /// The scene's bounding sphere.
    sphere: (Vec3, f32),
    epsilon: f32,
}

impl<'a> Sources<'a> {
    fn new(snapshot: &SceneSnapshot, lights: &[SnapshotLight], environment: Option<&'a Environment>, params: &TraceParams) -> Option<Self> {
        let (lo, hi) = snapshot.bounds()?;
        let centre = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-3) * 1.01;
        let disc_area = PI * radius * radius;
        let mut sources: Vec<(Source, Vec3)> = Vec::new();
        for &light in lights {
            let flux = match light {
                SnapshotLight::Directional { illuminance, .. } => illuminance * disc_area,
                SnapshotLight::Point { intensity, .. } => intensity * 4.0 * PI,
                SnapshotLight::Spot { intensity, spot_scale, spot_offset, .. } => {
                    let cos_outer = spot_cos_outer(spot_scale, spot_offset);
                    intensity * (2.0 * PI * (1.0 - cos_outer))
                }
            };
            sources.push((Source::Light(light), flux));
        }
        for (i, tri) in snapshot.triangles() {
            let (instance, local) = snapshot.locate(i);
            let Some(material) = snapshot.materials.get(instance.material as usize) else { continue };
            let emission = material.emission(params.exposure);
            if !emission.is_finite() || emission.max_element() <= 0.0 {
                continue;
            }
            let area = triangle_area(&tri);
            // Two-sided Lambertian emitter: π L_e A from each open face (a face inside its own closed mesh
            // emits nothing that leaves it, and its photons would be stored as light leaving the emitter).
            let open = instance.open_sides(local);
            sources.push((Source::Emitter(i, open), emission.max(Vec3::ZERO) * (open.count_ones() as f32 * PI * area)));
        }
        if let Some(env) = environment {
            let mean = (0..256).map(|i| env.radiance(fibonacci_sphere(i, 256))).sum::<Vec3>() / 256.0;
            // Radiance over the sphere of directions through a disc facing each one.
            sources.push((Source::Environment(env, mean), mean * (4.0 * PI * disc_area)));
        }
        sources.retain(|(_, flux)| luminance_sum(*flux) > 0.0);
        let total: f32 = sources.iter().map(|(_, f)| luminance_sum(*f)).sum();
        if sources.is_empty() || !total.is_finite() || params.photons == 0 {
            return None;
        }
        // Stratified allocation by flux: photon k comes from the source whose cumulative share holds
        // (k + ½)/N, and carries its flux over the photons it got.
        let mut cumulative = Vec::with_capacity(sources.len());
        let mut acc = 0.0;
        for (_, f) in &sources {
            acc += luminance_sum(*f) / total;
            cumulative.push(acc);
        }
        let mut this = Self { sources, cumulative, counts: Vec::new(), photons: params.photons, sphere: (centre, radius), epsilon: snapshot.ray_epsilon() };
        let mut counts = vec![0u32; this.sources.len()];
        for k in 0..params.photons {
            counts[this.source_of(k)] += 1;
        }
        this.counts = counts;
        Some(this)
    }

    fn source_of(&self, k: u32) -> usize {
        let u = (k as f32 + 0.5) / self.photons as f32;
        self.cumulative.partition_point(|&c| c < u).min(self.sources.len() - 1)
    }

    /// Photon `k`'s path, into `path` (cleared first: one buffer serves many paths).
    fn trace(&self, snapshot: &SceneSnapshot, vgrid: &VGrid, params: &TraceParams, k: u32, path: &mut TracedPath) {
        path.photons.clear();
        path.points.clear();
        path.stats = PhotonStats::default();
        let s = self.source_of(k);
        let (source, flux) = &self.sources[s];
        let mut rng = rng_for(params.seed, k as u64);
        let share = *flux / self.counts[s] as f32;
        let Some((origin, direction, power, falloff)) = emit(snapshot, source, share, self.sphere, &mut rng, self.epsilon) else {
            return;
        };
        if !power.is_finite() || power.max_element() <= 0.0 {
            return;
        }
        path.stats.paths = 1;
        path.stats.emitted = power;
        // The emission leaves an emitter: stored, like a reflection, with its direction.
        let emission = matches!(source, Source::Emitter(..));
        let start = PathStart { origin, direction, power, falloff, emission };
        let far = 4.0 * self.sphere.1;
        trace_path(snapshot, vgrid, params, start, self.epsilon, far, &mut rng, path);
    }

    /// The paths `ks`, traced on every core in runs of 1 024, in the order of `ks`.
    fn trace_many(&self, snapshot: &SceneSnapshot, vgrid: &VGrid, params: &TraceParams, ks: &[u32]) -> PhotonPaths {
        let runs: Vec<PhotonPaths> = ks
            .par_chunks(1024)
            .map(|run| {
                let (mut out, mut path) = (PhotonPaths::default(), TracedPath::default());
                for &k in run {
                    self.trace(snapshot, vgrid, params, k, &mut path);
                    out.push(&path);
                }
                out
            })
            .collect();
        let mut all = PhotonPaths::default();
        for run in &runs {
            all.copy_runs(run, 0..run.len());
        }
        all
    }
}

impl PhotonPaths {
    /// Traces every path (what [`trace_photons`] does), keeping each path's record.
    pub fn trace(snapshot: &SceneSnapshot, lights: &[SnapshotLight], environment: Option<&Environment>, vgrid: &VGrid, params: &TraceParams) -> Self {
        let Some(sources) = vgrid.layout.and(Sources::new(snapshot, lights, environment, params)) else {
            return Self::default();
        };
        let all: Vec<u32> = (0..params.photons).collect();
        let mut paths = sources.trace_many(snapshot, vgrid, params, &all);
        paths.sum_stats();
        paths
    }

    /// Bytes held by what is kept besides the photons (the paths' points, offsets and balances).
    pub fn bytes(&self) -> usize {
        self.points.len() * size_of::<Vec3>()
            + (self.photon_offsets.len() + self.point_offsets.len()) * 4
            + self.path_stats.len() * size_of::<PhotonStats>()
    }

    /// Drops the paths' records, keeping the photons and their balance: a later
    /// [`retrace`](Self::retrace) traces every path. (A scene in which nothing moves need not hold them.)
    pub fn forget_paths(&mut self) {
        (self.points, self.photon_offsets, self.point_offsets, self.path_stats) = Default::default();
    }

    /// Paths whose records are kept.
    pub fn len(&self) -> usize {
        self.path_stats.len()
    }

    /// Whether no path's record is kept.
    pub fn is_empty(&self) -> bool {
        self.path_stats.is_empty()
    }

    /// The offsets' leading zeros, before the first path is appended.
    fn begin(&mut self) {
        if self.photon_offsets.is_empty() {
            self.photon_offsets.push(0);
            self.point_offsets.push(0);
        }
    }

    /// Appends one path.
    fn push(&mut self, path: &TracedPath) {
        self.begin();
        self.photons.extend_from_slice(&path.photons);
        self.points.extend_from_slice(&path.points);
        self.photon_offsets.push(self.photons.len() as u32);
        self.point_offsets.push(self.points.len() as u32);
        self.path_stats.push(path.stats);
    }

    /// Whether path `k` ran a ray through one of `boxes`.
    fn touches(&self, k: usize, boxes: &[(Vec3, Vec3)]) -> bool {
        let points = &self.points[self.point_offsets[k] as usize..self.point_offsets[k + 1] as usize];
        points.windows(2).any(|w| boxes.iter().any(|&b| segment_meets_box(w[0], w[1], b)))
    }

    /// Brings the paths up to date with a scene in which only what lies in `changed` (world boxes:
    /// the old and new bounds of what moved) differs from the scene they were traced in, same sources and
    /// same settings: the paths whose rays ran through a box grown by [`GridLayout::change_margin`] (what
    /// a photon's storage reads around it) are traced again, the others kept. The result is the full trace's.
    /// Without the paths' records ([`forget_paths`](Self::forget_paths)) every path is traced, unless
    /// nothing changed. Returns how many paths were traced again.
    pub fn retrace(
        &mut self,
        snapshot: &SceneSnapshot,
        lights: &[SnapshotLight],
        environment: Option<&Environment>,
        vgrid: &VGrid,
        params: &TraceParams,
        changed: &[(Vec3, Vec3)],
    ) -> usize {
        let (Some(layout), Some(sources)) = (vgrid.layout, Sources::new(snapshot, lights, environment, params)) else {
            *self = Self::default();
            return 0;
        };
        if changed.is_empty() && self.stats.paths > 0 {
            return 0;
        }
        if self.len() != params.photons as usize {
            *self = Self::trace(snapshot, lights, environment, vgrid, params);
            return params.photons as usize;
        }
        let margin = layout.change_margin();
        let boxes: Vec<(Vec3, Vec3)> = changed.iter().map(|&(lo, hi)| (lo - margin, hi + margin)).collect();
        let redo: Vec<u32> = (0..params.photons).into_par_iter().filter(|&k| self.touches(k as usize, &boxes)).collect();
        if redo.is_empty() {
            return 0;
        }
        let traced = sources.trace_many(snapshot, vgrid, params, &redo);
        // The kept paths' runs are copied whole between the paths traced again.
        let old = std::mem::take(self);
        self.photons.reserve(old.photons.len());
        self.points.reserve(old.points.len());
        let mut next = 0usize;
        for (i, &k) in redo.iter().enumerate() {
            self.copy_runs(&old, next..k as usize);
            self.copy_runs(&traced, i..i + 1);
            next = k as usize + 1;
        }
        self.copy_runs(&old, next..old.len());
        self.sum_stats();
        redo.len()
    }

    /// Appends the paths `range` of `old` as they are.
    fn copy_runs(&mut self, old: &Self, range: std::ops::Range<usize>) {
        if range.is_empty() {
            return;
        }
        self.begin();
        let (p0, q0) = (old.photon_offsets[range.start], old.point_offsets[range.start]);
        let (p1, q1) = (old.photon_offsets[range.end], old.point_offsets[range.end]);
        let (dp, dq) = (self.photons.len() as i64 - p0 as i64, self.points.len() as i64 - q0 as i64);
        self.photons.extend_from_slice(&old.photons[p0 as usize..p1 as usize]);
        self.points.extend_from_slice(&old.points[q0 as usize..q1 as usize]);
        self.photon_offsets.extend(old.photon_offsets[range.start + 1..=range.end].iter().map(|&o| (o as i64 + dp) as u32));
        self.point_offsets.extend(old.point_offsets[range.start + 1..=range.end].iter().map(|&o| (o as i64 + dq) as u32));
        self.path_stats.extend_from_slice(&old.path_stats[range]);
    }

    /// Sums the paths' balances into `stats`, in double precision: hundreds of thousands of paths, each
    /// a small share.
    fn sum_stats(&mut self) {
        let mut sums = [bevy::math::DVec3::ZERO; 4];
        let mut stats = PhotonStats::default();
        for s in &self.path_stats {
            for (sum, v) in sums.iter_mut().zip([s.emitted, s.absorbed, s.escaped, s.truncated]) {
                *sum += v.as_dvec3();
            }
            stats.paths += s.paths;
            stats.stored += s.stored;
        }
        [stats.emitted, stats.absorbed, stats.escaped, stats.truncated] = sums.map(|v| v.as_vec3());
        self.stats = stats;
    }
}

/// `cos(outer)` of a spot cone from Bevy's scale and offset.
fn spot_cos_outer(spot_scale: f32, spot_offset: f32) -> f32 {
    (-spot_offset / spot_scale.max(1e-6)).clamp(-1.0, 1.0)
}


/// A photon leaving `source`: origin, unit direction, power and, for point and spot lights, `1 / range²`
/// (Bevy's range window applies at the first hit). `sphere` bounds the scene.
fn emit(
    snapshot: &SceneSnapshot,
    source: &Source,
    share: Vec3,
    (centre, radius): (Vec3, f32),
    rng: &mut rand_pcg::Pcg32,
    epsilon: f32,
) -> Option<(Vec3, Vec3, Vec3, Option<f32>)> {
    // A point of the disc of the bounding sphere facing `d`, two radii before the centre.
    let disc = |d: Vec3, rng: &mut rand_pcg::Pcg32| {
        let (t, b) = orthonormal_basis(d);
        let u = uniform2(rng);
        let r = radius * u.x.sqrt();
        let phi = std::f32::consts::TAU * u.y;
        centre - d * (2.0 * radius) + (t * phi.cos() + b * phi.sin()) * r
    };
    match *source {
        Source::Light(SnapshotLight::Point { position, inverse_range_squared, .. }) => {
            Some((position, uniform_sphere(uniform2(rng)), share, Some(inverse_range_squared)))
        }
        Source::Light(SnapshotLight::Spot { position, direction, inverse_range_squared, spot_scale, spot_offset, .. }) => {
            // Uniform over the outer cone's solid angle, weighted by Bevy's cone falloff.
            let cos_outer = spot_cos_outer(spot_scale, spot_offset);
            let u = uniform2(rng);
            let cos_t = 1.0 - u.x * (1.0 - cos_outer);
            let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
            let (t, b) = orthonormal_basis(direction);
            let phi = std::f32::consts::TAU * u.y;
            let d = (t * phi.cos() + b * phi.sin()) * sin_t + direction * cos_t;
            let cone = (cos_t * spot_scale + spot_offset).clamp(0.0, 1.0);
            Some((position, d.normalize_or(direction), share * cone * cone, Some(inverse_range_squared)))
        }
        Source::Light(SnapshotLight::Directional { direction, .. }) => {
            let d = direction.normalize_or(Vec3::NEG_Y);
            Some((disc(d, rng), d, share, None))
        }
        Source::Emitter(i, open) => {
            let tri = snapshot.triangle(i);
            let u = uniform2(rng);
            let Vec2 { x: a, y: b } = crate::sampling::uniform_triangle(u);
            let p = tri[0] + (tri[1] - tri[0]) * a + (tri[2] - tri[0]) * b;
            let mut n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
            if n == Vec3::ZERO {
                return None;
            }
            n = match open {
                OPEN_FRONT => n,
                OPEN_BACK => -n,
                _ if rng.random::<bool>() => -n,
                _ => n,
            };
            let d = cosine_hemisphere(n, uniform2(rng));
            Some((p + n * epsilon, d, share, None))
        }
        Source::Environment(env, mean) => {
            let d = uniform_sphere(uniform2(rng));
            let l = env.radiance(-d);
            let ratio = Vec3::select(mean.cmpgt(Vec3::ZERO), l / mean.max(Vec3::splat(1e-30)), Vec3::ZERO);
            Some((disc(d, rng), d, share * ratio, None))
        }
    }
}

/// Where a photon path starts: what [`emit`] gave, and whether it leaves an emitter (its emission is
/// then stored where it starts).
struct PathStart {
    origin: Vec3,
    direction: Vec3,
    power: Vec3,
    falloff: Option<f32>,
    emission: bool,
}

/// Stores a photon leaving `at` along `direction` in the SH cell of `at`, given `next`, the surface
/// its light meets next. Light that meets another surface within a V-cell (a panel 1 mm under a
/// ceiling, the gap of a corner) lights nothing a ray between the grid's cells can see: it is not
/// stored (it is still traced on).
#[expect(clippy::too_many_arguments, reason = "one photon and where it goes")]
fn store_photon(
    vgrid: &VGrid,
    layout: GridLayout,
    at: Vec3,
    direction: Vec3,
    power: Vec3,
    next: Option<&crate::scene::SceneHit>,
    photons: &mut Vec<Photon>,
    stats: &mut PhotonStats,
) {
    if next.is_some_and(|next| next.t < layout.v_cell()) {
        return;
    }
    if let Some(c) = layout.cell_of(at) {
        photons.push(Photon { cell: layout.index(c) as u32, direction, power, blocked: vgrid.blocked_faces(at) });
        stats.stored += 1;
    }
}

/// Follows one photon through up to `max_reflections` stored diffuse reflections.
/// Records in `path` the points its rays ran between (a ray that leaves the scene ends `far` metres
/// out).
#[expect(clippy::too_many_arguments, reason = "one photon path and where it ends up")]
fn trace_path(
    snapshot: &SceneSnapshot,
    vgrid: &VGrid,
    params: &TraceParams,
    start: PathStart,
    epsilon: f32,
    far: f32,
    rng: &mut rand_pcg::Pcg32,
    path: &mut TracedPath,
) {
    let Some(layout) = vgrid.layout else { return };
    let TracedPath { photons, points, stats } = path;
    let PathStart { mut origin, mut direction, mut power, mut falloff, emission } = start;
    let mut reflections = 0;
    let ray = |origin: Vec3, direction: Vec3, points: &mut Vec<Vec3>| {
        let hit = snapshot.intersect(origin, direction, epsilon, f32::INFINITY);
        points.push(origin + direction * hit.as_ref().map_or(far, |h| h.t));
        hit
    };
    points.push(origin);
    let mut hit = ray(origin, direction, points);
    if emission {
        store_photon(vgrid, layout, origin, direction, power, hit.as_ref(), photons, stats);
    }
    loop {
        let Some(h) = hit else {
            stats.escaped += power;
            return;
        };
        // Bevy's range window of a point or spot light, at the distance of the first surface.
        if let Some(inverse_range_squared) = falloff.take() {
            let kept = range_falloff(h.t * h.t, inverse_range_squared);
            // What the window removes is light Bevy's lights never emit: it leaves the balance.
            stats.emitted -= power * (1.0 - kept);
            power *= kept;
        }
        let surface = snapshot.surface(origin, direction, &h);
        // Two-sided surfaces, as the path tracer has them: the side the photon arrives on.
        let side = if surface.geometric_normal.dot(direction) > 0.0 { -1.0 } else { 1.0 };
        let n = surface.geometric_normal * side;
        let shading = surface.normal * side;
        let albedo = if surface.diffuse.is_finite() { surface.diffuse.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
        stats.absorbed += power * (Vec3::ONE - albedo);
        let survive = albedo.max_element();
        if survive <= 0.0 || rng.random::<f32>() >= survive {
            return;
        }
        power *= albedo / survive;
        let position = origin + direction * h.t;
        let mut out = cosine_hemisphere(if shading.dot(n) > 0.1 { shading } else { n }, uniform2(rng));
        if out.dot(n) <= 1e-4 {
            out = cosine_hemisphere(n, uniform2(rng));
        }
        reflections += 1;
        origin = position + n * epsilon;
        direction = out;
        hit = ray(origin, direction, points);
        // The photon lies on the side it leaves from, in the SH cell whose faces it lights.
        let stored_at = position + n * (layout.v_cell() * 0.01).max(epsilon);
        store_photon(vgrid, layout, stored_at, out, power, hit.as_ref(), photons, stats);
        if reflections >= params.max_reflections {
            stats.truncated += power;
            return;
        }
    }
}

/// The R-grid face weights of an outgoing direction (§3.3, Fig. 2): `d_x²`, `d_y²`, `d_z²` on the faces
/// `d` points through (they sum to one for a unit `d`).
pub fn face_weights(d: Vec3) -> [(usize, f32); 3] {
    [
        (if d.x >= 0.0 { 0 } else { 1 }, d.x * d.x),
        (if d.y >= 0.0 { 2 } else { 3 }, d.y * d.y),
        (if d.z >= 0.0 { 4 } else { 5 }, d.z * d.z),
    ]
}

/// Flux per face (lumens, per channel) of one R-grid cell.
pub type CellFaces = [Vec3; FACES];

/// The base level of the R-grid by the paper's atomic-free GPU algorithm (Fig. 3), on the CPU's
/// threads: [A] the photons' cell indices, [B] sorted, [C] a flag on the first photon of each cell,
/// [D] its exclusive scan, [E] the offset of each non-empty cell's first photon; then one task per
/// non-empty cell sums its photons' weighted flux into its six faces.
pub fn accumulate_sorted(photons: &[Photon], cells: usize) -> Vec<CellFaces> {
    // [A] → [B]: (cell, photon) pairs sorted by cell (ties by photon, so the sums are reproducible).
    let mut sorted: Vec<(u32, u32)> = photons.iter().enumerate().map(|(i, p)| (p.cell, i as u32)).collect();
    sorted.par_sort_unstable();
    // [C]: 1 where a photon starts a new cell.
    let flags: Vec<u32> = (0..sorted.len()).into_par_iter().map(|i| u32::from(i == 0 || sorted[i].0 != sorted[i - 1].0)).collect();
    // [D]: exclusive scan of the flags.
    let mut scan = Vec::with_capacity(flags.len());
    let mut sum = 0u32;
    for &f in &flags {
        scan.push(sum);
        sum += f;
    }
    // [E]: the first photon of each non-empty cell.
    let mut offsets = vec![0u32; sum as usize];
    for i in 0..flags.len() {
        if flags[i] == 1 {
            offsets[scan[i] as usize] = i as u32;
        }
    }
    let groups: Vec<(u32, CellFaces)> = (0..offsets.len())
        .into_par_iter()
        .map(|g| {
            let start = offsets[g] as usize;
            let end = offsets.get(g + 1).map_or(sorted.len(), |&e| e as usize);
            let mut faces = [Vec3::ZERO; FACES];
            for &(_, p) in &sorted[start..end] {
                let photon = &photons[p as usize];
                for (face, w) in face_weights(photon.direction) {
                    if photon.blocked & (1 << face) == 0 {
                        faces[face] += photon.power * w;
                    }
                }
            }
            (sorted[start].0, faces)
        })
        .collect();
    let mut out = vec![[Vec3::ZERO; FACES]; cells];
    for (cell, faces) in groups {
        if let Some(slot) = out.get_mut(cell as usize) {
            *slot = faces;
        }
    }
    out
}

/// The same base level by direct accumulation, photon by photon (what a GPU would do with atomic adds):
/// the reference the tests hold [`accumulate_sorted`] to.
pub fn accumulate_direct(photons: &[Photon], cells: usize) -> Vec<CellFaces> {
    let mut out = vec![[Vec3::ZERO; FACES]; cells];
    for photon in photons {
        if let Some(slot) = out.get_mut(photon.cell as usize) {
            for (face, w) in face_weights(photon.direction) {
                if photon.blocked & (1 << face) == 0 {
                    slot[face] += photon.power * w;
                }
            }
        }
    }
    out
}

/// The multilevel R-grid (§3.3): face flux per cell at the SH-grid's resolution and mip levels of
/// twice the cell size, each face the sum of its eight children's (flux is conserved; radiance, flux
/// over the face's area, is then the children's mean over the four faces a parent face covers).
#[derive(Clone, Debug, Default)]
pub struct RGrid {
    /// Level 0 first: (cells per axis, cell side in metres, faces).
    pub levels: Vec<(UVec3, f32, Vec<CellFaces>)>,
}

impl RGrid {
    /// Builds the levels above `base` until a level has at most two cells along its longest axis or
    /// `max_levels` are made.
    pub fn new(layout: GridLayout, base: Vec<CellFaces>, max_levels: usize) -> Self {
        let mut levels = vec![(layout.dims, layout.cell, base)];
        while levels.len() < max_levels.max(1) {
            let (dims, cell, faces) = levels.last().unwrap();
            if dims.max_element() <= 2 {
                break;
            }
            let next = (*dims + 1) / 2;
            let mut out = vec![[Vec3::ZERO; FACES]; (next.x * next.y * next.z) as usize];
            for z in 0..dims.z {
                for y in 0..dims.y {
                    for x in 0..dims.x {
                        let src = &faces[((z * dims.y + y) * dims.x + x) as usize];
                        let p = UVec3::new(x, y, z) / 2;
                        let dst = &mut out[((p.z * next.y + p.y) * next.x + p.x) as usize];
                        for f in 0..FACES {
                            dst[f] += src[f];
                        }
                    }
                }
            }
            let cell = cell * 2.0;
            levels.push((next, cell, out));
        }
        Self { levels }
    }

    /// Outgoing radiance (cd/m²) of the surface in the level-`level` cell containing `p`, seen on its
    /// side facing `n` (unit): `2 Σ_j n_j² F_j / (π A)` over the three faces `n` points through. A plane
    /// across a cell sends half its flux through the face it faces (`E[cos²] = ½` for Lambertian
    /// directions), hence the 2: exact for such a plane, within 5 % for one at 45°.
    pub fn radiance(&self, origin: Vec3, level: usize, p: Vec3, n: Vec3) -> Vec3 {
        let Some((dims, cell, faces)) = self.levels.get(level) else { return Vec3::ZERO };
        let c = ((p - origin) / *cell).floor();
        if !c.is_finite() || c.cmplt(Vec3::ZERO).any() || c.cmpge(dims.as_vec3()).any() {
            return Vec3::ZERO;
        }
        let c = c.as_uvec3();
        let f = &faces[((c.z * dims.y + c.y) * dims.x + c.x) as usize];
        let sum: Vec3 = face_weights(n).iter().map(|&(face, w)| f[face] * w).sum();
        sum * (2.0 / (PI * cell * cell))
    }
}

/// What the SH field is built with.
#[derive(Clone, Copy, Debug)]
pub struct FieldParams {
    /// Directions per probe (N_sh).
    pub directions: u32,
    /// Distance recorded for rays that leave the grid, metres (and the largest distance kept).
    pub max_distance: f32,
    /// The coarsest R-grid level the footprint filter may read (§3.4.3); 0 reads the base level only.
    pub filter_levels: u32,
}

/// The spherical-harmonics field (§3.4): at the centres of the SH-grid's boundary cells and their 26
/// neighbours, the incoming radiance (rgb) and the distance to the first surface (alpha) in nine
/// coefficients (bands 0–2, the order of [`crate::sh`]).
#[derive(Clone, Debug, Default)]
pub struct ShField {
    pub layout: Option<GridLayout>,
    /// Per SH cell: its probe's index in `coefficients`, or `u32::MAX` (no probe, or one inside solid
    /// geometry).
    pub cell_probe: Vec<u32>,
    /// Nine coefficients per probe.
    pub coefficients: Vec<[Vec4; 9]>,
    /// Probes dropped because most of their rays met the back of a surface (inside a wall or a box).
    pub inside: u32,
}

/// How far the probe's rays see the back of surfaces before it counts as inside solid geometry.
const INSIDE_FRACTION: f32 = 0.1;

/// Where each probe ray of a field met the V-grid, kept so that the next field after a local change
/// marches only the rays that run through it ([`ShField::build_reusing`]): per probe candidate (an SH
/// cell, sorted), per direction, the linear index of the V-cell hit, [`RAY_MISSED`] or [`RAY_NOT_MARCHED`].
#[derive(Clone, Debug, Default)]
pub struct ProbeRays {
    layout: Option<GridLayout>,
    directions: u32,
    cells: Vec<u32>,
    hits: Vec<u32>,
}

/// A probe ray that left the grid.
pub const RAY_MISSED: u32 = u32::MAX;

/// A probe ray not marched: its probe was found inside solid geometry before it (the next field
/// marches it).
const RAY_NOT_MARCHED: u32 = u32::MAX - 1;

impl ProbeRays {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        (self.cells.len() + self.hits.len()) * 4
    }
}

/// The SH cells that get a probe: the boundary cells and their 26 neighbours (linear indices, sorted).
pub(super) fn probe_cells(vgrid: &VGrid, layout: &GridLayout) -> Vec<usize> {
    let dims = layout.dims.as_ivec3();
    (0..layout.cell_count())
        .into_par_iter()
        .filter(|&i| {
            let c = layout.coords(i).as_ivec3();
            (-1..=1).any(|z| {
                (-1..=1).any(|y| {
                    (-1..=1).any(|x| {
                        let n = c + IVec3::new(x, y, z);
                        n.cmpge(IVec3::ZERO).all() && n.cmplt(dims).all() && vgrid.sh_boundary[layout.index(n.as_uvec3())]
                    })
                })
            })
        })
        .collect()
}

/// The count of a probe's `directions` rays meeting the back of a surface from which the probe lies
/// inside solid geometry ([`INSIDE_FRACTION`] of them): its remaining rays need not be marched.
pub(super) fn inside_limit(directions: u32) -> u32 {
    (INSIDE_FRACTION * directions as f32).ceil() as u32
}

/// A probe's coefficients, unless they are not finite or [`inside_limit`] of its `directions` rays met
/// the back of a surface (the probe lies inside solid geometry).
pub(super) fn kept_probe(coefficients: [Vec4; 9], back: u32, directions: u32) -> Option<[Vec4; 9]> {
    let finite = coefficients.iter().all(|c| c.is_finite());
    (finite && back < inside_limit(directions)).then_some(coefficients)
}

/// The V-cell (linear index) a probe ray from `c` along `d` meets first, or [`RAY_MISSED`].
fn probe_hit(vgrid: &VGrid, layout: &GridLayout, c: Vec3, d: Vec3) -> u32 {
    vgrid.march(c, d).map_or(RAY_MISSED, |(v, _)| layout.v_index(v))
}

/// The distance along the ray from `c` in the unit direction `d` at which it enters the V-cell `v`
/// (zero when it starts inside).
fn entry_distance(layout: &GridLayout, v: UVec3, c: Vec3, d: Vec3) -> f32 {
    let v_cell = layout.v_cell();
    let lo = layout.origin + v.as_vec3() * v_cell;
    let mut t = 0.0f32;
    for k in 0..3 {
        if d[k].abs() > 1e-8 {
            let plane = if d[k] > 0.0 { lo[k] } else { lo[k] + v_cell };
            t = t.max((plane - c[k]) / d[k]);
        }
    }
    t
}

/// The incoming radiance along one probe ray that met the V-cell `hit` ([`probe_hit`]) and the
/// distance to it (§3.4.2–3.4.3), and whether it met the back of a surface.
fn probe_ray(vgrid: &VGrid, rgrid: &RGrid, env: Option<&Environment>, c: Vec3, d: Vec3, hit: u32, params: &FieldParams) -> (Vec3, f32, bool) {
    let layout = vgrid.layout.expect("a grid");
    if hit == RAY_MISSED {
        return (env.map_or(Vec3::ZERO, |e| e.radiance(d)), params.max_distance, false);
    }
    let v = layout.v_coords(hit);
    let t = entry_distance(&layout, v, c, d);
    let data = vgrid.cell(v).unwrap_or_default();
    // The V-cell's mean normal turned towards the ray (surfaces are two-sided); where its normals cancel
    // (both faces of a thin wall, a sharp edge) the direction back along the ray.
    let coherent = data.normal_sum.length() > 0.5 * data.area;
    let mut n = if coherent { data.normal_sum.normalize() } else { -d };
    let back = coherent && n.dot(d) > 0.0;
    if back {
        n = -n;
    }
    let v_cell = layout.v_cell();
    let hit = layout.origin + (v.as_vec3() + 0.5) * v_cell;
    // §3.4.3: the area the ray stands for on the surface, 4π d² / (N_sh cos β), picks two R-grid levels.
    let cos_beta = n.dot(-d).max(0.25);
    let distance = t.max(0.5 * v_cell);
    let footprint = 4.0 * PI * distance * distance / (params.directions as f32 * cos_beta);
    let base_area = layout.cell * layout.cell;
    let level = (0.5 * (footprint / base_area).max(1.0).log2()).clamp(0.0, (rgrid.levels.len() - 1) as f32);
    let level = level.min(params.filter_levels as f32);
    let (l0, frac) = (level.floor() as usize, level.fract());
    let mut radiance = rgrid.radiance(layout.origin, l0, hit, n);
    if frac > 0.0 && l0 + 1 < rgrid.levels.len() {
        radiance = radiance.lerp(rgrid.radiance(layout.origin, l0 + 1, hit, n), frac);
    }
    (radiance, t.min(params.max_distance), back)
}

impl ShField {
    /// Projects the incoming radiance and distance at every probe (Eq. 1 with `N_sh` directions of the
    /// spherical Fibonacci lattice).
    pub fn build(vgrid: &VGrid, rgrid: &RGrid, env: Option<&Environment>, params: &FieldParams) -> Self {
        Self::build_reusing(vgrid, rgrid, env, params, &mut ProbeRays::default(), None).0
    }

    /// [`build`](Self::build), reusing the probe rays of the last field built with `rays` where only the
    /// geometry inside `changed` (world boxes) differs since: a ray that does not pass within one SH
    /// cell (and a V-cell) of a changed box crosses the same cells and meets the same V-cell, and only its radiance is
    /// read again from `rgrid`; the others are marched. `None` (or another grid or direction count)
    /// marches every ray. `rays` is left holding this field's rays. Returns the field and the rays
    /// marched. The field is the one [`build`](Self::build) makes.
    pub fn build_reusing(
        vgrid: &VGrid,
        rgrid: &RGrid,
        env: Option<&Environment>,
        params: &FieldParams,
        rays: &mut ProbeRays,
        changed: Option<&[(Vec3, Vec3)]>,
    ) -> (Self, usize) {
        let Some(layout) = vgrid.layout else {
            *rays = ProbeRays::default();
            return (Self::default(), 0);
        };
        let probes = probe_cells(vgrid, &layout);
        let n = params.directions.max(1);
        let directions: Vec<Vec3> = (0..n).map(|i| fibonacci_sphere(i, n)).collect();
        let bases: Vec<[f32; 9]> = directions.iter().map(|&d| basis(d)).collect();
        let weight = 4.0 * PI / n as f32;
        let limit = inside_limit(n);
        // The kept rays, when they were made on this grid with these directions.
        let margin = layout.change_margin();
        let boxes: Option<Vec<(Vec3, Vec3)>> = changed
            .filter(|_| rays.layout == Some(layout) && rays.directions == n)
            .map(|c| c.iter().map(|&(lo, hi)| (lo - margin, hi + margin)).collect());
        let old = std::mem::take(rays);
        let reach = (layout.dims.as_vec3() * layout.cell).length() + layout.cell;
        let v_cell = layout.v_cell();
        let traced: Vec<(Vec<u32>, usize, Option<[Vec4; 9]>)> = probes
            .par_iter()
            .map(|&i| {
                let c = layout.centre(layout.coords(i));
                let kept = boxes.as_ref().and_then(|boxes| {
                    let k = old.cells.binary_search(&(i as u32)).ok()?;
                    Some((boxes, &old.hits[k * n as usize..(k + 1) * n as usize]))
                });
                let mut hits = Vec::with_capacity(n as usize);
                let mut marched = 0;
                let mut coefficients = [Vec4::ZERO; 9];
                let mut back = 0u32;
                for (j, &d) in directions.iter().enumerate() {
                    let hit = match kept {
                        Some((_, old)) if old[j] == RAY_NOT_MARCHED => {
                            marched += 1;
                            probe_hit(vgrid, &layout, c, d)
                        }
                        Some((boxes, old)) => {
                            let h = old[j];
                            let end = if h == RAY_MISSED {
                                c + d * reach
                            } else {
                                c + d * (entry_distance(&layout, layout.v_coords(h), c, d) + 2.0 * v_cell)
                            };
                            if boxes.iter().any(|&b| segment_meets_box(c, end, b)) {
                                marched += 1;
                                probe_hit(vgrid, &layout, c, d)
                            } else {
                                h
                            }
                        }
                        None => {
                            marched += 1;
                            probe_hit(vgrid, &layout, c, d)
                        }
                    };
                    hits.push(hit);
                    let (radiance, distance, backface) = probe_ray(vgrid, rgrid, env, c, d, hit, params);
                    back += u32::from(backface);
                    if back >= limit {
                        // Inside solid geometry: dropped whatever its other rays meet.
                        hits.resize(n as usize, RAY_NOT_MARCHED);
                        break;
                    }
                    let value = radiance.extend(distance) * weight;
                    for (c, y) in coefficients.iter_mut().zip(bases[j]) {
                        *c += value * y;
                    }
                }
                (hits, marched, kept_probe(coefficients, back, n))
            })
            .collect();
        let mut marched = 0;
        let mut kept = ProbeRays { layout: Some(layout), directions: n, cells: Vec::with_capacity(probes.len()), hits: Vec::with_capacity(probes.len() * n as usize) };
        let mut found = Vec::with_capacity(probes.len());
        for (&i, (hits, m, p)) in probes.iter().zip(traced) {
            kept.cells.push(i as u32);
            kept.hits.extend_from_slice(&hits);
            marched += m;
            found.push(p);
        }
        *rays = kept;
        (Self::from_probes(layout, &probes, found), marched)
    }

    /// The field from each probe cell's coefficients, in the order of `probes` ([`probe_cells`]):
    /// `None` for a probe dropped ([`kept_probe`]).
    pub(super) fn from_probes(layout: GridLayout, probes: &[usize], found: impl IntoIterator<Item = Option<[Vec4; 9]>>) -> Self {
        let mut cell_probe = vec![u32::MAX; layout.cell_count()];
        let mut coefficients = Vec::with_capacity(probes.len());
        let mut inside = 0;
        for (&i, p) in probes.iter().zip(found) {
            match p {
                Some(c) => {
                    cell_probe[i] = coefficients.len() as u32;
                    coefficients.push(c);
                }
                None => inside += 1,
            }
        }
        Self { layout: Some(layout), cell_probe, coefficients, inside }
    }

    /// The interpolated coefficients at `x` on a surface with unit normal `n` (§4.1): the probes of the
    /// 27 cells around `x` weighted by `w_sh(d) = 2d³/r³ − 3d²/r² + 1` (`r = r_max`), times a weight that
    /// drops the probes behind the surface (see the module docs). `None` where no probe is near.
    pub fn coefficients_at(&self, x: Vec3, n: Vec3, r_max: f32, vgrid: Option<&VGrid>) -> Option<[Vec4; 9]> {
        let layout = self.layout?;
        let start = x + n * (GATHER_START_OFFSET * layout.v_cell());
        let base = ((x - layout.origin) / layout.cell).floor().as_ivec3();
        let dims = layout.dims.as_ivec3();
        // Every probe's weight, and (in `visible`) only those of the probes no V-cell hides from x; the
        // first where none is visible (x in a corner, its own surfaces' cells around it).
        let (mut all, mut visible) = (([Vec4::ZERO; 9], 0.0), ([Vec4::ZERO; 9], 0.0));
        for k in 0..27 {
            let c = base + IVec3::new(k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1);
            if c.cmplt(IVec3::ZERO).any() || c.cmpge(dims).any() {
                continue;
            }
            let index = self.cell_probe[layout.index(c.as_uvec3())];
            if index == u32::MAX {
                continue;
            }
            let p = layout.centre(c.as_uvec3());
            let probe = &self.coefficients[index as usize];
            let w = sh_weight((p - x).length(), r_max) * side_weight(n.dot(p - x) / layout.cell) * visibility_weight(probe, p, x);
            if w <= 0.0 {
                continue;
            }
            let seen = !vgrid.is_some_and(|g| g.segment_blocked(start, p));
            for k in 0..9 {
                all.0[k] += probe[k] * w;
                if seen {
                    visible.0[k] += probe[k] * w;
                }
            }
            all.1 += w;
            if seen {
                visible.1 += w;
            }
        }
        let (sum, total) = if visible.1 > 1e-6 { visible } else { all };
        (total > 1e-6).then(|| sum.map(|c| c / total))
    }

    /// Irradiance over π (`E/π`, the frame's unit) at `x` facing `n`: the clamped-cosine integral of the
    /// interpolated radiance, exact for the nine coefficients (what the paper's `N_d` hemisphere samples
    /// of §4.2 estimate).
    pub fn irradiance(&self, x: Vec3, n: Vec3, r_max: f32, vgrid: Option<&VGrid>) -> Vec3 {
        let Some(c) = self.coefficients_at(x, n, r_max, vgrid) else { return Vec3::ZERO };
        let y = basis(n);
        let e: Vec3 = (0..9).map(|k| c[k].truncate() * (COSINE_LOBE[band(k)] * y[k])).sum();
        (e / PI).max(Vec3::ZERO)
    }
}

/// The gather's visibility segments start this many V-cells off the surface, along its normal.
pub const GATHER_START_OFFSET: f32 = 0.75;

/// The paper's distance weight `w_sh(d) = 2d³/r³ − 3d²/r² + 1` for `d < r`, else 0 (§4.1).
pub fn sh_weight(d: f32, r_max: f32) -> f32 {
    if d >= r_max {
        return 0.0;
    }
    let t = d / r_max;
    2.0 * t * t * t - 3.0 * t * t + 1.0
}

/// Whether a probe sees the surface point `x`: its distance field towards `x` (§3.4.4) against the
/// distance to `x`. 0 when the probe's first surface in that direction is nearer than 0.4 of the way
/// (a wall between them), 1 from 0.8 of the way (the low-order field blurs the distance to the surface
/// itself).
pub fn visibility_weight(probe: &[Vec4; 9], p: Vec3, x: Vec3) -> f32 {
    let to_x = x - p;
    let d = to_x.length();
    if d < 1e-6 {
        return 1.0;
    }
    let y = basis(to_x / d);
    let seen: f32 = (0..9).map(|k| probe[k].w * y[k]).sum();
    ((seen / d - 0.4) / 0.4).clamp(0.0, 1.0)
}

/// Weight of a probe at signed distance `s` cells in front of the surface (along its normal): 0 from a
/// quarter cell behind, 1 from half a cell in front.
pub fn side_weight(s: f32) -> f32 {
    ((s + 0.25) / 0.75).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{InputTriangle, SnapshotLightEntry, SnapshotMaterial};
    use bevy::prelude::Entity;

    fn quad(corners: [Vec3; 4], material: u32) -> [InputTriangle; 2] {
        [
            InputTriangle::flat([corners[0], corners[1], corners[2]], material),
            InputTriangle::flat([corners[0], corners[2], corners[3]], material),
        ]
    }

    fn sun(direction: Vec3, lux: f32) -> SnapshotLightEntry {
        SnapshotLightEntry {
            entity: Entity::PLACEHOLDER,
            light: SnapshotLight::Directional { direction: direction.normalize(), illuminance: Vec3::splat(lux) },
            shadows_enabled: true,
        }
    }

    fn grey(albedo: f32) -> SnapshotMaterial {
        SnapshotMaterial { diffuse: Vec3::splat(albedo), ..SnapshotMaterial::DEFAULT_GREY }
    }

    /// A closed box of side `2h` (inward and outward faces: single-sided quads, two-sided to photons) with
    /// a point light inside.
    fn closed_box(h: f32, albedo: f32) -> SceneSnapshot {
        let mut triangles = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let n = Vec3::AXES[axis] * sign;
                let (u, v) = (Vec3::AXES[(axis + 1) % 3] * h, Vec3::AXES[(axis + 2) % 3] * h);
                let c = n * h;
                triangles.extend(quad([c - u - v, c + u - v, c + u + v, c - u + v], 0));
            }
        }
        let light = SnapshotLightEntry {
            entity: Entity::PLACEHOLDER,
            light: SnapshotLight::Point { position: Vec3::new(0.2, 0.1, -0.3), intensity: Vec3::splat(100.0), inverse_range_squared: 0.0 },
            shadows_enabled: true,
        };
        SceneSnapshot::build(triangles, vec![grey(albedo)], vec![], vec![light])
    }

    /// A box moved inside a lit room: only the photon paths and probe rays that ran near its old or
    /// new place are traced again, and the photons and the field are those of a trace from scratch.
    #[test]
    fn a_moved_box_retraces_only_the_paths_and_rays_near_it_and_gives_the_full_result() {
        let mut snapshot = closed_box(1.0, 0.6);
        let mut cube = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let n = Vec3::AXES[axis] * sign * 0.1;
                let (u, v) = (Vec3::AXES[(axis + 1) % 3] * 0.1, Vec3::AXES[(axis + 2) % 3] * 0.1);
                cube.extend(quad([n - u - v, n + u - v, n + u + v, n - u + v], 0));
            }
        }
        let cube = std::sync::Arc::new(crate::scene::MeshGeometry::new(cube));
        snapshot.set_instance(100, cube, bevy::math::Affine3A::from_translation(Vec3::new(-0.6, -0.85, 0.4)), 0);
        snapshot.commit();
        let (lo, hi) = snapshot.bounds().unwrap();
        let layout = GridLayout::fit(lo, hi, 16);
        let lights: Vec<_> = snapshot.lights.iter().map(|l| l.light).collect();
        let params = TraceParams { photons: 20_000, max_reflections: 4, seed: 5, exposure: 1.0 };
        let field_params = FieldParams { directions: 64, max_distance: 4.0 * layout.cell, filter_levels: 2 };
        let vgrid = VGrid::build(&snapshot, layout);
        let mut paths = PhotonPaths::trace(&snapshot, &lights, None, &vgrid, &params);
        let rgrid = RGrid::new(layout, accumulate_sorted(&paths.photons, layout.cell_count()), 6);
        let mut rays = ProbeRays::default();
        let (_, marched) = ShField::build_reusing(&vgrid, &rgrid, None, &field_params, &mut rays, None);
        // Every ray but those of the probes found inside solid geometry (outside the closed box here)
        // before them.
        let not_marched = rays.hits.iter().filter(|&&h| h == RAY_NOT_MARCHED).count();
        assert_eq!(marched + not_marched, rays.hits.len(), "a first field marches every ray of the probes it keeps");
        assert!(not_marched > rays.hits.len() / 4, "{not_marched} of {} rays of probes inside walls marched", rays.hits.len());

        let before = snapshot.instance(100).unwrap().bounds;
        snapshot.set_instance_transform(100, bevy::math::Affine3A::from_translation(Vec3::new(-0.45, -0.85, 0.4)));
        snapshot.commit();
        assert_eq!(snapshot.bounds().unwrap(), (lo, hi));
        let after = snapshot.instance(100).unwrap().bounds;
        let vgrid = VGrid::build(&snapshot, layout);
        let retraced = paths.retrace(&snapshot, &lights, None, &vgrid, &params, &[before, after]);
        let full = PhotonPaths::trace(&snapshot, &lights, None, &vgrid, &params);
        assert!(retraced > 0 && retraced < params.photons as usize / 2, "{retraced} of {} paths traced again", params.photons);
        assert_eq!(paths.photons, full.photons, "the photons of the paths kept and traced again are the full trace's");
        assert_eq!((paths.stats.paths, paths.stats.stored), (full.stats.paths, full.stats.stored));
        for (a, b) in [(paths.stats.emitted, full.stats.emitted), (paths.stats.absorbed, full.stats.absorbed), (paths.stats.escaped, full.stats.escaped)] {
            assert!((a - b).abs().max_element() <= 1e-3 * b.abs().max_element().max(1.0), "{a} against {b}");
        }

        let rgrid = RGrid::new(layout, accumulate_sorted(&full.photons, layout.cell_count()), 6);
        let total = rays.hits.len();
        let (field, marched) = ShField::build_reusing(&vgrid, &rgrid, None, &field_params, &mut rays, Some(&[before, after]));
        let fresh = ShField::build(&vgrid, &rgrid, None, &field_params);
        assert!(marched > 0 && marched < total / 2, "{marched} of {total} rays marched again");
        assert_eq!(field.cell_probe, fresh.cell_probe);
        assert_eq!(field.coefficients, fresh.coefficients, "the field is the one built from scratch");
        assert_eq!(field.inside, fresh.inside);
    }

    fn trace(snapshot: &SceneSnapshot, photons: u32, reflections: u32, resolution: u32) -> (GridLayout, Vec<Photon>, PhotonStats) {
        let (lo, hi) = snapshot.bounds().unwrap();
        let layout = GridLayout::fit(lo, hi, resolution);
        let lights: Vec<_> = snapshot.lights.iter().map(|l| l.light).collect();
        let params = TraceParams { photons, max_reflections: reflections, seed: 7, exposure: 1.0 };
        let (list, stats) = trace_photons(snapshot, &lights, snapshot.environment.as_deref(), &VGrid::build(snapshot, layout), &params);
        (layout, list, stats)
    }

    fn relative(a: Vec3, b: Vec3) -> f32 {
        ((a - b).abs() / b.abs().max(Vec3::splat(1e-9))).max_element()
    }

    #[test]
    fn photon_flux_is_conserved_emitted_equals_absorbed_escaped_and_truncated() {
        // Closed box: nothing escapes; everything emitted is absorbed or left at the last reflection.
        let snapshot = closed_box(1.0, 0.6);
        let (_, photons, s) = trace(&snapshot, 60_000, 4, 8);
        // (Rays through the quads' shared edges may slip out: one in tens of thousands.)
        assert!(s.escaped.max_element() < 1e-3 * s.emitted.max_element(), "{s:?}");
        let balance = s.absorbed + s.escaped + s.truncated;
        assert!(relative(balance, s.emitted) < 0.02, "{s:?}");
        // A point light of 100 cd emits 400π lm; the truncated share is ρ⁴ of the emission in expectation.
        assert!(relative(s.emitted, Vec3::splat(400.0 * PI)) < 1e-3, "{s:?}");
        assert!(relative(s.truncated, s.emitted * 0.6f32.powi(4)) < 0.05, "{s:?}");
        // Stored photons: ρ + ρ² + ρ³ + ρ⁴ of the paths (every photon hits the walls).
        let expected = 60_000.0 * (0.6 + 0.36 + 0.216 + 0.1296);
        assert!((photons.len() as f32 / expected - 1.0).abs() < 0.02, "{} against {expected}", photons.len());
        // An open floor under the sun: what it does not absorb escapes.
        let floor = SceneSnapshot::build(
            quad([Vec3::new(-2.0, 0.0, -2.0), Vec3::new(-2.0, 0.0, 2.0), Vec3::new(2.0, 0.0, 2.0), Vec3::new(2.0, 0.0, -2.0)], 0),
            vec![grey(0.5)],
            vec![],
            vec![sun(Vec3::new(0.3, -1.0, 0.2), 1000.0)],
        );
        let (_, photons, s) = trace(&floor, 40_000, 4, 8);
        assert!(relative(s.absorbed + s.escaped + s.truncated, s.emitted) < 0.02, "{s:?}");
        assert!(s.truncated.max_element() == 0.0 && s.escaped.max_element() > 0.0, "{s:?}");
        // The photons that hit the floor reflect half: stored flux is ρ × the floor's irradiance × area.
        let stored: Vec3 = photons.iter().map(|p| p.power).sum();
        let cos = Vec3::new(0.3, -1.0, 0.2).normalize().y.abs();
        let expected = 0.5 * 1000.0 * cos * 16.0;
        assert!(relative(stored, Vec3::splat(expected)) < 0.03, "{stored} against {expected}");
    }

    #[test]
    fn an_emissive_panel_sends_its_closed_form_flux_to_the_floor() {
        // A black 1 × 0.6 m panel of radiance Le, 0.8 m over a 4 m floor of albedo 0.5: the emitters are
        // two-sided (2 π Le A leaves), and the floor reflects ρ ∫ E dA, E the closed form
        // (`crate::emitters::parallel_rectangle_irradiance`), integrated here by the midpoint rule.
        let le = Vec3::new(30.0, 20.0, 10.0);
        let glow = SnapshotMaterial { emissive: le, diffuse: Vec3::ZERO, ..SnapshotMaterial::DEFAULT_GREY };
        let y = 0.8;
        let mut triangles = quad([Vec3::new(-0.5, y, -0.3), Vec3::new(0.5, y, -0.3), Vec3::new(0.5, y, 0.3), Vec3::new(-0.5, y, 0.3)], 1).to_vec();
        triangles.extend(quad([Vec3::new(-2.0, 0.0, -2.0), Vec3::new(-2.0, 0.0, 2.0), Vec3::new(2.0, 0.0, 2.0), Vec3::new(2.0, 0.0, -2.0)], 0));
        let snapshot = SceneSnapshot::build(triangles, vec![grey(0.5), glow], vec![], vec![]);
        let (layout, photons, stats) = trace(&snapshot, 200_000, 1, 8);
        let area = 0.6;
        assert!(relative(stats.emitted, 2.0 * PI * le * area) < 1e-3, "{stats:?}");
        let floor_cell = layout.cell_of(Vec3::new(0.0, 0.0, 0.0)).unwrap().y;
        assert_ne!(floor_cell, layout.cell_of(Vec3::new(0.0, y, 0.0)).unwrap().y, "the floor and the panel share cells");
        let reflected: Vec3 = photons.iter().filter(|p| layout.coords(p.cell as usize).y == floor_cell).map(|p| p.power).sum();
        let n = 200;
        let step = 4.0 / n as f32;
        let mut irradiance_integral = Vec3::ZERO;
        for i in 0..n {
            for j in 0..n {
                let (x, z) = (-2.0 + (i as f32 + 0.5) * step, -2.0 + (j as f32 + 0.5) * step);
                let e = crate::emitters::parallel_rectangle_irradiance(1.0, y, [-0.5 - x, 0.5 - x], [-0.3 - z, 0.3 - z]);
                irradiance_integral += le * e * step * step;
            }
        }
        let want = 0.5 * irradiance_integral;
        assert!(relative(reflected, want) < 0.03, "{reflected} lm reflected by the floor against {want}");
    }

    #[test]
    fn r_grid_face_weights_sum_to_one() {
        for i in 0..500 {
            let d = fibonacci_sphere(i, 500);
            let w = face_weights(d);
            let sum: f32 = w.iter().map(|(_, w)| w).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{d} {w:?}");
            // Each face it points through, one per axis.
            assert_eq!(w.map(|(f, _)| f / 2), [0, 1, 2]);
            for (f, weight) in w {
                let axis = Vec3::AXES[f / 2] * if f % 2 == 0 { 1.0 } else { -1.0 };
                assert!(weight == 0.0 || axis.dot(d) >= 0.0);
            }
        }
    }

    #[test]
    fn the_sort_based_r_grid_equals_direct_accumulation() {
        let snapshot = closed_box(1.0, 0.7);
        let (layout, photons, _) = trace(&snapshot, 20_000, 4, 6);
        let sorted = accumulate_sorted(&photons, layout.cell_count());
        let direct = accumulate_direct(&photons, layout.cell_count());
        assert_eq!(sorted.len(), direct.len());
        let mut nonempty = 0;
        for (a, b) in sorted.iter().zip(&direct) {
            for f in 0..FACES {
                // Same sums in another order: float rounding only.
                assert!((a[f] - b[f]).abs().max_element() <= 1e-4 * b[f].abs().max_element().max(1e-3), "{a:?} {b:?}");
            }
            nonempty += usize::from(b.iter().any(|v| v.max_element() > 0.0));
        }
        assert!(nonempty > 20, "{nonempty} non-empty cells");
        // Flux is conserved from level to level.
        let rgrid = RGrid::new(layout, sorted, 4);
        let total = |faces: &Vec<CellFaces>| faces.iter().flatten().copied().sum::<Vec3>();
        let base = total(&rgrid.levels[0].2);
        for level in &rgrid.levels[1..] {
            assert!(relative(total(&level.2), base) < 1e-4);
        }
        assert!(rgrid.levels.len() >= 2);
        // An empty list gives an empty grid.
        assert!(accumulate_sorted(&[], 8).iter().flatten().all(|v| *v == Vec3::ZERO));
    }

    #[test]
    fn sh_projection_of_a_known_field_recovers_its_coefficients_and_irradiance() {
        // L(ω) = 2 + 3 ω_z + ω_x ω_y, projected by Eq. 1 over the Fibonacci lattice.
        let n = 400;
        let field = |d: Vec3| 2.0 + 3.0 * d.z + d.x * d.y;
        let mut c = [0.0f32; 9];
        for i in 0..n {
            let d = fibonacci_sphere(i, n);
            let y = basis(d);
            for k in 0..9 {
                c[k] += field(d) * y[k] * 4.0 * PI / n as f32;
            }
        }
        let sqrt_pi = PI.sqrt();
        let expected = [2.0 * 2.0 * sqrt_pi, 0.0, 3.0 * 2.0 * sqrt_pi / 3f32.sqrt(), 0.0, 2.0 * sqrt_pi / 15f32.sqrt(), 0.0, 0.0, 0.0, 0.0];
        for k in 0..9 {
            assert!((c[k] - expected[k]).abs() < 0.01 * expected[0], "coefficient {k}: {} against {}", c[k], expected[k]);
        }
        // The clamped-cosine integral facing +z: ∫ (2 + 3 cos θ) cos θ dω = 2π + 2π = 4π (ω_x ω_y adds 0).
        let e: f32 = (0..9).map(|k| c[k] * COSINE_LOBE[band(k)] * basis(Vec3::Z)[k]).sum();
        assert!((e / (4.0 * PI) - 1.0).abs() < 0.01, "{e}");
    }

    /// A lit floor of albedo ρ under the sun, and the probes' view of it: the irradiance on a surface
    /// facing down just above the floor is its radiance × π = ρE (cos-weighted over the hemisphere).
    #[test]
    fn a_surface_facing_a_lit_floor_receives_its_radiance_times_pi() {
        let floor = quad([Vec3::new(-8.0, 0.0, -8.0), Vec3::new(-8.0, 0.0, 8.0), Vec3::new(8.0, 0.0, 8.0), Vec3::new(8.0, 0.0, -8.0)], 0);
        // A small tile at height 4 m so that the grid spans the space above the floor.
        let marker = quad([Vec3::new(-0.1, 4.0, -0.1), Vec3::new(0.1, 4.0, -0.1), Vec3::new(0.1, 4.0, 0.1), Vec3::new(-0.1, 4.0, 0.1)], 0);
        let snapshot = SceneSnapshot::build(floor.into_iter().chain(marker), vec![grey(0.5)], vec![], vec![sun(Vec3::NEG_Y, 1000.0)]);
        let (layout, photons, _) = trace(&snapshot, 400_000, 1, 16);
        let vgrid = VGrid::build(&snapshot, layout);
        let rgrid = RGrid::new(layout, accumulate_sorted(&photons, layout.cell_count()), 5);
        // The R-grid reads the floor's radiance ρE/π where a ray meets it from above.
        let l = rgrid.radiance(layout.origin, 0, Vec3::new(0.3, 0.01, 0.2), Vec3::Y);
        let truth = 0.5 * 1000.0 / PI;
        println!("floor radiance ratio {}", l.x / truth);
        assert!((l.x / truth - 1.0).abs() < 0.1, "{l} against {truth}");
        // A 45° plane: within 5 % of its radiance by the face flux read at its normal.
        let field = ShField::build(&vgrid, &rgrid, None, &FieldParams { directions: 512, max_distance: 100.0, filter_levels: 1 });
        assert!(!field.coefficients.is_empty());
        // E/π on a patch 0.5 m above the floor, facing down, away from the rim: ρE/π.
        let e = field.irradiance(Vec3::new(0.4, 0.5, -0.3), Vec3::NEG_Y, 1.75 * layout.cell, Some(&vgrid));
        println!("irradiance ratio {}", e.x / truth);
        assert!((e.x / truth - 1.0).abs() < 0.1, "E/π {e} against {truth}");
        // Facing up, the sun's direct light is Bevy's: the field sees only the sky-less void above.
        let up = field.irradiance(Vec3::new(0.4, 0.5, -0.3), Vec3::Y, 1.75 * layout.cell, Some(&vgrid));
        assert!(up.x < 0.02 * truth, "{up}");
    }

    #[test]
    fn a_tilted_plane_reads_its_radiance_within_five_percent() {
        // Lambertian photons leaving a plane at 45° to the axes through one cell: L = 2 Σ n_j² F_j / (π A)
        // against Φ / (π S), S the plane's area inside the cell (√2 A for this cut).
        let n = Vec3::new(1.0, 1.0, 0.0).normalize();
        let count = 200_000;
        let mut rng = rng_for(3, 0);
        let photons: Vec<Photon> =
            (0..count).map(|_| Photon { cell: 0, direction: cosine_hemisphere(n, uniform2(&mut rng)), power: Vec3::ONE, blocked: 0 }).collect();
        let layout = GridLayout { origin: Vec3::ZERO, cell: 1.0, dims: UVec3::ONE };
        let rgrid = RGrid::new(layout, accumulate_sorted(&photons, 1), 1);
        let l = rgrid.radiance(Vec3::ZERO, 0, Vec3::splat(0.5), n);
        let truth = count as f32 / (PI * 2f32.sqrt());
        assert!((l.x / truth - 1.0).abs() < 0.05, "{l} against {truth}");
        // The paper's face value (flux over the face's area, no factor) reads half of a facing plane's.
        let flat: Vec<Photon> =
            (0..count).map(|_| Photon { cell: 0, direction: cosine_hemisphere(Vec3::Y, uniform2(&mut rng)), power: Vec3::ONE, blocked: 0 }).collect();
        let faces = accumulate_direct(&flat, 1);
        assert!((faces[0][2].x / count as f32 - 0.5).abs() < 0.01);
    }

    #[test]
    fn bad_input_gives_finite_empty_or_zero_output() {
        // No light, a NaN light, a degenerate triangle: nothing stored, nothing non-finite.
        let mut snapshot = closed_box(1.0, 0.5);
        snapshot.lights[0].light = SnapshotLight::Point { position: Vec3::NAN, intensity: Vec3::splat(f32::INFINITY), inverse_range_squared: 0.0 };
        let (layout, photons, stats) = trace(&snapshot, 5_000, 4, 8);
        assert!(photons.iter().all(|p| p.power.is_finite() && p.direction.is_finite()));
        assert!(stats.emitted.is_finite());
        let vgrid = VGrid::build(&snapshot, layout);
        let rgrid = RGrid::new(layout, accumulate_sorted(&photons, layout.cell_count()), 4);
        let field = ShField::build(&vgrid, &rgrid, None, &FieldParams { directions: 64, max_distance: 10.0, filter_levels: 1 });
        assert!(field.coefficients.iter().flatten().all(|c| c.is_finite()));
        for i in 0..50 {
            let e = field.irradiance(Vec3::splat(i as f32 * 0.03 - 0.7), fibonacci_sphere(i, 50), 1.75 * layout.cell, Some(&vgrid));
            assert!(e.is_finite() && e.min_element() >= 0.0);
        }
        // An empty scene.
        let empty = SceneSnapshot::default();
        let grid = VGrid::build(&empty, GridLayout::fit(Vec3::ZERO, Vec3::ONE, 4));
        let (list, stats) = trace_photons(&empty, &[], None, &grid, &TraceParams { photons: 10, max_reflections: 4, seed: 0, exposure: 1.0 });
        assert!(list.is_empty() && stats == PhotonStats::default());
    }

    #[test]
    fn probes_inside_a_closed_box_are_dropped_and_rays_stop_at_walls() {
        let mut triangles = Vec::new();
        // A solid 1 m cube (outward faces) in a 4 m room (inward faces).
        for (h, sign, material) in [(0.5f32, 1.0f32, 0), (2.0, -1.0, 0)] {
            for axis in 0..3 {
                for s in [-1.0f32, 1.0] {
                    let n = Vec3::AXES[axis] * s;
                    let (u, v) = (Vec3::AXES[(axis + 1) % 3] * h, Vec3::AXES[(axis + 2) % 3] * h);
                    let c = n * h;
                    let q = quad([c - u - v, c + u - v, c + u + v, c - u + v], material);
                    // Orient each quad's normal outward (sign 1) or inward (sign −1).
                    for t in q {
                        let p = t.positions;
                        let facing = (p[1] - p[0]).cross(p[2] - p[0]).dot(n) * sign;
                        triangles.push(if facing >= 0.0 { t } else { InputTriangle::flat([p[0], p[2], p[1]], material) });
                    }
                }
            }
        }
        let snapshot = SceneSnapshot::build(triangles, vec![grey(0.5)], vec![], vec![]);
        let layout = GridLayout::fit(Vec3::splat(-2.0), Vec3::splat(2.0), 16);
        let vgrid = VGrid::build(&snapshot, layout);
        // From the room towards the cube, the ray stops at the cube's face (x = 0.5), within a V-cell.
        let (_, t) = vgrid.march(Vec3::new(1.6, 0.1, 0.05), Vec3::NEG_X).expect("a hit");
        assert!((t - 1.1).abs() <= layout.v_cell() * 1.01, "{t}");
        // Through empty SH cells in one step, it still finds the far wall.
        let (_, t) = vgrid.march(Vec3::new(1.0, 1.2, 1.0), Vec3::Y).expect("the ceiling");
        assert!((t - 0.8).abs() <= layout.v_cell() * 1.01, "{t}");
        let rgrid = RGrid::new(layout, vec![[Vec3::ZERO; FACES]; layout.cell_count()], 3);
        let field = ShField::build(&vgrid, &rgrid, None, &FieldParams { directions: 128, max_distance: 10.0, filter_levels: 1 });
        let probe = |p: Vec3| field.cell_probe[layout.index(layout.cell_of(p).unwrap())];
        assert_eq!(probe(Vec3::new(0.05, 0.05, 0.05)), u32::MAX, "the cube's centre");
        assert_ne!(probe(Vec3::new(0.8, 0.1, 0.1)), u32::MAX, "the room by the cube");
        // Far from every surface there is no probe (§3.1: only boundary cells and their neighbours).
        assert_eq!(probe(Vec3::new(1.2, 1.2, 1.2)), u32::MAX, "the middle of the room");
        assert!(field.inside > 0);
    }
}

#[cfg(all(test, feature = "reference"))]
mod against_the_tracer {
    use super::*;
    use crate::reference::{ReferenceSettings, incident_radiance};

    /// The R-grid's surface radiance and the probes' incoming radiance on `cornell`, against the path
    /// tracer's at the same points and directions (what the gather then integrates).
    #[test]
    fn surface_and_probe_radiance_follow_the_path_tracer_on_cornell() {
        let snapshot = crate::scenes::cornell::cornell_snapshot();
        let (lo, hi) = snapshot.bounds().unwrap();
        let layout = GridLayout::fit(lo, hi, 32);
        let lights: Vec<_> = snapshot.lights.iter().map(|l| l.light).collect();
        let vgrid = VGrid::build(&snapshot, layout);
        let params = TraceParams { photons: 1 << 19, max_reflections: 8, seed: 1, exposure: 1.0 };
        let (photons, _) = trace_photons(&snapshot, &lights, None, &vgrid, &params);
        let rgrid = RGrid::new(layout, accumulate_sorted(&photons, layout.cell_count()), 6);
        let settings = ReferenceSettings::default();
        // Surfaces away from edges: the floor, the ceiling, the back and side walls.
        for (p, n) in [
            (Vec3::new(-0.6, -1.0, 0.6), Vec3::Y),
            (Vec3::new(0.0, 1.0, 0.0), Vec3::NEG_Y),
            (Vec3::new(0.0, 0.0, -1.0), Vec3::Z),
            (Vec3::new(-1.0, 0.2, 0.0), Vec3::X),
            (Vec3::new(1.0, -0.5, 0.5), Vec3::NEG_X),
        ] {
            // Averaged over a few cells along the surface (photon noise).
            let (t1, t2) = crate::sampling::orthonormal_basis(n);
            let (mut ours, mut truth) = (Vec3::ZERO, Vec3::ZERO);
            for k in 0..9 {
                let offset = (t1 * (k % 3) as f32 + t2 * (k / 3) as f32 - (t1 + t2)) * layout.cell;
                ours += rgrid.radiance(layout.origin, 0, p + offset + n * 1e-3, n) / 9.0;
                let t = incident_radiance(&snapshot, p + offset + n * 0.05, -n, &settings, 512, 77 + k as u64);
                truth += (t[0] + t[1] + t[2]) / 9.0;
            }
            let ratio = luminance_sum(ours) / luminance_sum(truth);
            assert!((ratio - 1.0).abs() < 0.15, "surface at {p}: {ours} against {truth}");
        }
        // Incoming radiance at probes through the room, summed over their directions.
        let field = FieldParams { directions: 64, max_distance: 10.0, filter_levels: 1 };
        let (mut ours, mut theirs) = (0.0, 0.0);
        for (k, p) in [Vec3::new(0.3, 0.2, 0.1), Vec3::new(-0.7, 0.6, -0.5), Vec3::new(0.6, -0.6, 0.7), Vec3::new(-0.2, -0.9, -0.3)].into_iter().enumerate() {
            let c = layout.centre(layout.cell_of(p).unwrap());
            for i in 0..field.directions {
                let d = fibonacci_sphere(i, field.directions);
                ours += luminance_sum(probe_ray(&vgrid, &rgrid, None, c, d, probe_hit(&vgrid, &layout, c, d), &field).0);
                let t = incident_radiance(&snapshot, c, d, &settings, 16, (k as u64) << 16 | i as u64);
                theirs += luminance_sum(t[0] + t[1] + t[2]);
            }
        }
        assert!((0.85..1.1).contains(&(ours / theirs)), "probe radiance {:.3} of the truth's", ours / theirs);
    }
}
