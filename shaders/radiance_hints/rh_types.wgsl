// Shared definitions of the Radiance Hints passes: the volume uniform, spherical harmonics (same order and
// constants as `src/sh.rs`, whose tests pin them), grid mapping and random numbers.
#define_import_path bevy_diffuse_gi::rh_types

// Coefficients per colour channel: 4 (SH order 2) or 9 (order 3), from the pipeline's shader defs.
const SH_COEFS: u32 = #{SH_COEFS}u;
// RGB terms per hint in the field buffers (`radiance_hints::field_terms`): the SH coefficients, then the
// exact irradiance of a surface facing up (+Y, term FIELD_UP) and of one facing down (−Y, FIELD_DOWN).
// SH of order 2 or 3 cannot hold those next to strong light from the other side: over a sunlit floor the
// field holds the floor's own light, arriving from below and around the horizon, and Eq. 7 then gives a
// surface facing up a third to a half of the field's mean where the truth is the weak light from above.
const FIELD_TERMS: u32 = #{FIELD_TERMS}u;
const FIELD_UP: u32 = SH_COEFS;
const FIELD_DOWN: u32 = SH_COEFS + 1u;
// Floats per hint in the field buffers: RGB per term, term-major.
const SH_FLOATS: u32 = FIELD_TERMS * 3u;
const PI: f32 = 3.141592653589793;

struct RhVolume {
    // Unit cube [-0.5, 0.5]³ → world, and back.
    world_from_local: mat4x4<f32>,
    local_from_world: mat4x4<f32>,
    // xyz: hints per axis; w: hints in all.
    resolution: vec4<u32>,
    // xyz: world-space length of a cell along the volume's local axes; w: the cell's diagonal (metres).
    cell: vec4<f32>,
    // r_max of Eq. 9–11, metres.
    r_max: f32,
    // Jitter of RSM sample receivers inside the cell, fraction of a cell.
    jitter: f32,
    // N_s: RSM samples per hint.
    rsm_samples: u32,
    light_count: u32,
    // N_b of Eq. 8: hints sampled per hint and extra bounce.
    secondary_samples: u32,
    // Changes with every update and bounce: decorrelates the random numbers.
    seed: u32,
    // c_RSM for directional lights.
    coverage: f32,
    // Weight of this update in the temporal blend (1 on the first update).
    temporal_blend: f32,
    intensity: f32,
    bounce_threshold: f32,
    albedo_volume: u32,
    depth_occlusion_samples: u32,
    depth_occlusion_strength: f32,
    reconstruction_samples: u32,
    // The reconstruction hemisphere's offset and radius in cell diagonals (§5: 1).
    reconstruction_reach: f32,
    // 1: the blend adds the geometric tail of the extra bounces not run.
    bounce_tail: u32,
    // Workgroups of 64 covering every hint.
    workgroups: u32,
    // Index of the bounce being computed (1 = first extra bounce).
    bounce: u32,
    // Point samples of the emissive surfaces (src/emitters.rs), and their share of the N_s samples per
    // hint (by power, against the GI lights'); 0 without emitters.
    emitter_count: u32,
    emitter_fraction: f32,
    // Cells over which a volume nested inside a coarser one fades in from its faces; 0 for volumes that
    // are not nested (they fade out over half a cell outside their box instead).
    blend_band: f32,
    // Faces a nested volume fades in from: bit 2·axis + side (side 0 at local −0.5); the others, lying on
    // the coarser volume's boundary, fade out over half a cell outside as a lone volume's faces do.
    blend_faces: u32,
    // xyz: voxels of the occupancy grid per axis; w: 1 when lookups and injection test visibility through
    // it (`voxel_visibility`).
    occupancy_resolution: vec4<u32>,
    // Range of the reconstruction's near-field occlusion in metres (0: off).
    near_field_range: f32,
    // While things move: the bounce pass recomputes the workgroups w with (w + motion_phase) %
    // motion_period == 0 and the others add the bounce they kept (`bounce.wgsl`); 1 recomputes every one.
    motion_period: u32,
    motion_phase: u32,
    // The injection likewise injects the workgroups w with (w + motion_phase) % inject_period == 0 and
    // the others keep the injection of their last turn (`inject.wgsl`).
    inject_period: u32,
    // Cells the volume moved since the last frame (xyz; `scroll.wgsl`), when it moved by whole cells.
    scroll: vec4<i32>,
}

