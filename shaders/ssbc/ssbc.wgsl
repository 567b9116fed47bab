// Screen-space bias compensation (Novák, Engelhardt, Dachsbacher 2011, §3.2–4.3).
//
// Eq. 3: L = L_e + Σ_i T_rⁱ (T L_e + T_b L̂). The clamped solution (direct light from Bevy's main pass plus
// the clamped VPL gather in the frame's target) is the first term; each step applies the residual operator
//     (T_r L)(y) ≈ Σ_i f_r G_r(y, z_i) L(y ← z_i) A_i,   G_r = max(G − b, 0)      (§4.1)
// to the outgoing light of the visible surfaces z_i (the previous term), without visibility, inside the
// bounding radius r = 1/√b, over a mip chain of the G-buffer: a sample is refined into its four children
// while its projected solid angle exceeds `solid_angle`, or `discontinuity_solid_angle` where it spans a
// depth or normal discontinuity (§4.2). Pixels seen at more than 80° from their normal fade out
// quadratically (§4.3).
//
// Passes (one dispatch each, a thread per texel of the level they write):
//   gbuffer     level 0 of the hierarchy: position and area, normal, albedo (at the target's resolution)
//   reduce      level l from level l − 1: area-weighted position, normal; discontinuity flags
//   illuminate  level 0 of the light of step k: L_o = ρ E_b/π + direct (k = 0) or ρ E_{k−1}/π
//   reduce_light level l of that light
//   compensate  E_k(y) = Σ G_r L A over the hierarchy; total += E_k
// and `apply` (fragment) adds total/π (blurred) into the frame's target.

#import bevy_render::view::View
#import bevy_pbr::pbr_deferred_types::{unpack_24bit_normal, unpack_unorm4x8_, unpack_flags, DEFERRED_FLAGS_UNLIT_BIT}
#import bevy_pbr::utils::octahedral_decode
#import bevy_diffuse_gi::gi_frame::{target_pixel, world_at}
#ifdef APPLY
#import bevy_core_pipeline::fullscreen_vertex_shader::FullscreenVertexOutput
#endif

const PI: f32 = 3.141592653589793;
// cos 80°: the grazing angle beyond which pixels fade out (§4.3).
const GRAZING_COS: f32 = 0.17364818;
const STACK_SIZE: u32 = 96u;

struct SsbcUniform {
    // Level 0 size in texels (the frame's target).
    size: vec2<u32>,
    // Pixels per texel (1 or 2).
    scale: u32,
    levels: u32,
    // The level a reduce pass writes.
    level: u32,
    // The step (0 = first compensation).
    step: u32,
    // b (1/m²) and r = 1/√b (m).
    bound: f32,
    radius: f32,
    solid_angle: f32,
    discontinuity_solid_angle: f32,
    intensity: f32,
    blur: u32,
}

#ifndef APPLY
@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var depth_texture: texture_depth_2d;
@group(0) @binding(2) var gbuffer: texture_2d<u32>;
// Σ w·E_b/π (rgb), Σ w (a): the clamped VPL light.
@group(0) @binding(3) var gi_texture: texture_2d<f32>;
// The lit image after the opaque pass: direct light × exposure.
@group(0) @binding(4) var main_texture: texture_2d<f32>;

@group(1) @binding(0) var<uniform> u: SsbcUniform;
// Two vec4 per texel of every level: (position, area), (normal, discontinuity).
@group(1) @binding(1) var<storage, read_write> geo: array<vec4<f32>>;
// Level 0: albedo.
@group(1) @binding(2) var<storage, read_write> albedo: array<vec4<f32>>;
// Every level: outgoing radiance of the current step's light.
@group(1) @binding(3) var<storage, read_write> light: array<vec4<f32>>;
// Level 0: irradiance of the current step, and the sum of all steps.
@group(1) @binding(4) var<storage, read_write> step_result: array<vec4<f32>>;
@group(1) @binding(5) var<storage, read_write> total: array<vec4<f32>>;
#else
@group(0) @binding(0) var<uniform> u: SsbcUniform;
@group(0) @binding(1) var<storage, read> geo: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> total: array<vec4<f32>>;
#endif

