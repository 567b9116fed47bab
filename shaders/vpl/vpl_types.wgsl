// Shared definitions of the VPL passes. The Rust side is `GpuVpl` and `VplUniform` in src/vpl/render.rs
// (`ShaderType`); sizes come in as shader defs.
#define_import_path bevy_diffuse_gi::vpl_types

const PI: f32 = 3.141592653589793;

// One virtual point light: a diffuse emitter of reflected flux `flux` (lumens) at `position`, facing
// `normal`. Its intensity towards ω is flux/π · max(0, n·ω).
struct Vpl {
    position: vec4<f32>,
    normal: vec4<f32>,
    flux: vec4<f32>,
}

struct VplUniform {
    // VPLs in the buffer.
    vpl_count: u32,
    // Side of each imperfect shadow map (level 0), texels; a multiple of 4.
    ism_resolution: u32,
    // u32 words per VPL's shadow map: levels 0, 1 and 2 of its pull-push pyramid.
    ism_stride: u32,
    // Scene points each VPL splats.
    points_per_ism: u32,
    // Points in the point set.
    point_count: u32,
    // b of G_b = min(G, b), 1/m².
    geometry_bound: f32,
    // Depth tolerance of the shadow-map test, fraction of the distance.
    ism_bias: f32,
    // Multiplies the gathered light.
    intensity: f32,
    // Radius of the surface disk one shadow-map point stands for, metres.
    point_radius: f32,
    // Multiplies the slope-scaled part of the depth tolerance: 1 for splatted maps, 0 for traced ones.
    slope_tolerance: f32,
    // 1: the maps are traced (texels hold the far side and the first surface, two f16); 0: splatted.
    traced: u32,
    // Traced maps: how far off a receiver's plane, as a fraction of its distance from the point a
    // texel's centre ray hit, that point still counts as the receiver's own surface.
    plane_tolerance: f32,
}

// A continuous orthonormal basis (t, b, n) around unit n (Duff et al. 2017); the same in every pass.
fn basis(n: vec3<f32>) -> mat3x3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return mat3x3(vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x), vec3(b, s + n.y * n.y * a, -n.y), n);
}

// Unit direction `d` in the frame of normal `n` (z along n).
fn to_local(n: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    return d * basis(n);
}

// Continuous paraboloid coordinates in [0, resolution)² of a local direction with z > 0
// (Brabec et al. 2002: uv = xy / (1 + z) over the unit disk).
fn paraboloid_coords(local: vec3<f32>, resolution: u32) -> vec2<f32> {
    let uv = local.xy / (1.0 + max(local.z, 0.0));
    return (uv * 0.5 + 0.5) * f32(resolution);
}

// The unit direction, in the frame of the map's normal, through the centre of texel `t` of a
// `resolution`² paraboloid map (the inverse of `paraboloid_coords`; src/vpl/generate.rs,
// paraboloid_direction). Texels outside the paraboloid's disk give their direction on its rim.
fn paraboloid_direction(t: vec2<u32>, resolution: u32) -> vec3<f32> {
    var uv = (vec2<f32>(t) + 0.5) / f32(resolution) * 2.0 - 1.0;
    uv /= max(length(uv), 1.0);
    let r2 = dot(uv, uv);
    let z = (1.0 - r2) / (1.0 + r2);
    return normalize(vec3(uv * (1.0 + z), z));
}

// Word index of texel `t` of level `level` (0, 1, 2) of VPL `vpl`'s shadow map.
fn ism_index(u: VplUniform, vpl: u32, level: u32, t: vec2<u32>) -> u32 {
    let r0 = u.ism_resolution;
    var offset = 0u;
    if level >= 1u {
        offset += r0 * r0;
    }
    if level >= 2u {
        offset += (r0 / 2u) * (r0 / 2u);
    }
    let r = r0 >> level;
    return vpl * u.ism_stride + offset + t.y * r + t.x;
}
