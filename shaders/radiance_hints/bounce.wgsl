// One extra diffuse bounce between hints (Papaioannou 2011, §6–7).
//
// Hint n gathers from N_b points p_j drawn uniformly in the ball of radius r_max around it. Each point's
// radiance field (trilinear between hints) is turned into the radiance a diffuse surface there would send
// back towards n (Eq. 10): L_o = ρ_j/π · E_j(n = −ω_j), with ρ_j from the albedo volume (or white, as in the
// paper). Points are weighted by the distance-based visibility V of Eq. 11 and the confidence
// c_j = 1 − r_min,j of Eq. 9 that a surface is near p_j, and projected onto SH along ω_j = n → j.
//
// Eq. 8 as printed divides by the visibility sum *and* by the confidence sum, which shrinks the bounce as
// 1/N_b. SECONDARY_PAPER reads it as the weighted Monte Carlo estimator the text describes ("standard Monte
// Carlo with rejection sampling"):
//     ΔL(n, lm) = 4π · Σ_j w_j L_o,j Y_lm(ω_j) / Σ_j w_j,     w_j = V_j c_j
// (Counting rejected points as black instead, 4π/N_b · Σ_j w_j L_o,j Y_lm(ω_j), delivered too little on
// cornell: +0.07 of the indirect energy for the first extra bounce where the truth adds +0.21.)
// Each bounce gathers from the previous bounce's increment, not from the running sum: gathering from the
// sum would send the first bounce's light around again at every step.
//
// Without SECONDARY_PAPER (the default, SecondaryTransport::VoxelMarch), the paper's ball sampling is
// replaced by Monte Carlo over directions: N_b stratified directions ω_j are marched through the volume's
// voxelised scene to the first surface, and the previous bounce's field just in front of it gives the light
// that surface reflects back (Eq. 10 at the true reflector):
//     ΔL(n, lm) = 4π/N_b · Σ_j ρ(x_j)/π · E(x_j − ω_j·δ, −ω_j) · Y_lm(ω_j)
// Directions that leave the volume without meeting a surface contribute nothing.

#import bevy_diffuse_gi::rh_types::{
    Sh, FIELD_TERMS, SH_FLOATS, PI, sh_add, sh_irradiance, cell_coords, cell_center_local, local_to_world, pcg,
    rand, rand3, uniform_sphere, finite3, on_turn,
}
#import bevy_diffuse_gi::rh_sampling::{volume, distances, albedo, trilinear, trilinear_from, sh_at, distances_at, albedo_at, inside_volume}
#import bevy_diffuse_gi::rh_types::{world_to_local, local_to_occupancy}
#ifndef SECONDARY_PAPER
#import bevy_diffuse_gi::rh_occupancy::{first_hit_face, free_start}
#import bevy_diffuse_gi::rh_masks::hint_lookup
#endif

@group(0) @binding(0) var<storage, read_write> out_delta: array<f32>;
@group(0) @binding(1) var<storage, read_write> out_sum: array<f32>;
// Per workgroup: (luminance of this bounce's DC terms, luminance of the running sum's DC terms).
@group(0) @binding(2) var<storage, read_write> partials: array<vec2<f32>>;

var<workgroup> shared_energy: array<vec2<f32>, #{WORKGROUP_SIZE}>;

