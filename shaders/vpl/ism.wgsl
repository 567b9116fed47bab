// Imperfect shadow maps (Ritschel et al. 2008): every VPL splats its own run of scene points into a small
// paraboloid depth map over its hemisphere, each as the footprint of the surface disk it stands for, then
// pull-push fills the holes the sparse points leave.
//
// A texel stores the nearest point's inverse distance as f32 bits (0 = no point = unoccluded), so the
// nearest splat wins with an integer atomicMax and a cleared buffer means "empty".

#import bevy_diffuse_gi::vpl_types::{VplUniform, Vpl, to_local, paraboloid_coords, ism_index}

@group(0) @binding(0) var<uniform> u: VplUniform;
@group(0) @binding(1) var<storage, read> vpls: array<Vpl>;
@group(0) @binding(2) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> ism: array<atomic<u32>>;

// One thread per (point of the run, VPL): x counts points, y (and z beyond 65535) VPLs.
@compute @workgroup_size(#{WORKGROUP_SIZE})
fn splat(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let vpl_index = id.y + id.z * groups.y;
    if vpl_index >= u.vpl_count || id.x >= u.points_per_ism || u.point_count == 0u {
        return;
    }
    let vpl = vpls[vpl_index];
    // VPL i splats points [i·P, i·P + P) of the shuffled set (cyclically).
    let p = points[(vpl_index * u.points_per_ism + id.x) % u.point_count].xyz;
    let v = p - vpl.position.xyz;
    let d = length(v);
    if d < 1e-6 {
        return;
    }
    let local = to_local(vpl.normal.xyz, v / d);
    if local.z <= 0.0 {
        return;
    }
    let r = u.ism_resolution;
    let centre = paraboloid_coords(local, r);
    // The point stands for a disk of `point_radius`: splat its footprint (the paraboloid's texels span
    // 2/R to 4/R radians), so that nearby surfaces, whose few points land far apart, leave no holes
    // that light would pass through. At most 7 × 7 texels.
    let footprint = min(u.point_radius / d * f32(r) / 3.0, 3.0);
    let lo = vec2<i32>(floor(centre - footprint));
    let hi = vec2<i32>(floor(centre + footprint));
    let value = bitcast<u32>(1.0 / d);
    for (var y = max(lo.y, 0); y <= min(hi.y, i32(r) - 1); y++) {
        for (var x = max(lo.x, 0); x <= min(hi.x, i32(r) - 1); x++) {
            atomicMax(&ism[ism_index(u, vpl_index, 0u, vec2(u32(x), u32(y)))], value);
        }
    }
}

fn load(vpl: u32, level: u32, t: vec2<u32>) -> u32 {
    return atomicLoad(&ism[ism_index(u, vpl, level, t)]);
}

// Pull: level l+1 holds the mean distance of the non-empty texels of its 2×2 children (empty if all are).
fn pull(vpl: u32, level: u32, lid: u32) {
    let r = u.ism_resolution >> level;
    for (var i = lid; i < r * r; i += #{WORKGROUP_SIZE}u) {
        let t = vec2(i % r, i / r);
        var sum = 0.0;
        var n = 0.0;
        for (var c = 0u; c < 4u; c++) {
            let v = load(vpl, level - 1u, t * 2u + vec2(c & 1u, c >> 1u));
            if v != 0u {
                sum += 1.0 / bitcast<f32>(v);
                n += 1.0;
            }
        }
        let value = select(0u, bitcast<u32>(n / max(sum, 1e-20)), n > 0.0);
        atomicStore(&ism[ism_index(u, vpl, level, t)], value);
    }
}

// Push: an empty texel of level l takes its parent's value (level l+1).
fn push(vpl: u32, level: u32, lid: u32) {
    let r = u.ism_resolution >> level;
    for (var i = lid; i < r * r; i += #{WORKGROUP_SIZE}u) {
        let t = vec2(i % r, i / r);
        let index = ism_index(u, vpl, level, t);
        if atomicLoad(&ism[index]) == 0u {
            atomicStore(&ism[index], load(vpl, level + 1u, t / 2u));
        }
    }
}

// One workgroup per VPL: pull two levels up, then push the holes back down. Holes wider than four
// texels stay empty (unoccluded): filling them from coarser levels would close real openings.
@compute @workgroup_size(#{WORKGROUP_SIZE})
fn pull_push(@builtin(workgroup_id) group: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let vpl = group.x + group.y * groups.x;
    if vpl >= u.vpl_count {
        return;
    }
    pull(vpl, 1u, lid);
    storageBarrier();
    pull(vpl, 2u, lid);
    storageBarrier();
    push(vpl, 1u, lid);
    storageBarrier();
    push(vpl, 0u, lid);
}
