// Adds a GI method's indirect light to the camera's HDR target, or shows a debug view instead.
//
// The GI target holds Σ w·E/π (rgb) and Σ w (a), written by whichever method the camera uses (Radiance
// Hints sums its volumes there; the VPL gather writes weight 1). The light added is `albedo × E/π × exposure`, with the albedo decoded from Bevy's
// G-buffer (base colour stored gamma-2.2, times 1 − metallic): the indirect-only image of the metrics.
// The reconstruction rotates its hemisphere samples per pixel (interleaved gradient noise), which turns
// differences between hints into a fine pattern; it is filtered away. At full resolution each pixel
// averages its 3×3 neighbourhood here; a reduced-resolution target is filtered the same way at its own
// resolution first (filter.wgsl), and each pixel interpolates the 2×2 texels around it (bilinear); all
// weighted by how similar the neighbours' depth and normal are to its own (joint bilateral filtering).

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_pbr::pbr_deferred_types::{unpack_24bit_normal, unpack_unorm4x8_, unpack_flags, DEFERRED_FLAGS_UNLIT_BIT}
#import bevy_pbr::utils::octahedral_decode
#import bevy_diffuse_gi::gi_frame::{target_pixel, view_depth, similarity, resolve}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;
@group(0) @binding(3) var gi_texture: texture_2d<f32>;

#if DISPLAY >= 4
struct RsmDebug {
    first_layer: u32,
    faces: u32,
    resolution: u32,
    flux_display_scale: f32,
}
@group(1) @binding(0) var rsm_position: texture_2d_array<f32>;
@group(1) @binding(1) var rsm_normal: texture_2d_array<f32>;
@group(1) @binding(2) var rsm_flux: texture_2d_array<f32>;
@group(1) @binding(3) var<uniform> rsm_debug: RsmDebug;
#endif

// 0 add to the lit image, 1 indirect only, 2 irradiance, 3 irradiance texel by texel (no filter),
// 4 RSM flux, 5 RSM normal, 6 RSM position (see `TargetDisplay` in src/camera.rs).
const DISPLAY: u32 = #{DISPLAY}u;
const GI_SCALE: i32 = #{GI_SCALE};

fn normal_at(pixel: vec2<i32>) -> vec3<f32> {
    return octahedral_decode(unpack_24bit_normal(textureLoad(gbuffer, pixel, 0).a));
}

fn gi_at(pixel: vec2<i32>, n: vec3<f32>, depth: f32) -> vec3<f32> {
    let low_size = vec2<i32>(textureDimensions(gi_texture));
    let full_size = vec2<i32>(textureDimensions(depth_texture));
    // Full resolution: the 3×3 neighbourhood, equal spatial weights. Reduced resolution: the target was
    // filtered at its own resolution (filter.wgsl); the 2×2 texels around the pixel, bilinear weights.
    let pos = (vec2<f32>(pixel) + 0.5) / f32(GI_SCALE) - 0.5;
    let base = select(vec2<i32>(floor(pos)), pixel - 1, GI_SCALE == 1);
    let taps = select(2, 3, GI_SCALE == 1);
    let z = view_depth(view.view_from_clip, depth);
    var sum = vec3(0.0);
    var total = 0.0;
    var nearest = vec3(0.0);
    var nearest_distance = 1e30;
    for (var i = 0; i < taps * taps; i++) {
        let o = vec2(i % taps, i / taps);
        let q = clamp(base + o, vec2(0), low_size - 1);
        let source = target_pixel(q, GI_SCALE, full_size);
        let d = textureLoad(depth_texture, source, 0);
        let texel = textureLoad(gi_texture, q, 0);
        // Nothing written (a method found no light it could trust there, e.g. a Radiance Hints pixel in
        // a junction whose every hint lies behind a wall): the neighbours on the same surface fill it.
        if d <= 0.0 || texel.a <= 0.0 {
            continue;
        }
        let zd = view_depth(view.view_from_clip, d);
        let dist = abs(vec2<f32>(base + o) - pos);
        let bilinear = select(max(1.0 - dist.x, 0.0) * max(1.0 - dist.y, 0.0), 1.0, GI_SCALE == 1);
        let value = resolve(texel);
        let w = (bilinear + 1e-3) * similarity(zd, z, normal_at(source), n);
        sum += value * w;
        total += w;
        let dz = abs(zd - z);
        if dz < nearest_distance {
            nearest_distance = dz;
            nearest = value;
        }
    }
    return select(nearest, sum / total, total > 1e-6);
}

@fragment
fn composite(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let pixel = vec2<i32>(floor(in.position.xy));
#if DISPLAY >= 4
    // The first GI light's RSM, its faces side by side.
    let size = vec2<f32>(textureDimensions(depth_texture));
    let faces = max(rsm_debug.faces, 1u);
    let u = in.uv.x * f32(faces);
    let face = min(u32(u), faces - 1u);
    let texel = vec2<i32>(vec2(fract(u), in.uv.y) * f32(rsm_debug.resolution));
    let layer = i32(rsm_debug.first_layer + face);
    var c = vec3(0.0);
    if DISPLAY == 4u {
        c = textureLoad(rsm_flux, texel, layer, 0).rgb * rsm_debug.flux_display_scale;
    } else if DISPLAY == 5u {
        c = textureLoad(rsm_normal, texel, layer, 0).xyz * 0.5 + 0.5;
    } else {
        let p = textureLoad(rsm_position, texel, layer, 0);
        c = select(vec3(0.0), fract(p.xyz), p.w > 0.0);
    }
    return vec4(c, 1.0);
#else
    let depth = textureLoad(depth_texture, pixel, 0);
    if depth <= 0.0 {
        if DISPLAY == 0u {
            discard;
        }
        return vec4(0.0);
    }
    let g = textureLoad(gbuffer, pixel, 0);
    let unlit = (unpack_flags(g.a) & DEFERRED_FLAGS_UNLIT_BIT) != 0u;
    let n = octahedral_decode(unpack_24bit_normal(g.a));
    let base_color = pow(unpack_unorm4x8_(g.r).rgb, vec3(2.2));
    let metallic = unpack_unorm4x8_(g.b).g;
    let albedo = select(base_color * (1.0 - metallic), vec3(0.0), unlit);
#if DISPLAY == 3
    let texel = min(pixel / GI_SCALE, vec2<i32>(textureDimensions(gi_texture)) - 1);
    return vec4(resolve(textureLoad(gi_texture, texel, 0)) * view.exposure, 1.0);
#else
    let gi = gi_at(pixel, n, depth);
    if DISPLAY == 2u {
        return vec4(gi * view.exposure, 1.0);
    }
    let light = albedo * gi * view.exposure;
    if DISPLAY == 1u {
        return vec4(light, 1.0);
    }
    if unlit {
        discard;
    }
    return vec4(light, 0.0);
#endif
#endif
}
