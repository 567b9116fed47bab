// Joint bilateral filter of a reduced-resolution indirect-light target, at its own resolution, before the
// composite upsamples it (the GI frame does this for every method; src/composite/mod.rs).
//
// Methods write one estimate per texel, often with a per-texel pattern (Radiance Hints rotates its
// hemisphere samples per pixel, the VPL gather interleaves): each texel averages its 3×3 neighbourhood
// with binomial weights (1-2-1 per axis), times how similar the neighbours' depth and normal are to its own
// (those of the full-resolution pixels the texels stand for). Texels a method left empty (alpha 0) are
// skipped, so their neighbours on the same surface fill them. The output holds the resolved light
// (rgb / max(alpha, 1)) in rgb and 1 in alpha where any neighbour had light, so the composite reads it as
// one volume's weight. Filtering the few low-resolution texels once is cheaper than filtering as many
// neighbours per full-resolution pixel in the composite, which then interpolates the 2×2 texels around
// each pixel.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_pbr::pbr_deferred_types::unpack_24bit_normal
#import bevy_pbr::utils::octahedral_decode
#import bevy_diffuse_gi::gi_frame::{target_pixel, view_depth, similarity, resolve}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;
@group(0) @binding(3) var gi_texture: texture_2d<f32>;

// Pixels per texel along each axis (2 at half resolution).
const GI_SCALE: i32 = #{GI_SCALE};

fn normal_at(pixel: vec2<i32>) -> vec3<f32> {
    return octahedral_decode(unpack_24bit_normal(textureLoad(gbuffer, pixel, 0).a));
}

@fragment
fn filter_target(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let texel = vec2<i32>(floor(in.position.xy));
    let low_size = vec2<i32>(textureDimensions(gi_texture));
    let full_size = vec2<i32>(textureDimensions(depth_texture));
    let pixel = target_pixel(texel, GI_SCALE, full_size);
    let depth = textureLoad(depth_texture, pixel, 0);
    if depth <= 0.0 {
        return vec4(0.0);
    }
    let z = view_depth(view.view_from_clip, depth);
    let n = normal_at(pixel);
    var sum = vec3(0.0);
    var total = 0.0;
    for (var i = 0; i < 9; i++) {
        let o = vec2(i % 3, i / 3) - 1;
        let q = clamp(texel + o, vec2(0), low_size - 1);
        let t = textureLoad(gi_texture, q, 0);
        if t.a <= 0.0 {
            continue;
        }
        let source = target_pixel(q, GI_SCALE, full_size);
        let d = textureLoad(depth_texture, source, 0);
        if d <= 0.0 {
            continue;
        }
        let binomial = f32((2 - abs(o.x)) * (2 - abs(o.y)));
        let w = binomial * similarity(view_depth(view.view_from_clip, d), z, normal_at(source), n);
        sum += resolve(t) * w;
        total += w;
    }
    if total <= 1e-6 {
        return vec4(0.0);
    }
    return vec4(sum / total, 1.0);
}
