// The reflective shadow map gather (Dachsbacher & Stamminger 2005), per texel of the camera's
// indirect-light target. Each RSM texel p is a small diffuse reflector of flux Φ_p (lumens):
//
//     E(x) = Σ_p Φ_p · max(0, n_p·(x − x_p)) · max(0, n·(x_p − x)) / (π ‖x − x_p‖⁴)      (paper Eq. 1)
//
// summed over the texels of a disk of radius r_max around x's projection, estimated from the fixed
// pattern of src/rsm_gather/render.rs (`sample_pattern`: denser near the centre, weighted by ξ₁²). Each
// sample stands for `weight × res²` texels, a disk of area A = that × the texel's area: ‖x − x_p‖² is
// taken as ‖x − x_p‖² + A/π, the disk's exact on-axis irradiance, which bounds the singularity where
// surfaces meet. No visibility. Writes E/π (the frame multiplies by the albedo and the exposure) and
// weight 1.
//
// Cube lights (points, wide spots: six faces) sample directions in a cap of angular radius π·r_max
// around the one from the light to x (r_max = 1: the whole sphere, as a room lit by a bulb needs), each
// looked up in the face it falls into, so the cap crosses the faces' edges; a sample then stands for its
// solid angle over its texel's.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_diffuse_gi::rsm_types::{GiLight, RsmFace, LIGHT_KIND_DIRECTIONAL, face_uv, cube_face}
#import bevy_diffuse_gi::gi_frame::{surface_at, finite_or_zero}

struct RsmGatherUniform {
    samples: u32,
    light_count: u32,
    intensity: f32,
}

struct RsmGatherSample {
    // xy: offset in units of the map's side; z: weight as a fraction of the map's area
    offset_weight: vec4<f32>,
}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

@group(1) @binding(0) var<uniform> u: RsmGatherUniform;
@group(1) @binding(1) var<storage, read> pattern: array<RsmGatherSample>;
@group(1) @binding(2) var rsm_position: texture_2d_array<f32>;
@group(1) @binding(3) var rsm_normal: texture_2d_array<f32>;
@group(1) @binding(4) var rsm_flux: texture_2d_array<f32>;
@group(1) @binding(5) var<storage, read> lights: array<GiLight>;
@group(1) @binding(6) var<storage, read> faces: array<RsmFace>;

const PI: f32 = 3.141592653589793;
// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};

// Σ over one light's sampled texels of Φ_p cos θ_p cos θ / (π (d² + A/π)), i.e. the irradiance at x.
fn gather_light(light: GiLight, x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let res = f32(light.resolution);
    let texels = res * res;
    let cube = light.faces == 6u;
    // Single face: the disk's centre is x's projection, kept on the map (surfaces beside a spot's cone
    // gather from the nearest edge).
    var centre = vec2(0.5);
    var omega = vec3(0.0, -1.0, 0.0);
    var t = vec3(1.0, 0.0, 0.0);
    var b = vec3(0.0, 0.0, 1.0);
    if cube {
        let to_x = x - faces[light.first_layer].light_position.xyz;
        omega = to_x / max(length(to_x), 1e-6);
        // A frame around the direction.
        let helper = select(vec3(0.0, 1.0, 0.0), vec3(1.0, 0.0, 0.0), abs(omega.y) > 0.9);
        t = normalize(cross(helper, omega));
        b = cross(omega, t);
    } else {
        // Behind a spot light (its ceiling) x has no projection: the disk is centred on the map.
        let projected = face_uv(faces[light.first_layer], x);
        centre = select(vec2(0.5), clamp(projected.xy, vec2(0.0), vec2(1.0)), projected.z > 0.0);
    }
    var e = vec3(0.0);
    for (var i = 0u; i < u.samples; i++) {
        let s = pattern[i].offset_weight;
        var layer = light.first_layer;
        var uv = centre + s.xy;
        // Texels the sample stands for, per unit of its weight × res².
        var density = 1.0;
        if cube {
            // The disk maps to a cap of angular radius π·r_max around ω: ρ → θ = π ρ (ρ in units of
            // the map's side, r_max ≤ 1 reaching the whole sphere).
            let rho = max(length(s.xy), 1e-6);
            let theta = PI * rho;
            let around = s.xy / rho;
            let d = cos(theta) * omega + sin(theta) * (around.x * t + around.y * b);
            let f = cube_face(d);
            layer = light.first_layer + f;
            uv = face_uv(faces[layer], faces[layer].light_position.xyz + d).xy;
            // The sample covers the solid angle (weight × π sin θ / ρ); a texel of the face it lands in
            // covers (2/res)² cos³α (α off the face's axis).
            let a = abs(d);
            let cos_alpha = max(a.x, max(a.y, a.z));
            density = PI * sin(theta) / rho / (4.0 * cos_alpha * cos_alpha * cos_alpha);
        }
        if any(uv < vec2(0.0)) || any(uv >= vec2(1.0)) {
            continue;
        }
        let texel = vec2<i32>(uv * res);
        let p = textureLoad(rsm_position, texel, i32(layer), 0);
        if p.w <= 0.0 {
            continue;
        }
        let v = p.xyz - x;
        let d2 = dot(v, v);
        let cos_x = dot(n, v);
        let n_p = textureLoad(rsm_normal, texel, i32(layer), 0).xyz;
        let cos_p = -dot(n_p, v);
        if cos_x <= 0.0 || cos_p <= 0.0 || d2 <= 1e-12 {
            continue;
        }
        let weight = s.z * texels * density;
        let area = weight * p.w;
        let flux = textureLoad(rsm_flux, texel, i32(layer), 0).rgb * light.flux_scale;
        // cos_x cos_p / d² with unnormalised v: (n·v)(−n_p·v) / d⁴, the disk's A/π added to d².
        e += flux * (weight * cos_x * cos_p / (d2 * (d2 + area / PI)));
    }
    return e / PI;
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
    for (var l = 0u; l < u.light_count; l++) {
        e += gather_light(lights[l], x, n);
    }
    return vec4(finite_or_zero(e / PI * u.intensity), 1.0);
}