fn level_size(level: u32) -> vec2<u32> {
    return max((u.size + (vec2(1u) << vec2(level)) - 1u) >> vec2(level), vec2(1u));
}

fn level_offset(level: u32) -> u32 {
    var offset = 0u;
    for (var l = 0u; l < level; l++) {
        let s = level_size(l);
        offset += s.x * s.y;
    }
    return offset;
}

fn texel_index(level: u32, t: vec2<u32>) -> u32 {
    return level_offset(level) + t.y * level_size(level).x + t.x;
}

fn finite4(v: vec4<f32>) -> vec4<f32> {
    return select(vec4(0.0), v, all(v == v) && all(abs(v) < vec4(1e30)));
}

#ifndef APPLY
@compute @workgroup_size(8, 8, 1)
fn gbuffer_level(@builtin(global_invocation_id) id: vec3<u32>) {
    if any(id.xy >= u.size) {
        return;
    }
    let index = id.y * u.size.x + id.x;
    let full = vec2<i32>(textureDimensions(depth_texture));
    let pixel = target_pixel(vec2<i32>(id.xy), i32(u.scale), full);
    let depth = textureLoad(depth_texture, pixel, 0);
    let g = textureLoad(gbuffer, pixel, 0);
    let unlit = (unpack_flags(g.a) & DEFERRED_FLAGS_UNLIT_BIT) != 0u;
    if depth <= 0.0 {
        geo[2u * index] = vec4(0.0);
        geo[2u * index + 1u] = vec4(0.0, 0.0, 1.0, 0.0);
        albedo[index] = vec4(0.0);
        return;
    }
    let p = world_at(view.world_from_clip, pixel, full, depth);
    let n = octahedral_decode(unpack_24bit_normal(g.a));
    let base_color = pow(unpack_unorm4x8_(g.r).rgb, vec3(2.2));
    let metallic = unpack_unorm4x8_(g.b).g;
    let rho = select(base_color * (1.0 - metallic), vec3(0.0), unlit);

    // World area of the texel: the pixel's footprint on the image plane at the point's depth (s², with
    // s = depth · 2/(P₁₁·H), or 2/(P₁₁·H) for orthographic views) times cos α (ray against the view
    // axis) over |n·ω| (§4.1: "the surface area A_i that the pixel represents").
    let orthographic = view.clip_from_view[3][3] == 1.0;
    let to_camera = select(normalize(view.world_position - p), view.world_from_view[2].xyz, orthographic);
    let axis = view.world_from_view[2].xyz;
    let view_z = -(view.view_from_world * vec4(p, 1.0)).z;
    let side = 2.0 / (view.clip_from_view[1][1] * f32(full.y)) * select(view_z, 1.0, orthographic) * f32(u.scale);
    let cos_view = abs(dot(n, to_camera));
    let cos_alpha = abs(dot(to_camera, axis));
    var area = side * side * cos_alpha / max(cos_view, 0.02);
    // §4.3: fade pixels seen at grazing angles (over 80°) quadratically.
    if cos_view < GRAZING_COS {
        let f = cos_view / GRAZING_COS;
        area *= f * f;
    }
    geo[2u * index] = finite4(vec4(p, area));
    geo[2u * index + 1u] = vec4(n, 0.0);
    albedo[index] = vec4(rho, 1.0);
}

