//! Every GPU struct is written twice, once as a Rust `ShaderType` and once in WGSL; this test parses the
//! WGSL with naga and checks that both sides agree on the size of each, and member by member on the
//! names and offsets (encase's layout of the Rust struct against naga's of the WGSL one), so a field added,
//! moved or swapped on one side only fails here instead of corrupting a buffer at run time.

use bevy::render::render_resource::ShaderType;
use bevy::render::render_resource::encase::private::StructMetadata;
use bevy_diffuse_gi::drm::{DrmFaceJob, DrmGatherUniform, DrmPhoton, DrmPhotonsUniform};
use bevy_diffuse_gi::emitters::GpuEmitter;
use bevy_diffuse_gi::radiance_hints::{RhVolumeUniform, VisibilityRegion};
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

/// The members of the WGSL struct, in order: name and byte offset, as naga lays them out.
fn wgsl_members(file: &str, name: &str) -> Vec<(String, u64)> {
    let source = wgsl_struct(file, name);
    let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{file}: {name}: {e}"));
    let (_, ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)).expect("the struct");
    let naga::TypeInner::Struct { members, .. } = &ty.inner else {
        panic!("{file}: {name} is not a struct");
    };
    members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset as u64)).collect()
}

/// The field names of `pub struct NAME { … }` in the crate's sources, in order.
fn rust_fields(name: &str) -> Vec<String> {
    fn files(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).expect("src").flatten() {
            let path = entry.path();
            if path.is_dir() {
                files(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let mut sources = Vec::new();
    files(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src"), &mut sources);
    let header = format!("pub struct {name} {{");
    let text = sources
        .iter()
        .map(|p| std::fs::read_to_string(p).expect("a source file"))
        .find(|t| t.contains(&header))
        .unwrap_or_else(|| panic!("no `{header}` under src/"));
    let body = &text[text.find(&header).unwrap() + header.len()..];
    let body = &body[..body.find("\n}").expect("closing brace")];
    body.lines()
        .map(str::trim)
        .filter(|l| !l.starts_with("//") && !l.starts_with('#'))
        .filter_map(|l| {
            let l = l.strip_prefix("pub(crate) ").or_else(|| l.strip_prefix("pub ")).unwrap_or(l);
            let (field, _) = l.split_once(':')?;
            field.chars().all(|c| c.is_ascii_alphanumeric() || c == '_').then(|| field.to_string())
        })
        .collect()
}

/// The byte offsets encase gives the fields of a Rust `ShaderType` struct, in order.
fn rust_offsets<T, const N: usize>() -> Vec<u64>
where
    T: ShaderType<ExtraMetadata = StructMetadata<N>>,
{
    T::METADATA.extra.offsets.to_vec()
}

/// One struct on both sides: the WGSL file and name, the Rust name, its size and field offsets.
macro_rules! case {
    ($file:literal, $wgsl:literal, $rust:ty) => {
        ($file, $wgsl, stringify!($rust), <$rust>::min_size().get(), rust_offsets::<$rust, _>())
    };
}

#[test]
fn rust_and_wgsl_agree_on_every_gpu_struct() {
    let cases = [
        case!("rsm/rsm_types.wgsl", "RsmFace", RsmFaceUniform),
        case!("rsm/rsm_types.wgsl", "GiLight", GpuGiLight),
        case!("rsm/rsm_types.wgsl", "Emitter", GpuEmitter),
        case!("radiance_hints/rh_types.wgsl", "RhVolume", RhVolumeUniform),
        case!("radiance_hints/visibility.wgsl", "VisibilityRegion", VisibilityRegion),
        case!("vpl/vpl_types.wgsl", "Vpl", GpuVpl),
        case!("vpl/vpl_types.wgsl", "VplUniform", VplUniform),
        case!("ssbc/ssbc.wgsl", "SsbcUniform", SsbcUniform),
        case!("rsm_gather/gather.wgsl", "RsmGatherUniform", RsmGatherUniform),
        case!("rsm_gather/gather.wgsl", "RsmGatherSample", RsmGatherSample),
        case!("drm/drm_types.wgsl", "DrmPhoton", DrmPhoton),
        case!("drm/drm_types.wgsl", "DrmFaceJob", DrmFaceJob),
        case!("drm/drm_types.wgsl", "DrmPhotonsUniform", DrmPhotonsUniform),
        case!("drm/drm_types.wgsl", "DrmGatherUniform", DrmGatherUniform),
        case!("radiosity/display.wgsl", "RadiosityVertex", RadiosityVertex),
        case!("photon_grid/gather.wgsl", "PhotonGridUniform", PhotonGridUniform),
    ];
    for (file, name, rust, size, offsets) in cases {
        assert_eq!(wgsl_size(file, name), size, "{file}: struct {name} and its Rust ShaderType {rust} differ in size");
        let members = wgsl_members(file, name);
        let wgsl: Vec<(&str, u64)> = members.iter().map(|(n, o)| (n.as_str(), *o)).collect();
        let fields = rust_fields(rust);
        let ours: Vec<(&str, u64)> = fields.iter().map(String::as_str).zip(offsets.iter().copied()).collect();
        assert_eq!(fields.len(), offsets.len(), "{rust}: the fields read from the source are not encase's");
        assert_eq!(wgsl, ours, "{file}: struct {name} and {rust} differ member by member (name, byte offset)");
    }
    // The packed irradiance per hint (no ShaderType: the buffer is written by the blend pass only).
    let packed = ("radiance_hints/rh_packed.wgsl", "Packed");
    assert_eq!(wgsl_size(packed.0, packed.1), bevy_diffuse_gi::radiance_hints::PACKED_BYTES);
}

#[test]
fn a_swapped_field_is_caught() {
    // The check itself: two fields of the same size in the other order have the same size and offsets,
    // but not the same names at those offsets.
    let members = wgsl_members("rsm/rsm_types.wgsl", "Emitter");
    let mut swapped = rust_fields("GpuEmitter");
    swapped.swap(0, 1);
    let names: Vec<&str> = members.iter().map(|(n, _)| n.as_str()).collect();
    assert_ne!(names, swapped.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(names, rust_fields("GpuEmitter").iter().map(String::as_str).collect::<Vec<_>>());
}
