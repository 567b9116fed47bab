// The compact irradiance form of a hint that the per-pixel reconstruction reads: two `vec4<u32>` instead
// of the 18 floats of its order-2 field, written by the blend pass once per update.
//
// The clamped-cosine convolution of the SH radiance (Ramamoorthi & Hanrahan, Eq. 7 of the paper) gives,
// per colour channel c, the irradiance on a surface with normal n as
//     E_c(n) = a_c (1 + d_c · n),   a_c = π Y₀₀ L₀₀,c,   d_c = (2π/3) Y₁ (L₁₁, L₁₋₁, L₁₀)_c / a_c
// (|d_c| ≤ 2 for any non-negative radiance). a is stored as three 16-bit logarithms (2⁻³²…2³², 0.07 %
// steps: the HDR range of any scene without a per-volume scale), d as nine 8-bit signed fractions of 2
// (steps of 0.016, under 1 % of the irradiance of a hint). The second word holds the exact irradiance
// facing up and facing down (`rh_types::FIELD_TERMS`), six more 16-bit logarithms; only normals that are
// not horizontal read it (walls read the first word alone).
#define_import_path bevy_diffuse_gi::rh_packed

#import bevy_diffuse_gi::rh_types::{with_vertical, vertical_of}

const PI: f32 = 3.141592653589793;
// π Y₀₀ and (2π/3) Y₁: the band-0 and band-1 weights of the irradiance.
const BAND0: f32 = 0.8862269;
const BAND1: f32 = 1.0233267;

fn encode_log(a: f32) -> u32 {
    if !(a > 2.3283064e-10) {
        return 0u;
    }
    return u32(clamp(round((log2(a) + 32.0) * 1024.0), 1.0, 65535.0));
}

fn decode_log(q: vec3<u32>) -> vec3<f32> {
    return select(vec3(0.0), exp2(vec3<f32>(q) / 1024.0 - 32.0), q != vec3(0u));
}

// Two words per hint: the SH part and the vertical irradiances.
struct Packed {
    sh: vec4<u32>,
    vertical: vec4<u32>,
}

// Order-2 SH radiance (coefficients L₀₀, L₁₋₁, L₁₀, L₁₁ as RGB) and the irradiance facing up and down →
// packed irradiance.
fn pack_field(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, c3: vec3<f32>, up: vec3<f32>, down: vec3<f32>) -> Packed {
    let u = vec3(encode_log(up.x), encode_log(up.y), encode_log(up.z));
    let d = vec3(encode_log(down.x), encode_log(down.y), encode_log(down.z));
    let vertical = vec4(u.x | (u.y << 16u), u.z | (d.x << 16u), d.y | (d.z << 16u), 0u);
    return Packed(pack_irradiance(c0, c1, c2, c3), vertical);
}

fn pack_irradiance(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, c3: vec3<f32>) -> vec4<u32> {
    let a = max(BAND0 * c0, vec3(0.0));
    let inv = select(vec3(0.0), 1.0 / a, a > vec3(1e-30));
    // Directions in world axis order (x, y, z) = (L₁₁, L₁₋₁, L₁₀), per channel, halved into [-1, 1].
    let dr = clamp(BAND1 * vec3(c3.r, c1.r, c2.r) * inv.r * 0.5, vec3(-1.0), vec3(1.0));
    let dg = clamp(BAND1 * vec3(c3.g, c1.g, c2.g) * inv.g * 0.5, vec3(-1.0), vec3(1.0));
    let db = clamp(BAND1 * vec3(c3.b, c1.b, c2.b) * inv.b * 0.5, vec3(-1.0), vec3(1.0));
    let w0 = encode_log(a.r) | (encode_log(a.g) << 16u);
    let w1 = encode_log(a.b) | (pack4x8snorm(vec4(0.0, 0.0, dr.x, dr.y)) & 0xffff0000u);
    let w2 = pack4x8snorm(vec4(dr.z, dg.x, dg.y, dg.z));
    let w3 = pack4x8snorm(vec4(db, 0.0));
    return vec4(w0, w1, w2, w3);
}

