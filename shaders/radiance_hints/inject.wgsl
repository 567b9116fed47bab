// Radiance Hints injection (Papaioannou 2011, §4): every hint samples the reflective shadow maps of all GI
// lights and projects the radiance it receives onto spherical harmonics.
//
// For RSM sample k at x_k (normal n_k, reflected flux ρΦ_T) and a receiving point y_k jittered inside the
// hint's cell, Eq. 3–4 give the radiance-times-solid-angle arriving at y_k from direction ω_k = y_k → x_k:
//
//   L̃(y_k) = ρΦ_T(x_k) · (M/N) · max(0, n_k·(−ω_k)) / (π d²)
//
// with M the texels the samples are drawn from and N the samples; Eq. 5 sums L̃ · Y_lm(ω_k). This is the
// unbiased estimator (d² is clamped at 1 cm²). Treating each sample as a disk of area A_k = A_texel·M/N
// (d² + A_k/π, or the disk's exact solid angle) tames the noise of samples next to the hint but removes
// 40–60 % of the light a hint one cell from a lit wall receives; on cornell it was less accurate than the
// noisy unbiased form, whose noise the temporal refinement averages away (docs/radiance_hints.md).
//
// The hint also records the minimum and maximum distance to the RSM samples (normalised by r_max) for the
// confidence (Eq. 9) and visibility (Eq. 11) of the paper's secondary bounces.
//
// Emissive surfaces (src/emitters.rs) are injected the same way: an emitter sample of flux Φ_k sends
// Φ_k |n_k·ω_k| / (π d²) (M/N) to the receiver from the face it sees, if that face is open (not inside
// a closed mesh), M the emitter samples and N those drawn; they take
// `emitter_fraction` of the N_s samples (their power against the GI lights').
//
// VOXEL_VISIBILITY: the paper leaves the first bounce unoccluded (§7), so light reaches hints through
// walls. Each sample's segment y_k → x_k is walked through the volume's voxelised scene and dropped when it
// crosses a surface before reaching x_k. Hints inside solid geometry (validity 0) are skipped.

#import bevy_diffuse_gi::rh_types::{
    RhVolume, FreeExtents, free_extents, Sh, FIELD_TERMS, SH_FLOATS, PI, sh_add, cell_coords, cell_center_local, local_to_world, world_to_local,
    local_to_occupancy, pcg, rand, rand3, finite3, on_turn,
}
#ifdef VOXEL_VISIBILITY
#import bevy_diffuse_gi::rh_occupancy::{first_hit, free_start, occupied}
#endif
#ifdef DEPTH_OCCLUSION
#import bevy_render::view::View
#endif

#import bevy_diffuse_gi::rsm_types::{GiLight, RsmFace, Emitter, LIGHT_KIND_DIRECTIONAL, face_uv, cube_face}

@group(0) @binding(0) var<uniform> volume: RhVolume;
@group(0) @binding(1) var<storage, read_write> out_delta: array<f32>;
@group(0) @binding(2) var<storage, read_write> out_sum: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_distances: array<vec4<f32>>;
// Per hint: albedo (rgb) and validity (a).
@group(0) @binding(4) var<storage, read> hint_albedo: array<vec4<f32>>;

@group(1) @binding(0) var rsm_position: texture_2d_array<f32>;
@group(1) @binding(1) var rsm_normal: texture_2d_array<f32>;
@group(1) @binding(2) var rsm_flux: texture_2d_array<f32>;
@group(1) @binding(3) var<storage, read> lights: array<GiLight>;
@group(1) @binding(4) var<storage, read> emitters: array<Emitter>;
@group(1) @binding(5) var<storage, read> faces: array<RsmFace>;

#ifdef DEPTH_OCCLUSION
@group(3) @binding(0) var<uniform> view: View;
@group(3) @binding(1) var depth_texture: texture_depth_2d;

