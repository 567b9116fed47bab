//! Linear HDR images: the common currency of the headless renderer, the path tracer and the metrics.
//!
//! Every image this crate writes is linear RGBA 32-bit float, stored *after* exposure and *before*
//! tonemapping (see `shared/METRICS.md`). The alpha channel is the pixel's geometry coverage: 1 where a
//! surface is seen, 0 for background. The metrics mask out pixels whose coverage is below one half.

use std::path::Path;

use image::{ImageBuffer, Rgba, Rgba32FImage};

/// Coverage below this value marks a background pixel, excluded from every metric.
pub const COVERAGE_THRESHOLD: f32 = 0.5;

/// A linear, exposure-scaled RGBA float image. Row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct HdrImage {
    pub width: u32,
    pub height: u32,
    /// `width * height` texels, `[r, g, b, coverage]`.
    pub pixels: Vec<[f32; 4]>,
}

/// Why an image could not be read or written.
#[derive(Debug)]
pub enum HdrImageError {
    Io(std::path::PathBuf, String),
    Size { expected: (u32, u32), found: (u32, u32) },
}

impl std::fmt::Display for HdrImageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HdrImageError::Io(path, why) => write!(f, "{}: {why}", path.display()),
            HdrImageError::Size { expected, found } => write!(
                f,
                "image sizes differ: {}x{} and {}x{}",
                expected.0, expected.1, found.0, found.1
            ),
        }
    }
}

impl std::error::Error for HdrImageError {}

