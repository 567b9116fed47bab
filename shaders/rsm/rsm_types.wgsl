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
    // xyz: unit normal of the emitting triangle
    normal: vec4<f32>,
    // rgb: flux in lumens carried by this sample
    flux: vec4<f32>,
}
