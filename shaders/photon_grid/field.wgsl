// The photon grid's SH field on the GPU (Chang, Park & Ihm, §3.4), one workgroup per probe: each of its
// threads marches some of the probe's N_sh directions of the spherical Fibonacci lattice through the
// V-grid (the two-level traversal of §3.4.2: SH cells without a boundary V-cell are crossed in one
// step), reads the radiance the R-grid's multilevel filter gives the surface it meets (§3.4.3) or the
// environment's where the ray leaves the grid, and projects it and the distance onto the nine SH
// coefficients (Eq. 1: Σ_j L(ω_j) Y_lm(ω_j) 4π/N_sh); the workgroup sums its threads' coefficients and
// counts the rays that met the back of a surface (the CPU drops the probe inside solid geometry; once
// enough did, the probe's other rays are not marched).
//
// The CPU twin, which the GPU test holds this to, is `ShField::build` in src/photon_grid/grid.rs
// (`VGrid::march`, `probe_ray`, `RGrid::radiance`); the Rust side of every struct here is in
// src/photon_grid/field_gpu.rs (`ShaderType`); V_PER_SH (`grid::V_PER_SH`), WORKGROUP_SIZE (the crate's) and
// FIELD_PROBES (`field_gpu::PROBES_PER_GROUP`) are shader defs.

const V_PER_SH: i32 = #{V_PER_SH};

struct FieldParams {
    // World position of the grid's minimum corner, and the SH cell's side (metres).
    origin: vec3<f32>,
    cell: f32,
    // SH cells per axis, and the V-cell's side (metres).
    dims: vec3<u32>,
    v_cell: f32,
    // V-cells per axis, and N_sh.
    v_dims: vec3<u32>,
    directions: u32,
    // Distance recorded for rays that leave the grid (and the largest kept), metres.
    max_distance: f32,
    // The coarsest R-grid level the filter may read, and the levels there are.
    filter_levels: u32,
    levels: u32,
    // The first probe of this dispatch (the probes are dispatched in chunks).
    first_probe: u32,
    probe_count: u32,
    // 4π / N_sh.
    weight: f32,
    // Rays meeting the back of a surface from which the probe lies inside solid geometry
    // (`grid::inside_limit`): its other rays are not marched.
    inside_limit: u32,
}

// One level of the R-grid: cells per axis, the index of its first cell's first face in `rgrid`, and the
// cell's side in metres.
struct RLevel {
    dims: vec3<u32>,
    offset: u32,
    cell: f32,
}

// One of the N_sh directions: the direction, the environment's radiance along it (zero without one),
// and its nine SH basis values (the last three components of basis[2] unused).
struct FieldDirection {
    direction: vec3<f32>,
    environment: vec3<f32>,
    basis: array<vec4<f32>, 3>,
}

@group(0) @binding(0) var<uniform> params: FieldParams;
// The V-grid's boundary cells, a bit each (bit i % 32 of word i / 32), then as many words more: per
// word, the boundary cells in the words before it (a boundary cell's rank in `v_cells`). One buffer, so
// that the pass binds eight storage buffers (WebGPU's default limit).
@group(0) @binding(1) var<storage, read> occupancy: array<u32>;
// Per boundary V-cell, in the order of its linear index: the area-weighted normal sum and the area.
@group(0) @binding(2) var<storage, read> v_cells: array<vec4<f32>>;
// Per SH cell, a bit: whether one of its V-cells is a boundary cell.
@group(0) @binding(3) var<storage, read> sh_boundary: array<u32>;
// Six faces' flux (rgb, lumens) per cell, level after level.
@group(0) @binding(4) var<storage, read> rgrid: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> levels: array<RLevel>;
@group(0) @binding(6) var<storage, read> directions: array<FieldDirection>;
// The probes' SH cells (linear indices).
@group(0) @binding(7) var<storage, read> probes: array<u32>;
// Ten vec4 per probe: the nine coefficients (radiance rgb, distance a), then the count of rays that met
// the back of a surface (x).
@group(0) @binding(8) var<storage, read_write> output: array<vec4<f32>>;

const PI: f32 = 3.141592653589793;
// Threads per workgroup, probes per workgroup, and threads per probe.
const THREADS: u32 = #{WORKGROUP_SIZE}u;
const PROBES: u32 = #{FIELD_PROBES}u;
const SPLIT: u32 = THREADS / PROBES;
// Components smaller than this are treated as zero (`voxels::VoxelWalk`'s STILL).
const STILL: f32 = 1e-8;

var<workgroup> partial: array<array<vec4<f32>, 9>, THREADS>;
var<workgroup> back_faces: array<atomic<u32>, PROBES>;

fn bit(words_index: u32) -> u32 {
    return 1u << (words_index % 32u);
}

