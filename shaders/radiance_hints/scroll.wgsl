// Scrolls a volume's displayed field after the volume moved by whole cells (a cascade level following its
// camera): hint c now shows what hint c + scroll showed, so every hint keeps its place in the world and
// nothing is recomputed for it. Hints that came into the box take the nearest hint that was in it (the
// field's edge, continued), until the updates that follow bring their own light.
//
// `source` is a copy of the field before the move; `destination` is the field itself. The packed
// irradiance the reconstruction reads needs no scroll: the update's blend rewrites it from the field.

#import bevy_diffuse_gi::rh_types::{RhVolume, SH_FLOATS, cell_index}

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read> source: array<u32>;
@group(0) @binding(2) var<storage, read_write> destination: array<u32>;

// The hint whose values hint `index` takes.
fn scrolled_from(index: u32) -> u32 {
    let res = volume.resolution.xyz;
    let c = vec3<i32>(vec3(index % res.x, (index / res.x) % res.y, index / (res.x * res.y)));
    let old = clamp(c + volume.scroll.xyz, vec3(0), vec3<i32>(res) - 1);
    return cell_index(vec3<u32>(old), res);
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn scroll_field(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    let old = scrolled_from(index);
    for (var k = 0u; k < SH_FLOATS; k++) {
        destination[index * SH_FLOATS + k] = source[old * SH_FLOATS + k];
    }
}