// While things move, whether workgroup `w` of hints takes its turn this update when one workgroup in
// `period` does (`motion_period` for the bounce, `inject_period` for the injection and the blend).
fn on_turn(v: RhVolume, w: u32, period: u32) -> bool {
    return (w + v.motion_phase) % max(period, 1u) == 0u;
}

// Volume-local position → occupancy-grid coordinates (voxel v spans [v, v + 1)).
fn local_to_occupancy(v: RhVolume, local: vec3<f32>) -> vec3<f32> {
    return (local + 0.5) * vec3<f32>(v.occupancy_resolution.xyz);
}

// A hint's field: SH radiance coefficients and the two vertical irradiances (see FIELD_TERMS).
struct Sh {
    c: array<vec3<f32>, FIELD_TERMS>,
}

// The real SH basis at unit direction d (see src/sh.rs).
fn sh_basis(d: vec3<f32>) -> array<f32, SH_COEFS> {
    var y: array<f32, SH_COEFS>;
    y[0] = 0.2820948;
    y[1] = 0.4886025 * d.y;
    y[2] = 0.4886025 * d.z;
    y[3] = 0.4886025 * d.x;
#if SH_COEFS == 9
    y[4] = 1.0925485 * d.x * d.y;
    y[5] = 1.0925485 * d.y * d.z;
    y[6] = 0.31539157 * (3.0 * d.z * d.z - 1.0);
    y[7] = 1.0925485 * d.x * d.z;
    y[8] = 0.5462742 * (d.x * d.x - d.y * d.y);
#endif
    return y;
}

// Ramamoorthi–Hanrahan clamped-cosine weight of coefficient i: π, 2π/3, π/4 for bands 0, 1, 2.
fn cosine_lobe(i: u32) -> f32 {
    if i == 0u {
        return PI;
    }
    if i < 4u {
        return 2.0 * PI / 3.0;
    }
    return PI / 4.0;
}

// Adds value · Y(d): one sample of the projection integral (Eq. 5), and value · max(0, ±d_y) to the
// irradiance facing up and down (the same Monte Carlo estimate of the clamped-cosine integral, exact in
// the limit).
fn sh_add(sh: ptr<function, Sh>, d: vec3<f32>, value: vec3<f32>) {
    let y = sh_basis(d);
    for (var i = 0u; i < SH_COEFS; i++) {
        (*sh).c[i] += value * y[i];
    }
    (*sh).c[FIELD_UP] += value * max(d.y, 0.0);
    (*sh).c[FIELD_DOWN] += value * max(-d.y, 0.0);
}

// Eq. 7 alone: the SH part's irradiance at n, unclamped.
fn sh_only_irradiance(sh: Sh, n: vec3<f32>) -> vec3<f32> {
    let y = sh_basis(n);
    var e = vec3(0.0);
    for (var i = 0u; i < SH_COEFS; i++) {
        e += sh.c[i] * (cosine_lobe(i) * y[i]);
    }
    return e;
}

// The straight up or down normal on n's side: where `with_vertical` reads the exact irradiance.
fn vertical_of(n: vec3<f32>) -> vec3<f32> {
    return vec3(0.0, select(-1.0, 1.0, n.y >= 0.0), 0.0);
}

// `e`, the irradiance some reconstruction of the SH part gives at n, with its vertical part replaced by
// the exact one: e + n_y² (E_exact(±Y) − e_±Y), where e_±Y is that reconstruction facing straight up or
// down. Floors and ceilings get the exact value, walls keep the SH one, and slopes blend.
fn with_vertical(e: vec3<f32>, e_vertical: vec3<f32>, up: vec3<f32>, down: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let exact = select(down, up, n.y >= 0.0);
    return max(e + n.y * n.y * (exact - e_vertical), vec3(0.0));
}