fn v_index(v: vec3<i32>) -> u32 {
    let d = params.v_dims;
    return (u32(v.z) * d.y + u32(v.y)) * d.x + u32(v.x);
}

fn occupied(i: u32) -> bool {
    return (occupancy[i / 32u] & bit(i)) != 0u;
}

fn sh_has_boundary(sh: vec3<i32>) -> bool {
    let i = (u32(sh.z) * params.dims.y + u32(sh.y)) * params.dims.x + u32(sh.x);
    return (sh_boundary[i / 32u] & bit(i)) != 0u;
}

// The normal sum and area of boundary V-cell `i`.
fn v_cell_data(i: u32) -> vec4<f32> {
    let below = occupancy[i / 32u] & (bit(i) - 1u);
    let rank = occupancy[arrayLength(&occupancy) / 2u + i / 32u];
    return v_cells[rank + countOneBits(below)];
}

// The voxel walk of `voxels::VoxelWalk` (grid coordinates): the voxel, the ray parameter of the next
// boundary per axis and where the ray entered the voxel.
struct Walk {
    voxel: vec3<i32>,
    t_max: vec3<f32>,
    t: f32,
}

fn walk_inverse(d: vec3<f32>) -> vec3<f32> {
    let moving = abs(d) >= vec3(STILL);
    return select(vec3(1e30), 1.0 / max(abs(d), vec3(STILL)), moving);
}

fn walk_start(a: vec3<f32>, d: vec3<f32>, inv: vec3<f32>, t: f32) -> Walk {
    let p = a + d * t;
    let cell = floor(p);
    let frac = p - cell;
    let to_boundary = select(vec3(1.0) - frac, frac, d < vec3(0.0));
    let t_max = select(vec3(1e30), to_boundary * inv + t, inv < vec3(1e29));
    return Walk(vec3<i32>(cell), t_max, t);
}

fn walk_advance(w: ptr<function, Walk>, d: vec3<f32>, inv: vec3<f32>) {
    let t = (*w).t_max;
    var axis = 2;
    if t.x < t.y && t.x < t.z {
        axis = 0;
    } else if t.y < t.z {
        axis = 1;
    }
    (*w).t = t[axis];
    (*w).t_max[axis] += inv[axis];
    (*w).voxel[axis] += select(1, -1, d[axis] < 0.0);
}

// `VGrid::march`: the first boundary V-cell along the ray from the world point `c` in the unit
// direction `d`, as its linear index, or 0xffffffff where the ray leaves the grid.
fn march(c: vec3<f32>, d: vec3<f32>) -> u32 {
    let a = (c - params.origin) / params.v_cell;
    let inv = walk_inverse(d);
    var w = walk_start(a, d, inv, 0.0);
    let dims = vec3<i32>(params.v_dims);
    let steps = 4 * (dims.x + dims.y + dims.z) + 8;
    for (var k = 0; k < steps; k++) {
        let v = w.voxel;
        if any(v < vec3(0)) || any(v >= dims) {
            return 0xffffffffu;
        }
        let sh = v / V_PER_SH;
        if !sh_has_boundary(sh) {
            // An SH cell without surfaces is crossed in one step.
            let lo = vec3<f32>(sh * V_PER_SH);
            var t_exit = 1e30;
            for (var j = 0; j < 3; j++) {
                if d[j] > STILL {
                    t_exit = min(t_exit, (lo[j] + f32(V_PER_SH) - a[j]) / d[j]);
                } else if d[j] < -STILL {
                    t_exit = min(t_exit, (lo[j] - a[j]) / d[j]);
                }
            }
            if t_exit >= 1e29 {
                return 0xffffffffu;
            }
            w = walk_start(a, d, inv, max(t_exit, w.t) + 1e-4);
            continue;
        }
        let i = v_index(v);
        if occupied(i) {
            return i;
        }
        walk_advance(&w, d, inv);
    }
    return 0xffffffffu;
}

// `RGrid::radiance`: the outgoing radiance of the level's cell containing `p`, on its side facing `n`.
fn r_radiance(level: u32, p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let l = levels[level];
    let c = floor((p - params.origin) / l.cell);
    if any(c < vec3(0.0)) || any(c >= vec3<f32>(l.dims)) {
        return vec3(0.0);
    }
    let cu = vec3<u32>(c);
    let base = l.offset + ((cu.z * l.dims.y + cu.y) * l.dims.x + cu.x) * 6u;
    let fx = select(1u, 0u, n.x >= 0.0);
    let fy = select(3u, 2u, n.y >= 0.0);
    let fz = select(5u, 4u, n.z >= 0.0);
    let sum = rgrid[base + fx].rgb * (n.x * n.x) + rgrid[base + fy].rgb * (n.y * n.y) + rgrid[base + fz].rgb * (n.z * n.z);
    return sum * (2.0 / (PI * l.cell * l.cell));
}

