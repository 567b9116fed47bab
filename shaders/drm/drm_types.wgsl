// The GPU layouts of Direct Radiance Mapping, shared by its passes. The Rust side is `DrmPhoton`,
// `DrmFaceJob`, `DrmPhotonsUniform` and `DrmGatherUniform` in src/drm/render.rs (`ShaderType`).
#define_import_path bevy_diffuse_gi::drm_types

const PI: f32 = 3.141592653589793;

// One sample photon: a cell of a light face's direct radiance map.
struct DrmPhoton {
    // xyz: world position; w: surface area A_p (m², 0 = no surface)
    position: vec4<f32>,
    // xyz: unit normal facing the light; w: area across the beam A'_p (m²)
    normal: vec4<f32>,
    // rgb: reflected flux ρΦ (lumens); w: Eq. 11's solid angle 2π/M of its light
    flux: vec4<f32>,
}

// One light face whose map is cut into photons.
struct DrmFaceJob {
    layer: u32,
    light: u32,
    // photons of this face's light (n² × faces): Eq. 11's M
    light_photons: u32,
}

struct DrmPhotonsUniform {
    samples_per_axis: u32,
    photon_count: u32,
    // 1: the cell's mip-map texel; 0: its centre texel
    mip_mapped: u32,
}

struct DrmGatherUniform {
    photon_count: u32,
    // ‖B_max − B_min‖² of the scene (Eq. 15)
    scene_diagonal_squared: f32,
    intensity: f32,
}
