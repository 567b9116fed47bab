// Writes a volume's irradiance into Bevy's IrradianceVolume layout (an ambient cube per voxel): the
// texture is (Rx, 2·Ry, 3·Rz); rows [0, Ry) hold the +X/+Y/+Z faces and [Ry, 2Ry) the −X/−Y/−Z faces; slices
// [0, Rz), [Rz, 2Rz), [2Rz, 3Rz) hold the X, Y and Z axes. Bevy multiplies the value by the diffuse colour,
// so it stores E/π. The voxels coincide with the hints.

#import bevy_diffuse_gi::rh_types::{PI, cell_coords, sh_irradiance}
#import bevy_diffuse_gi::rh_sampling::{volume, load_sh}

@group(0) @binding(0) var output: texture_storage_3d<rgba16float, write>;

@compute @workgroup_size(64)
fn export_irradiance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    let res = volume.resolution.xyz;
    let c = cell_coords(index, res);
    let sh = load_sh(index);
    for (var axis = 0u; axis < 3u; axis++) {
        var n = vec3(0.0);
        n[axis] = 1.0;
        for (var side = 0u; side < 2u; side++) {
            let normal = select(n, -n, side == 1u);
            let value = min(sh_irradiance(sh, normal) / PI, vec3(65000.0));
            let texel = vec3<u32>(c.x, c.y + side * res.y, c.z + axis * res.z);
            textureStore(output, texel, vec4(value, 1.0));
        }
    }
}
