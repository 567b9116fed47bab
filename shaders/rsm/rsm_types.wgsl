// The GPU layouts of the reflective shadow maps, shared by every pass that draws or reads them. The Rust
// side is `RsmFaceUniform` and `GpuGiLight` in src/rsm/mod.rs (`ShaderType`); the light kinds come from
// the crate's shared shader defs (`shared_shader_defs` in src/lib.rs), so no number is written twice.
#define_import_path bevy_diffuse_gi::rsm_types

const LIGHT_KIND_DIRECTIONAL: u32 = #{LIGHT_KIND_DIRECTIONAL}u;
const LIGHT_KIND_SPOT: u32 = #{LIGHT_KIND_SPOT}u;
const LIGHT_KIND_POINT: u32 = #{LIGHT_KIND_POINT}u;

// One face of a light's RSM, as drawn by rsm.wgsl.
struct RsmFace {
    clip_from_world: mat4x4<f32>,
    // xyz: light position (local lights); w: unused
    light_position: vec4<f32>,
    // xyz: face axis (directional: the direction light travels); w: unused
    axis: vec4<f32>,
    // xyz: spot direction (spot lights); w: unused
    spot_direction: vec4<f32>,
    // rgb: illuminance (lux) or intensity (cd) divided by `flux_scale`'s photometric part
    color: vec4<f32>,
    // x: spot_scale, y: spot_offset, z: 1/range², w: texel measure (A⊥ in m² or (2 tan(fov/2)/res)² in sr)
    params: vec4<f32>,
    // LIGHT_KIND_*
    kind: u32,
}

// One GI light as the passes that read the RSM atlas see it.
struct GiLight {
    // Clip space of face 0 (used to centre the sampled disk of directional lights).
    clip_from_world: mat4x4<f32>,
    // Multiplies the stored flux back into lumens.
    flux_scale: f32,
    // Share of the RSM samples of each hint, by light power.
    sample_fraction: f32,
    first_layer: u32,
    faces: u32,
    resolution: u32,
    // LIGHT_KIND_*
    kind: u32,
}

// One point sample of the scene's emissive surfaces (`GpuEmitter` in src/emitters.rs): it sends
// flux · |n·ω| / (π d²) towards a receiver, like an RSM texel. Emission leaves both faces.
struct Emitter {
    // xyz: world position
    position: vec4<f32>,
    // xyz: unit normal of the emitting triangle, towards its open face when only one is; w: the faces
    // that emit, 2 (both) or 1 (the one the normal points to)
    normal: vec4<f32>,
    // rgb: flux in lumens carried by this sample
    flux: vec4<f32>,
}

// Texture coordinates of world point `p` in RSM face `face` (x right, y down), and in z whether it lies in
// front of the face.
fn face_uv(face: RsmFace, p: vec3<f32>) -> vec3<f32> {
    let clip = face.clip_from_world * vec4(p, 1.0);
    let ndc = clip.xy / max(clip.w, 1e-6);
    return vec3(vec2(ndc.x, -ndc.y) * 0.5 + 0.5, select(0.0, 1.0, clip.w > 1e-6));
}

// The cube face (+X, −X, +Y, −Y, +Z, −Z, the order of a point light's faces) direction `d` falls into.
fn cube_face(d: vec3<f32>) -> u32 {
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, d.x > 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, d.y > 0.0);
    }
    return select(5u, 4u, d.z > 0.0);
}
