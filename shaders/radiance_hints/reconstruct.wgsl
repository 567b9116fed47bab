// Reconstruction of indirect light per pixel (Papaioannou 2011, §5, Eq. 6–7), one draw per volume into the
// camera's GI target with additive blending.
//
// For a visible point p with normal n, N_RH positions are laid on a hemisphere of radius r (the cell
// diagonal) around p + n·r/2 — the first on the normal, the rest on a cone 80° from it, rotated per pixel —
// so that no hint behind the surface is read. At each, the radiance field is interpolated trilinearly and
// integrated against the clamped cosine around n (Eq. 7); Eq. 6 averages them:
//     L_r(p) = ρ(p)/(π N_RH) Σ_n E_n(n)
// This pass writes E/π (the composite multiplies by ρ and the exposure), times a weight that is 1 inside the
// volume's box and fades to zero over half a cell outside it (surfaces often lie exactly on the box, a volume
// fitted to a room), and the weight itself in alpha, so overlapping volumes average. A volume nested inside
// a coarser one instead fades in over `blend_band` cells inside its box and is drawn over the coarser one
// (premultiplied alpha blending), so the finer field takes over without a seam.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_pbr::pbr_deferred_types::unpack_24bit_normal
#import bevy_pbr::utils::{octahedral_decode, interleaved_gradient_noise}
#import bevy_diffuse_gi::rh_types::{PI, world_to_local, local_to_occupancy, sh_irradiance, cell_index}
#import bevy_diffuse_gi::rh_sampling::{volume, trilinear, sh_at, load_sh}
#import bevy_diffuse_gi::rh_occupancy::first_hit_inclusive
#import bevy_diffuse_gi::gi_frame::{target_pixel, world_at}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;

// 1 at full resolution, 2 at half resolution.
const GI_SCALE: i32 = #{GI_SCALE};
// Angle of the outer hemisphere samples from the normal (§5: 80°).
const CONE_COS: f32 = 0.17364818;
const CONE_SIN: f32 = 0.98480775;

fn basis(n: vec3<f32>) -> mat3x3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return mat3x3(vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x), vec3(b, s + n.y * n.y * a, -n.y), n);
}

@fragment
fn reconstruct(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(depth_texture));
    let pixel = target_pixel(vec2<i32>(floor(in.position.xy)), GI_SCALE, size);
    let depth = textureLoad(depth_texture, pixel, 0);
    if depth <= 0.0 {
        discard;
    }
    let world = world_at(view.world_from_clip, pixel, size, depth);

    let local = world_to_local(volume, world);
    // Distance in cells to each face (negative outside). A lone volume fades out over half a cell outside
    // its box; a volume inside a coarser one fades in over `blend_band` cells inside its box from the
    // faces that lie inside the coarser volume and is drawn over it (the coarser field shows through where
    // the weight is below 1): no seam at its faces.
    let res_f = vec3<f32>(volume.resolution.xyz);
    let below = (local + 0.5) * res_f;
    let above = (0.5 - local) * res_f;
    var weight = 1.0;
    for (var face = 0u; face < 6u; face++) {
        let axis = face / 2u;
        let d = select(below[axis], above[axis], face % 2u == 1u);
        let fades_in = volume.blend_band > 0.0 && ((volume.blend_faces >> face) & 1u) != 0u;
        weight = min(weight, select(saturate(1.0 + 2.0 * d), smoothstep(0.0, volume.blend_band, d), fades_in));
    }
    if weight <= 0.0 {
        discard;
    }

    let n = octahedral_decode(unpack_24bit_normal(textureLoad(gbuffer, pixel, 0).a));
#ifdef HINT_GRID
    // Debug view: the nearest hint's irradiance, no interpolation, cell borders darkened.
    if any(abs(local) > vec3(0.5)) {
        discard;
    }
    let res = volume.resolution.xyz;
    let g_pos = (local + 0.5) * vec3<f32>(res);
    let cell = min(vec3<u32>(g_pos), res - 1u);
    let edge = min(fract(g_pos), 1.0 - fract(g_pos));
    let border = select(1.0, 0.35, min(edge.x, min(edge.y, edge.z)) < 0.04);
    return vec4(sh_irradiance(load_sh(cell_index(cell, res)), n) / PI * border, 1.0);
#else
    let r = volume.cell.w;
    let origin = world + n * (0.5 * r);
    let frame = basis(n);
    let rotation = 2.0 * PI * interleaved_gradient_noise(vec2<f32>(pixel), 0u);
    let count = max(volume.reconstruction_samples, 1u);
    var irradiance = vec3(0.0);
    var used = 0.0;
    for (var i = 0u; i < count; i++) {
        var d = n;
        if i > 0u {
            let phi = rotation + 2.0 * PI * f32(i - 1u) / f32(max(count - 1u, 1u));
            d = frame * vec3(CONE_SIN * cos(phi), CONE_SIN * sin(phi), CONE_COS);
        }
        var p = origin + d * r;
        // A sample position must be reachable from the surface: a cone sample half a metre to the side
        // can otherwise land beyond a thin wall, among the next room's hints. Such a sample is pulled back
        // along its path to a voxel before the obstacle. Positions that still see no hint are skipped.
        // The origin lies half a cell off the pixel's own surface, so an occupied voxel around it is
        // another surface (the wall meeting the ceiling at a junction): the sample then stays at the
        // origin instead of marching through that wall into the next room.
        if volume.occupancy_resolution.w != 0u {
            let start = local_to_occupancy(volume, world_to_local(volume, origin));
            let end = local_to_occupancy(volume, world_to_local(volume, p));
            let t = first_hit_inclusive(start, end, volume.occupancy_resolution.xyz);
            if t >= 0.0 {
                let voxels = max(length(end - start), 1e-3);
                p = mix(origin, p, max(t - 1.0 / voxels, 0.0));
            }
        }
        let lookup = trilinear(p);
        if lookup.found {
            irradiance += sh_irradiance(sh_at(lookup), n);
            used += 1.0;
        }
    }
    if used == 0.0 {
        // Every sample fell in a wall (a pixel in a tight corner): read the field just off the surface.
        // Where every hint around it is hidden by the walls that meet there, write nothing: the
        // composite fills the pixel from its neighbours on the same surface (a hint from the other side
        // of a wall would be a bright speck).
        let near = world + n * (0.1 * r);
        let lookup = trilinear(near);
        if !lookup.found {
            discard;
        }
        irradiance = sh_irradiance(sh_at(lookup), n);
        used = 1.0;
    }
    irradiance /= used;
    let radiance_per_albedo = irradiance / PI;
    return vec4(radiance_per_albedo * weight, weight);
#endif
}
