// Temporal smoothing (§9.1): the displayed field moves towards this update's result by `temporal_blend`
// (1 on the first update, which replaces it).

#import bevy_diffuse_gi::rh_types::{RhVolume, SH_FLOATS}

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read> sum: array<f32>;
@group(0) @binding(2) var<storage, read_write> result: array<f32>;

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    let base = index * SH_FLOATS;
    for (var i = 0u; i < SH_FLOATS; i++) {
        result[base + i] = mix(result[base + i], sum[base + i], volume.temporal_blend);
    }
}