// `probe_ray`: the incoming radiance along the ray from `c` along `d` that met V-cell `hit` and the
// distance to it (w), and whether it met the back of a surface.
fn probe_ray(c: vec3<f32>, j: u32, hit: u32, back: ptr<function, bool>) -> vec4<f32> {
    let dir = directions[j];
    let d = dir.direction;
    *back = false;
    if hit == 0xffffffffu {
        return vec4(dir.environment, params.max_distance);
    }
    let dims = params.v_dims;
    let v = vec3<u32>(hit % dims.x, (hit / dims.x) % dims.y, hit / (dims.x * dims.y));
    // Where the ray enters the V-cell.
    let lo = params.origin + vec3<f32>(v) * params.v_cell;
    var t = 0.0;
    for (var k = 0; k < 3; k++) {
        if abs(d[k]) > STILL {
            let plane = select(lo[k] + params.v_cell, lo[k], d[k] > 0.0);
            t = max(t, (plane - c[k]) / d[k]);
        }
    }
    let data = v_cell_data(hit);
    // The V-cell's mean normal turned towards the ray; the direction back along it where the normals
    // cancel.
    let is_coherent = length(data.xyz) > 0.5 * data.w;
    var n = -d;
    if is_coherent {
        n = normalize(data.xyz);
    }
    if is_coherent && dot(n, d) > 0.0 {
        *back = true;
        n = -n;
    }
    let centre = params.origin + (vec3<f32>(v) + 0.5) * params.v_cell;
    // §3.4.3: the footprint 4π d² / (N_sh cos β) picks two R-grid levels.
    let cos_beta = max(dot(n, -d), 0.25);
    let distance = max(t, 0.5 * params.v_cell);
    let footprint = 4.0 * PI * distance * distance / (f32(params.directions) * cos_beta);
    let base_area = params.cell * params.cell;
    var level = clamp(0.5 * log2(max(footprint / base_area, 1.0)), 0.0, f32(params.levels - 1u));
    level = min(level, f32(params.filter_levels));
    let l0 = u32(floor(level));
    let frac = level - floor(level);
    var radiance = r_radiance(l0, centre, n);
    if frac > 0.0 && l0 + 1u < params.levels {
        radiance = mix(radiance, r_radiance(l0 + 1u, centre, n), frac);
    }
    return vec4(radiance, min(t, params.max_distance));
}

// Thread `lid` of a workgroup takes probe `lid % PROBES` of the group's PROBES and every SPLIT-th
// direction from `lid / PROBES`: neighbouring threads (one SIMD batch on a CPU rasteriser, part of a
// warp on a GPU) march the same direction from neighbouring probes, so their walks take similar steps.
@compute @workgroup_size(#{WORKGROUP_SIZE}, 1, 1)
fn field(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let slot = lid % PROBES;
    let split = lid / PROBES;
    let probe = params.first_probe + group.x * PROBES + slot;
    if lid < PROBES {
        atomicStore(&back_faces[lid], 0u);
    }
    workgroupBarrier();
    var sum = array<vec4<f32>, 9>();
    if probe < params.probe_count {
        let i = probes[probe];
        let dims = params.dims;
        let cell = vec3<u32>(i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y));
        let c = params.origin + (vec3<f32>(cell) + 0.5) * params.cell;
        for (var j = split; j < params.directions; j += SPLIT) {
            // Inside solid geometry: dropped whatever the other rays meet.
            if atomicLoad(&back_faces[slot]) >= params.inside_limit {
                break;
            }
            let d = directions[j].direction;
            var back = false;
            let value = probe_ray(c, j, march(c, d), &back) * params.weight;
            if back {
                atomicAdd(&back_faces[slot], 1u);
            }
            let y = directions[j].basis;
            sum[0] += value * y[0].x;
            sum[1] += value * y[0].y;
            sum[2] += value * y[0].z;
            sum[3] += value * y[0].w;
            sum[4] += value * y[1].x;
            sum[5] += value * y[1].y;
            sum[6] += value * y[1].z;
            sum[7] += value * y[1].w;
            sum[8] += value * y[2].x;
        }
    }
    partial[lid] = sum;
    workgroupBarrier();
    // Sum each probe's SPLIT partial sums.
    for (var stride = SPLIT / 2u; stride > 0u; stride /= 2u) {
        if split < stride {
            for (var k = 0u; k < 9u; k++) {
                partial[lid][k] += partial[lid + stride * PROBES][k];
            }
        }
        workgroupBarrier();
    }
    if split == 0u && probe < params.probe_count {
        for (var k = 0u; k < 9u; k++) {
            output[probe * 10u + k] = partial[slot][k];
        }
        output[probe * 10u + 9u] = vec4(f32(atomicLoad(&back_faces[slot])), 0.0, 0.0, 0.0);
    }
}