impl HdrImage {
    /// A black image with zero coverage.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 4]; width as usize * height as usize],
        }
    }

    /// An image with every pixel set to `value`.
    pub fn filled(width: u32, height: u32, value: [f32; 4]) -> Self {
        Self {
            width,
            height,
            pixels: vec![value; width as usize * height as usize],
        }
    }

    #[inline]
    pub fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> [f32; 4] {
        self.pixels[self.index(x, y)]
    }

    #[inline]
    pub fn set(&mut self, x: u32, y: u32, value: [f32; 4]) {
        let i = self.index(x, y);
        self.pixels[i] = value;
    }

    /// Whether the pixel sees geometry (coverage at or above [`COVERAGE_THRESHOLD`]).
    #[inline]
    pub fn covered(&self, i: usize) -> bool {
        self.pixels[i][3] >= COVERAGE_THRESHOLD
    }

    /// Mean RGB over a rectangle `[x0, x1) × [y0, y1)`, covered pixels only. `None` if none is covered.
    pub fn region_mean(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> Option<[f32; 3]> {
        let mut sum = [0.0f64; 3];
        let mut count = 0usize;
        for y in y0..y1.min(self.height) {
            for x in x0..x1.min(self.width) {
                let i = self.index(x, y);
                if self.covered(i) {
                    let p = self.pixels[i];
                    for c in 0..3 {
                        sum[c] += p[c] as f64;
                    }
                    count += 1;
                }
            }
        }
        (count > 0).then(|| {
            let n = count as f64;
            [(sum[0] / n) as f32, (sum[1] / n) as f32, (sum[2] / n) as f32]
        })
    }

    /// Whether any RGB value is NaN or infinite.
    pub fn has_non_finite(&self) -> bool {
        self.pixels.iter().any(|p| p[..3].iter().any(|v| !v.is_finite()))
    }

    /// Texel-wise weighted sum `Σ wᵢ · imageᵢ` (coverage is averaged with the same weights). All images must
    /// have the same size. Used to average path-traced renders of different seeds.
    pub fn weighted_sum(images: &[(&HdrImage, f32)]) -> Result<HdrImage, HdrImageError> {
        let Some((first, _)) = images.first() else {
            return Ok(HdrImage::new(0, 0));
        };
        let mut out = HdrImage::new(first.width, first.height);
        for (image, weight) in images {
            check_same_size(first, image)?;
            for (o, p) in out.pixels.iter_mut().zip(&image.pixels) {
                for c in 0..4 {
                    o[c] += weight * p[c];
                }
            }
        }
        Ok(out)
    }

    /// The texel-wise mean of `images` (all the same size): the average of path-traced renders of
    /// different seeds.
    pub fn average(images: &[&HdrImage]) -> Result<HdrImage, HdrImageError> {
        let weight = 1.0 / images.len().max(1) as f32;
        Self::weighted_sum(&images.iter().map(|image| (*image, weight)).collect::<Vec<_>>())
    }

    /// Per-pixel `self − other` on RGB, keeping `self`'s coverage.
    pub fn subtract(&self, other: &HdrImage) -> Result<HdrImage, HdrImageError> {
        check_same_size(self, other)?;
        let mut out = self.clone();
        for (o, p) in out.pixels.iter_mut().zip(&other.pixels) {
            for c in 0..3 {
                o[c] -= p[c];
            }
        }
        Ok(out)
    }

    /// Reads an OpenEXR (or any float format `image` knows) as linear RGBA. Images without alpha get
    /// coverage 1 everywhere.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, HdrImageError> {
        let path = path.as_ref();
        let image = image::open(path).map_err(|e| HdrImageError::Io(path.to_owned(), e.to_string()))?;
        let has_alpha = image.color().has_alpha();
        let rgba = image.into_rgba32f();
        let (width, height) = rgba.dimensions();
        let pixels = rgba
            .pixels()
            .map(|p| [p[0], p[1], p[2], if has_alpha { p[3] } else { 1.0 }])
            .collect();
        Ok(Self { width, height, pixels })
    }

    /// Writes a 32-bit float RGBA OpenEXR file, creating parent directories.
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<(), HdrImageError> {
        let path = path.as_ref();
        create_parent(path)?;
        let flat: Vec<f32> = self.pixels.iter().flatten().copied().collect();
        let buffer: Rgba32FImage = ImageBuffer::<Rgba<f32>, _>::from_raw(self.width, self.height, flat)
            .expect("pixel count matches the image size");
        buffer
            .save_with_format(path, image::ImageFormat::OpenExr)
            .map_err(|e| HdrImageError::Io(path.to_owned(), e.to_string()))
    }

    /// An 8-bit sRGB image after Reinhard tonemapping `x / (1 + x)` of `scale · rgb`, for looking at.
    pub fn tonemapped(&self, scale: f32) -> image::RgbImage {
        let mut out = image::RgbImage::new(self.width, self.height);
        for (o, p) in out.pixels_mut().zip(&self.pixels) {
            for c in 0..3 {
                let v = (p[c] * scale).max(0.0);
                let v = if v.is_finite() { v / (1.0 + v) } else { 1.0 };
                o[c] = (linear_to_srgb(v) * 255.0 + 0.5) as u8;
            }
        }
        out
    }

    /// Writes [`Self::tonemapped`] as a PNG.
    pub fn write_png_tonemapped(&self, path: impl AsRef<Path>, scale: f32) -> Result<(), HdrImageError> {
        let path = path.as_ref();
        create_parent(path)?;
        self.tonemapped(scale).save(path).map_err(|e| HdrImageError::Io(path.to_owned(), e.to_string()))
    }
}

pub(crate) fn check_same_size(a: &HdrImage, b: &HdrImage) -> Result<(), HdrImageError> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(HdrImageError::Size {
            expected: (a.width, a.height),
            found: (b.width, b.height),
        });
    }
    Ok(())
}

fn create_parent(path: &Path) -> Result<(), HdrImageError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| HdrImageError::Io(parent.to_owned(), e.to_string()))?;
    }
    Ok(())
}

/// The sRGB transfer function for a linear value in `[0, 1]`.
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trip_keeps_values_and_coverage() {
        let mut image = HdrImage::new(5, 3);
        image.set(1, 2, [1.5, 1e-4, 300.0, 1.0]);
        image.set(4, 0, [0.25, 0.5, 0.75, 0.0]);
        let dir = std::env::temp_dir().join(format!("bdgi-exr-{}", std::process::id()));
        let path = dir.join("round_trip.exr");
        image.write_exr(&path).unwrap();
        let back = HdrImage::read(&path).unwrap();
        assert_eq!(back, image);
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn region_mean_ignores_background() {
        let mut image = HdrImage::new(2, 1);
        image.set(0, 0, [2.0, 4.0, 6.0, 1.0]);
        image.set(1, 0, [100.0, 100.0, 100.0, 0.0]);
        assert_eq!(image.region_mean(0, 0, 2, 1), Some([2.0, 4.0, 6.0]));
        assert_eq!(image.region_mean(1, 0, 2, 1), None);
    }
}
