// The clamped VPL gather (Novák et al. 2011, §3.1): per pixel of the camera's indirect-light target,
//     E_b(x) = Σ_i Φ_i/π · G_b(x, y_i) · V(x, y_i),   G_b = min(G, b),   G = cos θ_x cos θ_i / d²,
// with V from VPL i's imperfect shadow map (2×2 bilinear percentage-closer test). Writes E_b/π (the frame
// multiplies by the albedo and the exposure) and weight 1.
//
// VPL_POSITIONS (debug view): the irradiance, with every VPL drawn as a dot coloured by its flux.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_diffuse_gi::vpl_types::{PI, Vpl, VplUniform, basis, to_local, paraboloid_coords, paraboloid_direction, ism_index}
#import bevy_diffuse_gi::gi_frame::{surface_at, finite_or_zero}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

@group(1) @binding(0) var<uniform> u: VplUniform;
@group(1) @binding(1) var<storage, read> vpls: array<Vpl>;
@group(1) @binding(2) var<storage, read> ism: array<u32>;

// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};

// Whether VPL `i` sees the point at distance `d` in local direction `local` (fraction, 0–1), for a
// receiver whose normal makes cosine `cos_x` with the direction to the VPL. The depth tolerance is
// `ism_bias · d`, plus a slope-scaled part (within one texel, about 4/R radians at the paraboloid's
// centre, a receiver tilted by θ_x spans d · (4/R) · tan θ_x of depth, which must not shadow itself),
// plus the radius of the surface disk a splatted point stands for.
//
// Traced maps (`u.traced`): see `traced_test`; `x` and `n` are the receiver's position and normal.
fn visibility(i: u32, local: vec3<f32>, d: f32, cos_x: f32, x: vec3<f32>, n: vec3<f32>) -> f32 {
    let r = u.ism_resolution;
    let tan_x = min(sqrt(max(1.0 - cos_x * cos_x, 0.0)) / max(cos_x, 1e-3), 8.0);
    // Points are splatted as disks of `point_radius`: the receiver's own surface may stand that much
    // closer to the VPL within its footprint.
    let tolerance = d * (u.ism_bias + u.slope_tolerance * 4.0 / f32(r) * tan_x) + u.point_radius;
    let p = paraboloid_coords(local, r) - 0.5;
    let base = vec2<i32>(floor(p));
    let f = p - floor(p);
    var v = 0.0;
    var on_surface = true;
    for (var c = 0; c < 4; c++) {
        let o = vec2(c & 1, c >> 1u);
        let t = vec2<u32>(clamp(base + o, vec2(0), vec2(i32(r) - 1)));
        let stored = ism[ism_index(u, i, 0u, t)];
        var lit = 0.0;
        if u.traced != 0u {
            let test = traced_test(stored, vpls[i], t, x, n, d);
            lit = select(0.0, 1.0, test.x);
            on_surface = on_surface && (test.x || test.y);
        } else {
            // 0: no occluder in this direction.
            let occluder = select(1e30, 1.0 / bitcast<f32>(stored), stored != 0u);
            lit = select(0.0, 1.0, d <= occluder + tolerance);
        }
        let w = select(1.0 - f.x, f.x, o.x == 1) * select(1.0 - f.y, f.y, o.y == 1);
        v += lit * w;
    }
    // Traced maps: a receiver whose four texels all either see past it or met its own surface lies on
    // that surface, lit (src/vpl/generate.rs, traced_visibility).
    if u.traced != 0u && on_surface {
        return 1.0;
    }
    return v;
}

// A traced texel against the receiver at `x` (normal `n`, distance `d`): whether it is nearer than the
// far side of the texel's first occluder (x), and, when it is not, whether the point the texel's centre
// ray met lies in the receiver's plane (y). src/vpl/generate.rs, traced_test, is its CPU twin.
fn traced_test(stored: u32, vpl: Vpl, t: vec2<u32>, x: vec3<f32>, n: vec3<f32>, d: f32) -> vec2<bool> {
    if stored == 0u {
        return vec2(true, false);
    }
    let depths = unpack2x16float(stored);
    if d <= depths.x + u.ism_bias * d {
        return vec2(true, false);
    }
    let direction = basis(vpl.normal.xyz) * paraboloid_direction(t, u.ism_resolution);
    let offset = vpl.position.xyz + direction * depths.y - x;
    return vec2(false, abs(dot(offset, n)) <= u.plane_tolerance * length(offset));
}

@fragment
fn gather(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let surface = surface_at(vec2<i32>(floor(in.position.xy)), GI_SCALE, view.world_from_clip, depth_texture, gbuffer);
    if !surface.found {
        discard;
    }
    let x = surface.position;
    let n = surface.normal;

    var e = vec3(0.0);
    for (var i = 0u; i < u.vpl_count; i++) {
        let vpl = vpls[i];
        let v = vpl.position.xyz - x;
        let d2 = dot(v, v);
        if d2 <= 1e-12 {
            continue;
        }
        let d = sqrt(d2);
        let w = v / d;
        let cos_x = dot(n, w);
        let cos_y = -dot(vpl.normal.xyz, w);
        if cos_x <= 0.0 || cos_y <= 0.0 {
            continue;
        }
        let g = min(cos_x * cos_y / d2, u.geometry_bound);
        let vis = visibility(i, to_local(vpl.normal.xyz, -w), d, cos_x, x, n);
        e += vpl.flux.rgb * (g * vis);
    }
    let result = finite_or_zero(e / (PI * PI) * u.intensity);

#ifdef VPL_POSITIONS
    let full = vec2<f32>(textureDimensions(depth_texture));
    let here = vec2<f32>(surface.pixel) + 0.5;
    let surface_z = (view.view_from_world * vec4(x, 1.0)).z;
    for (var i = 0u; i < u.vpl_count; i++) {
        let vpl = vpls[i];
        let clip = view.clip_from_world * vec4(vpl.position.xyz, 1.0);
        if clip.w <= 0.0 {
            continue;
        }
        let ndc = clip.xy / clip.w;
        let screen = vec2(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5) * full;
        let vpl_z = (view.view_from_world * vec4(vpl.position.xyz, 1.0)).z;
        // Drawn where it is not hidden behind the surface seen at this pixel.
        if distance(screen, here) < 2.5 * f32(GI_SCALE) && vpl_z >= surface_z - 0.05 * abs(surface_z) {
            let c = vpl.flux.rgb / max(max(vpl.flux.r, max(vpl.flux.g, vpl.flux.b)), 1e-20);
            return vec4(c / view.exposure, 1.0);
        }
    }
#endif
    return vec4(result, 1.0);
}
