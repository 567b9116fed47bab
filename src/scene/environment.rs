//! The environment light as the CPU sees it: the radiance of a camera's Bevy
//! [`EnvironmentMapLight`](bevy::light::EnvironmentMapLight), for the methods that gather light from
//! directions where no geometry is (radiosity's empty bins, §4.4 of Dong et al.) and for the path tracer,
//! whose escaping rays return it.
//!
//! [`Environment::from_image`] reads mip 0 of the light's **specular map** (the radiance: Bevy's
//! prefiltered maps keep the unfiltered environment at roughness 0), multiplies it by the light's
//! `intensity` (cd/m² after it, as Bevy's docs say) and keeps the light's `rotation`. A direction is looked
//! up exactly as `environment_map.wgsl` does: rotated by the inverse of `rotation`, its z negated (Bevy's
//! cubemaps are left-handed), then the Vulkan/wgpu cube-face rules, bilinear within a face. Faces larger
//! than [`Environment::MAX_FACE`] texels are box-filtered down to it: the consumers integrate the
//! environment over solid angles of at least a few degrees.
//!
//! Read formats: `Rgba32Float`, `Rgba16Float`, `Rgb9e5Ufloat` (Bevy's KTX2 environment maps),
//! `Rg11b10Ufloat`, `Rgba8Unorm(Srgb)`, `Bgra8Unorm(Srgb)`, in either texture data order and with any
//! mip count. Block-compressed maps and images without CPU data (`RenderAssetUsages::RENDER_WORLD` only,
//! as `EnvironmentMapLight::hemispherical_gradient` makes them, once the renderer has taken them) are an
//! error that names the reason.

use bevy::asset::RenderAssetUsages;
use bevy::image::Image;
use bevy::math::{Quat, Vec2, Vec3};
use bevy::render::render_resource::{
    Extent3d, TextureDataOrder, TextureDimension, TextureFormat, TextureViewDescriptor, TextureViewDimension,
};

