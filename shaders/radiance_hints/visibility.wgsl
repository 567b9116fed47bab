// Which hints a lookup may use, prepared once per geometry change instead of per pixel: for every voxel of
// the occupancy grid, an 8-bit mask of the eight hints around its centre (the trilinear stencil that
// `rh_sampling::stencil_base` picks for any point of the voxel) that are valid (outside solids) and, with
// voxel visibility on, not hidden behind a surface as seen from the voxel's centre — the same test that
// `rh_sampling::trilinear` marches per lookup. Four voxels per word (x fastest, bits 8·(x mod 4)…).
//
// The reconstruction then reads one word per hemisphere sample instead of marching eight rays
// (`reconstruct.wgsl`). Dispatched over a box of words: the whole grid after a full voxelisation, the
// cells around the change after an incremental one. After a scroll by whole cells (a cascade level
// following its camera) the whole grid, copying each mask from where its voxel was before the move
// (`previous`), except within a cell (plus a voxel) of the faces the move crossed, old or new: there the
// stencil was or is clamped to the grid, or reaches voxels that just came in.

#import bevy_diffuse_gi::rh_types::cell_index
#import bevy_diffuse_gi::rh_sampling::{volume, albedo, stencil_base, stencil_hint_occupancy}
#import bevy_diffuse_gi::rh_occupancy::first_hit_from

struct VisibilityRegion {
    // First voxel of the box (x a multiple of 4).
    origin: vec4<u32>,
    // Words along x (4 voxels each), voxels along y and z.
    size: vec4<u32>,
    // xyz: voxel v now holds what v + shift held; w = 1: copy masks away from the faces from `previous`.
    shift: vec4<i32>,
}

@group(0) @binding(0) var<uniform> region: VisibilityRegion;
@group(0) @binding(1) var<storage, read_write> visibility: array<u32>;
@group(0) @binding(2) var<storage, read> previous: array<u32>;

// Whether voxel v's mask after a scroll equals that of voxel v + shift before it: v + shift lay in the
// grid, and neither v nor v + shift lies within `margin` voxels of a face along an axis that moved.
fn mask_carries_over(v: vec3<i32>, res: vec3<i32>, margin: i32) -> bool {
    let shift = region.shift.xyz;
    let source = v + shift;
    if any(source < vec3(0)) || any(source >= res) {
        return false;
    }
    let moved = shift != vec3(0);
    let near_new = (v < vec3(margin)) | (v >= res - margin);
    let near_old = (source < vec3(margin)) | (source >= res - margin);
    return !any(moved & (near_new | near_old));
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn visibility_masks(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let linear = gid.x + gid.y * groups.x * #{WORKGROUP_SIZE}u;
    let size = region.size.xyz;
    if linear >= size.x * size.y * size.z {
        return;
    }
    let occ_res = volume.occupancy_resolution.xyz;
    let res = volume.resolution.xyz;
    let word_coords = vec3(linear % size.x, (linear / size.x) % size.y, linear / (size.x * size.y));
    let first = region.origin.xyz + vec3(4u * word_coords.x, word_coords.y, word_coords.z);
    var word = 0u;
    // A cell of voxels and one more: how far a mask's stencil and its visibility rays reach.
    let margin = i32(occ_res.x / res.x) + 1;
    let scrolled = region.shift.w != 0;
    // x shifts are whole words (checked on the CPU): the word before the move holds these four voxels.
    let source_word = cell_index(vec3<u32>(vec3<i32>(first) + region.shift.xyz), occ_res) / 4u;
    for (var k = 0u; k < 4u; k++) {
        let voxel = first + vec3(k, 0u, 0u);
        if voxel.x >= occ_res.x {
            break;
        }
        if scrolled && mask_carries_over(vec3<i32>(voxel), vec3<i32>(occ_res), margin) {
            word |= ((previous[source_word] >> (8u * k)) & 0xffu) << (8u * k);
            continue;
        }
        let base = stencil_base(voxel);
        let centre = vec3<f32>(voxel) + 0.5;
        var mask = 0u;
        for (var i = 0u; i < 8u; i++) {
            let o = vec3<u32>(i & 1u, (i >> 1u) & 1u, (i >> 2u) & 1u);
            let c = min(base + o, res - 1u);
            var usable = albedo[cell_index(c, res)].a > 0.0;
            // Surfaces entered within one voxel length of the centre do not block: the voxel may hold the
            // surface a lookup point sits just above (as `trilinear` does for its exact position).
            if usable && volume.occupancy_resolution.w != 0u {
                usable = first_hit_from(centre, stencil_hint_occupancy(c), occ_res, 1.0) < 0.0;
            }
            mask |= select(0u, 1u << i, usable);
        }
        word |= mask << (8u * k);
    }
    visibility[cell_index(first, occ_res) / 4u] = word;
}
