//! Real spherical harmonics of order 2 (4 coefficients, bands l ≤ 1) and order 3 (9 coefficients, l ≤ 2),
//! the radiance encoding of Radiance Hints (Papaioannou 2011, §4–5).
//!
//! Coefficient `i = l(l+1) + m`: `[Y₀₀, Y₁₋₁, Y₁₀, Y₁₁, Y₂₋₂, Y₂₋₁, Y₂₀, Y₂₁, Y₂₂]` in the usual real basis
//! (Sloan, "Stupid Spherical Harmonics Tricks"), with `(x, y, z)` a unit direction. The WGSL side
//! (`shaders/radiance_hints/sh.wgsl`) uses the same order and constants; the tests here pin them.
//!
//! * Projection (paper Eq. 5): `L_lm = ∫ L(ω) Y_lm(ω) dω`, estimated as `Σ_k L_k ΔΩ_k Y_lm(ω_k)`.
//! * Irradiance (Eq. 6–7): the hemisphere integral `E(n) = ∫ L(ω) max(0, n·ω) dω` is the dot product of the
//!   radiance coefficients with the clamped-cosine lobe's, `H_n(l, m) = Â_l Y_lm(n)` with Ramamoorthi and
//!   Hanrahan's `Â₀ = π`, `Â₁ = 2π/3`, `Â₂ = π/4`. It is exact for radiance within the kept bands.

use bevy::math::Vec3;
use std::f32::consts::PI;

/// `1 / (2√π)`.
pub const Y00: f32 = 0.282_094_8;
/// `√3 / (2√π)`.
pub const Y1: f32 = 0.488_602_5;
/// `√15 / (2√π)`.
pub const Y2_XY: f32 = 1.092_548_5;
/// `√5 / (4√π)`.
pub const Y20: f32 = 0.315_391_57;
/// `√15 / (4√π)`.
pub const Y22: f32 = 0.546_274_2;

/// Clamped-cosine convolution weights per band: `Â₀ = π`, `Â₁ = 2π/3`, `Â₂ = π/4`.
pub const COSINE_LOBE: [f32; 3] = [PI, 2.0 * PI / 3.0, PI / 4.0];

/// The spherical-harmonics order: the number of bands kept.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, bevy::reflect::Reflect, serde::Serialize)]
pub enum ShOrder {
    /// Bands 0–1: 4 coefficients per colour channel (12 floats per hint).
    #[default]
    Two,
    /// Bands 0–2: 9 coefficients per colour channel (27 floats per hint).
    Three,
}

impl ShOrder {
    /// Coefficients per colour channel.
    pub const fn coefficients(self) -> usize {
        match self {
            ShOrder::Two => 4,
            ShOrder::Three => 9,
        }
    }

    /// Bands kept (2 or 3).
    pub const fn bands(self) -> u32 {
        match self {
            ShOrder::Two => 2,
            ShOrder::Three => 3,
        }
    }
}

/// The nine basis functions at unit direction `d`.
pub fn basis(d: Vec3) -> [f32; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        Y00,
        Y1 * y,
        Y1 * z,
        Y1 * x,
        Y2_XY * x * y,
        Y2_XY * y * z,
        Y20 * (3.0 * z * z - 1.0),
        Y2_XY * x * z,
        Y22 * (x * x - y * y),
    ]
}

/// The band of coefficient `i`.
pub const fn band(i: usize) -> usize {
    match i {
        0 => 0,
        1..=3 => 1,
        _ => 2,
    }
}

/// RGB spherical-harmonic coefficients (`coefficients[i]` is the RGB of basis function `i`); only the first
/// `order.coefficients()` are used.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ShRgb {
    pub order: ShOrder,
    pub coefficients: [Vec3; 9],
}

impl ShRgb {
    pub fn new(order: ShOrder) -> Self {
        Self {
            order,
            coefficients: [Vec3::ZERO; 9],
        }
    }

    /// Adds `value · Y(direction)`: one sample of the projection integral, `value` being radiance times
    /// the solid angle (or Monte Carlo weight) it stands for.
    pub fn add_sample(&mut self, direction: Vec3, value: Vec3) {
        let y = basis(direction);
        for i in 0..self.order.coefficients() {
            self.coefficients[i] += value * y[i];
        }
    }

    /// The encoded function at `direction`.
    pub fn evaluate(&self, direction: Vec3) -> Vec3 {
        let y = basis(direction);
        (0..self.order.coefficients()).fold(Vec3::ZERO, |acc, i| acc + self.coefficients[i] * y[i])
    }

    /// Irradiance `∫ L(ω) max(0, n·ω) dω` on a surface with unit normal `n`, for radiance `L` encoded here
    /// as a function of the direction light comes *from*.
    pub fn irradiance(&self, n: Vec3) -> Vec3 {
        let y = basis(n);
        (0..self.order.coefficients()).fold(Vec3::ZERO, |acc, i| {
            acc + self.coefficients[i] * (COSINE_LOBE[band(i)] * y[i])
        })
    }

