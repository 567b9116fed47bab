//! Error metrics of an image against a ground truth, exactly as `shared/METRICS.md` defines them.
//!
//! With `a` the method's image, `r` the ground truth, pixels `i` in the mask (both images cover geometry
//! there, see [`crate::hdr_image::COVERAGE_THRESHOLD`]) and channels `c` in RGB:
//!
//! * relative RMSE = `sqrt(mean_i mean_c (a_ic − r_ic)²) / mean_i mean_c r_ic`
//! * block relative RMSE: the same over the means of 4×4 pixel blocks that lie wholly in the mask. This is
//!   the headline number: diffuse GI is low-frequency, and it does not measure the ground truth's own
//!   per-pixel noise.
//! * energy ratio = `Σ a / Σ r` over the mask (1.0 = no overall bias).
//! * FLIP (feature `flip`): the mean FLIP error over the mask of both images tonemapped the same way
//!   (Reinhard, same scale).

use crate::hdr_image::{HdrImage, HdrImageError, check_same_size};

/// Side of the square pixel blocks of [`ErrorMetrics::block_relative_rmse`].
pub const BLOCK_SIZE: u32 = 4;

/// The numbers that compare an image with its ground truth.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorMetrics {
    /// Per-pixel relative RMSE.
    pub relative_rmse: f64,
    /// Relative RMSE of 4×4 block means (the headline number).
    pub block_relative_rmse: f64,
    /// `Σ a / Σ r`.
    pub energy_ratio: f64,
    /// Mean FLIP error in `[0, 1]`, when computed.
    pub flip: Option<f64>,
    /// Pixels in the mask.
    pub pixels: usize,
    /// Blocks wholly inside the mask.
    pub blocks: usize,
    /// Share of those blocks whose mean (summed over RGB) is more than 50 % off the truth's: how much of
    /// the image is visibly wrong, whatever the average error.
    pub blocks_over_half_off: f64,
}

/// A block is "off" when its mean differs from the truth's by more than this fraction of the truth's.
pub const BLOCK_OFF_TOLERANCE: f64 = 0.5;

/// Why two images cannot be compared.
#[derive(Debug)]
pub enum MetricsError {
    Image(HdrImageError),
    /// No pixel is covered in both images, or the ground truth is zero everywhere in the mask.
    EmptyMask,
}

impl std::fmt::Display for MetricsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MetricsError::Image(e) => e.fmt(f),
            MetricsError::EmptyMask => write!(
                f,
                "nothing to compare: no pixel sees geometry in both images, or the reference is black there"
            ),
        }
    }
}

impl std::error::Error for MetricsError {}

impl From<HdrImageError> for MetricsError {
    fn from(e: HdrImageError) -> Self {
        MetricsError::Image(e)
    }
}

/// The comparison mask: pixels that see geometry in both images.
pub fn mask(a: &HdrImage, r: &HdrImage) -> Result<Vec<bool>, MetricsError> {
    check_same_size(a, r)?;
    Ok((0..a.pixels.len()).map(|i| a.covered(i) && r.covered(i)).collect())
}

/// Relative RMSE of `values` against `reference` (each `[r, g, b]`).
fn relative_rmse(values: &[[f64; 3]], reference: &[[f64; 3]]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let n = (values.len() * 3) as f64;
    let mut squared = 0.0;
    let mut sum_r = 0.0;
    for (a, r) in values.iter().zip(reference) {
        for c in 0..3 {
            squared += (a[c] - r[c]).powi(2);
            sum_r += r[c];
        }
    }
    let mean_r = sum_r / n;
    (mean_r > 0.0).then(|| (squared / n).sqrt() / mean_r)
}

