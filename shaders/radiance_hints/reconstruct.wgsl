// Reconstruction of indirect light per pixel (Papaioannou 2011, §5, Eq. 6–7), one draw per volume into the
// camera's GI target with additive blending.
//
// For a visible point p with normal n, N_RH positions are laid around p + n·r/2 — the first there, the rest
// on a cone 80° from the normal at distance r, rotated per pixel — so that no hint behind the surface is
// read; r is the cell diagonal times `reconstruction_reach`. At each, the radiance field is interpolated
// trilinearly and integrated against the clamped cosine around n (Eq. 7); Eq. 6 averages them:
//     L_r(p) = ρ(p)/(π N_RH) Σ_n E_n(n)
// Two departures from §5, measured on six scenes (docs/radiance_hints.md, § reconstruction): the paper's
// r is a whole cell diagonal and its first sample lies on the normal r beyond p + n·r/2. Both read the
// light up to one and a half diagonals in front of the surface, which is not the light the surface gets
// near a bright wall (closer to it) or in a concave corner (where it sees the next room through a door:
// `cellar`'s corner beside its door read 3.2× the truth). Half a diagonal and the first sample at the
// centre read what the surface sees, and the exact vertical irradiance of floors needs that.
// This pass writes E/π (the composite multiplies by ρ and the exposure), times a weight that is 1 inside the
// volume's box and fades to zero over half a cell outside it (surfaces often lie exactly on the box, a volume
// fitted to a room), and the weight itself in alpha, so overlapping volumes average. A volume nested inside
// a coarser one instead fades in over `blend_band` cells inside its box and is drawn over the coarser one
// (premultiplied alpha blending), so the finer field takes over without a seam.

#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#import bevy_render::view::View
#import bevy_pbr::pbr_deferred_types::{unpack_24bit_normal, unpack_unorm4x8_}
#import bevy_pbr::utils::{octahedral_decode, interleaved_gradient_noise}
#import bevy_diffuse_gi::rh_types::{PI, world_to_local, local_to_occupancy, sh_irradiance, cell_index}
#import bevy_diffuse_gi::rh_sampling::{Trilinear, volume, trilinear_masked, occupancy_voxel, sh_at, load_sh}
#import bevy_diffuse_gi::rh_occupancy::{first_hit_inclusive, first_hit_from}
#import bevy_diffuse_gi::rh_masks::hint_lookup
#import bevy_diffuse_gi::rh_packed::{Packed, PackedField, add_packed, add_packed_field, field_linear, field_nonlinear, sh_linear, sh_nonlinear}
#import bevy_diffuse_gi::gi_frame::{target_pixel, world_at}

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;
// Each hint's field in the compact irradiance form (rh_packed.wgsl), for SH order 2.
@group(2) @binding(2) var<storage, read> packed: array<Packed>;

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

// Rays of the near-field occlusion per pixel.
const NEAR_FIELD_RAYS: u32 = 4u;

// The share of the indirect light a pixel keeps after the occlusion below the hints' scale: the fraction
// of NEAR_FIELD_RAYS cosine-distributed rays that leave `near_field_range` metres without entering an
// occupied voxel (surfaces within a voxel of the start, the pixel's own, do not count), turned into the
// visibility of a surface that also receives what the occluders reflect (Jimenez et al. 2016, Eq. 10,
// with the pixel's albedo standing for its surroundings'), per channel.
fn near_field_visibility(world: vec3<f32>, n: vec3<f32>, frame: mat3x3<f32>, rotation: f32, albedo: vec3<f32>) -> vec3<f32> {
    let occ = vec3<f32>(volume.occupancy_resolution.xyz);
    // Rays start 1.5 voxels off the surface along its normal, out of the voxels of the pixel's own
    // surface (which grazing rays would otherwise walk through).
    let edges = volume.cell.xyz * vec3<f32>(volume.resolution.xyz) / occ;
    let voxel = max(edges.x, max(edges.y, edges.z));
    let start = local_to_occupancy(volume, world_to_local(volume, world + n * (1.5 * voxel)));
    var open = 0.0;
    for (var k = 0u; k < NEAR_FIELD_RAYS; k++) {
        // Stratified in the cosine-weighted hemisphere, rotated per pixel.
        let u = (f32(k) + 0.5) / f32(NEAR_FIELD_RAYS);
        let phi = rotation + 2.0 * PI * fract(f32(k) * 0.618034);
        let s = sqrt(u);
        let d = frame * vec3(s * cos(phi), s * sin(phi), sqrt(1.0 - u));
        let step = (volume.local_from_world * vec4(d * volume.near_field_range, 0.0)).xyz * occ;
        if first_hit_inclusive(start, start + step, volume.occupancy_resolution.xyz) < 0.0 {
            open += 1.0;
        }
    }
    let v = open / f32(NEAR_FIELD_RAYS);
    let a = 2.0404 * albedo - 0.3324;
    let b = -4.7951 * albedo + 0.6417;
    let c = 2.7552 * albedo + 0.6903;
    return max(vec3(v), ((v * a + b) * v + c) * v);
}

