//! Emissive surfaces as light sources: the scene snapshot's emissive triangles, sampled into point emitters
//! (position, normal, flux) that the GI methods inject like the texels of a reflective shadow map.
//!
//! Bevy renders an emissive `StandardMaterial` as a glowing surface but casts no light from it: a room lit
//! only by a glowing panel (Bevy's own Cornell box asset is lit that way) is black apart from the panel.
//! Every emitted photon that reaches another surface is therefore light the GI has to add, and the
//! ground-truth tracer counts it with the indirect light ([`crate::reference`]).
//!
//! # Sampling
//! A Lambertian emitter of radiance `L_e` and area `A` emits the flux `Φ = π L_e A` (the same quantity as
//! an RSM texel's reflected flux `ρΦ_T`, Eq. 4 of Dachsbacher & Stamminger), so a point sample of flux `Φ_k`
//! at `x_k` with normal `n_k` sends `Φ_k max(0, n_k·ω) / (π d²)` towards a receiver at distance `d`: the
//! injection of Radiance Hints (§4, Eq. 3–5 of Papaioannou 2011) applies unchanged. [`MAX_EMITTER_SAMPLES`]
//! samples are spread over the emissive triangles in proportion to their power (stratified over the
//! cumulative power, uniform by area inside each triangle); each carries `Φ_total / N` in its brightest
//! channel and the triangle's colour in the others, which keeps the estimator unbiased for any mix of
//! colours and sizes. Emitters are two-sided, as the tracer's are, except where a face looks into its own
//! closed mesh ([`MeshGeometry::open_sides`](crate::scene::MeshGeometry::open_sides)): the inside of a
//! glowing box. The tracer never lets that light out; a method whose visibility is coarser than the box
//! (Radiance Hints' voxels) would let the top face's inside light the room below as brightly as the
//! bottom face (a room lit by a glowing ceiling box got 2.1–2.3 × its light), so such samples carry
//! only their open face (`GpuEmitter::normal`'s w), and a triangle closed on both sides none.
//!
//! # Cost
//! Regenerated only when the snapshot's geometry or materials change, and then only the instances whose
//! material emits are visited: O(instances + emissive triangles + samples) on the main thread; a change
//! that leaves the samples as they were (another mesh moved) is not passed on. Scenes without emissive
//! materials get an empty set, and the methods skip their emitter pass.
//!
//! # Known issues
//! * Emissive textures are not read (the emitter's colour is `emissive` alone), as in the tracer.
//! * `emissive.alpha < 1` (exposure-scaled emission) is evaluated at the exposure of the first camera with
//!   [`DiffuseGi`](crate::camera::DiffuseGi).

use std::sync::Arc;

use bevy::camera::Exposure;
use bevy::prelude::*;
use bevy::render::extract_resource::{ExtractResource, ExtractResourcePlugin};
use bevy::render::render_resource::ShaderType;

use crate::camera::DiffuseGi;
use crate::scene::{OPEN_BACK, OPEN_FRONT, SceneSnapshot, SceneSnapshotSystems, triangle_area};

/// Samples drawn over all emissive surfaces of the scene.
pub const MAX_EMITTER_SAMPLES: usize = 4096;

/// One point emitter as the passes see it (`Emitter` in `shaders/rsm/rsm_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct GpuEmitter {
    /// World position (xyz), w unused.
    pub position: Vec4,
    /// Unit geometric normal of the emitting triangle (xyz), turned towards its open face when only one
    /// is; w: the faces that emit, 2 (both) or 1 (the one the normal points to: the other lies inside
    /// the closed mesh, [`crate::scene::MeshGeometry::open_sides`]).
    pub normal: Vec4,
    /// Flux in lumens per channel (rgb) carried by this sample.
    pub flux: Vec4,
}

