// Temporal smoothing (§9.1): the displayed field moves towards this update's result by `temporal_blend`
// (1 on the first update, which replaces it). Each hint's displayed field is also written in the compact
// irradiance form the per-pixel reconstruction reads (`rh_packed.wgsl`): prepared once per update instead
// of converted in every pixel.
//
// The bounces not run: a full update stops its extra bounces at `extra_bounces` or once one adds less than
// `bounce_threshold` of the light so far (`decide.wgsl`), and the light of the later bounces is lost. In a
// closed room each bounce adds about the same fraction q of the one before (the albedo seen around), and
// the increments settle into one spatial shape, so the rest of the series is the last increment times
// q + q² + … = q / (1 − q), q measured as the ratio of the last two increments' light over the whole
// volume (at most 0.9). `cellar`'s unlit room kept 0.82 of its path-traced light after eight bounces; the
// tail brings the sum to what sixteen bounces give. Motion updates gather one bounce a frame from the
// displayed field, which converges to every bounce by itself: they add no tail.

#import bevy_diffuse_gi::rh_types::{RhVolume, SH_FLOATS, FIELD_TERMS, FIELD_UP, FIELD_DOWN, on_turn}
#import bevy_diffuse_gi::rh_packed::{Packed, pack_field}

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read> sum: array<f32>;
@group(0) @binding(2) var<storage, read_write> result: array<f32>;
@group(0) @binding(3) var<storage, read_write> packed: array<Packed>;
// The bounce increments: bounce k wrote delta_b when k is odd, delta_a when even.
@group(0) @binding(4) var<storage, read> delta_a: array<f32>;
@group(0) @binding(5) var<storage, read> delta_b: array<f32>;
// decide.wgsl's: [0] the last extra bounce that ran, [1] and [2] its light and the one before's (f32 bits).
@group(0) @binding(6) var<storage, read> stats: array<u32>;

// The largest ratio of one bounce's light to the one before that the tail assumes.
const TAIL_RATIO_MAX: f32 = 0.9;

// The factor q / (1 − q) of the last increment that stands for the bounces not run (0: none).
fn tail_factor() -> f32 {
    if volume.bounce_tail == 0u || stats[0] == 0u {
        return 0.0;
    }
    let last = bitcast<f32>(stats[1]);
    let before = bitcast<f32>(stats[2]);
    if !(last > 0.0) || !(before > 0.0) {
        return 0.0;
    }
    // A series that does not shrink (the paper's Eq. 8–11 with a large r_max) gets no tail.
    if last >= before {
        return 0.0;
    }
    let q = min(last / before, TAIL_RATIO_MAX);
    return q / (1.0 - q);
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn blend(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    // A workgroup that did not inject this update (`RadianceHintsVolume::motion_hints_per_update`) keeps
    // its displayed field until its turn: the running sum holds nothing of this update for it.
    if !on_turn(volume, wid.x, volume.inject_period) {
        return;
    }
    let base = index * SH_FLOATS;
    let tail = tail_factor();
    let odd = (stats[0] & 1u) == 1u;
    var c: array<vec3<f32>, FIELD_TERMS>;
    for (var i = 0u; i < FIELD_TERMS; i++) {
        for (var k = 0u; k < 3u; k++) {
            let j = base + 3u * i + k;
            var goal = sum[j];
            if tail > 0.0 {
                goal += tail * select(delta_a[j], delta_b[j], odd);
            }
            let v = mix(result[j], goal, volume.temporal_blend);
            result[j] = v;
            c[i][k] = v;
        }
    }
    packed[index] = pack_field(c[0], c[1], c[2], c[3], c[FIELD_UP], c[FIELD_DOWN]);
}