@compute @workgroup_size(8, 8, 1)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = level_size(u.level);
    if any(id.xy >= size) {
        return;
    }
    let child_size = level_size(u.level - 1u);
    var area = 0.0;
    var p = vec3(0.0);
    var n = vec3(0.0);
    var flag = 0.0;
    var valid = 0u;
    var empty = 0u;
    var children: array<vec4<f32>, 4>;
    var normals: array<vec4<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        let t = id.xy * 2u + vec2(c & 1u, c >> 1u);
        children[c] = vec4(0.0);
        if any(t >= child_size) {
            continue;
        }
        let i = texel_index(u.level - 1u, t);
        let a = geo[2u * i];
        let b = geo[2u * i + 1u];
        children[c] = a;
        normals[c] = b;
        if a.w > 0.0 {
            area += a.w;
            p += a.xyz * a.w;
            n += b.xyz * a.w;
            flag = max(flag, b.w);
            valid += 1u;
        } else {
            empty += 1u;
        }
    }
    let out = texel_index(u.level, id.xy);
    if valid == 0u {
        geo[2u * out] = vec4(0.0);
        geo[2u * out + 1u] = vec4(0.0, 0.0, 1.0, 1.0);
        return;
    }
    p /= area;
    n = normalize(n + vec3(0.0, 0.0, 1e-12));
    // A discontinuity: part of the cell is background, or its children disagree in depth (more than 5 %
    // of the distance to the camera) or in normal (more than ~25°).
    let distance = max(length(p - view.world_position), 1e-4);
    if empty > 0u {
        flag = 1.0;
    }
    for (var c = 0u; c < 4u; c++) {
        if children[c].w > 0.0 {
            let dz = abs(length(children[c].xyz - view.world_position) - distance) / distance;
            if dz > 0.05 || dot(normals[c].xyz, n) < 0.9 {
                flag = 1.0;
            }
        }
    }
    geo[2u * out] = vec4(p, area);
    geo[2u * out + 1u] = vec4(n, flag);
}

@compute @workgroup_size(8, 8, 1)
fn illuminate(@builtin(global_invocation_id) id: vec3<u32>) {
    if any(id.xy >= u.size) {
        return;
    }
    let index = id.y * u.size.x + id.x;
    let rho = albedo[index].rgb;
    var l = vec3(0.0);
    if u.step == 0u {
        // The clamped solution: Bevy's direct light (radiance × exposure in the main texture) and the
        // clamped VPL light (E_b/π per unit albedo in the target, scaled by the intensity).
        let full = vec2<i32>(textureDimensions(main_texture));
        let pixel = target_pixel(vec2<i32>(id.xy), i32(u.scale), full);
        let direct = textureLoad(main_texture, pixel, 0).rgb / max(view.exposure, 1e-30);
        let t = textureLoad(gi_texture, vec2<i32>(id.xy), 0);
        let indirect = t.rgb / max(t.a, 1.0) / max(u.intensity, 1e-20);
        l = direct + rho * indirect;
    } else {
        l = rho * step_result[index].rgb / PI;
    }
    light[index] = finite4(vec4(l, 1.0));
}

@compute @workgroup_size(8, 8, 1)
fn reduce_light(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = level_size(u.level);
    if any(id.xy >= size) {
        return;
    }
    let child_size = level_size(u.level - 1u);
    var sum = vec3(0.0);
    var area = 0.0;
    for (var c = 0u; c < 4u; c++) {
        let t = id.xy * 2u + vec2(c & 1u, c >> 1u);
        if any(t >= child_size) {
            continue;
        }
        let i = texel_index(u.level - 1u, t);
        let a = geo[2u * i].w;
        sum += light[i].rgb * a;
        area += a;
    }
    light[texel_index(u.level, id.xy)] = vec4(select(vec3(0.0), sum / area, area > 0.0), 1.0);
}

