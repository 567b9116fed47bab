//! Monte Carlo sampling helpers shared by the path tracer and the CPU models of the GI methods.

use std::f32::consts::{PI, TAU};

use bevy::math::{Vec2, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg32;

/// A seeded random number generator for one independent stream (a pixel, a hint, a light path).
/// Streams with different `(seed, stream)` pairs are independent; the same pair always repeats.
pub fn rng_for(seed: u64, stream: u64) -> Pcg32 {
    // SplitMix64 finaliser: decorrelates neighbouring stream indices before they seed PCG.
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    Pcg32::seed_from_u64(z)
}

/// Owen-scrambled Sobol samples for one pixel (or any stream), padded per path vertex: vertex `k` of sample
/// `i` draws the 4D point `i` of a sequence seeded by `(stream, k)`. Within a vertex the samples of one
/// stream are stratified in all four dimensions; across vertices they are independent (padding), which
/// keeps the estimator unbiased however long the path. Supports any sample count (2¹⁶ per sequence,
/// further blocks get fresh seeds).
#[derive(Clone, Copy, Debug)]
pub struct SobolStream {
    seed: u32,
}

impl SobolStream {
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut z = seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        z = (z ^ (z >> 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        Self { seed: (z ^ (z >> 29)) as u32 }
    }

    /// The 4D point of sample `index` at path vertex `vertex`, each coordinate in `[0, 1)`.
    #[inline]
    pub fn vertex_4d(&self, index: u32, vertex: u32) -> [f32; 4] {
        let block = index >> 16;
        let seed = self
            .seed
            .wrapping_add(vertex.wrapping_mul(0x68E3_1DA4))
            .wrapping_add(block.wrapping_mul(0xB529_7A4D));
        sobol_burley::sample_4d(index & 0xFFFF, 0, seed)
    }
}

/// A uniform sample in `[0, 1)²`.
#[inline]
pub fn uniform2(rng: &mut Pcg32) -> Vec2 {
    Vec2::new(rng.random::<f32>(), rng.random::<f32>())
}

/// An orthonormal basis `(t, b)` around unit `n` (Duff et al. 2017, "Building an Orthonormal Basis,
/// Revisited"): continuous everywhere and branch-free apart from the sign.
#[inline]
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// A cosine-weighted direction in the hemisphere around unit `n`, from `u ∈ [0,1)²`.
/// Its density is `cos θ / π`.
#[inline]
pub fn cosine_hemisphere(n: Vec3, u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let phi = TAU * u.y;
    let (t, b) = orthonormal_basis(n);
    let z = (1.0 - u.x).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

/// A uniform direction on the unit sphere from `u ∈ [0,1)²`. Its density is `1 / 4π`.
#[inline]
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = TAU * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Point `i` of `n` of the spherical Fibonacci lattice: unit directions spread evenly over the sphere
/// (each stands for the solid angle `4π / n`), the same set for the same `n`.
#[inline]
pub fn fibonacci_sphere(i: u32, n: u32) -> Vec3 {
    // The golden angle, 2π (1 − 1/φ).
    const GOLDEN_ANGLE: f32 = 2.399_963_3;
    let n = n.max(1);
    let z = 1.0 - (2.0 * i as f32 + 1.0) / n as f32;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = GOLDEN_ANGLE * i as f32;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A uniform point in the unit ball from three uniforms.
#[inline]
pub fn uniform_ball(u: Vec3) -> Vec3 {
    uniform_sphere(Vec2::new(u.x, u.y)) * u.z.cbrt()
}

/// A uniform point in a triangle from `u ∈ [0,1)²`: the barycentric weights `(s, r)` of its second and
/// third vertices (the point is `a + (b − a) s + (c − a) r`), the unit square folded onto the triangle.
#[inline]
pub fn uniform_triangle(u: Vec2) -> Vec2 {
    if u.x + u.y > 1.0 { Vec2::new(1.0 - u.x, 1.0 - u.y) } else { u }
}

/// Density of [`cosine_hemisphere`] for a direction at `cos θ` from the normal.
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) / PI
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal_for_many_normals() {
        let mut rng = rng_for(1, 2);
        for _ in 0..1000 {
            let n = uniform_sphere(uniform2(&mut rng));
            let (t, b) = orthonormal_basis(n);
            for (x, y) in [(n, t), (n, b), (t, b)] {
                assert!(x.dot(y).abs() < 1e-5);
            }
            for v in [t, b] {
                assert!((v.length() - 1.0).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn cosine_hemisphere_has_the_right_mean_cosine() {
        // E[cos θ] under the density cos θ / π over the hemisphere is 2/3.
        let mut rng = rng_for(7, 0);
        let n = Vec3::new(0.3, -0.4, 0.866).normalize();
        let samples = 200_000;
        let mean: f64 = (0..samples)
            .map(|_| {
                let d = cosine_hemisphere(n, uniform2(&mut rng));
                assert!(d.dot(n) >= -1e-6);
                d.dot(n) as f64
            })
            .sum::<f64>()
            / samples as f64;
        assert!((mean - 2.0 / 3.0).abs() < 3e-3, "mean cosine {mean}");
    }

    #[test]
    fn sobol_stream_is_stratified_and_uniform() {
        // 256 points of one vertex: every 16×16 cell of the first two dimensions holds exactly one.
        let s = SobolStream::new(3, 17);
        let mut cells = [0u8; 256];
        let mut mean = 0.0;
        for i in 0..256 {
            let p = s.vertex_4d(i, 2);
            cells[(p[0] * 16.0) as usize * 16 + (p[1] * 16.0) as usize] += 1;
            mean += p[2] as f64 / 256.0;
            assert!(p.iter().all(|v| (0.0..1.0).contains(v)));
        }
        assert!(cells.iter().all(|&c| c == 1), "not stratified");
        assert!((mean - 0.5).abs() < 0.01);
        // Different vertices and streams give different points.
        assert_ne!(s.vertex_4d(5, 0), s.vertex_4d(5, 1));
        assert_ne!(s.vertex_4d(5, 0), SobolStream::new(3, 18).vertex_4d(5, 0));
        // Past 2^16 samples a new block starts, still in range.
        assert!(s.vertex_4d(70_000, 0).iter().all(|v| (0.0..1.0).contains(v)));
    }

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<f32> = (0..4).map(|_| rng_for(5, 9).random::<f32>()).collect();
        assert!(a.windows(2).all(|w| w[0] == w[1]));
        let mut x = rng_for(5, 9);
        let mut y = rng_for(5, 10);
        assert_ne!(x.random::<u64>(), y.random::<u64>());
    }
}