// §8: the fraction of a sample's light left after testing points along x → y against the camera's depth
// buffer; each point found behind the visible surface removes `strength` of what remains.
fn depth_attenuation(x: vec3<f32>, y: vec3<f32>) -> f32 {
    let steps = volume.depth_occlusion_samples;
    let size = vec2<f32>(textureDimensions(depth_texture));
    var hidden = 0.0;
    for (var i = 1u; i <= steps; i++) {
        let p = mix(x, y, f32(i) / f32(steps + 1u));
        let clip = view.clip_from_world * vec4(p, 1.0);
        if clip.w <= 1e-6 {
            continue;
        }
        let ndc = clip.xyz / clip.w;
        if any(abs(ndc.xy) > vec2(1.0)) {
            continue;
        }
        let pixel = vec2<i32>(clamp((vec2(ndc.x, -ndc.y) * 0.5 + 0.5) * size, vec2(0.0), size - 1.0));
        // Reverse Z: larger is nearer. The point is hidden when the visible surface is nearer.
        if ndc.z < textureLoad(depth_texture, pixel, 0) - 1e-7 {
            hidden += 1.0;
        }
    }
    return pow(1.0 - volume.depth_occlusion_strength, hidden);
}
#endif

// A uniform point on the unit disk (concentric mapping).
fn disk(u: vec2<f32>) -> vec2<f32> {
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    return r * vec2(cos(phi), sin(phi));
}

// A receiving point jittered inside the hint's cell (§4), or none (w = 0) when it lies across a wall
// from the hint: the hint stands for the free part of its cell, so such receivers are left out of the
// average.
//
// Hint centres lie on voxel corners, and the receivers of the default jitter fall in the eight voxels
// around it. Where a floor or wall passes next to the hint, some of those voxels hold its surface and are
// occupied though most of them may be free space on the hint's side. Leaving out every receiver in an
// occupied voxel kept only those away from the surface (a hint 0.2 m above `open_field`'s ground then read
// 1.7× the truth's light from below), so a receiver in an occupied voxel is kept when the path to it from
// the hint's free start (`free_start`) crosses no other occupied voxel and the voxel beyond it, away
// from the hint, is occupied too: it lies on the hint's side of a solid at least two voxels thick, or just
// inside it, where it reads the surface's light. A surface one voxel thick (a thin wall between rooms)
// has free space beyond: there the receiver might be in the next room, and it is left out.
//
// The jitter stays within the hint's free extents (`free_extents`, traced on the CPU against the real
// surfaces): a hint 4 cm from a wall otherwise put a quarter of its receivers behind the wall's face,
// inside the wall's voxel layer, where the wall's light cannot reach them (hints next to walls held 0.67
// of their traced first-bounce light in a generated room, docs/unseen_rooms.md).
fn receiver(cell: vec3<f32>, free: FreeExtents, rng: ptr<function, u32>) -> vec4<f32> {
    let res = volume.resolution.xyz;
    let half = 0.5 * volume.jitter;
    let lo = -min(vec3(half), 0.5 * free.negative);
    let hi = min(vec3(half), 0.5 * free.positive);
    let jitter = mix(lo, hi, rand3(rng));
    let y_local = cell_center_local(cell + jitter, res);
#ifdef VOXEL_VISIBILITY
    if any(jitter != vec3(0.0)) {
        let occ_res = volume.occupancy_resolution.xyz;
        let a = free_start(local_to_occupancy(volume, cell_center_local(cell, res)), occ_res);
        let b = local_to_occupancy(volume, y_local);
        let t = first_hit(a, b, occ_res, 0.0);
        let own = vec3<i32>(floor(b));
        if occupied(own, occ_res) {
            let away = b - a;
            let axis = select(select(2u, 1u, abs(away.y) >= abs(away.z)), 0u, abs(away.x) >= max(abs(away.y), abs(away.z)));
            var beyond = own;
            beyond[axis] += select(-1, 1, away[axis] >= 0.0);
            let entered = vec3<i32>(floor(mix(a, b, min(t + 1e-3, 1.0))));
            if !occupied(beyond, occ_res) || (t >= 0.0 && any(entered != own)) {
                return vec4(0.0);
            }
        } else if t >= 0.0 {
            return vec4(0.0);
        }
    }
#endif
    return vec4(local_to_world(volume, y_local), 1.0);
}