// A weighted sum of packed hints, Σ wₖ aₖ (rgb) and Σ wₖ aₖ dₖ (per channel): the field of a trilinear
// lookup (or several), whose irradiance is E_c(n) = a_c + b_c · n.
struct PackedField {
    a: vec3<f32>,
    br: vec3<f32>,
    bg: vec3<f32>,
    bb: vec3<f32>,
    // Σ wₖ of the exact irradiance facing up and facing down.
    up: vec3<f32>,
    down: vec3<f32>,
}

fn add_packed_field(f: ptr<function, PackedField>, q: Packed, w: f32) {
    add_packed(f, q.sh, w);
    (*f).up += w * vertical_up(q.vertical);
    (*f).down += w * vertical_down(q.vertical);
}

// The exact irradiance facing up, and facing down, of a packed hint's second word.
fn vertical_up(v: vec4<u32>) -> vec3<f32> {
    return decode_log(vec3(v.x & 0xffffu, v.x >> 16u, v.y & 0xffffu));
}

fn vertical_down(v: vec4<u32>) -> vec3<f32> {
    return decode_log(vec3(v.y >> 16u, v.z & 0xffffu, v.z >> 16u));
}

fn add_packed(f: ptr<function, PackedField>, q: vec4<u32>, w: f32) {
    let a = w * decode_log(vec3(q.x & 0xffffu, q.x >> 16u, q.y & 0xffffu));
    let h = unpack4x8snorm(q.y);
    let g = unpack4x8snorm(q.z);
    let b = unpack4x8snorm(q.w);
    (*f).a += a;
    (*f).br += 2.0 * a.r * vec3(h.z, h.w, g.x);
    (*f).bg += 2.0 * a.g * g.yzw;
    (*f).bb += 2.0 * a.b * b.xyz;
}

// Linear: a + b·n, clamped at zero.
fn sh_linear(f: PackedField, n: vec3<f32>) -> vec3<f32> {
    return max(f.a + vec3(dot(f.br, n), dot(f.bg, n), dot(f.bb, n)), vec3(0.0));
}

// The linear form with the exact vertical irradiances (`rh_types::with_vertical`).
fn field_linear(f: PackedField, n: vec3<f32>) -> vec3<f32> {
    return with_vertical(sh_linear(f, n), sh_linear(f, vertical_of(n)), f.up, f.down, n);
}

// Hazel's non-linear reconstruction of L1 irradiance ("Reconstructing diffuse lighting from spherical
// harmonic data", Geomerics, 2015) for one channel with mean a and linear term b: it matches the mean
// irradiance over all normals, is exact for a single distant light, and never goes below zero, where the
// linear form rings negative on the side facing away from a strong light and eats the weaker light that
// side does receive (a surface lit by a bright wall or floor behind the point the hints describe).
fn hazel(a: f32, b: vec3<f32>, n: vec3<f32>) -> f32 {
    let len = length(b);
    if !(a > 0.0) {
        return 0.0;
    }
    if len < 1e-6 * a {
        return a;
    }
    let r = min(0.5 * len / a, 1.0);
    let q = 0.5 * (1.0 + dot(b / len, n));
    let p = 1.0 + 2.0 * r;
    let alpha = (1.0 - r) / (1.0 + r);
    return a * (alpha + (1.0 - alpha) * (p + 1.0) * pow(max(q, 0.0), p));
}

fn sh_nonlinear(f: PackedField, n: vec3<f32>) -> vec3<f32> {
    return vec3(hazel(f.a.r, f.br, n), hazel(f.a.g, f.bg, n), hazel(f.a.b, f.bb, n));
}

// Hazel's form with the exact vertical irradiances (`rh_types::with_vertical`).
fn field_nonlinear(f: PackedField, n: vec3<f32>) -> vec3<f32> {
    return with_vertical(sh_nonlinear(f, n), sh_nonlinear(f, vertical_of(n)), f.up, f.down, n);
}