/// Compares `a` (the method) with `r` (the ground truth). FLIP is not computed; see `compare_with_flip` (feature `flip`).
pub fn compare(a: &HdrImage, r: &HdrImage) -> Result<ErrorMetrics, MetricsError> {
    let mask = mask(a, r)?;
    let rgb = |p: [f32; 4]| [p[0] as f64, p[1] as f64, p[2] as f64];

    let mut pa = Vec::new();
    let mut pr = Vec::new();
    let (mut sum_a, mut sum_r) = (0.0, 0.0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (va, vr) = (rgb(a.pixels[i]), rgb(r.pixels[i]));
        sum_a += va.iter().sum::<f64>();
        sum_r += vr.iter().sum::<f64>();
        pa.push(va);
        pr.push(vr);
    }

    let mut ba = Vec::new();
    let mut br = Vec::new();
    for by in 0..a.height / BLOCK_SIZE {
        for bx in 0..a.width / BLOCK_SIZE {
            let mut ma = [0.0; 3];
            let mut mr = [0.0; 3];
            let mut whole = true;
            'block: for y in by * BLOCK_SIZE..(by + 1) * BLOCK_SIZE {
                for x in bx * BLOCK_SIZE..(bx + 1) * BLOCK_SIZE {
                    let i = a.index(x, y);
                    if !mask[i] {
                        whole = false;
                        break 'block;
                    }
                    let (va, vr) = (rgb(a.pixels[i]), rgb(r.pixels[i]));
                    for c in 0..3 {
                        ma[c] += va[c];
                        mr[c] += vr[c];
                    }
                }
            }
            if whole {
                let n = (BLOCK_SIZE * BLOCK_SIZE) as f64;
                ba.push(ma.map(|v| v / n));
                br.push(mr.map(|v| v / n));
            }
        }
    }

    let relative = relative_rmse(&pa, &pr).ok_or(MetricsError::EmptyMask)?;
    let block = relative_rmse(&ba, &br).ok_or(MetricsError::EmptyMask)?;
    let off = ba
        .iter()
        .zip(&br)
        .filter(|(a, r)| {
            let (sa, sr) = (a.iter().sum::<f64>(), r.iter().sum::<f64>());
            (sa - sr).abs() > BLOCK_OFF_TOLERANCE * sr
        })
        .count();
    Ok(ErrorMetrics {
        relative_rmse: relative,
        block_relative_rmse: block,
        energy_ratio: sum_a / sum_r,
        flip: None,
        pixels: pa.len(),
        blocks: ba.len(),
        blocks_over_half_off: off as f64 / ba.len().max(1) as f64,
    })
}

/// [`compare`] plus the mean FLIP error over the mask, both images Reinhard-tonemapped after scaling by
/// `tonemap_scale` (use the same value for every method of a scene).
#[cfg(feature = "flip")]
pub fn compare_with_flip(a: &HdrImage, r: &HdrImage, tonemap_scale: f32) -> Result<ErrorMetrics, MetricsError> {
    let mut metrics = compare(a, r)?;
    let map = flip_error_map(a, r, tonemap_scale)?;
    let mask = mask(a, r)?;
    let (sum, count) = map
        .iter()
        .zip(&mask)
        .filter(|(_, m)| **m)
        .fold((0.0f64, 0usize), |(s, n), (v, _)| (s + *v as f64, n + 1));
    metrics.flip = (count > 0).then(|| sum / count as f64);
    Ok(metrics)
}