// Whether the path from receiver y to the surface point x (normal n, facing y) is free. The test starts
// from x lifted off its surface along n: a path skimming the surface it leaves must not count its own
// voxels as occluders (that falsely removes grazing light and leaves only steep directions, whose SH
// ringing darkens surfaces facing the other way). A receiver closer than the lift to x's tangent plane
// (one jittered into the voxels of the wall it faces) is raised to the same height first, where the step
// up is free: otherwise its paths to the rest of that wall run through the wall's own voxels, and a hint
// a few centimetres from a lit wall lost half its light (`cellar`; the receivers in the wall's voxel
// layer kept under a tenth of theirs).
fn path_free(y: vec3<f32>, x: vec3<f32>, n: vec3<f32>, lift: f32) -> bool {
#ifdef VOXEL_VISIBILITY
    let res = volume.occupancy_resolution.xyz;
    var a = local_to_occupancy(volume, world_to_local(volume, y));
    let height = dot(y - x, n);
    if height > 0.0 && height < lift {
        let raised = local_to_occupancy(volume, world_to_local(volume, y + n * (lift - height)));
        if first_hit(a, raised, res, 0.0) < 0.0 {
            a = raised;
        }
    }
    let b = local_to_occupancy(volume, world_to_local(volume, x + n * lift));
    return first_hit(a, b, res, 0.5) < 0.0;
#else
    return true;
#endif
}

// Adds one source's projection to the hint's, rescaled from the receivers that lay in free space to all
// the samples drawn: the hint stands for the free part of its cell.
fn add_rescaled(sum: ptr<function, Sh>, part: Sh, samples: f32, receivers: f32) {
    if receivers > 0.0 {
        for (var i = 0u; i < FIELD_TERMS; i++) {
            (*sum).c[i] += part.c[i] * (samples / receivers);
        }
    }
}


// The near windows: squares of texels around the hint's projection into the RSM face it falls in, which
// see the surfaces right behind the hint along the light's rays.
//
// A hint close to a lit surface (a few centimetres in front of a spot-lit wall, a little above a sunlit
// floor) receives most of its light from the few texels right behind it, at 1/d². Drawn uniformly from a
// map of 65 536 texels they are hit once in hundreds of updates: the refinement's average then stays far
// below the mean (a hint 5 cm from `cellar`'s lit wall read a tenth of its path-traced irradiance) and, when
// they are hit, a hint flashes. So a third of the samples is drawn from a wide window, half-side NEAR_WINDOW
// cell diagonals in world units at the hint (the light of the surfaces around the cell), a third from a
// narrow one, half-side NARROW_WINDOW times the hint's distance to the surface behind it (the 1/d² peak
// itself: most of a plane's light at distance h arrives from within a few h), and a third from the whole
// map; each sample is weighted by its probability under all three (one-sample MIS, balance heuristic), so
// the estimate stays unbiased.
const NEAR_WINDOW: f32 = 1.0;
const NARROW_WINDOW: f32 = 3.0;

struct Window {
    face: u32,
    center: vec2<i32>,
    // Half-sides in texels of the wide and the narrow window (0: none).
    wide: i32,
    narrow: i32,
    narrow_center: vec2<i32>,
}

// Texels in a window of half-side `half` (0 for none).
fn window_texels(half: i32) -> f32 {
    let side = f32(2 * half + 1);
    return select(0.0, side * side, half > 0);
}

// A window of half-side `half` around `texel`, kept on a face of `res` texels: its centre.
fn window_center(texel: vec2<i32>, half: i32, res: i32) -> vec2<i32> {
    return clamp(texel, vec2(half), vec2(res - 1 - half));
}

fn near_windows(light: GiLight, center: vec3<f32>, res: f32, use_disk: bool) -> Window {
    var w: Window;
    if use_disk {
        return w;
    }
    if light.faces == 6u {
        w.face = cube_face(center - faces[light.first_layer].light_position.xyz);
    }
    let face = faces[light.first_layer + w.face];
    let uv = face_uv(face, center);
    if uv.z <= 0.0 || any(uv.xy < vec2(0.0)) || any(uv.xy >= vec2(1.0)) {
        return w;
    }
    // Texels per metre at the hint: the largest displacement of the projection when the hint moves along
    // a world axis (at least two axes are not along the light's rays).
    var per_metre = 0.0;
    for (var axis = 0u; axis < 3u; axis++) {
        var offset = vec3(0.0);
        offset[axis] = 0.01;
        per_metre = max(per_metre, length(face_uv(face, center + offset).xy - uv.xy) * res * 100.0);
    }
    let limit = max(i32(res) / 2 - 1, 1);
    let texel = vec2<i32>(uv.xy * res);
    w.wide = clamp(i32(ceil(NEAR_WINDOW * volume.cell.w * per_metre)), 1, limit);
    w.center = window_center(texel, w.wide, i32(res));
    // The surface right behind the hint along the light's ray, when it lies beyond the hint.
    let foot = textureLoad(rsm_position, texel, i32(light.first_layer + w.face), 0);
    var beyond: bool;
    if light.kind == LIGHT_KIND_DIRECTIONAL {
        beyond = dot(foot.xyz - center, face.axis.xyz) > 0.0;
    } else {
        beyond = distance(foot.xyz, face.light_position.xyz) > distance(center, face.light_position.xyz);
    }
    if foot.w > 0.0 && beyond {
        let h = distance(foot.xyz, center);
        w.narrow = clamp(i32(ceil(NARROW_WINDOW * h * per_metre)), 1, w.wide);
        w.narrow_center = window_center(texel, w.narrow, i32(res));
    }
    return w;
}

