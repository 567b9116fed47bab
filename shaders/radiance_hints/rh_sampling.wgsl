// Reading a Radiance Hints volume at arbitrary positions (trilinear between hint centres).
// Bind group 1 of every pass that reads a volume.
#define_import_path bevy_diffuse_gi::rh_sampling

#import bevy_diffuse_gi::rh_types::{RhVolume, Sh, FIELD_TERMS, SH_FLOATS, world_to_local, cell_index, local_to_occupancy}
#import bevy_diffuse_gi::rh_occupancy::first_hit_from

@group(1) @binding(0) var<uniform> volume: RhVolume;
// SH_FLOATS floats per hint: the radiance field being read.
@group(1) @binding(1) var<storage, read> source_sh: array<f32>;
// Per hint: (r_min, r_max) of Eq. 9–11 normalised by r_max, valid RSM samples, unused.
@group(1) @binding(2) var<storage, read> distances: array<vec4<f32>>;
// Per hint: mean diffuse albedo of the surfaces in its cell (rgb), validity (a: 0 = inside solid geometry).
@group(1) @binding(3) var<storage, read> albedo: array<vec4<f32>>;

struct Trilinear {
    cells: array<u32, 8>,
    weights: array<f32, 8>,
    // False when no hint around the position is usable: the lookup returns nothing.
    found: bool,
}

// The eight hints around a world position and their trilinear weights (clamped to the grid, so
// positions beyond the outer hints take the nearest ones). Hints inside solid geometry get no weight
// (they see light through the solid), and, with `voxel_visibility`, neither do hints behind a surface as
// seen from the position (a wall between a room and the hints of the next room, closer than a cell). When
// none is left (the position lies inside a wall or slab) the lookup finds nothing rather than falling back
// to hints in another room. Surfaces within a voxel of `world` are taken for the one it sits on (a
// reflector's hit point) and do not block; see `trilinear_from` for a point known to be off all surfaces.
fn trilinear(world: vec3<f32>) -> Trilinear {
    return trilinear_from(world, 1.0);
}

// `trilinear`, where occupied voxels entered within `skip` voxel lengths of `world` do not block a hint
// (0: every surface between the point and a hint does, beyond the voxel containing the point).
fn trilinear_from(world: vec3<f32>, skip: f32) -> Trilinear {
    let res = volume.resolution.xyz;
    let local = world_to_local(volume, world);
    let g = clamp((local + 0.5) * vec3<f32>(res) - 0.5, vec3(0.0), vec3<f32>(res - 1u));
    let base = min(vec3<u32>(floor(g)), res - 1u);
    let t = stencil(base, g - vec3<f32>(base));
    var usable: array<f32, 8>;
    let from_voxel = local_to_occupancy(volume, local);
    for (var i = 0u; i < 8u; i++) {
        usable[i] = select(0.0, 1.0, albedo[t.cells[i]].a >= 0.5);
        // A skip past any segment in the volume (a lookup regardless of visibility) marches nothing.
        if volume.occupancy_resolution.w != 0u && skip < 1.0e8 && usable[i] > 0.0 && t.weights[i] > 0.0 {
            let o = vec3<u32>(i & 1u, (i >> 1u) & 1u, (i >> 2u) & 1u);
            let hint = stencil_hint_occupancy(min(base + o, res - 1u));
            if first_hit_from(from_voxel, hint, volume.occupancy_resolution.xyz, skip) >= 0.0 {
                usable[i] = 0.0;
            }
        }
    }
    return keep_usable(t, usable);
}

// The eight hints from `base` (clamped to the grid) with their trilinear weights at fraction `f`.
fn stencil(base: vec3<u32>, f: vec3<f32>) -> Trilinear {
    let res = volume.resolution.xyz;
    var t: Trilinear;
    for (var i = 0u; i < 8u; i++) {
        let o = vec3<u32>(i & 1u, (i >> 1u) & 1u, (i >> 2u) & 1u);
        t.cells[i] = cell_index(min(base + o, res - 1u), res);
        let w = select(1.0 - f, f, vec3<bool>(o == vec3(1u)));
        t.weights[i] = w.x * w.y * w.z;
    }
    return t;
}