// Irradiance ∫ L(ω) max(0, n·ω) dω on a surface with normal n: Eq. 7 (clamped at zero against ringing)
// with the exact vertical irradiances (`with_vertical`).
fn sh_irradiance(sh: Sh, n: vec3<f32>) -> vec3<f32> {
    let e_vertical = max(sh_only_irradiance(sh, vertical_of(n)), vec3(0.0));
    return with_vertical(max(sh_only_irradiance(sh, n), vec3(0.0)), e_vertical, sh.c[FIELD_UP], sh.c[FIELD_DOWN], n);
}

fn cell_coords(index: u32, res: vec3<u32>) -> vec3<u32> {
    return vec3(index % res.x, (index / res.x) % res.y, index / (res.x * res.y));
}

fn cell_index(c: vec3<u32>, res: vec3<u32>) -> u32 {
    return c.x + res.x * (c.y + res.y * c.z);
}

// Volume-local position in [-0.5, 0.5]³ of the centre of cell c (hints sit at cell centres).
fn cell_center_local(c: vec3<f32>, res: vec3<u32>) -> vec3<f32> {
    return (c + 0.5) / vec3<f32>(res) - 0.5;
}

fn local_to_world(v: RhVolume, local: vec3<f32>) -> vec3<f32> {
    return (v.world_from_local * vec4(local, 1.0)).xyz;
}

fn world_to_local(v: RhVolume, world: vec3<f32>) -> vec3<f32> {
    return (v.local_from_world * vec4(world, 1.0)).xyz;
}

// PCG hash (Jarzynski & Olano 2020).
fn pcg(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// A uniform float in [0, 1) from a 32-bit state, advancing it.
fn rand(state: ptr<function, u32>) -> f32 {
    *state = pcg(*state);
    return f32(*state >> 8u) * (1.0 / 16777216.0);
}

fn rand3(state: ptr<function, u32>) -> vec3<f32> {
    return vec3(rand(state), rand(state), rand(state));
}

// Uniform direction on the sphere.
fn uniform_sphere(u: vec2<f32>) -> vec3<f32> {
    let z = 1.0 - 2.0 * u.x;
    let r = sqrt(max(0.0, 1.0 - z * z));
    let phi = 2.0 * PI * u.y;
    return vec3(r * cos(phi), r * sin(phi), z);
}

// A finite vector or zero: every value written to a buffer goes through this.
fn finite3(v: vec3<f32>) -> vec3<f32> {
    // NaN fails every comparison; infinities exceed the largest float.
    let ok = abs(v) <= vec3(3.0e38);
    return select(vec3(0.0), v, ok);
}

// The free extents of a valid hint (`voxelize.rs`, `encode_free_extents`, whose constants come in as the
// RH_FREE_* shader defs): how far its cell is free of surfaces along −x, +x, −y, +y, −z, +z, as fractions
// of half a cell (0 to 1). A plain validity of 1 (no extents stored) is free all round.
struct FreeExtents {
    negative: vec3<f32>,
    positive: vec3<f32>,
}

fn free_extents(validity: f32) -> FreeExtents {
    let bits = bitcast<u32>(validity) & 0x7fffffu;
    if validity < 1.0 || (bits & (1u << #{RH_FREE_MARKER_BIT}u)) == 0u {
        return FreeExtents(vec3(1.0), vec3(1.0));
    }
    let steps = #{RH_FREE_STEPS}u;
    let w = #{RH_FREE_BITS}u;
    // Sides in order −x, +x, −y, +y, −z, +z.
    let negative = vec3(bits, bits >> (2u * w), bits >> (4u * w)) & vec3(steps);
    let positive = vec3(bits >> w, bits >> (3u * w), bits >> (5u * w)) & vec3(steps);
    return FreeExtents(vec3<f32>(negative) / f32(steps), vec3<f32>(positive) / f32(steps));
}