// Eq. 7 at one hemisphere sample: the irradiance on a surface with normal n of the interpolated field.
// SH order 2 reads the packed irradiance form (`rh_packed.wgsl`) and turns it into irradiance linearly,
// clamped at zero, or with Hazel's non-linear reconstruction, which cannot ring below zero; a surface
// that is not vertical also reads the exact irradiance facing up or down (`rh_types::with_vertical`).
// Order 3 reads the SH radiance.
fn sample_irradiance(t: Trilinear, n: vec3<f32>) -> vec3<f32> {
#if SH_COEFS == 4
    // Walls (n_y = 0, most of a level's pixels) need neither the vertical word nor a second evaluation.
    let vertical = n.y * n.y > 1e-4;
    var field: PackedField;
    for (var k = 0u; k < 8u; k++) {
        if t.weights[k] > 0.0 {
            let c = t.cells[k];
            if vertical {
                add_packed_field(&field, packed[c], t.weights[k]);
            } else {
                add_packed(&field, packed[c].sh, t.weights[k]);
            }
        }
    }
#ifdef NONLINEAR_IRRADIANCE
    if !vertical {
        return sh_nonlinear(field, n);
    }
    return field_nonlinear(field, n);
#else
    if !vertical {
        return sh_linear(field, n);
    }
    return field_linear(field, n);
#endif
#else
    return sh_irradiance(sh_at(t), n);
#endif
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
    let r = volume.cell.w * volume.reconstruction_reach;
    // Positions in the volume's local frame from here on (one transform per pixel, not per sample).
    let origin = world_to_local(volume, world + n * (0.5 * r));
    let start = local_to_occupancy(volume, origin);
    let frame = basis(n);
    let rotation = 2.0 * PI * interleaved_gradient_noise(vec2<f32>(pixel), 0u);
    let count = max(volume.reconstruction_samples, 1u);
    var irradiance = vec3(0.0);
    var used = 0.0;
    // The cone samples' azimuths: the first at `rotation`, the rest a fixed step further each (one sine
    // and cosine per pixel, each next one by rotating the last).
    let step = 2.0 * PI / f32(max(count - 1u, 1u));
    let turn = vec2(cos(step), sin(step));
    var azimuth = vec2(cos(rotation), sin(rotation));
    for (var i = 0u; i < count; i++) {
        var d = n;
        if i > 0u {
            d = frame * vec3(CONE_SIN * azimuth, CONE_COS);
            azimuth = vec2(azimuth.x * turn.x - azimuth.y * turn.y, azimuth.x * turn.y + azimuth.y * turn.x);
        }
        // The first sample at the hemisphere's centre, the others r from it.
        var p = origin + (volume.local_from_world * vec4(d * select(r, 0.0, i == 0u), 0.0)).xyz;
        // A sample position must be reachable from the surface: a cone sample half a metre to the side
        // can otherwise land beyond a thin wall, among the next room's hints. Such a sample is pulled back
        // along its path to a voxel before the obstacle. Positions that still see no hint are skipped.
        // The origin lies half a cell off the pixel's own surface, so an occupied voxel around it is
        // another surface (the wall meeting the ceiling at a junction): the sample then stays at the
        // origin instead of marching through that wall into the next room.
        if volume.occupancy_resolution.w != 0u {
            let end = local_to_occupancy(volume, p);
            let t = first_hit_inclusive(start, end, volume.occupancy_resolution.xyz);
            if t >= 0.0 {
                let voxels = max(length(end - start), 1e-3);
                p = mix(origin, p, max(t - 1.0 / voxels, 0.0));
            }
        }
        let lookup = hint_lookup(p);
        if lookup.found {
            irradiance += sample_irradiance(lookup, n);
            used += 1.0;
        }
    }
    if used == 0.0 {
        // Every sample fell in a wall (a pixel in a tight corner): read the field just off the surface.
        // Where every hint around it is hidden by the walls that meet there, write nothing: the
        // composite fills the pixel from its neighbours on the same surface (a hint from the other side
        // of a wall would be a bright speck).
        let lookup = hint_lookup(world_to_local(volume, world + n * (0.1 * r)));
        if !lookup.found {
            discard;
        }
        irradiance = sample_irradiance(lookup, n);
        used = 1.0;
    }
    if volume.near_field_range > 0.0 {
        let g = textureLoad(gbuffer, pixel, 0);
        let albedo = pow(unpack_unorm4x8_(g.r).rgb, vec3(2.2)) * (1.0 - unpack_unorm4x8_(g.b).g);
        irradiance *= near_field_visibility(world, n, frame, rotation, albedo);
    }
    let radiance_per_albedo = irradiance / (PI * used);
    return vec4(radiance_per_albedo * weight, weight);
#endif
}