// `t` with each weight scaled by its hint's usability and renormalised; `found` is false when (almost)
// nothing is left.
fn keep_usable(s: Trilinear, usable: array<f32, 8>) -> Trilinear {
    var t = s;
    var total = 0.0;
    for (var i = 0u; i < 8u; i++) {
        total += t.weights[i] * usable[i];
    }
    t.found = total > 1e-4;
    for (var i = 0u; i < 8u; i++) {
        t.weights[i] = select(0.0, t.weights[i] * usable[i] / total, t.found);
    }
    return t;
}

// The trilinear stencil (the lowest of its eight hints) used for every point of occupancy voxel `voxel`:
// the one around the voxel's centre. With the default grids a voxel never straddles two stencils (hint
// centres lie on voxel faces); where the occupancy grid is capped it can, and points in the voxel then
// extrapolate the centre's stencil by up to half a voxel (their weights are clamped).
fn stencil_base(voxel: vec3<u32>) -> vec3<u32> {
    let res = volume.resolution.xyz;
    let centre = (vec3<f32>(voxel) + 0.5) / vec3<f32>(volume.occupancy_resolution.xyz);
    let g = clamp(centre * vec3<f32>(res) - 0.5, vec3(0.0), vec3<f32>(res - 1u));
    return min(vec3<u32>(floor(g)), res - 1u);
}

// Occupancy-grid position of the hint of cell `c`.
fn stencil_hint_occupancy(c: vec3<u32>) -> vec3<f32> {
    let hint = (vec3<f32>(c) + 0.5) / vec3<f32>(volume.resolution.xyz) - 0.5;
    return local_to_occupancy(volume, hint);
}

// `trilinear` at the volume-local position `local`, with the hints' usability read from a prepared mask
// instead of marched: `mask` is the visibility mask of `voxel`, the occupancy voxel holding the position
// (`visibility.wgsl`), bit i for the stencil's hint i. Outside the occupancy grid the nearest voxel's
// mask applies.
fn trilinear_masked(local: vec3<f32>, mask: u32, voxel: vec3<u32>) -> Trilinear {
    let res = volume.resolution.xyz;
    let g = clamp((local + 0.5) * vec3<f32>(res) - 0.5, vec3(0.0), vec3<f32>(res - 1u));
    let base = stencil_base(voxel);
    var usable: array<f32, 8>;
    for (var i = 0u; i < 8u; i++) {
        usable[i] = f32((mask >> i) & 1u);
    }
    return keep_usable(stencil(base, clamp(g - vec3<f32>(base), vec3(0.0), vec3(1.0))), usable);
}

// The occupancy voxel holding a volume-local position, clamped to the grid.
fn occupancy_voxel(local: vec3<f32>) -> vec3<u32> {
    let o = local_to_occupancy(volume, local);
    let res = volume.occupancy_resolution.xyz;
    return vec3<u32>(clamp(floor(o), vec3(0.0), vec3<f32>(res - 1u)));
}

fn load_sh(cell: u32) -> Sh {
    var sh: Sh;
    let base = cell * SH_FLOATS;
    for (var i = 0u; i < FIELD_TERMS; i++) {
        sh.c[i] = vec3(source_sh[base + 3u * i], source_sh[base + 3u * i + 1u], source_sh[base + 3u * i + 2u]);
    }
    return sh;
}

// The interpolated field for the weights of `trilinear` (zero where no hint is usable). The `*_at`
// functions take the weights so that a caller reading several quantities at one position marches the
// visibility rays once.
fn sh_at(t: Trilinear) -> Sh {
    var sh: Sh;
    for (var k = 0u; k < 8u; k++) {
        let w = t.weights[k];
        if w <= 0.0 {
            continue;
        }
        let base = t.cells[k] * SH_FLOATS;
        for (var i = 0u; i < FIELD_TERMS; i++) {
            sh.c[i] += w * vec3(source_sh[base + 3u * i], source_sh[base + 3u * i + 1u], source_sh[base + 3u * i + 2u]);
        }
    }
    return sh;
}

fn distances_at(t: Trilinear) -> vec4<f32> {
    var d = vec4(0.0);
    for (var k = 0u; k < 8u; k++) {
        d += t.weights[k] * distances[t.cells[k]];
    }
    return d;
}

fn albedo_at(t: Trilinear) -> vec3<f32> {
    var a = vec3(0.0);
    for (var k = 0u; k < 8u; k++) {
        a += t.weights[k] * albedo[t.cells[k]].rgb;
    }
    return a;
}

// Whether a world position lies inside the volume's box.
fn inside_volume(world: vec3<f32>) -> bool {
    let l = world_to_local(volume, world);
    return all(abs(l) <= vec3(0.5));
}