/// A cube-map image (`Rgba32Float`, `size²` texels per face, viewed as a cube) whose texels hold
/// `radiance` of the world direction through their centre, as Bevy samples them (no rotation): the
/// inverse of [`Environment::radiance`]'s lookup. For environment maps made in code; `usage` without
/// `MAIN_WORLD` leaves the GI nothing to read once the renderer has the image.
pub fn cube_image(size: u32, usage: RenderAssetUsages, radiance: impl Fn(Vec3) -> Vec3) -> Image {
    let n = size.max(1);
    let mut data = Vec::with_capacity((6 * n * n * 16) as usize);
    for face in 0..6 {
        for y in 0..n {
            for x in 0..n {
                let s = 2.0 * (x as f32 + 0.5) / n as f32 - 1.0;
                let t = 2.0 * (y as f32 + 0.5) / n as f32 - 1.0;
                // Cube-map space direction of the texel (Vulkan's face rules inverted) ...
                let c = match face {
                    0 => Vec3::new(1.0, -t, -s),
                    1 => Vec3::new(-1.0, -t, s),
                    2 => Vec3::new(s, 1.0, t),
                    3 => Vec3::new(s, -1.0, -t),
                    4 => Vec3::new(s, -t, 1.0),
                    _ => Vec3::new(-s, -t, -1.0),
                };
                // ... and in the world, where Bevy negates z before the lookup.
                let r = radiance(Vec3::new(c.x, c.y, -c.z).normalize());
                for v in [r.x, r.y, r.z, 1.0] {
                    data.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
    }
    let mut image = Image::new(
        Extent3d { width: n, height: n, depth_or_array_layers: 6 },
        TextureDimension::D2,
        data,
        TextureFormat::Rgba32Float,
        usage,
    );
    image.texture_view_descriptor = Some(TextureViewDescriptor { dimension: Some(TextureViewDimension::Cube), ..Default::default() });
    image
}

/// Radiance around the scene, per direction.
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    /// Texels per face side.
    size: u32,
    /// Radiance in cd/m² (intensity applied), faces `+x −x +y −y +z −z` in cube-map space, rows from the
    /// top (the face's `t = 0`).
    texels: Vec<Vec3>,
    /// Bevy's `EnvironmentMapLight::rotation`: world directions are rotated by its inverse.
    rotation: Quat,
}

impl Environment {
    /// Largest face kept, texels per side.
    pub const MAX_FACE: u32 = 64;

    /// The same radiance in every direction.
    pub fn uniform(radiance: Vec3) -> Self {
        Self { size: 1, texels: vec![radiance; 6], rotation: Quat::IDENTITY }
    }

    /// An environment from `size × size` texels per face, faces `+x −x +y −y +z −z` in cube-map space
    /// (wgpu's layer order), rows from the top, already in cd/m².
    pub fn from_faces(size: u32, texels: Vec<Vec3>, rotation: Quat) -> Result<Self, String> {
        let size = size.max(1);
        if texels.len() != 6 * (size * size) as usize {
            return Err(format!("{} texels for six {size}² faces", texels.len()));
        }
        let texels = texels.into_iter().map(|t| if t.is_finite() { t.max(Vec3::ZERO) } else { Vec3::ZERO }).collect();
        Ok(Self::downsampled(size, texels, rotation))
    }

    /// Mip 0 of a cube-map image (six array layers), times `intensity`, turned by `rotation` (the fields
    /// of Bevy's `EnvironmentMapLight`).
    pub fn from_image(image: &Image, intensity: f32, rotation: Quat) -> Result<Self, String> {
        let desc = &image.texture_descriptor;
        let (width, height, layers) = (desc.size.width, desc.size.height, desc.size.depth_or_array_layers);
        if layers != 6 || width != height || width == 0 {
            return Err(format!("a cube map has six square layers; this image is {width}×{height}×{layers}"));
        }
        let Some(data) = image.data.as_ref() else {
            return Err("the image has no CPU data (its RenderAssetUsages lack MAIN_WORLD)".into());
        };
        let format = desc.format;
        let Some(pixel) = format.block_copy_size(None).filter(|_| format.block_dimensions() == (1, 1)) else {
            return Err(format!("{format:?} cannot be read on the CPU"));
        };
        let pixel = pixel as usize;
        let decode = decoder(format).ok_or_else(|| format!("{format:?} cannot be read on the CPU"))?;
        let mips = desc.mip_level_count.max(1);
        let mip_bytes = |m: u32| ((width >> m).max(1) as usize).pow(2) * pixel;
        let layer_stride = match image.data_order {
            TextureDataOrder::LayerMajor => (0..mips).map(mip_bytes).sum::<usize>(),
            _ => mip_bytes(0),
        };
        let face = (width * width) as usize;
        if data.len() < 5 * layer_stride + face * pixel {
            return Err(format!("{} bytes are too few for a {width}² {format:?} cube map", data.len()));
        }
        let scale = if intensity.is_finite() { intensity.max(0.0) } else { 0.0 };
        let mut texels = Vec::with_capacity(6 * face);
        for layer in 0..6 {
            let base = layer * layer_stride;
            for t in 0..face {
                let at = base + t * pixel;
                texels.push(decode(&data[at..at + pixel]) * scale);
            }
        }
        Self::from_faces(width, texels, rotation)
    }

    /// Box-filters faces larger than [`Self::MAX_FACE`].
    fn downsampled(size: u32, texels: Vec<Vec3>, rotation: Quat) -> Self {
        let factor = size.div_ceil(Self::MAX_FACE);
        if factor <= 1 {
            return Self { size, texels, rotation };
        }
        let small = size.div_ceil(factor);
        let mut out = Vec::with_capacity(6 * (small * small) as usize);
        for f in 0..6 {
            for y in 0..small {
                for x in 0..small {
                    let (mut sum, mut n) = (Vec3::ZERO, 0.0);
                    for sy in y * factor..((y + 1) * factor).min(size) {
                        for sx in x * factor..((x + 1) * factor).min(size) {
                            sum += texels[((f * size + sy) * size + sx) as usize];
                            n += 1.0;
                        }
                    }
                    out.push(sum / n);
                }
            }
        }
        Self { size: small, texels: out, rotation }
    }

    /// Texels per face side (after downsampling).
    pub fn face_size(&self) -> u32 {
        self.size
    }

    /// Radiance arriving from world direction `direction` (any length), cd/m².
    pub fn radiance(&self, direction: Vec3) -> Vec3 {
        let mut d = self.rotation.inverse() * direction;
        d.z = -d.z;
        let a = d.abs();
        // Vulkan's cube-face selection (§16.5.4 of the spec): face, major axis, s and t before division.
        let (face, major, s, t) = if a.x >= a.y && a.x >= a.z {
            if d.x >= 0.0 { (0, a.x, -d.z, -d.y) } else { (1, a.x, d.z, -d.y) }
        } else if a.y >= a.z {
            if d.y >= 0.0 { (2, a.y, d.x, d.z) } else { (3, a.y, d.x, -d.z) }
        } else if d.z >= 0.0 {
            (4, a.z, d.x, -d.y)
        } else {
            (5, a.z, -d.x, -d.y)
        };
        if major.is_nan() || major <= 0.0 {
            return Vec3::ZERO;
        }
        let uv = (Vec2::new(s, t) / major + 1.0) * 0.5;
        self.bilinear(face, uv)
    }

    fn bilinear(&self, face: u32, uv: Vec2) -> Vec3 {
        let n = self.size;
        let p = (uv * n as f32 - 0.5).clamp(Vec2::ZERO, Vec2::splat((n - 1) as f32));
        let (x0, y0) = (p.x.floor() as u32, p.y.floor() as u32);
        let (x1, y1) = ((x0 + 1).min(n - 1), (y0 + 1).min(n - 1));
        let f = p - Vec2::new(x0 as f32, y0 as f32);
        let at = |x: u32, y: u32| self.texels[((face * n + y) * n + x) as usize];
        let top = at(x0, y0).lerp(at(x1, y0), f.x);
        let bottom = at(x0, y1).lerp(at(x1, y1), f.x);
        top.lerp(bottom, f.y)
    }

    /// Irradiance on a surface facing `normal` under this environment, unoccluded (lux): the cosine-weighted
    /// integral of [`radiance`](Self::radiance) over the hemisphere, by a `samples²` stratified estimate.
    pub fn irradiance(&self, normal: Vec3, samples: u32) -> Vec3 {
        let n = samples.max(1);
        let mut sum = Vec3::ZERO;
        for j in 0..n {
            for i in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                sum += self.radiance(crate::sampling::cosine_hemisphere(normal, u));
            }
        }
        sum * (std::f32::consts::PI / (n * n) as f32)
    }
}

/// Linear RGB of one texel of `format`.
fn decoder(format: TextureFormat) -> Option<fn(&[u8]) -> Vec3> {
    fn f32s(b: &[u8]) -> Vec3 {
        let c = |i: usize| f32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        Vec3::new(c(0), c(1), c(2))
    }
    fn f16s(b: &[u8]) -> Vec3 {
        let c = |i: usize| half::f16::from_le_bytes([b[2 * i], b[2 * i + 1]]).to_f32();
        Vec3::new(c(0), c(1), c(2))
    }
    fn rgb9e5(b: &[u8]) -> Vec3 {
        let v = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let scale = 2f32.powi((v >> 27) as i32 - 15 - 9);
        Vec3::new((v & 0x1ff) as f32, ((v >> 9) & 0x1ff) as f32, ((v >> 18) & 0x1ff) as f32) * scale
    }
    fn small_float(bits: u32, mantissa_bits: u32) -> f32 {
        let (e, m) = (bits >> mantissa_bits, bits & ((1 << mantissa_bits) - 1));
        let m = m as f32 / (1u32 << mantissa_bits) as f32;
        match e {
            0 => m * 2f32.powi(-14),
            31 => 0.0,
            e => (1.0 + m) * 2f32.powi(e as i32 - 15),
        }
    }
    fn rg11b10(b: &[u8]) -> Vec3 {
        let v = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        Vec3::new(small_float(v & 0x7ff, 6), small_float((v >> 11) & 0x7ff, 6), small_float(v >> 22, 5))
    }
    fn srgb(c: u8) -> f32 {
        bevy::color::Srgba::gamma_function(c as f32 / 255.0)
    }
    fn rgba8_srgb(b: &[u8]) -> Vec3 {
        Vec3::new(srgb(b[0]), srgb(b[1]), srgb(b[2]))
    }
    fn bgra8_srgb(b: &[u8]) -> Vec3 {
        Vec3::new(srgb(b[2]), srgb(b[1]), srgb(b[0]))
    }
    fn rgba8(b: &[u8]) -> Vec3 {
        Vec3::new(b[0] as f32, b[1] as f32, b[2] as f32) / 255.0
    }
    fn bgra8(b: &[u8]) -> Vec3 {
        Vec3::new(b[2] as f32, b[1] as f32, b[0] as f32) / 255.0
    }
    Some(match format {
        TextureFormat::Rgba32Float => f32s,
        TextureFormat::Rgba16Float => f16s,
        TextureFormat::Rgb9e5Ufloat => rgb9e5,
        TextureFormat::Rg11b10Ufloat => rg11b10,
        TextureFormat::Rgba8UnormSrgb => rgba8_srgb,
        TextureFormat::Bgra8UnormSrgb => bgra8_srgb,
        TextureFormat::Rgba8Unorm => rgba8,
        TextureFormat::Bgra8Unorm => bgra8,
        _ => return None,
    })
}

/// `light` with its diffuse map replaced by a black one, for a camera whose GI method reads the
/// environment (radiosity, the photon grid): Bevy then adds only the environment's specular reflections,
/// and the method its diffuse light with occlusion (a room lit through a window gets the sky's light
/// where the window lets it in, not everywhere). The methods read the specular map, whose image must
/// keep its CPU data (the default `RenderAssetUsages` of loaded images).
///
/// ```no_run
/// # use bevy::prelude::*;
/// # use bevy::light::EnvironmentMapLight;
/// # use bevy_diffuse_gi::prelude::*;
/// # fn setup(mut commands: Commands, mut images: ResMut<Assets<Image>>, assets: Res<AssetServer>) {
/// let sky = assets.load("sky_specular_rgb9e5.ktx2");
/// let light = EnvironmentMapLight { diffuse_map: sky.clone(), specular_map: sky, intensity: 1000.0, ..default() };
/// commands.spawn((
///     Camera3d::default(),
///     DiffuseGi { method: GiMethod::Radiosity, ..default() },
///     bevy_diffuse_gi::scene::environment::occluded_environment(&light, &mut images),
/// ));
/// # }
/// ```
pub fn occluded_environment(light: &bevy::light::EnvironmentMapLight, images: &mut bevy::asset::Assets<Image>) -> bevy::light::EnvironmentMapLight {
    let black = cube_image(1, bevy::asset::RenderAssetUsages::RENDER_WORLD, |_| Vec3::ZERO);
    bevy::light::EnvironmentMapLight { diffuse_map: images.add(black), ..light.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2² cube map whose every face has its own colour (face index + 1 in red) in `Rgba32Float`.
    fn labelled_faces() -> Image {
        let mut data = Vec::new();
        for face in 0..6 {
            for _ in 0..4 {
                for c in [face as f32 + 1.0, 0.5, 0.25, 1.0] {
                    data.extend_from_slice(&c.to_le_bytes());
                }
            }
        }
        Image::new(
            Extent3d { width: 2, height: 2, depth_or_array_layers: 6 },
            TextureDimension::D2,
            data,
            TextureFormat::Rgba32Float,
            RenderAssetUsages::default(),
        )
    }

    #[test]
    fn directions_pick_the_faces_bevy_samples() {
        let env = Environment::from_image(&labelled_faces(), 2.0, Quat::IDENTITY).unwrap();
        // Bevy negates z before the lookup: world +z is the cube's −z face (index 5), world −z its +z face.
        for (dir, face) in [(Vec3::X, 0), (Vec3::NEG_X, 1), (Vec3::Y, 2), (Vec3::NEG_Y, 3), (Vec3::Z, 5), (Vec3::NEG_Z, 4)] {
            let r = env.radiance(dir);
            assert!((r.x - 2.0 * (face as f32 + 1.0)).abs() < 1e-5, "{dir} -> {r}");
            assert!((r.y - 1.0).abs() < 1e-5 && (r.z - 0.5).abs() < 1e-5);
        }
        // The rotation turns the environment: rotated a quarter turn about y, world −x sees what +z saw
        // (the light's rotation is applied as its inverse to world directions, as Bevy does).
        let turned = Environment::from_image(&labelled_faces(), 1.0, Quat::from_rotation_y(std::f32::consts::FRAC_PI_2)).unwrap();
        let plain = Environment::from_image(&labelled_faces(), 1.0, Quat::IDENTITY).unwrap();
        let q = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        for dir in [Vec3::X, Vec3::Z, Vec3::new(0.3, 0.2, -0.9)] {
            assert_eq!(turned.radiance(q * dir), plain.radiance(dir));
        }
    }

    #[test]
    fn within_a_face_rows_run_from_the_top_and_columns_follow_s() {
        // +y face (index 2): s = x, t = z after the z flip, so the row at t = 0 is world +z.
        let mut texels = vec![Vec3::ZERO; 6 * 4];
        texels[2 * 4] = Vec3::X; // row 0, column 0: s < 0 (world −x), t < 0 (world +z after the flip).
        let env = Environment::from_faces(2, texels, Quat::IDENTITY).unwrap();
        let corner = env.radiance(Vec3::new(-0.5, 1.0, 0.5));
        assert!((corner.x - 1.0).abs() < 1e-5, "{corner}");
        assert_eq!(env.radiance(Vec3::new(0.5, 1.0, -0.5)), Vec3::ZERO);
    }

    #[test]
    fn packed_formats_decode_and_bad_images_are_errors() {
        // 1.0 in rgb9e5: mantissa 256, exponent 15 + 9 − 8 = 16.
        let one = (256u32) | (256 << 9) | (256 << 18) | (16 << 27);
        let image = Image::new(
            Extent3d { width: 1, height: 1, depth_or_array_layers: 6 },
            TextureDimension::D2,
            (0..6).flat_map(|_| one.to_le_bytes()).collect(),
            TextureFormat::Rgb9e5Ufloat,
            RenderAssetUsages::default(),
        );
        let env = Environment::from_image(&image, 3.0, Quat::IDENTITY).unwrap();
        assert!((env.radiance(Vec3::Y) - Vec3::splat(3.0)).abs().max_element() < 1e-5);
        // Rg11b10: 1.0 is exponent 15, mantissa 0, in each field.
        let v = (15u32 << 6) | ((15u32 << 6) << 11) | ((15u32 << 5) << 22);
        assert!((decoder(TextureFormat::Rg11b10Ufloat).unwrap()(&v.to_le_bytes()) - Vec3::ONE).abs().max_element() < 1e-6);

        let mut gone = labelled_faces();
        gone.data = None;
        assert!(Environment::from_image(&gone, 1.0, Quat::IDENTITY).unwrap_err().contains("no CPU data"));
        let flat = Image::new_fill(Extent3d::default(), TextureDimension::D2, &[0; 16], TextureFormat::Rgba32Float, RenderAssetUsages::default());
        assert!(Environment::from_image(&flat, 1.0, Quat::IDENTITY).is_err());
    }

    #[test]
    fn large_faces_are_box_filtered_and_keep_their_mean() {
        let size = 130;
        let texels: Vec<Vec3> = (0..6 * size * size).map(|i| Vec3::splat((i % 7) as f32)).collect();
        let mean = texels.iter().sum::<Vec3>() / texels.len() as f32;
        let env = Environment::from_faces(size, texels, Quat::IDENTITY).unwrap();
        assert!(env.face_size() <= Environment::MAX_FACE);
        let kept = env.texels.iter().sum::<Vec3>() / env.texels.len() as f32;
        assert!((kept - mean).abs().max_element() < 0.05 * mean.x, "{kept} vs {mean}");
    }

    #[test]
    fn a_bright_top_face_lights_a_floor_as_the_closed_form_of_a_square_overhead() {
        // Only the +y face (a 2 × 2 square one unit above the point, in cube-map space) shines: a floor
        // facing up receives the irradiance of a parallel square of that radiance (Howell B-3,
        // `emitters::parallel_rectangle_irradiance`), a ceiling facing down none, a wall facing +x a
        // share of it between the two. Independent of the tracer and of every method that reads the sky.
        let size = 8;
        let radiance = 5.0;
        let mut texels = vec![Vec3::ZERO; 6 * size * size];
        texels[2 * size * size..3 * size * size].fill(Vec3::splat(radiance));
        let env = Environment::from_faces(size as u32, texels, Quat::IDENTITY).unwrap();
        let exact = crate::emitters::parallel_rectangle_irradiance(radiance, 1.0, [-1.0, 1.0], [-1.0, 1.0]);
        let floor = env.irradiance(Vec3::Y, 256).x;
        assert!((floor / exact - 1.0).abs() < 0.01, "floor {floor} vs closed form {exact}");
        assert_eq!(env.irradiance(Vec3::NEG_Y, 64), Vec3::ZERO);
        let wall = env.irradiance(Vec3::X, 256).x;
        assert!(wall > 0.05 * exact && wall < 0.5 * exact, "wall {wall} vs floor {exact}");
    }

    #[test]
    fn a_uniform_sky_gives_pi_times_its_radiance() {
        let e = Environment::uniform(Vec3::new(1.0, 2.0, 3.0)).irradiance(Vec3::new(0.3, 0.9, 0.1).normalize(), 16);
        assert!((e - Vec3::new(1.0, 2.0, 3.0) * std::f32::consts::PI).abs().max_element() < 1e-3, "{e}");
    }
}