fn in_window(texel: vec2<i32>, center: vec2<i32>, half: i32) -> bool {
    return half > 0 && all(abs(texel - center) <= vec2(half));
}

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn inject(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    // While things move in a volume of more hints than `motion_hints_per_update`, one workgroup in
    // `inject_period` injects this update; the others keep their displayed field until their turn (the
    // blend skips them) and the injection of their last turn in `out_delta`. Whole workgroups, so that
    // the skipped ones cost nothing.
    if !on_turn(volume, wid.x, volume.inject_period) {
        return;
    }
    let res = volume.resolution.xyz;
    let cell = vec3<f32>(cell_coords(index, res));
    let center = local_to_world(volume, cell_center_local(cell, res));
    var rng = pcg(index ^ pcg(volume.seed));

    var sh: Sh;
    var d_min = 3.0e38;
    var d_max = 0.0;
    var valid = 0.0;
    let inside_solid = hint_albedo[index].a < 0.5;
    let free = free_extents(hint_albedo[index].a);
    // How far an RSM sample is lifted off its surface before its path is tested: 1.5 occupancy voxels.
    let lift = 1.5 * max(volume.cell.x, max(volume.cell.y, volume.cell.z)) / f32(volume.occupancy_resolution.x / volume.resolution.x);
    for (var l = 0u; l < select(volume.light_count, 0u, inside_solid); l++) {
        let light = lights[l];
        if light.sample_fraction <= 0.0 {
            continue;
        }
        let share = light.sample_fraction * (1.0 - volume.emitter_fraction);
        let samples = u32(max(round(f32(volume.rsm_samples) * share), 1.0));
        let res_l = f32(light.resolution);
        // c_RSM: directional lights may sample a disk around the hint's projection (§4).
        let use_disk = light.kind == LIGHT_KIND_DIRECTIONAL && volume.coverage < 0.75;
        var disk_center = vec2(0.5);
        let radius = sqrt(volume.coverage / PI);
        var texels = f32(light.faces) * res_l * res_l;
        if use_disk {
            let clip = light.clip_from_world * vec4(center, 1.0);
            let ndc = clip.xy / max(clip.w, 1e-6);
            disk_center = clamp(vec2(ndc.x, -ndc.y) * 0.5 + 0.5, vec2(radius), vec2(1.0 - radius));
            texels = volume.coverage * res_l * res_l;
        }
        // The near windows (see NEAR_WINDOW): none where the hint projects off every face.
        let window = near_windows(light, center, res_l, use_disk);
        let strategies = 1.0 + select(0.0, 1.0, window.wide > 0) + select(0.0, 1.0, window.narrow > 0);
        // This light's contribution, rescaled below by the receivers that lay in free space.
        var light_sh: Sh;
        var receivers = 0.0;
        for (var s = 0u; s < samples; s++) {
            let receiving = receiver(cell, free, &rng);
            if receiving.w == 0.0 {
                continue;
            }
            let y = receiving.xyz;
            receivers += 1.0;
            var face = 0u;
            var texel: vec2<i32>;
            let strategy = u32(rand(&rng) * strategies);
            if strategy > 0u {
                let half = select(window.wide, window.narrow, strategy == 2u);
                let side = 2 * half + 1;
                let pick = min(vec2<i32>(vec2(rand(&rng), rand(&rng)) * f32(side)), vec2(side - 1));
                texel = select(window.center, window.narrow_center, strategy == 2u) + pick - half;
                face = window.face;
            } else {
                var uv: vec2<f32>;
                if use_disk {
                    uv = disk_center + radius * disk(vec2(rand(&rng), rand(&rng)));
                } else {
                    face = min(u32(rand(&rng) * f32(light.faces)), light.faces - 1u);
                    uv = vec2(rand(&rng), rand(&rng));
                }
                texel = vec2<i32>(clamp(uv * res_l, vec2(0.0), vec2(res_l - 1.0)));
            }
            // The texel's probability under the mixture of the strategies: the estimate stays unbiased
            // whichever drew it.
            var probability = 1.0 / texels;
            if face == window.face {
                if in_window(texel, window.center, window.wide) {
                    probability += 1.0 / window_texels(window.wide);
                }
                if in_window(texel, window.narrow_center, window.narrow) {
                    probability += 1.0 / window_texels(window.narrow);
                }
            }
            let weight = 1.0 / (f32(samples) * probability / strategies);
            let layer = i32(light.first_layer + face);
            let p = textureLoad(rsm_position, texel, layer, 0);
            if p.w <= 0.0 {
                continue;
            }
            let to_x = p.xyz - y;
            let d2 = dot(to_x, to_x);
            let d = sqrt(d2);
            d_min = min(d_min, d);
            d_max = max(d_max, d);
            valid += 1.0;
            let w = to_x / max(d, 1e-6);
            let n = textureLoad(rsm_normal, texel, layer, 0).xyz;
            let cos_x = dot(n, -w);
            if cos_x <= 0.0 {
                continue;
            }
            if !path_free(y, p.xyz, n, lift) {
                continue;
            }
            let flux = textureLoad(rsm_flux, texel, layer, 0).rgb * light.flux_scale;
            var contribution = flux * (weight * cos_x / (PI * max(d2, 1e-4)));
#ifdef DEPTH_OCCLUSION
            contribution *= depth_attenuation(p.xyz, y);
#endif
            sh_add(&light_sh, w, contribution);
        }
        add_rescaled(&sh, light_sh, f32(samples), receivers);
    }

    // The emissive surfaces, sampled like one more light.
    let emitter_samples = select(0u, u32(max(round(f32(volume.rsm_samples) * volume.emitter_fraction), 1.0)),
        volume.emitter_count > 0u && !inside_solid);
    var emitter_sh: Sh;
    var emitter_receivers = 0.0;
    for (var s = 0u; s < emitter_samples; s++) {
        let receiving = receiver(cell, free, &rng);
        if receiving.w == 0.0 {
            continue;
        }
        let y = receiving.xyz;
        emitter_receivers += 1.0;
        let e = emitters[min(u32(rand(&rng) * f32(volume.emitter_count)), volume.emitter_count - 1u)];
        let to_x = e.position.xyz - y;
        let d2 = dot(to_x, to_x);
        let d = sqrt(d2);
        d_min = min(d_min, d);
        d_max = max(d_max, d);
        valid += 1.0;
        let w = to_x / max(d, 1e-6);
        // The face that looks at the receiver emits, if it is open (w = 2: both faces are; w = 1: only
        // the one the normal points to, the other lies inside its closed mesh).
        let facing = dot(e.normal.xyz, -w);
        let emitting = select(facing, abs(facing), e.normal.w > 1.5);
        let n = e.normal.xyz * sign(facing);
        if emitting <= 0.0 || !path_free(y, e.position.xyz, n, lift) {
            continue;
        }
        let weight = f32(volume.emitter_count) / f32(emitter_samples);
        var contribution = e.flux.rgb * (weight * emitting / (PI * max(d2, 1e-4)));
#ifdef DEPTH_OCCLUSION
        contribution *= depth_attenuation(e.position.xyz, y);
#endif
        sh_add(&emitter_sh, w, contribution);
    }
    add_rescaled(&sh, emitter_sh, f32(emitter_samples), emitter_receivers);

    let base = index * SH_FLOATS;
    for (var i = 0u; i < FIELD_TERMS; i++) {
        let c = finite3(sh.c[i] * volume.intensity);
        out_delta[base + 3u * i] = c.x;
        out_delta[base + 3u * i + 1u] = c.y;
        out_delta[base + 3u * i + 2u] = c.z;
        out_sum[base + 3u * i] = c.x;
        out_sum[base + 3u * i + 1u] = c.y;
        out_sum[base + 3u * i + 2u] = c.z;
    }
    let r = max(volume.r_max, 1e-6);
    if valid > 0.0 {
        out_distances[index] = vec4(min(d_min / r, 1.0), d_max / r, valid, 0.0);
    } else {
        // No geometry seen: far from everything, zero confidence.
        out_distances[index] = vec4(1.0, 1.0, 0.0, 0.0);
    }
}
