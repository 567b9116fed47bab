// The photon grid's final gather (Chang, Park & Ihm, §4.1–4.2 and 4.4), per texel of the camera's
// indirect-light target. The SH field holds, at the centres of the SH-grid cells near surfaces, nine
// coefficients (bands 0–2) of the incoming radiance (rgb) and of the distance to the first surface (a).
// At the texel's surface point x with normal n:
//
//     I_lm(x) = Σ_pqr w(x_pqr) I_lm(x_pqr) / Σ_pqr w(x_pqr)         over the 27 cells around x (§4.1)
//     w = w_sh(d) · side · visible,  w_sh(d) = 2d³/r³ − 3d²/r² + 1 (d < r)
//
// where `side` fades out the probes behind the surface and `visible` those whose distance field says a
// surface lies between them and x (src/photon_grid/grid.rs `side_weight`, `visibility_weight`); of the
// rest, those a V-grid boundary cell hides from x are dropped (unless that drops them all). Then
// E = ∫ Ī(ω) cos θ dω over the hemisphere: exactly, by the clamped-cosine convolution of the nine
// coefficients (N_d = 0), or by the paper's N_d directions: of 2 N_d uniform directions on the sphere,
// those above the surface, E ≈ 2π/N Σ cos θ_i Ī(ω_i) (§4.2). With an obscurance distance D the result is
// multiplied by O = 2/N Σ min(d̄(ω_i)/D, 1) cos θ_i (§4.4). Writes E/π (the frame multiplies by the
// albedo and the exposure) and weight 1. The CPU twin is `ShField::irradiance` in grid.rs.
// The Rust side of `PhotonGridUniform` is `PhotonGridUniform` in src/photon_grid/mod.rs (`ShaderType`).

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_diffuse_gi::gi_frame::{surface_at, finite_or_zero}

struct PhotonGridUniform {
    origin: vec3<f32>,
    cell_size: f32,
    dims: vec3<u32>,
    r_max: f32,
    intensity: f32,
    gather_samples: u32,
    obscurance_distance: f32,
    probes: u32,
    // The new field's weight while it blends in over the previous one (1 once it has).
    blend: f32,
}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

@group(1) @binding(0) var<uniform> grid: PhotonGridUniform;
@group(1) @binding(1) var<storage, read> cell_probe: array<u32>;
@group(1) @binding(2) var<storage, read> coefficients: array<vec4<f32>>;
// The V-grid's boundary cells, a bit each (bit i % 32 of word i / 32).
@group(1) @binding(3) var<storage, read> occupancy: array<u32>;
// Where the blend starts: the previous field at the same probes (`coefficients` once blended in).
@group(1) @binding(4) var<storage, read> from_coefficients: array<vec4<f32>>;

