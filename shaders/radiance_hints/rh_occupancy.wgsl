// The voxelised scene of a Radiance Hints volume: one bit per voxel of a grid finer than the hints, set
// where a triangle overlaps the voxel (src/radiance_hints/voxelize.rs). Bind group 2 of the passes that
// trace through it. Positions are in occupancy-grid coordinates: voxel v spans [v, v + 1).
#define_import_path bevy_diffuse_gi::rh_occupancy

@group(2) @binding(0) var<storage, read> occupancy: array<u32>;

fn occupied(v: vec3<i32>, res: vec3<u32>) -> bool {
    if any(v < vec3(0)) || any(v >= vec3<i32>(res)) {
        return false;
    }
    let i = u32(v.x) + res.x * (u32(v.y) + res.y * u32(v.z));
    return (occupancy[i >> 5u] & (1u << (i & 31u))) != 0u;
}

// Walks the voxels the segment a → b passes through (Amanatides & Woo) and returns the fraction of the
// segment at which it first enters an occupied voxel, or -1. The voxel containing `a` is skipped (the
// start may sit on a surface), and so are voxels entered within `skip_end` voxel lengths of `b` (the end
// is a surface point whose own voxels must not count).
fn first_hit(a: vec3<f32>, b: vec3<f32>, res: vec3<u32>, skip_end: f32) -> f32 {
    return first_hit_face(a, b, res, skip_end, 0.0).w;
}

// Like `first_hit`, also ignoring occupied voxels entered within `skip_start` voxel lengths of `a`: for a
// lookup point close to a surface (in a corner, the voxels of both walls lie next to it).
fn first_hit_from(a: vec3<f32>, b: vec3<f32>, res: vec3<u32>, skip_start: f32) -> f32 {
    return first_hit_face(a, b, res, 0.0, skip_start).w;
}

// Like `first_hit`, but the voxel containing `a` counts too (fraction 0 when it is occupied): for a start
// point known to be off every surface it belongs to, whose own voxel can only hold another surface.
fn first_hit_inclusive(a: vec3<f32>, b: vec3<f32>, res: vec3<u32>) -> f32 {
    if occupied(vec3<i32>(floor(a)), res) {
        return 0.0;
    }
    return first_hit_face(a, b, res, 0.0, 0.0).w;
}

// Like `first_hit`, with the normal of the voxel face the segment entered through (grid axes, pointing
// back towards `a`) in xyz and the fraction in w (-1 for no hit).
fn first_hit_face(a: vec3<f32>, b: vec3<f32>, res: vec3<u32>, skip_end: f32, skip_start: f32) -> vec4<f32> {
    let delta = b - a;
    let len = length(delta);
    if len < 1e-5 {
        return vec4(0.0, 0.0, 0.0, -1.0);
    }
    let d = delta / len;
    var v = vec3<i32>(floor(a));
    let stepv = vec3<i32>(sign(d));
    let inv = 1.0 / max(abs(d), vec3(1e-8));
    // Distance along the segment to the next voxel boundary on each axis.
    var t_max = select((floor(a) + 1.0 - a), (a - floor(a)), d < vec3(0.0)) * inv;
    t_max = select(t_max, vec3(3.0e38), abs(d) < vec3(1e-8));
    let t_delta = inv;
    var t = 0.0;
    let limit = len - skip_end;
    let max_steps = i32(res.x + res.y + res.z) + 2;
    var face = vec3(0.0);
    for (var i = 0; i < max_steps; i++) {
        // Advance to the next voxel.
        if t_max.x < t_max.y && t_max.x < t_max.z {
            t = t_max.x;
            t_max.x += t_delta.x;
            v.x += stepv.x;
            face = vec3(-f32(stepv.x), 0.0, 0.0);
        } else if t_max.y < t_max.z {
            t = t_max.y;
            t_max.y += t_delta.y;
            v.y += stepv.y;
            face = vec3(0.0, -f32(stepv.y), 0.0);
        } else {
            t = t_max.z;
            t_max.z += t_delta.z;
            v.z += stepv.z;
            face = vec3(0.0, 0.0, -f32(stepv.z));
        }
        if t >= limit {
            return vec4(0.0, 0.0, 0.0, -1.0);
        }
        if t >= skip_start && occupied(v, res) {
            return vec4(face, t / len);
        }
    }
    return vec4(0.0, 0.0, 0.0, -1.0);
}

// A start for rays from `a` that is off every surface: `a` itself when its voxel is free, otherwise the
// point of the nearest free voxel among its 26 neighbours closest to `a` (nudged a hundredth of a voxel
// inside it); `a` when none is free.
//
// Hint centres lie on voxel corners, so a hint a little above a floor or beside a wall often falls in the
// voxel that holds that surface. Rays from there run along the inside of the surface's voxel layer and
// meet its neighbouring voxels through their side faces: phantom walls at the hint's own height (a hint
// 0.2 m above `open_field`'s ground gathered ten times the truth's light from above from them).
fn free_start(a: vec3<f32>, res: vec3<u32>) -> vec3<f32> {
    let v0 = vec3<i32>(floor(a));
    if !occupied(v0, res) {
        return a;
    }
    var best = a;
    var best_distance = 3.0e38;
    for (var k = 0; k < 27; k++) {
        let o = vec3(k % 3, (k / 3) % 3, k / 9) - 1;
        let v = v0 + o;
        if k == 13 || any(v < vec3(0)) || any(v >= vec3<i32>(res)) || occupied(v, res) {
            continue;
        }
        let lo = vec3<f32>(v);
        let nearest = clamp(a, lo + 0.01, lo + 0.99);
        let d = distance(nearest, a);
        if d < best_distance {
            best_distance = d;
            best = nearest;
        }
    }
    return best;
}