/// The scene's emitters, sampled from the [`SceneSnapshot`] (see the [module docs](self)).
#[derive(Resource, Clone, Debug, Default, ExtractResource)]
pub struct EmitterSamples {
    /// Bumped whenever the samples change.
    pub generation: u64,
    pub samples: Arc<Vec<GpuEmitter>>,
    /// Total flux leaving the emitters' open faces, in lumens of the brightest channel (the measure the
    /// RSM lights use to share samples between them).
    pub power: f32,
    /// What the samples were drawn from: snapshot geometry generation and exposure.
    key: (u64, u32),
}

/// Keeps [`EmitterSamples`] up to date. Added by [`crate::DiffuseGiPlugin`].
pub struct EmittersPlugin;

impl Plugin for EmittersPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<EmitterSamples>()
            .add_plugins(ExtractResourcePlugin::<EmitterSamples>::default())
            .add_systems(
                PostUpdate,
                update_emitters.after(SceneSnapshotSystems::Update).run_if(resource_exists::<SceneSnapshot>),
            );
    }
}

pub(crate) fn update_emitters(
    snapshot: Res<SceneSnapshot>,
    cameras: Query<(&Camera, Option<&Exposure>), With<DiffuseGi>>,
    mut emitters: ResMut<EmitterSamples>,
) {
    let exposure = cameras
        .iter()
        .find(|(camera, _)| camera.is_active)
        .map_or(Exposure::default().exposure(), |(_, e)| e.copied().unwrap_or_default().exposure());
    let key = (snapshot.geometry_generation, exposure.to_bits());
    if emitters.key == key {
        return;
    }
    let (samples, power) = sample_emitters(&snapshot, exposure, MAX_EMITTER_SAMPLES);
    // The same set (no emitters, or a change that moved only other meshes): no change to report, so
    // the volumes do not update for it.
    if *emitters.samples == samples {
        emitters.key = key;
        return;
    }
    let generation = emitters.generation + 1;
    *emitters = EmitterSamples {
        generation,
        samples: Arc::new(samples),
        power,
        key,
    };
}

