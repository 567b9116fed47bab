// What every method's per-view pass shares with the frame: which full-resolution pixel a texel of the
// indirect-light target stands for (the composite upsamples with the same convention), and the world
// position of a pixel from the depth buffer.
#define_import_path bevy_diffuse_gi::gi_frame

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
