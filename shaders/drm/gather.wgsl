// Direct Radiance Mapping's gather (Frisvad et al. 2005, Eq. 10), per texel of the camera's
// indirect-light target:
//
//     E(x) = Σ_j L_o,j cos θ_j Δω'_j,      L_o,j = ρΦ_j / (π A_p,j)
//
// over the sample photons of every GI light (photons.wgsl), with Δω' by DRM_SOLID_ANGLE:
//     11: 2π / M                                  (the hemisphere split among the light's M photons)
//     14: cos θ'_j A_p,j / (A_p,j + r_j²)         (surface area seen from x, Lambert's rule)
//     15: A'_p,j / ‖B_max − B_min‖²               (area across the beam over the scene diagonal²)
// No visibility. Writes E/π (the frame multiplies by the albedo and the exposure) and weight 1.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_diffuse_gi::drm_types::{PI, DrmPhoton, DrmGatherUniform}
#import bevy_diffuse_gi::gi_frame::{surface_at, finite_or_zero}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

@group(1) @binding(0) var<uniform> u: DrmGatherUniform;
@group(1) @binding(1) var<storage, read> photons: array<DrmPhoton>;

// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};
// The paper's equation for Δω': 11, 14 or 15 (`DrmSolidAngle::equation`).
const SOLID_ANGLE: u32 = #{DRM_SOLID_ANGLE}u;

@fragment
fn gather(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let surface = surface_at(vec2<i32>(floor(in.position.xy)), GI_SCALE, view.world_from_clip, depth_texture, gbuffer);
    if !surface.found {
        discard;
    }
    let x = surface.position;
    let n = surface.normal;

    var e = vec3(0.0);
    for (var j = 0u; j < u.photon_count; j++) {
        let photon = photons[j];
        let area = photon.position.w;
        if area <= 0.0 {
            continue;
        }
        let v = photon.position.xyz - x;
        let r2 = dot(v, v);
        if r2 <= 1e-12 {
            continue;
        }
        let w = v * inverseSqrt(r2);
        let cos_theta = dot(n, w);
        if cos_theta <= 0.0 {
            continue;
        }
        var solid_angle: f32;
        if SOLID_ANGLE == 11u {
            solid_angle = photon.flux.w;
        } else if SOLID_ANGLE == 14u {
            let cos_photon = max(-dot(photon.normal.xyz, w), 0.0);
            solid_angle = cos_photon * area / (area + r2);
        } else {
            solid_angle = photon.normal.w / u.scene_diagonal_squared;
        }
        let radiance = photon.flux.rgb / (PI * area);
        e += radiance * (cos_theta * solid_angle);
    }
    return vec4(finite_or_zero(e / PI * u.intensity), 1.0);
}