/// Draws `count` point emitters over the emissive triangles of `snapshot` for a camera of `exposure`,
/// and returns them with the total power leaving their open faces (see the [module docs](self)). Empty
/// without emitters.
pub fn sample_emitters(snapshot: &SceneSnapshot, exposure: f32, count: usize) -> (Vec<GpuEmitter>, f32) {
    // (triangle vertices, normal and open faces, radiance, power of one face) of every emissive triangle.
    let mut triangles: Vec<([Vec3; 3], Vec4, Vec3, f32)> = Vec::new();
    for instance in snapshot.instances() {
        let Some(material) = snapshot.materials.get(instance.material as usize) else {
            continue;
        };
        let radiance = material.emission(exposure);
        if !radiance.is_finite() || radiance.max_element() <= 0.0 {
            continue;
        }
        for i in 0..instance.triangle_count() {
            let v = instance.triangle(i);
            let area = triangle_area(&v);
            let normal = (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero();
            // A face inside its own closed mesh (the top of a glowing box seen from below, through the
            // box) emits nothing that leaves it; the sample's normal points to its one open face.
            let (normal, sides) = match instance.open_sides(i) {
                s if s == OPEN_FRONT | OPEN_BACK => (normal, 2.0),
                OPEN_FRONT => (normal, 1.0),
                OPEN_BACK => (-normal, 1.0),
                _ => continue,
            };
            if area > 0.0 && normal != Vec3::ZERO {
                triangles.push((v, normal.extend(sides), radiance, std::f32::consts::PI * radiance.max_element() * area));
            }
        }
    }
    let total: f64 = triangles.iter().map(|t| t.3 as f64).sum();
    if triangles.is_empty() || total.is_nan() || total <= 0.0 || count == 0 {
        return (Vec::new(), 0.0);
    }
    let per_sample = (total / count as f64) as f32;
    let mut samples = Vec::with_capacity(count);
    let mut cumulative = 0.0f64;
    let mut t = 0;
    for k in 0..count {
        // Stratified over the cumulative power: sample k lands in the triangle holding (k + ½)/N of it.
        let target = (k as f64 + 0.5) / count as f64 * total;
        while t + 1 < triangles.len() && cumulative + triangles[t].3 as f64 <= target {
            cumulative += triangles[t].3 as f64;
            t += 1;
        }
        let (v, normal, radiance, _) = triangles[t];
        // A uniform point in the triangle from the R2 sequence (Roberts 2018).
        let u = Vec2::new((0.5 + 0.754_877_7 * k as f32).fract(), (0.5 + 0.569_840_3 * k as f32).fract());
        let Vec2 { x: a, y: b } = crate::sampling::uniform_triangle(u);
        let position = v[0] + a * (v[1] - v[0]) + b * (v[2] - v[0]);
        let colour = radiance / radiance.max_element();
        samples.push(GpuEmitter {
            position: position.extend(1.0),
            normal,
            flux: (colour * per_sample).extend(0.0),
        });
    }
    // What leaves the open faces: twice a face's flux where both are open.
    let emitted: f64 = triangles.iter().map(|t| t.3 as f64 * t.1.w as f64).sum();
    (samples, emitted as f32)
}

/// Irradiance (lux) at a point from a Lambertian rectangle of radiance `radiance` in a plane parallel to
/// the receiver's and facing it, at height `height` above it; the rectangle spans `[x0, x1] × [z0, z1]`
/// in the plane's coordinates, measured from the foot of the receiver. The closed form `E = π L F` with
/// the differential-area-to-parallel-rectangle form factor of a rectangle with a corner over the point
/// (Howell's catalogue, B-3), `F = 1/2π [A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²) atan(A/√(1+B²))]`,
/// `A = a/h`, `B = b/h`, summed with signs over the four corner rectangles.
///
/// The ground truth's tracer and every method's injection of emissive surfaces are checked against it,
/// so that an error in the shared emission lookups cannot cancel between the truth and the methods.
pub fn parallel_rectangle_irradiance(radiance: f32, height: f32, [x0, x1]: [f32; 2], [z0, z1]: [f32; 2]) -> f32 {
    let h = height.abs().max(1e-12);
    let corner = |x: f32, z: f32| {
        let (a, b) = (x.abs() / h, z.abs() / h);
        let (sa, sb) = ((1.0 + a * a).sqrt(), (1.0 + b * b).sqrt());
        let f = (a / sa * (b / sa).atan() + b / sb * (a / sb).atan()) / (2.0 * std::f32::consts::PI);
        f * x.signum() * z.signum()
    };
    let form_factor = corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0);
    std::f32::consts::PI * radiance * form_factor
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{InputTriangle, SnapshotMaterial};

    fn quad(y: f32, size: f32, material: u32) -> [InputTriangle; 2] {
        let h = size / 2.0;
        let (a, b, c, d) = (Vec3::new(-h, y, -h), Vec3::new(h, y, -h), Vec3::new(h, y, h), Vec3::new(-h, y, h));
        [InputTriangle::flat([a, c, b], material), InputTriangle::flat([a, d, c], material)]
    }

    #[test]
    fn samples_carry_the_emitted_flux_in_its_colour_and_lie_on_the_emitters() {
        let glow = SnapshotMaterial {
            emissive: Vec3::new(100.0, 50.0, 10.0),
            ..SnapshotMaterial::DEFAULT_GREY
        };
        let mut triangles = quad(1.0, 0.5, 1).to_vec();
        triangles.extend(quad(0.0, 2.0, 0));
        let snapshot = SceneSnapshot::build(triangles, vec![SnapshotMaterial::DEFAULT_GREY, glow], vec![], vec![]);
        let (samples, power) = sample_emitters(&snapshot, 1.0, 1000);
        assert_eq!(samples.len(), 1000);
        // Φ = π L A in the brightest channel, from each face of the sheet.
        let expected = 2.0 * std::f32::consts::PI * 100.0 * 0.25;
        assert!((power - expected).abs() < 1e-3 * expected, "{power} vs {expected}");
        let flux: Vec3 = samples.iter().map(|s| s.flux.truncate()).sum();
        let want = std::f32::consts::PI * Vec3::new(100.0, 50.0, 10.0) * 0.25;
        assert!((flux - want).abs().max_element() < 1e-3 * want.x, "{flux} vs {want}");
        for s in &samples {
            assert!((s.position.y - 1.0).abs() < 1e-5 && s.position.x.abs() <= 0.25 + 1e-5 && s.position.z.abs() <= 0.25 + 1e-5);
            assert!((s.normal.y.abs() - 1.0).abs() < 1e-5);
            assert_eq!(s.normal.w, 2.0, "a sheet emits from both faces");
        }
        // Uniform by area: as many samples in each half of the panel, within the stratification.
        let left = samples.iter().filter(|s| s.position.x < 0.0).count();
        assert!((left as i32 - 500).abs() < 40, "{left} of 1000 on the left half");
    }

    #[test]
    fn a_scene_without_emission_has_no_emitters() {
        let snapshot = SceneSnapshot::build(quad(0.0, 2.0, 0).to_vec(), vec![SnapshotMaterial::DEFAULT_GREY], vec![], vec![]);
        let (samples, power) = sample_emitters(&snapshot, 1.0, 64);
        assert!(samples.is_empty());
        assert_eq!(power, 0.0);
    }

    #[test]
    fn brighter_triangles_get_more_samples() {
        let dim = SnapshotMaterial { emissive: Vec3::splat(1.0), ..SnapshotMaterial::DEFAULT_GREY };
        let bright = SnapshotMaterial { emissive: Vec3::splat(3.0), ..SnapshotMaterial::DEFAULT_GREY };
        let mut triangles = quad(0.0, 1.0, 0).to_vec();
        triangles.extend(quad(2.0, 1.0, 1));
        let snapshot = SceneSnapshot::build(triangles, vec![dim, bright], vec![], vec![]);
        let (samples, _) = sample_emitters(&snapshot, 1.0, 400);
        let high = samples.iter().filter(|s| s.position.y > 1.0).count();
        assert_eq!(high, 300);
        // Every sample carries the same flux in its brightest channel.
        assert!(samples.iter().all(|s| (s.flux.x - samples[0].flux.x).abs() < 1e-4 * s.flux.x));
    }

    #[test]
    fn the_closed_form_covers_half_space_and_superposes() {
        // A plane without bounds: E = π L.
        let e = parallel_rectangle_irradiance(2.0, 1.0, [-1e5, 1e5], [-1e5, 1e5]);
        assert!((e - 2.0 * std::f32::consts::PI).abs() < 1e-3, "{e}");
        // Two halves of a rectangle add up to it, and a rectangle off to the side gives less than centred.
        let whole = parallel_rectangle_irradiance(1.0, 0.7, [-0.5, 0.8], [-0.3, 0.4]);
        let halves = parallel_rectangle_irradiance(1.0, 0.7, [-0.5, 0.1], [-0.3, 0.4])
            + parallel_rectangle_irradiance(1.0, 0.7, [0.1, 0.8], [-0.3, 0.4]);
        assert!((whole - halves).abs() < 1e-5 * whole, "{whole} vs {halves}");
        // Far away it is a point source: E ≈ L A / d² (head-on).
        let far = parallel_rectangle_irradiance(1.0, 100.0, [-0.5, 0.5], [-0.5, 0.5]);
        assert!((far - 1.0 / 1e4).abs() < 1e-3 * far, "{far}");
    }

    #[test]
    fn the_samples_give_a_panels_irradiance_on_a_parallel_plane() {
        // A 1 × 0.6 m panel 0.8 m over a floor: Σ Φ_k |n_k·ω| cos θ / (π d²) over the samples is the
        // point estimate every method that injects them makes (Radiance Hints' inject.wgsl).
        let le = Vec3::new(30.0, 20.0, 10.0);
        let glow = SnapshotMaterial { emissive: le, diffuse: Vec3::ZERO, ..SnapshotMaterial::DEFAULT_GREY };
        let (a, b, c, d) = (Vec3::new(-0.5, 0.8, -0.3), Vec3::new(0.5, 0.8, -0.3), Vec3::new(0.5, 0.8, 0.3), Vec3::new(-0.5, 0.8, 0.3));
        let triangles = vec![InputTriangle::flat([a, b, c], 0), InputTriangle::flat([a, c, d], 0)];
        let snapshot = SceneSnapshot::build(triangles, vec![glow], vec![], vec![]);
        let (samples, _) = sample_emitters(&snapshot, 1.0, MAX_EMITTER_SAMPLES);
        for p in [Vec3::ZERO, Vec3::new(0.4, 0.0, 0.1), Vec3::new(-1.2, 0.0, 0.9)] {
            let mut e = Vec3::ZERO;
            for s in &samples {
                let to = s.position.truncate() - p;
                let d2 = to.length_squared();
                let w = to.normalize();
                e += s.flux.truncate() * s.normal.truncate().dot(w).abs() * w.y.max(0.0) / (std::f32::consts::PI * d2);
            }
            for (channel, got) in [(le.x, e.x), (le.y, e.y), (le.z, e.z)] {
                let want = parallel_rectangle_irradiance(channel, 0.8, [-0.5 - p.x, 0.5 - p.x], [-0.3 - p.z, 0.3 - p.z]);
                assert!((got - want).abs() < 0.02 * want, "at {p}: {got} lx vs {want} lx");
            }
        }
    }

    /// The twelve triangles of Bevy's cuboid `lo..hi` (wound to face outwards).
    fn closed_box(lo: Vec3, hi: Vec3, material: u32) -> Vec<InputTriangle> {
        let mesh = Mesh::from(Cuboid::from_corners(lo, hi));
        crate::scene::mesh_triangles(&mesh, &GlobalTransform::from_translation((lo + hi) / 2.0), material).expect("mesh")
    }

    #[test]
    fn a_closed_glowing_box_emits_from_its_outside_only() {
        // A 1 × 0.02 × 0.6 m glowing box whose underside is 0.8 m over the floor, as a generated room's
        // ceiling light. Its faces' insides look into the box: every sample carries its outward face only.
        let le = Vec3::splat(40.0);
        let glow = SnapshotMaterial { emissive: le, diffuse: Vec3::ZERO, ..SnapshotMaterial::DEFAULT_GREY };
        let (lo, hi) = (Vec3::new(-0.5, 0.8, -0.3), Vec3::new(0.5, 0.82, 0.3));
        let mut triangles = closed_box(lo, hi, 1);
        triangles.extend(quad(0.0, 4.0, 0));
        let snapshot = SceneSnapshot::build(triangles, vec![SnapshotMaterial::DEFAULT_GREY, glow], vec![], vec![]);
        let (samples, power) = sample_emitters(&snapshot, 1.0, MAX_EMITTER_SAMPLES);
        let centre = (lo + hi) / 2.0;
        for s in &samples {
            assert_eq!(s.normal.w, 1.0, "one face of a closed box emits");
            let out = s.position.truncate() - centre;
            assert!(s.normal.truncate().dot(out) > 0.0, "the normal {} at {} points into the box", s.normal, s.position);
        }
        let area = 2.0 * (1.0 * 0.02 + 1.0 * 0.6 + 0.02 * 0.6);
        let expected = std::f32::consts::PI * 40.0 * area;
        assert!((power - expected).abs() < 1e-3 * expected, "{power} vs {expected}");
        // Under the box, the floor gets the underside's light (and a little from the thin sides), not the
        // top face's as well: counting both faces of every triangle gave twice the light.
        let mut e = 0.0;
        for s in &samples {
            let to = s.position.truncate();
            let w = to.normalize();
            e += s.flux.x * s.normal.truncate().dot(-w).max(0.0) * w.y.max(0.0) / (std::f32::consts::PI * to.length_squared());
        }
        let underside = parallel_rectangle_irradiance(40.0, 0.8, [-0.5, 0.5], [-0.3, 0.3]);
        assert!(e > 0.98 * underside && e < 1.05 * underside, "{e} lx under the box, its underside alone {underside} lx");
    }
}