const PI: f32 = 3.141592653589793;
const NO_PROBE: u32 = 0xffffffffu;
// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};
// Directions of the obscurance when the integral itself is exact (N_d = 0).
const OBSCURANCE_SAMPLES: u32 = 32u;
// V-grid cells per SH cell along an axis (`grid::V_PER_SH`) and the start of the visibility segments
// off the surface, in V-cells (`grid::GATHER_START_OFFSET`, as a percentage): shader defs.
const V_PER_SH: i32 = #{V_PER_SH};
const GATHER_START_OFFSET: f32 = f32(#{GATHER_START_OFFSET_PERCENT}u) / 100.0;

// The nine real SH basis functions (the order and constants of src/sh.rs).
fn sh_basis(d: vec3<f32>) -> array<f32, 9> {
    return array<f32, 9>(
        0.2820948,
        0.4886025 * d.y,
        0.4886025 * d.z,
        0.4886025 * d.x,
        1.0925485 * d.x * d.y,
        1.0925485 * d.y * d.z,
        0.31539157 * (3.0 * d.z * d.z - 1.0),
        1.0925485 * d.x * d.z,
        0.5462742 * (d.x * d.x - d.y * d.y),
    );
}

// Point i of n of the spherical Fibonacci lattice (`sampling::fibonacci_sphere`).
fn fibonacci_sphere(i: u32, n: u32) -> vec3<f32> {
    let z = 1.0 - (2.0 * f32(i) + 1.0) / f32(n);
    let r = sqrt(max(1.0 - z * z, 0.0));
    let phi = 2.3999632 * f32(i);
    return vec3(r * cos(phi), r * sin(phi), z);
}

// `sh_weight` and `side_weight` of grid.rs.
fn probe_weight(x: vec3<f32>, n: vec3<f32>, p: vec3<f32>) -> f32 {
    let d = length(p - x);
    if d >= grid.r_max {
        return 0.0;
    }
    let t = d / grid.r_max;
    let w_sh = 2.0 * t * t * t - 3.0 * t * t + 1.0;
    let side = clamp((dot(n, p - x) / grid.cell_size + 0.25) / 0.75, 0.0, 1.0);
    return w_sh * side;
}

fn occupied(v: vec3<i32>, dims: vec3<i32>) -> bool {
    if any(v < vec3(0)) || any(v >= dims) {
        return false;
    }
    let i = u32((v.z * dims.y + v.y) * dims.x + v.x);
    return (occupancy[i / 32u] & (1u << (i % 32u))) != 0u;
}

// Whether a boundary V-cell lies strictly between the V-cells of world points a and b
// (`VGrid::segment_blocked`).
fn segment_blocked(a_world: vec3<f32>, b_world: vec3<f32>) -> bool {
    let v_cell = grid.cell_size / f32(V_PER_SH);
    let dims = vec3<i32>(grid.dims) * V_PER_SH;
    let a = (a_world - grid.origin) / v_cell;
    let b = (b_world - grid.origin) / v_cell;
    let len = length(b - a);
    if len < 1e-5 {
        return false;
    }
    let d = (b - a) / len;
    var v = vec3<i32>(floor(a));
    let end = vec3<i32>(floor(b));
    let stepv = vec3<i32>(sign(d));
    let inv = 1.0 / max(abs(d), vec3(1e-8));
    var t_max = select(floor(a) + 1.0 - a, a - floor(a), d < vec3(0.0)) * inv;
    t_max = select(t_max, vec3(3.0e38), abs(d) < vec3(1e-8));
    let steps = i32(ceil(len)) * 3 + 3;
    for (var i = 0; i < steps; i++) {
        if t_max.x < t_max.y && t_max.x < t_max.z {
            if t_max.x >= len {
                return false;
            }
            t_max.x += inv.x;
            v.x += stepv.x;
        } else if t_max.y < t_max.z {
            if t_max.y >= len {
                return false;
            }
            t_max.y += inv.y;
            v.y += stepv.y;
        } else {
            if t_max.z >= len {
                return false;
            }
            t_max.z += inv.z;
            v.z += stepv.z;
        }
        if all(v == end) {
            return false;
        }
        if occupied(v, dims) {
            return true;
        }
    }
    return false;
}

// `visibility_weight` of grid.rs: the probe's distance field towards x against the distance to x.
fn visibility_weight(c: array<vec4<f32>, 9>, p: vec3<f32>, x: vec3<f32>) -> f32 {
    let d = length(x - p);
    if d < 1e-6 {
        return 1.0;
    }
    let seen = evaluate(c, (x - p) / d).a;
    return clamp((seen / d - 0.4) / 0.4, 0.0, 1.0);
}

fn evaluate(c: array<vec4<f32>, 9>, d: vec3<f32>) -> vec4<f32> {
    let y = sh_basis(d);
    var v = vec4(0.0);
    for (var k = 0u; k < 9u; k++) {
        v += c[k] * y[k];
    }
    return v;
}

@fragment
fn gather(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let surface = surface_at(vec2<i32>(floor(in.position.xy)), GI_SCALE, view.world_from_clip, depth_texture, gbuffer);
    if !surface.found {
        discard;
    }
    let x = surface.position;
    let n = surface.normal;
    let base = vec3<i32>(floor((x - grid.origin) / grid.cell_size));
    let dims = vec3<i32>(grid.dims);
    let start = x + n * (GATHER_START_OFFSET * grid.cell_size / f32(V_PER_SH));
    // Every probe's weight, and (in `seen`) only those of the probes no V-cell hides from x; the first
    // where none is visible (x in a corner, its own surfaces' cells around it).
    var all_c = array<vec4<f32>, 9>();
    var seen_c = array<vec4<f32>, 9>();
    var all_w = 0.0;
    var seen_w = 0.0;
    for (var k = 0; k < 27; k++) {
        let cell = base + vec3(k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1);
        if any(cell < vec3(0)) || any(cell >= dims) {
            continue;
        }
        let probe = cell_probe[(cell.z * dims.y + cell.y) * dims.x + cell.x];
        if probe == NO_PROBE {
            continue;
        }
        let p = grid.origin + (vec3<f32>(cell) + 0.5) * grid.cell_size;
        var probe_c = array<vec4<f32>, 9>();
        for (var j = 0u; j < 9u; j++) {
            probe_c[j] = mix(from_coefficients[probe * 9u + j], coefficients[probe * 9u + j], grid.blend);
        }
        let w = probe_weight(x, n, p) * visibility_weight(probe_c, p, x);
        if w <= 0.0 {
            continue;
        }
        let visible = !segment_blocked(start, p);
        for (var j = 0u; j < 9u; j++) {
            all_c[j] += probe_c[j] * w;
            if visible {
                seen_c[j] += probe_c[j] * w;
            }
        }
        all_w += w;
        if visible {
            seen_w += w;
        }
    }
    var c = all_c;
    var total = all_w;
    if seen_w > 1e-6 {
        c = seen_c;
        total = seen_w;
    }
    if total <= 1e-6 {
        return vec4(0.0, 0.0, 0.0, 1.0);
    }
    for (var j = 0u; j < 9u; j++) {
        c[j] /= total;
    }

    var e = vec3(0.0);
    var obscurance = 1.0;
    let directions = 2u * select(grid.gather_samples, OBSCURANCE_SAMPLES, grid.gather_samples == 0u);
    if grid.gather_samples == 0u {
        // The clamped-cosine lobe's coefficients: Â₀ = π, Â₁ = 2π/3, Â₂ = π/4.
        let y = sh_basis(n);
        let lobe = array<f32, 9>(PI, 2.0 * PI / 3.0, 2.0 * PI / 3.0, 2.0 * PI / 3.0, PI / 4.0, PI / 4.0, PI / 4.0, PI / 4.0, PI / 4.0);
        for (var j = 0u; j < 9u; j++) {
            e += c[j].rgb * (lobe[j] * y[j]);
        }
    }
    if grid.gather_samples > 0u || grid.obscurance_distance > 0.0 {
        var sum = vec3(0.0);
        var open = 0.0;
        var used = 0.0;
        for (var i = 0u; i < directions; i++) {
            let w = fibonacci_sphere(i, directions);
            let cos_theta = dot(w, n);
            if cos_theta <= 0.0 {
                continue;
            }
            let v = evaluate(c, w);
            sum += max(v.rgb, vec3(0.0)) * cos_theta;
            if grid.obscurance_distance > 0.0 {
                open += min(max(v.a, 0.0) / grid.obscurance_distance, 1.0) * cos_theta;
            }
            used += 1.0;
        }
        if grid.gather_samples > 0u {
            e = sum * (2.0 * PI / max(used, 1.0));
        }
        if grid.obscurance_distance > 0.0 {
            obscurance = clamp(open * 2.0 / max(used, 1.0), 0.0, 1.0);
        }
    }
    return vec4(finite_or_zero(max(e, vec3(0.0)) / PI * grid.intensity * obscurance), 1.0);
}