fn luminance(c: vec3<f32>) -> f32 {
    return dot(c, vec3(0.2126, 0.7152, 0.0722));
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn bounce(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let index = gid.x;
    var energy = vec2(0.0);
    if index < volume.resolution.w {
        let res = volume.resolution.xyz;
        let cell = vec3<f32>(cell_coords(index, res));
        let p_n = local_to_world(volume, cell_center_local(cell, res));
        let dist_n = distances[index];
        var rng = pcg(index ^ pcg(volume.seed));
        var acc: Sh;
        var weight_sum = 0.0;
        var scale = 0.0;
        // While things move, one workgroup in `motion_period` recomputes its bounce this update; the
        // others add the one they kept in `out_delta` (`RadianceHintsVolume::motion_bounce_period`).
        // Whole workgroups, so that the skipped ones cost nothing.
        let refresh = on_turn(volume, wid.x, volume.motion_period);
        if refresh {
#ifndef SECONDARY_PAPER
            // Directions through the whole volume: its diagonal in world units.
            let reach = length((volume.world_from_local * vec4(1.0, 1.0, 1.0, 0.0)).xyz);
            // The rays start off the voxels of the surfaces the hint sits beside (see `free_start`).
            let occ_res = volume.occupancy_resolution.xyz;
            let a = free_start(local_to_occupancy(volume, world_to_local(volume, p_n)), occ_res);
            let start = local_to_world(volume, a / vec3<f32>(occ_res) - 0.5);
            let n_samples = volume.secondary_samples;
            // Stratified over the sphere: a √N × √N grid of (cos θ, φ) cells, jittered.
            let side = max(u32(sqrt(f32(n_samples))), 1u);
            let inside_solid = albedo[index].a < 0.5;
            for (var j = 0u; j < select(n_samples, 0u, inside_solid); j++) {
                let cell_uv = vec2(f32(j % side), f32((j / side) % side));
                let u = select((cell_uv + vec2(rand(&rng), rand(&rng))) / f32(side), vec2(rand(&rng), rand(&rng)), j >= side * side);
                let omega = uniform_sphere(u);
                let b = local_to_occupancy(volume, world_to_local(volume, start + omega * reach));
                let found = first_hit_face(a, b, occ_res, 0.0, 0.0);
                let t = found.w;
                if t < 0.0 {
                    continue;
                }
                // The reflector's normal: the face of the voxel the ray entered (exact for axis-aligned
                // surfaces), in world space, facing the hint.
                let face_normal = normalize((volume.world_from_local * vec4(found.xyz, 0.0)).xyz);
                let hit = start + omega * (reach * t);
                // The reflector's light: the field half a cell in front of it along its normal, where a surface
                // facing that way would be lit as the reflector is. (Half a cell diagonal back along the ray,
                // as this read before, lies behind the hint when the hint is closer to the wall than that,
                // and often under the floor for a hint just above it: a hint 0.2 m above `open_field`'s
                // ground, 0.5 m from a wall, got a twentieth of the light that wall sends down.) Where that
                // point sees no hint (a corner), the point halfway back to the hint along the ray.
                let cell_along = dot(abs(found.xyz), volume.cell.xyz);
                // The prepared mask of the point's voxel (`rh_masks::hint_lookup`) stands for the eight
                // visibility marches of `trilinear_from(front, 0.0)`: the same test from the voxel's centre,
                // surfaces within a voxel length of it not counted. (A march that skipped those let the next
                // room's hints in where a grazing hit by a junction puts the point beside a wall: specks on
                // `cellar` at the high preset. The mask shows none there: no 4×4 block moved by more than
                // 6 %.) On `cornell` with a moving light the marches of this lookup and the albedo's below
                // were a third of the frame; the images moved by < 0.005 block RMSE (`cellar` high 0.1315 →
                // 0.135), the generated rooms by ±0.005.
                let front = hit + face_normal * (0.5 * cell_along);
                var lookup = hint_lookup(world_to_local(volume, front));
                if !lookup.found {
                    lookup = trilinear_from(mix(hit, p_n, 0.5), 0.0);
                }
                var rho = vec3(1.0);
                if volume.albedo_volume != 0u {
                    // The albedo of the cells around the reflector, those behind a surface as seen from it
                    // left out (the next room's wall colour beyond a thin wall). Where every one is (a hit
                    // in a corner, on a voxel face whose own cells lie behind the wall), the cells' albedo
                    // regardless of visibility: this lookup used to find nothing there and reflect nothing,
                    // which lost a tenth of every bounce's light in a generated room (room_3's field 0.89 →
                    // 1.00 of the traced one).
                    // The hit voxel's prepared mask for `trilinear(hit)`'s marches (the same skip of a voxel).
                    let at_hit = hint_lookup(world_to_local(volume, hit + omega * (0.01 * cell_along)));
                    rho = select(albedo_at(trilinear_from(hit, 1.0e9)), albedo_at(at_hit), at_hit.found);
                }
                let radiance = rho / PI * sh_irradiance(sh_at(lookup), face_normal);
                sh_add(&acc, omega, radiance);
            }
            scale = 4.0 * PI / f32(max(n_samples, 1u));
#else
            for (var j = 0u; j < volume.secondary_samples; j++) {
                let offset = uniform_sphere(vec2(rand(&rng), rand(&rng))) * (volume.r_max * pow(rand(&rng), 1.0 / 3.0));
                let p_j = p_n + offset;
                if !inside_volume(p_j) {
                    continue;
                }
                let lookup = trilinear(p_j);
                let dist_j = distances_at(lookup);
                // Eq. 11, distances normalised by r_max.
                let d = length(offset) / volume.r_max;
                let near = dist_n.x + dist_j.x;
                let far = dist_n.y + dist_j.y;
                let visibility = 1.0 - clamp((d - near) / max(far - near, 1e-4), 0.0, 1.0);
                // Eq. 9 (before normalisation).
                let confidence = max(1.0 - dist_j.x, 0.0);
                let w = visibility * confidence;
                if w <= 0.0 {
                    continue;
                }
                let omega = offset / max(length(offset), 1e-6);
                var rho = vec3(1.0);
                if volume.albedo_volume != 0u {
                    rho = albedo_at(lookup);
                }
                // Eq. 10: radiance leaving p_j towards p_n.
                let radiance = rho / PI * sh_irradiance(sh_at(lookup), -omega);
                sh_add(&acc, omega, w * radiance);
                weight_sum += w;
            }
            scale = select(0.0, 4.0 * PI / weight_sum, weight_sum > 0.0);
#endif
        }
        let base = index * SH_FLOATS;
        for (var i = 0u; i < FIELD_TERMS; i++) {
            let b = base + 3u * i;
            let c = select(vec3(out_delta[b], out_delta[b + 1u], out_delta[b + 2u]), finite3(acc.c[i] * scale), refresh);
            out_delta[b] = c.x;
            out_delta[b + 1u] = c.y;
            out_delta[b + 2u] = c.z;
            let s = vec3(out_sum[b], out_sum[b + 1u], out_sum[b + 2u]) + c;
            out_sum[b] = s.x;
            out_sum[b + 1u] = s.y;
            out_sum[b + 2u] = s.z;
            if i == 0u {
                energy = vec2(luminance(abs(c)), luminance(abs(s)));
            }
        }
    }
    // Workgroup sum of the DC energies, for the early stop.
    shared_energy[lid] = energy;
    workgroupBarrier();
    for (var stride = #{WORKGROUP_SIZE}u / 2u; stride > 0u; stride >>= 1u) {
        if lid < stride {
            shared_energy[lid] += shared_energy[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        partials[wid.x] = shared_energy[0];
    }
}