    /// `self + other · weight`, coefficient-wise.
    pub fn add_scaled(&mut self, other: &ShRgb, weight: f32) {
        for i in 0..self.order.coefficients() {
            self.coefficients[i] += other.coefficients[i] * weight;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{rng_for, uniform_sphere, uniform2};

    /// Checks `a ≈ b` within an absolute plus relative tolerance, per component.
    #[track_caller]
    fn assert_vec_close(a: Vec3, b: Vec3, abs: f32, rel: f32) {
        let tol = abs + rel * b.abs().max_element();
        assert!((a - b).abs().max_element() <= tol, "{a} != {b} (tolerance {tol})");
    }

    /// Midpoint quadrature over the sphere in (cos θ, φ), which has equal-area cells.
    fn integrate_sphere(n: usize, mut f: impl FnMut(Vec3, f32)) {
        let d_omega = 4.0 * PI / (n * n) as f32;
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            for j in 0..n {
                let phi = 2.0 * PI * (j as f32 + 0.5) / n as f32;
                f(Vec3::new(r * phi.cos(), r * phi.sin(), z), d_omega);
            }
        }
    }

    #[test]
    fn basis_is_orthonormal() {
        let mut gram = [[0.0f64; 9]; 9];
        integrate_sphere(400, |d, w| {
            let y = basis(d);
            for i in 0..9 {
                for j in 0..9 {
                    gram[i][j] += (y[i] * y[j] * w) as f64;
                }
            }
        });
        for i in 0..9 {
            for j in 0..9 {
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!((gram[i][j] - expected).abs() < 2e-3, "<Y{i}, Y{j}> = {}", gram[i][j]);
            }
        }
    }

    #[test]
    fn projecting_a_band_limited_function_reconstructs_it() {
        // f(ω) = 1 + 2x − 0.5y + 0.75z + 0.6xy − 0.4(3z² − 1) lies in bands 0–2.
        let f = |d: Vec3| 1.0 + 2.0 * d.x - 0.5 * d.y + 0.75 * d.z + 0.6 * d.x * d.y - 0.4 * (3.0 * d.z * d.z - 1.0);
        let mut sh = ShRgb::new(ShOrder::Three);
        integrate_sphere(300, |d, w| sh.add_sample(d, Vec3::new(f(d), 2.0 * f(d), -f(d)) * w));
        let mut rng = rng_for(4, 4);
        for _ in 0..100 {
            let d = uniform_sphere(uniform2(&mut rng));
            assert_vec_close(sh.evaluate(d), Vec3::new(f(d), 2.0 * f(d), -f(d)), 2e-3, 2e-3);
        }
        // Order 2 keeps only bands 0–1: the linear part, exactly.
        let mut sh2 = ShRgb::new(ShOrder::Two);
        integrate_sphere(300, |d, w| sh2.add_sample(d, Vec3::splat(f(d)) * w));
        let linear = |d: Vec3| 1.0 + 2.0 * d.x - 0.5 * d.y + 0.75 * d.z;
        for _ in 0..100 {
            let d = uniform_sphere(uniform2(&mut rng));
            assert_vec_close(sh2.evaluate(d), Vec3::splat(linear(d)), 2e-3, 2e-3);
        }
    }

    #[test]
    fn irradiance_matches_numerical_hemisphere_integration() {
        // For radiance inside the kept bands, the cosine-lobe dot product is exact.
        let radiance = |d: Vec3| Vec3::new(2.0 + d.x + 0.5 * d.z * d.z, 1.0 - 0.3 * d.y + 0.8 * d.x * d.z, 0.7 + 0.2 * d.z);
        let mut sh = ShRgb::new(ShOrder::Three);
        integrate_sphere(400, |d, w| sh.add_sample(d, radiance(d) * w));
        let mut rng = rng_for(9, 1);
        for _ in 0..20 {
            let n = uniform_sphere(uniform2(&mut rng));
            let mut numeric = Vec3::ZERO;
            integrate_sphere(400, |d, w| numeric += radiance(d) * n.dot(d).max(0.0) * w);
            assert_vec_close(sh.irradiance(n), numeric, 1e-3, 3e-3);
        }
    }

    #[test]
    fn constant_radiance_gives_pi_irradiance_in_both_orders() {
        for order in [ShOrder::Two, ShOrder::Three] {
            let mut sh = ShRgb::new(order);
            integrate_sphere(200, |d, w| sh.add_sample(d, Vec3::ONE * w));
            let e = sh.irradiance(Vec3::new(0.0, 0.6, 0.8));
            assert_vec_close(e, Vec3::splat(PI), 1e-3, 1e-3);
        }
    }

    #[test]
    fn one_directional_source_irradiance_follows_the_cosine_roughly() {
        // A small source of solid angle ΔΩ and radiance L straight above: E(n) ≈ L ΔΩ max(0, cos).
        // SH order 3 reproduces the clamped cosine within its ringing: at the normal, E is within 10 %.
        let mut sh = ShRgb::new(ShOrder::Three);
        sh.add_sample(Vec3::Y, Vec3::splat(1.0));
        let head_on = sh.irradiance(Vec3::Y).x;
        assert!((head_on - 1.0).abs() < 0.1, "{head_on}");
        assert!(sh.irradiance(Vec3::NEG_Y).x.abs() < 0.1);
    }
}
