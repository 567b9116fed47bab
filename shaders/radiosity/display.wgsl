// Implicit-visibility radiosity's display: the element mesh drawn into the camera's indirect-light
// target with the gathered irradiance E/π at its corners (interpolated across each triangle, as the
// paper's per-vertex colours). The mesh is pulled from two storage buffers (no vertex buffer).
//
// The element mesh is the scene's own surfaces, so only fragments on the surface the depth prepass saw
// are kept: the target texel's surface point (depth and G-buffer normal, as every method reads it) must
// lie on this triangle's plane and face its way. Kept fragments add (E/π, 1) with additive blending, so
// where two coplanar triangles meet at a texel the frame averages them (`resolve`).
// The Rust side of `RadiosityVertex` is `RadiosityVertex` in src/radiosity/mod.rs (`ShaderType`).

#import bevy_render::view::View
#import bevy_diffuse_gi::gi_frame::{surface_at, finite_or_zero}

struct RadiosityVertex {
    // xyz: world position; w = 1
    position: vec4<f32>,
    // rgb: gathered irradiance over π (before exposure); w unused
    irradiance: vec4<f32>,
}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

@group(1) @binding(0) var<storage, read> vertices: array<RadiosityVertex>;
@group(1) @binding(1) var<storage, read> indices: array<u32>;

// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};

struct VertexOutput {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) irradiance: vec3<f32>,
    // The triangle's unit geometric normal (counter-clockwise front).
    @location(2) @interpolate(flat) normal: vec3<f32>,
}

@vertex
fn vertex(@builtin(vertex_index) index: u32) -> VertexOutput {
    let first = index - index % 3u;
    let a = vertices[indices[first]].position.xyz;
    let b = vertices[indices[first + 1u]].position.xyz;
    let c = vertices[indices[first + 2u]].position.xyz;
    let v = vertices[indices[index]];
    var out: VertexOutput;
    out.clip = view.clip_from_world * vec4(v.position.xyz, 1.0);
    out.world = v.position.xyz;
    out.irradiance = v.irradiance.rgb;
    let cross_ab = cross(b - a, c - a);
    out.normal = cross_ab / max(length(cross_ab), 1e-20);
    return out;
}

@fragment
fn fragment(in: VertexOutput) -> @location(0) vec4<f32> {
    let surface = surface_at(vec2<i32>(floor(in.clip.xy)), GI_SCALE, view.world_from_clip, depth_texture, gbuffer);
    if !surface.found {
        discard;
    }
    // The texel's surface point on this triangle's plane, within 1 % of its distance to the eye (and a
    // few texel footprints at grazing angles), facing the same way.
    let distance = length(surface.position - view.world_position);
    let off_plane = abs(dot(surface.position - in.world, in.normal));
    if off_plane > 0.01 * distance + 1e-4 || dot(in.normal, surface.normal) < 0.5 {
        discard;
    }
    return vec4(finite_or_zero(in.irradiance), 1.0);
}
