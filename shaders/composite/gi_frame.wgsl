// What every method's per-view pass shares with the frame: which full-resolution pixel a texel of the
// indirect-light target stands for (the composite upsamples with the same convention), and the world
// position of a pixel from the depth buffer.
#define_import_path bevy_diffuse_gi::gi_frame

#import bevy_pbr::pbr_deferred_types::unpack_24bit_normal
#import bevy_pbr::utils::octahedral_decode

// The visible surface a target texel stands for.
struct GiSurface {
    // The full-resolution pixel (`target_pixel`).
    pixel: vec2<i32>,
    position: vec3<f32>,
    normal: vec3<f32>,
    // false: the pixel sees no geometry (background).
    found: bool,
}

// The surface of target texel `texel` at `scale` pixels per texel: world position from the depth buffer,
// normal from the G-buffer.
fn surface_at(
    texel: vec2<i32>,
    scale: i32,
    world_from_clip: mat4x4<f32>,
    depth_texture: texture_depth_2d,
    gbuffer: texture_2d<u32>,
) -> GiSurface {
    var s: GiSurface;
    let size = vec2<i32>(textureDimensions(depth_texture));
    s.pixel = target_pixel(texel, scale, size);
    let depth = textureLoad(depth_texture, s.pixel, 0);
    s.found = depth > 0.0;
    s.position = world_at(world_from_clip, s.pixel, size, depth);
    s.normal = octahedral_decode(unpack_24bit_normal(textureLoad(gbuffer, s.pixel, 0).a));
    return s;
}

// `v` where every component is finite, otherwise zero: no NaN or Inf may reach the image.
fn finite_or_zero(v: vec3<f32>) -> vec3<f32> {
    return select(vec3(0.0), v, all(v == v) && all(abs(v) < vec3(1e30)));
}

// The pixel a target texel stands for: its top-left pixel at `scale` pixels per texel.
fn target_pixel(texel: vec2<i32>, scale: i32, size: vec2<i32>) -> vec2<i32> {
    return min(texel * scale, size - 1);
}

// World position of `pixel` of an image of `size` pixels at (reverse-Z) `depth`.
fn world_at(world_from_clip: mat4x4<f32>, pixel: vec2<i32>, size: vec2<i32>, depth: f32) -> vec3<f32> {
    let uv = (vec2<f32>(pixel) + 0.5) / vec2<f32>(size);
    let world = world_from_clip * vec4(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, depth, 1.0);
    return world.xyz / world.w;
}

// View-space distance of a (reverse-Z) depth value.
fn view_depth(view_from_clip: mat4x4<f32>, depth: f32) -> f32 {
    let p = view_from_clip * vec4(0.0, 0.0, depth, 1.0);
    return -p.z / p.w;
}

// How much a neighbour at view depth `z_other` with normal `n_other` stands for a pixel at `z` with normal
// `n` when the frame filters or upsamples the target: 1 on the same smooth surface, falling off with the
// relative depth difference (e^(−20 Δz/z)) and the normals' angle (cos⁸).
fn similarity(z_other: f32, z: f32, n_other: vec3<f32>, n: vec3<f32>) -> f32 {
    let dz = abs(z_other - z) / max(z, 1e-4);
    let c = max(dot(n_other, n), 0.0);
    let c2 = c * c;
    let c4 = c2 * c2;
    return exp(-dz * 20.0) * c4 * c4;
}

// The light a target texel holds: Σ w·E/π over Σ w, where weights below 1 (one volume fading out at its
// box) fade the light with them.
fn resolve(t: vec4<f32>) -> vec3<f32> {
    return t.rgb / max(t.a, 1.0);
}
