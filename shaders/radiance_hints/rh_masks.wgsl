// Lookups that read a volume's prepared visibility masks (visibility.wgsl) instead of marching eight
// rays: the passes that import this bind the masks in group 2, beside the occupancy bits.
#define_import_path bevy_diffuse_gi::rh_masks

#import bevy_diffuse_gi::rh_types::cell_index
#import bevy_diffuse_gi::rh_sampling::{Trilinear, volume, trilinear_masked, occupancy_voxel}

// The hints each occupancy voxel may use: 8 bits per voxel, 4 voxels per word.
@group(2) @binding(1) var<storage, read> visibility: array<u32>;

// The eight hints around a volume-local position with the weights of the hints a lookup there may use:
// the prepared mask of the occupancy voxel holding it (valid hints not hidden behind a surface, surfaces
// within a voxel length of the voxel's centre not counted) replaces the eight visibility marches of
// `rh_sampling::trilinear`, whose test it is, made from the voxel's centre instead of the exact point.
fn hint_lookup(local: vec3<f32>) -> Trilinear {
    let v = occupancy_voxel(local);
    let index = cell_index(v, volume.occupancy_resolution.xyz);
    let mask = (visibility[index >> 2u] >> (8u * (index & 3u))) & 0xffu;
    return trilinear_masked(local, mask, v);
}
