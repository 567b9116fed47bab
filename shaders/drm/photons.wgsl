// Direct Radiance Mapping, step 2 of the paper's §5: the sample photons. Each face of each GI light is
// cut into n × n regularly spaced cells of its direct radiance map (the RSM), and each cell becomes one
// photon (one workgroup each):
//   mip-mapped (§5): the cell's mip-map texel — its total reflected flux Σ ρΦ_T and surface area Σ A
//                    (Eq. 12–13 per texel: A = A'/cos α, stored by rsm.wgsl) and area across the beam
//                    Σ A', at the flux-weighted mean position and normal;
//   otherwise:       the cell's centre texel, its flux and areas scaled by the cell's texel count.
// The photon's radiance is then L_o = ρΦ / (π A_p) (Lambertian), and it stands for its whole cell.

#import bevy_diffuse_gi::drm_types::{PI, DrmPhoton, DrmPhotonsUniform, DrmFaceJob}
#import bevy_diffuse_gi::rsm_types::{GiLight, RsmFace, LIGHT_KIND_DIRECTIONAL}

@group(0) @binding(0) var<uniform> u: DrmPhotonsUniform;
@group(0) @binding(1) var<storage, read> jobs: array<DrmFaceJob>;
@group(0) @binding(2) var rsm_position: texture_2d_array<f32>;
@group(0) @binding(3) var rsm_normal: texture_2d_array<f32>;
@group(0) @binding(4) var rsm_flux: texture_2d_array<f32>;
@group(0) @binding(5) var<storage, read> lights: array<GiLight>;
@group(0) @binding(6) var<storage, read> faces: array<RsmFace>;
@group(0) @binding(7) var<storage, read_write> photons: array<DrmPhoton>;

const THREADS: u32 = #{WORKGROUP_SIZE}u;

// Per thread: (flux rgb, area), (flux-weighted position, weight), (flux-weighted normal, area across the beam).
var<workgroup> sum_flux: array<vec4<f32>, THREADS>;
var<workgroup> sum_position: array<vec4<f32>, THREADS>;
var<workgroup> sum_normal: array<vec4<f32>, THREADS>;

// What one texel adds: its flux (lumens) and area, its position and normal weighted by its flux, and
// its area across the beam A' = A cos α.
fn texel_terms(texel: vec2<i32>, layer: i32, face: RsmFace, flux_scale: f32, scale: f32) -> array<vec4<f32>, 3> {
    let p = textureLoad(rsm_position, texel, layer, 0);
    if p.w <= 0.0 {
        return array(vec4(0.0), vec4(0.0), vec4(0.0));
    }
    let n = textureLoad(rsm_normal, texel, layer, 0).xyz;
    let flux = textureLoad(rsm_flux, texel, layer, 0).rgb * flux_scale * scale;
    var to_light = -face.axis.xyz;
    if face.kind != LIGHT_KIND_DIRECTIONAL {
        to_light = normalize(face.light_position.xyz - p.xyz);
    }
    // rsm.wgsl stores A = A' / max(|cos α|, 0.05); undo exactly that.
    let across = p.w * max(abs(dot(n, to_light)), 0.05) * scale;
    let w = flux.r + flux.g + flux.b + 1e-20;
    return array(vec4(flux, p.w * scale), vec4(p.xyz * w, w), vec4(n * w, across));
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn make_photons(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) thread: u32,
) {
    let index = wid.x + wid.y * groups.x;
    if index >= u.photon_count {
        return;
    }
    let n = u.samples_per_axis;
    let cells = n * n;
    let job = jobs[index / cells];
    let cell = index % cells;
    let light = lights[job.light];
    let face = faces[job.layer];
    let res = light.resolution;
    let c = vec2(cell % n, cell / n);
    let lo = c * res / n;
    let hi = (c + 1u) * res / n;
    let size = hi - lo;
    let texels = size.x * size.y;
    let layer = i32(job.layer);

    var acc = array(vec4(0.0), vec4(0.0), vec4(0.0));
    if u.mip_mapped == 1u {
        for (var t = thread; t < texels; t += THREADS) {
            let texel = vec2<i32>(lo + vec2(t % size.x, t / size.x));
            let terms = texel_terms(texel, layer, face, light.flux_scale, 1.0);
            acc[0] += terms[0];
            acc[1] += terms[1];
            acc[2] += terms[2];
        }
    } else if thread == 0u && texels > 0u {
        acc = texel_terms(vec2<i32>(lo + size / 2u), layer, face, light.flux_scale, f32(texels));
    }
    sum_flux[thread] = acc[0];
    sum_position[thread] = acc[1];
    sum_normal[thread] = acc[2];
    workgroupBarrier();
    for (var stride = THREADS / 2u; stride > 0u; stride /= 2u) {
        if thread < stride {
            sum_flux[thread] += sum_flux[thread + stride];
            sum_position[thread] += sum_position[thread + stride];
            sum_normal[thread] += sum_normal[thread + stride];
        }
        workgroupBarrier();
    }
    if thread == 0u {
        let f = sum_flux[0];
        let p = sum_position[0];
        let nn = sum_normal[0];
        var photon: DrmPhoton;
        if f.w > 0.0 && p.w > 0.0 {
            let normal = nn.xyz / max(length(nn.xyz), 1e-20);
            photon.position = vec4(p.xyz / p.w, f.w);
            photon.normal = vec4(normal, nn.w);
            photon.flux = vec4(f.rgb, 2.0 * PI / f32(max(job.light_photons, 1u)));
        } else {
            photon.position = vec4(0.0);
            photon.normal = vec4(0.0);
            photon.flux = vec4(0.0);
        }
        photons[index] = photon;
    }
}