/// The per-pixel FLIP error map (values in `[0, 1]`).
#[cfg(feature = "flip")]
pub fn flip_error_map(a: &HdrImage, r: &HdrImage, tonemap_scale: f32) -> Result<Vec<f32>, MetricsError> {
    check_same_size(a, r)?;
    let to_ldr = |image: &HdrImage| {
        let bytes: Vec<u8> = image
            .pixels
            .iter()
            .flat_map(|p| {
                [0, 1, 2].map(|c| {
                    let v = (p[c] * tonemap_scale).max(0.0);
                    let v = if v.is_finite() { v / (1.0 + v) } else { 1.0 };
                    (crate::hdr_image::linear_to_srgb(v) * 255.0 + 0.5) as u8
                })
            })
            .collect();
        nv_flip::FlipImageRgb8::with_data(image.width, image.height, &bytes)
    };
    let map = nv_flip::flip(to_ldr(r), to_ldr(a), nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    Ok(map.to_vec())
}

/// A false-colour picture of the per-pixel error `|a − r|` (mean over RGB), divided by the mean of the
/// reference over the mask: black = 0, then blue, green, yellow, red at ≥ `full_scale` (e.g. 1.0 = an
/// error as large as the average reference value). Background pixels are grey.
pub fn difference_image(a: &HdrImage, r: &HdrImage, full_scale: f32) -> Result<image::RgbImage, MetricsError> {
    let mask = mask(a, r)?;
    let (sum, count) = mask
        .iter()
        .enumerate()
        .filter(|(_, m)| **m)
        .fold((0.0f64, 0usize), |(s, n), (i, _)| {
            (s + r.pixels[i][..3].iter().map(|v| *v as f64).sum::<f64>() / 3.0, n + 1)
        });
    let mean_r = if count > 0 { (sum / count as f64) as f32 } else { 1.0 };
    let mut out = image::RgbImage::new(a.width, a.height);
    for (i, px) in out.pixels_mut().enumerate() {
        if !mask[i] {
            *px = image::Rgb([64, 64, 64]);
            continue;
        }
        let err = (0..3).map(|c| (a.pixels[i][c] - r.pixels[i][c]).abs()).sum::<f32>() / 3.0;
        let t = if mean_r > 0.0 { err / mean_r / full_scale.max(1e-6) } else { 0.0 };
        *px = image::Rgb(false_colour(t));
    }
    Ok(out)
}

/// Maps `t ∈ [0, 1]` (clamped; NaN maps to magenta) to black → blue → green → yellow → red.
pub fn false_colour(t: f32) -> [u8; 3] {
    if t.is_nan() {
        return [255, 0, 255];
    }
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 0.0],
        [0.0, 0.2, 1.0],
        [0.0, 0.9, 0.3],
        [1.0, 0.9, 0.0],
        [1.0, 0.0, 0.0],
    ];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    let mut out = [0u8; 3];
    for c in 0..3 {
        out[c] = ((STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f) * 255.0 + 0.5) as u8;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_close(a: f64, b: f64, tol: f64) {
        assert!((a - b).abs() <= tol, "{a} != {b} (tolerance {tol})");
    }

    #[test]
    fn identical_images_have_zero_error_and_unit_energy() {
        let r = HdrImage::filled(8, 8, [1.0, 2.0, 3.0, 1.0]);
        let m = compare(&r, &r).unwrap();
        assert_eq!(m.relative_rmse, 0.0);
        assert_eq!(m.block_relative_rmse, 0.0);
        assert_close(m.energy_ratio, 1.0, 1e-12);
        assert_eq!((m.pixels, m.blocks), (64, 4));
    }

    #[test]
    fn uniform_scale_gives_known_numbers() {
        // a = 1.5 r everywhere: every error is 0.5 r, so relative RMSE = 0.5 (per pixel and per block)
        // and the energy ratio is 1.5.
        let r = HdrImage::filled(8, 8, [2.0, 2.0, 2.0, 1.0]);
        let a = HdrImage::filled(8, 8, [3.0, 3.0, 3.0, 1.0]);
        let m = compare(&a, &r).unwrap();
        assert_close(m.relative_rmse, 0.5, 1e-12);
        assert_close(m.block_relative_rmse, 0.5, 1e-12);
        assert_close(m.energy_ratio, 1.5, 1e-12);
    }

    #[test]
    fn blocks_more_than_half_off_are_counted() {
        // One 4×4 block of four at 1.6× the truth (60 % off), one at 1.4× (within 50 %), two exact.
        let r = HdrImage::filled(8, 8, [1.0, 1.0, 1.0, 1.0]);
        let mut a = r.clone();
        for y in 0..4 {
            for x in 0..8 {
                let v = if x < 4 { 1.6 } else { 1.4 };
                a.set(x, y, [v, v, v, 1.0]);
            }
        }
        let m = compare(&a, &r).unwrap();
        assert_close(m.blocks_over_half_off, 0.25, 1e-12);
        assert_eq!(compare(&r, &r).unwrap().blocks_over_half_off, 0.0);
    }

    #[test]
    fn zero_mean_noise_vanishes_in_blocks_but_not_per_pixel() {
        // A checkerboard ±1 around a constant 4: per-pixel relative RMSE = 1/4, block means are exact.
        let r = HdrImage::filled(8, 8, [4.0, 4.0, 4.0, 1.0]);
        let mut a = r.clone();
        for y in 0..8 {
            for x in 0..8 {
                let v = if (x + y) % 2 == 0 { 5.0 } else { 3.0 };
                a.set(x, y, [v, v, v, 1.0]);
            }
        }
        let m = compare(&a, &r).unwrap();
        assert_close(m.relative_rmse, 0.25, 1e-12);
        assert_close(m.block_relative_rmse, 0.0, 1e-12);
        assert_close(m.energy_ratio, 1.0, 1e-12);
    }

    #[test]
    fn background_is_masked_and_partial_blocks_dropped() {
        // Left half covered with an error of 1 on a reference of 1; the right half is background with a
        // huge error that must not count. One 4×4 block straddles the edge and must be dropped.
        let mut r = HdrImage::new(12, 4);
        let mut a = HdrImage::new(12, 4);
        for y in 0..4 {
            for x in 0..12 {
                let covered = x < 6;
                r.set(x, y, [1.0, 1.0, 1.0, if covered { 1.0 } else { 0.0 }]);
                a.set(x, y, if covered { [2.0, 2.0, 2.0, 1.0] } else { [1e6, 1e6, 1e6, 1.0] });
            }
        }
        let m = compare(&a, &r).unwrap();
        assert_eq!((m.pixels, m.blocks), (24, 1));
        assert_close(m.relative_rmse, 1.0, 1e-12);
        assert_close(m.block_relative_rmse, 1.0, 1e-12);
        assert_close(m.energy_ratio, 2.0, 1e-12);
    }

    #[test]
    fn per_channel_error_is_averaged_over_channels() {
        // Only red is wrong by 3 on a reference of 1: RMSE = sqrt(9/3) = sqrt(3), mean r = 1.
        let r = HdrImage::filled(4, 4, [1.0, 1.0, 1.0, 1.0]);
        let a = HdrImage::filled(4, 4, [4.0, 1.0, 1.0, 1.0]);
        let m = compare(&a, &r).unwrap();
        assert_close(m.relative_rmse, 3f64.sqrt(), 1e-12);
        assert_close(m.energy_ratio, 6.0 / 3.0, 1e-12);
    }

    #[test]
    fn empty_mask_and_size_mismatch_are_errors() {
        let r = HdrImage::new(4, 4);
        assert!(matches!(compare(&r, &r), Err(MetricsError::EmptyMask)));
        let black = HdrImage::filled(4, 4, [0.0, 0.0, 0.0, 1.0]);
        assert!(matches!(compare(&black, &black), Err(MetricsError::EmptyMask)));
        let other = HdrImage::new(4, 8);
        assert!(matches!(compare(&r, &other), Err(MetricsError::Image(_))));
    }

    #[test]
    fn false_colour_endpoints() {
        assert_eq!(false_colour(0.0), [0, 0, 0]);
        assert_eq!(false_colour(1.0), [255, 0, 0]);
        assert_eq!(false_colour(7.0), [255, 0, 0]);
        assert_eq!(false_colour(f32::NAN), [255, 0, 255]);
    }

    #[cfg(feature = "flip")]
    #[test]
    fn flip_is_zero_for_identical_and_positive_for_different() {
        let r = HdrImage::filled(16, 16, [1.0, 0.5, 0.25, 1.0]);
        let same = compare_with_flip(&r, &r, 1.0).unwrap();
        assert!(same.flip.unwrap() < 1e-6);
        let a = HdrImage::filled(16, 16, [0.1, 0.5, 2.0, 1.0]);
        let diff = compare_with_flip(&a, &r, 1.0).unwrap();
        assert!(diff.flip.unwrap() > 0.05);
    }
}
