//! Every GPU struct is written twice, once as a Rust `ShaderType` and once in WGSL; this test parses the
//! WGSL with naga and checks that both sides agree on the size of each, so a field added on one side only
//! fails here instead of corrupting a buffer at run time.

use bevy::render::render_resource::ShaderType;
use bevy_diffuse_gi::drm::{DrmFaceJob, DrmGatherUniform, DrmPhoton, DrmPhotonsUniform};
use bevy_diffuse_gi::emitters::GpuEmitter;
use bevy_diffuse_gi::radiance_hints::prepare::{RhVolumeUniform, VisibilityRegion};
use bevy_diffuse_gi::photon_grid::PhotonGridUniform;
use bevy_diffuse_gi::radiosity::RadiosityVertex;
use bevy_diffuse_gi::rsm::{GpuGiLight, RsmFaceUniform};
use bevy_diffuse_gi::rsm_gather::{RsmGatherSample, RsmGatherUniform};
use bevy_diffuse_gi::ssbc::SsbcUniform;
use bevy_diffuse_gi::vpl::{GpuVpl, VplUniform};

/// The text of `struct NAME { … }` in `file` (under `shaders/`).
fn wgsl_struct(file: &str, name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders").join(file);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let start = text.find(&format!("struct {name} {{")).unwrap_or_else(|| panic!("{file}: no struct {name}"));
    let end = start + text[start..].find("\n}").expect("closing brace") + 2;
    text[start..end].to_string()
}

/// The WGSL size of the struct, as naga lays it out for a uniform or storage buffer.
fn wgsl_size(file: &str, name: &str) -> u64 {
    let source = wgsl_struct(file, name);
    let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{file}: {name}: {e}"));
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).expect("layout");
    let (handle, _) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)).expect("the struct");
    layouter[handle].size as u64
}

#[test]
fn rust_and_wgsl_agree_on_every_gpu_struct() {
    let cases = [
        ("rsm/rsm_types.wgsl", "RsmFace", RsmFaceUniform::min_size().get()),
        ("rsm/rsm_types.wgsl", "GiLight", GpuGiLight::min_size().get()),
        ("rsm/rsm_types.wgsl", "Emitter", GpuEmitter::min_size().get()),
        ("radiance_hints/rh_types.wgsl", "RhVolume", RhVolumeUniform::min_size().get()),
        ("radiance_hints/visibility.wgsl", "VisibilityRegion", VisibilityRegion::min_size().get()),
        ("vpl/vpl_types.wgsl", "Vpl", GpuVpl::min_size().get()),
        ("vpl/vpl_types.wgsl", "VplUniform", VplUniform::min_size().get()),
        ("ssbc/ssbc.wgsl", "SsbcUniform", SsbcUniform::min_size().get()),
        ("rsm_gather/gather.wgsl", "RsmGatherUniform", RsmGatherUniform::min_size().get()),
        ("rsm_gather/gather.wgsl", "RsmGatherSample", RsmGatherSample::min_size().get()),
        ("drm/drm_types.wgsl", "DrmPhoton", DrmPhoton::min_size().get()),
        ("drm/drm_types.wgsl", "DrmFaceJob", DrmFaceJob::min_size().get()),
        ("drm/drm_types.wgsl", "DrmPhotonsUniform", DrmPhotonsUniform::min_size().get()),
        ("drm/drm_types.wgsl", "DrmGatherUniform", DrmGatherUniform::min_size().get()),
        ("radiosity/display.wgsl", "RadiosityVertex", RadiosityVertex::min_size().get()),
        ("photon_grid/gather.wgsl", "PhotonGridUniform", PhotonGridUniform::min_size().get()),
        // The packed irradiance per hint (no ShaderType: the buffer is written by the blend pass only).
        ("radiance_hints/rh_packed.wgsl", "Packed", bevy_diffuse_gi::radiance_hints::PACKED_BYTES),
    ];
    for (file, name, rust) in cases {
        assert_eq!(wgsl_size(file, name), rust, "{file}: struct {name} and its Rust ShaderType differ in size");
    }
}
