// Reflective shadow map rasterisation (Dachsbacher & Stamminger 2005), one light face per draw.
//
// Outputs per texel (paper notation of Papaioannou 2011, §4):
//   position: world position x_k (xyz) and the surface area A_texel the texel covers (w, m²; 0 = empty)
//   normal:   unit normal n_k, turned to face the light (xyz), 1 (w)
//   flux:     reflected flux ρ·Φ_T of Eq. 4 divided by the face's `flux_scale` (rgb), so it fits f16
//
// Φ_T, the flux reaching the texel's patch:
//   directional: E⊥ · A⊥               (illuminance on a surface facing the light × texel area across the beam)
//   spot/point:  I · cone · range · ω   (intensity × Bevy's cone and range falloff × the texel's solid angle,
//                                        ω = (2 tan(fov/2) / res)² · cos³α for a texel at angle α off the axis)

#import bevy_diffuse_gi::rsm_types::{RsmFace, LIGHT_KIND_DIRECTIONAL, LIGHT_KIND_SPOT}

@group(0) @binding(0) var<uniform> face: RsmFace;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
}

@vertex
fn vertex(in: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = face.clip_from_world * vec4(in.position, 1.0);
    out.world = in.position;
    out.normal = in.normal;
    out.albedo = in.albedo;
    return out;
}

struct FragmentOut {
    @location(0) position: vec4<f32>,
    @location(1) normal: vec4<f32>,
    @location(2) flux: vec4<f32>,
}

// Grazing texels would claim huge areas: clamp the cosine of the incidence angle.
const MIN_COS: f32 = 0.05;

@fragment
fn fragment(in: VertexOut) -> FragmentOut {
    var to_light: vec3<f32>;
    var flux_factor: f32;
    var area: f32;
    var n = normalize(in.normal);
    if face.kind == LIGHT_KIND_DIRECTIONAL {
        // Directional: parallel light travelling along `axis`.
        to_light = -face.axis.xyz;
        let cos_theta = max(abs(dot(n, to_light)), MIN_COS);
        flux_factor = 1.0;
        area = face.params.w / cos_theta;
    } else {
        let offset = face.light_position.xyz - in.world;
        let d2 = max(dot(offset, offset), 1e-8);
        let d = sqrt(d2);
        to_light = offset / d;
        // Solid angle of this texel of a perspective face: ω₀ cos³α.
        let cos_alpha = max(dot(-to_light, face.axis.xyz), 0.0);
        let omega = face.params.w * cos_alpha * cos_alpha * cos_alpha;
        // Bevy's range window and (for spot lights) cone falloff.
        let factor = d2 * face.params.z;
        let smooth_factor = saturate(1.0 - factor * factor);
        var falloff = smooth_factor * smooth_factor;
        if face.kind == LIGHT_KIND_SPOT {
            let cone = saturate(dot(-to_light, face.spot_direction.xyz) * face.params.x + face.params.y);
            falloff *= cone * cone;
        }
        flux_factor = falloff * cos_alpha * cos_alpha * cos_alpha;
        let cos_theta = max(abs(dot(n, to_light)), MIN_COS);
        area = omega * d2 / cos_theta;
    }
    // Two-sided: the normal of the side the light sees.
    n = select(n, -n, dot(n, to_light) < 0.0);

    var out: FragmentOut;
    out.position = vec4(in.world, area);
    out.normal = vec4(n, 1.0);
    out.flux = vec4(in.albedo * face.color.rgb * flux_factor, 1.0);
    return out;
}
