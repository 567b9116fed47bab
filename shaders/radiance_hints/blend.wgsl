// Temporal smoothing (§9.1): the displayed field moves towards this update's result by `temporal_blend`
// (1 on the first update, which replaces it). Each hint's displayed field is also written in the compact
// irradiance form the per-pixel reconstruction reads (`rh_packed.wgsl`): prepared once per update instead
// of converted in every pixel.

#import bevy_diffuse_gi::rh_types::{RhVolume, SH_FLOATS, SH_COEFS}
#import bevy_diffuse_gi::rh_packed::pack_irradiance

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read> sum: array<f32>;
@group(0) @binding(2) var<storage, read_write> result: array<f32>;
@group(0) @binding(3) var<storage, read_write> packed: array<vec4<u32>>;

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    let base = index * SH_FLOATS;
    var c: array<vec3<f32>, SH_COEFS>;
    for (var i = 0u; i < SH_COEFS; i++) {
        for (var k = 0u; k < 3u; k++) {
            let v = mix(result[base + 3u * i + k], sum[base + 3u * i + k], volume.temporal_blend);
            result[base + 3u * i + k] = v;
            c[i][k] = v;
        }
    }
    packed[index] = pack_irradiance(c[0], c[1], c[2], c[3]);
}
