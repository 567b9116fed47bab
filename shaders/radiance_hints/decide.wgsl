// Decides whether the next extra bounce runs: it does while the bounce just computed added at least
// `bounce_threshold` of the light gathered so far (DC terms, luminance). Writes the next bounce's indirect
// dispatch arguments: all workgroups, or none.

#import bevy_diffuse_gi::rh_types::RhVolume

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read> partials: array<vec2<f32>>;
// Three u32 per extra bounce: the indirect dispatch arguments.
@group(0) @binding(2) var<storage, read_write> args: array<u32>;
// [0]: extra bounces computed in the last update; [1], [2]: the DC luminance the last bounce that ran
// added and the one before it (for the first bounce: the injection's), as f32 bits, for the blend's tail.
@group(0) @binding(3) var<storage, read_write> stats: array<u32>;

var<workgroup> sums: array<vec2<f32>, #{WORKGROUP_SIZE}>;

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn decide(@builtin(local_invocation_index) lid: u32) {
    var s = vec2(0.0);
    for (var i = lid; i < volume.workgroups; i += #{WORKGROUP_SIZE}u) {
        s += partials[i];
    }
    sums[lid] = s;
    workgroupBarrier();
    for (var stride = #{WORKGROUP_SIZE}u / 2u; stride > 0u; stride >>= 1u) {
        if lid < stride {
            sums[lid] += sums[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        // `volume.bounce` is the bounce that just ran (1-based); its arguments sit at slot bounce − 1.
        let k = volume.bounce;
        let ran = args[3u * (k - 1u)] > 0u;
        let added = sums[0].x;
        let total = max(sums[0].y, 1e-30);
        if ran {
            stats[0] = k;
            stats[2] = select(stats[1], bitcast<u32>(max(total - added, 0.0)), k == 1u);
            stats[1] = bitcast<u32>(added);
        }
        let go = ran && added > 0.0 && added / total >= volume.bounce_threshold;
        let next = 3u * k;
        if next + 2u < arrayLength(&args) {
            args[next] = select(0u, volume.workgroups, go);
            args[next + 1u] = 1u;
            args[next + 2u] = 1u;
        }
    }
}
