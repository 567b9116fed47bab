// Writes a volume's irradiance into Bevy's IrradianceVolume layout (an ambient cube per voxel): the
// texture is (Rx, 2·Ry, 3·Rz); rows [0, Ry) hold the +X/+Y/+Z faces and [Ry, 2Ry) the −X/−Y/−Z faces; slices
// [0, Rz), [Rz, 2Rz), [2Rz, 3Rz) hold the X, Y and Z axes. Bevy multiplies the value by the diffuse colour,
// so it stores E/π. The voxels coincide with the hints.
//
// Bevy interpolates the voxels trilinearly without knowing about walls, so a hint inside solid geometry
// (validity 0, no light of its own) would darken the surfaces around it: it takes the mean of its valid
// neighbours instead.

#import bevy_diffuse_gi::rh_types::{PI, Sh, FIELD_TERMS, cell_coords, cell_index, sh_irradiance}
#import bevy_diffuse_gi::rh_sampling::{volume, albedo, load_sh}

@group(0) @binding(0) var output: texture_storage_3d<rgba16float, write>;

@compute @workgroup_size(#{WORKGROUP_SIZE})
fn export_irradiance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= volume.resolution.w {
        return;
    }
    let res = volume.resolution.xyz;
    let c = cell_coords(index, res);
    var sh = load_sh(index);
    if albedo[index].a < 0.5 {
        var sum: Sh;
        var count = 0.0;
        for (var k = 0u; k < 27u; k++) {
            let o = vec3<i32>(vec3(k % 3u, (k / 3u) % 3u, k / 9u)) - 1;
            let n = vec3<i32>(c) + o;
            if k == 13u || any(n < vec3(0)) || any(n >= vec3<i32>(res)) {
                continue;
            }
            let j = cell_index(vec3<u32>(n), res);
            if albedo[j].a >= 0.5 {
                let s = load_sh(j);
                for (var i = 0u; i < FIELD_TERMS; i++) {
                    sum.c[i] += s.c[i];
                }
                count += 1.0;
            }
        }
        if count > 0.0 {
            for (var i = 0u; i < FIELD_TERMS; i++) {
                sh.c[i] = sum.c[i] / count;
            }
        }
    }
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