@compute @workgroup_size(8, 8, 1)
fn compensate(@builtin(global_invocation_id) id: vec3<u32>) {
    if any(id.xy >= u.size) {
        return;
    }
    let index = id.y * u.size.x + id.x;
    let here = geo[2u * index];
    var e = vec3(0.0);
    if here.w > 0.0 {
        let y = here.xyz;
        let ny = geo[2u * index + 1u].xyz;
        // §4.1: the bounding radius in texels of level 0.
        let orthographic = view.clip_from_view[3][3] == 1.0;
        let view_z = max(-(view.view_from_world * vec4(y, 1.0)).z, 1e-4);
        let full_height = f32(u.size.y * u.scale);
        let r_texels = u.radius * view.clip_from_view[1][1] * 0.5 * full_height / select(view_z, 1.0, orthographic) / f32(u.scale);
        // Start at the level whose cells are at least half the radius: at most 5 × 5 cells cover it.
        let start = min(u32(max(ceil(log2(max(r_texels, 1.0) * 0.5)), 0.0)), u.levels - 1u);
        let cell = f32(1u << start);
        let start_size = level_size(start);
        let lo = vec2<u32>(clamp((vec2<f32>(id.xy) - r_texels) / cell, vec2(0.0), vec2<f32>(start_size - 1u)));
        let hi = vec2<u32>(clamp((vec2<f32>(id.xy) + r_texels) / cell, vec2(0.0), vec2<f32>(start_size - 1u)));
        var stack: array<vec3<u32>, STACK_SIZE>;
        var top = 0u;
        for (var ty = lo.y; ty <= hi.y; ty++) {
            for (var tx = lo.x; tx <= hi.x; tx++) {
                if top < STACK_SIZE {
                    stack[top] = vec3(tx, ty, start);
                    top++;
                }
            }
        }
        var visits = 0u;
        while top > 0u && visits < 4096u {
            visits++;
            top--;
            let s = stack[top];
            let level = s.z;
            let i = texel_index(level, s.xy);
            let a = geo[2u * i];
            if a.w <= 0.0 {
                continue;
            }
            let b = geo[2u * i + 1u];
            let v = a.xyz - y;
            let d2 = dot(v, v);
            let d = sqrt(d2);
            // A cell's surface lies within about √area of its centre.
            let extent = sqrt(a.w);
            if d - extent > u.radius {
                continue;
            }
            let w = v / max(d, 1e-6);
            let omega = a.w * max(-dot(b.xyz, w), 0.0) / max(d2, 1e-12);
            let refine = omega > u.solid_angle || (b.w > 0.0 && omega > u.discontinuity_solid_angle) || d < extent;
            if level > 0u && refine && top + 4u <= STACK_SIZE {
                let child_size = level_size(level - 1u);
                for (var c = 0u; c < 4u; c++) {
                    let t = s.xy * 2u + vec2(c & 1u, c >> 1u);
                    if all(t < child_size) {
                        stack[top] = vec3(t, level - 1u);
                        top++;
                    }
                }
                continue;
            }
            if level == 0u && i == index {
                continue;
            }
            let cos_y = dot(ny, w);
            let cos_z = -dot(b.xyz, w);
            if cos_y <= 0.0 || cos_z <= 0.0 || d2 <= 1e-12 {
                continue;
            }
            let g_r = max(cos_y * cos_z / d2 - u.bound, 0.0);
            e += g_r * light[i].rgb * a.w;
        }
    }
    let result = finite4(vec4(e, 1.0));
    step_result[index] = result;
    if u.step == 0u {
        total[index] = result;
    } else {
        total[index] += result;
    }
}
#else
// Adds the compensation E_r/π (× intensity) to the frame's target; with `blur`, a 5×5 average weighted
// by depth and normal similarity (§5: an optional edge-preserving blur against blocky artefacts).
@fragment
fn apply(in: FullscreenVertexOutput) -> @location(0) vec4<f32> {
    let t = min(vec2<u32>(floor(in.position.xy)), u.size - 1u);
    let index = t.y * u.size.x + t.x;
    let centre = geo[2u * index];
    if centre.w <= 0.0 {
        discard;
    }
    let n = geo[2u * index + 1u].xyz;
    var sum = total[index].rgb;
    if u.blur != 0u {
        sum = vec3(0.0);
        var weight = 0.0;
        let scale = max(sqrt(centre.w), 1e-6);
        for (var j = -2; j <= 2; j++) {
            for (var i = -2; i <= 2; i++) {
                let q = vec2<i32>(t) + vec2(i, j);
                if any(q < vec2(0)) || any(q >= vec2<i32>(u.size)) {
                    continue;
                }
                let k = u32(q.y) * u.size.x + u32(q.x);
                let g = geo[2u * k];
                if g.w <= 0.0 {
                    continue;
                }
                let nk = geo[2u * k + 1u].xyz;
                // Distance in texel footprints and normal agreement.
                let dist = length(g.xyz - centre.xyz) / scale;
                let w = exp(-0.25 * f32(i * i + j * j)) * exp(-0.5 * dist * dist / 8.0) * pow(max(dot(n, nk), 0.0), 16.0);
                sum += total[k].rgb * w;
                weight += w;
            }
        }
        sum /= max(weight, 1e-12);
    }
    let value = finite4(vec4(sum / PI * u.intensity, 0.0));
#ifdef REPLACE
    return vec4(value.rgb, 1.0);
#else
    return value;
#endif
}
#endif
