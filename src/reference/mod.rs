//! The ground truth: a CPU path tracer over the [`SceneSnapshot`].
//!
//! Every GI method of this crate is judged against this renderer (`shared/METRICS.md`). It reads the same
//! Bevy world as the game — meshes with their transforms, `StandardMaterial` diffuse colour and emission,
//! directional / point / spot lights in Bevy's units with Bevy's range window and spot-cone falloff, the
//! camera and its exposure — and solves the rendering equation for Lambertian surfaces:
//!
//! * **Sampling**: Owen-scrambled Sobol points (`sobol_burley`), one 4D point per path vertex, padded
//!   across vertices (see [`SobolStream`]). On `cornell` at 256² and 256 spp, two seeds' indirect images
//!   differ by 6.3 % block relative RMSE against 8.2 % with independent random numbers: about 1.7× fewer
//!   samples for the same noise.
//! * **Estimator**: unidirectional path tracing with next-event estimation towards every analytic light
//!   (they are delta lights, so NEE is their only estimator), emission picked up by BSDF sampling,
//!   cosine-weighted hemisphere sampling (the Lambertian BRDF `ρ/π` times `cos θ` over the density
//!   `cos θ/π` leaves a throughput factor of `ρ`), and Russian roulette from the third vertex on with
//!   survival probability `min(max(throughput), 0.95)`.
//! * **Path classes**: a path's contribution is binned by the number `k` of surface vertices that
//!   *reflect* light on it: `k = 0` is emission seen directly, `k = 1` is direct light, `k ≥ 2` is indirect
//!   light with `k − 1` diffuse bounces before the last one towards the eye. Emission reflected once
//!   (`k = 1` through an emissive surface) is binned with the *indirect* light: Bevy's direct pass
//!   renders only the analytic lights, so the light an emissive panel casts on a wall is light a GI
//!   method must add, and the direct image stays what Bevy renders. `max_bounces = N` keeps
//!   indirect paths with `k − 1 ≤ N` (the per-bounce ground truth of `shared/METRICS.md`).
//! * **Outputs**: full (`k ≥ 0`), direct-only (`k = 1`) and indirect-only (`k ≥ 2`) images, all multiplied
//!   by the camera's exposure, plus per-pixel geometry coverage in alpha.
//! * **Pixel filter**: a box filter over the pixel (uniform jitter); Bevy shades the pixel centre, which
//!   only differs along edges. [`ReferenceSettings::pixel_centers`] samples the centre instead.
//! * **Visibility**: lights always cast shadows here, even where Bevy renders them without shadow maps.
//! * **Burley check**: Bevy's direct light uses Burley's diffuse lobe, up to ~30 % brighter than Lambert at
//!   grazing angles. [`DiffuseModel::Burley`] evaluates Bevy's `Fd_Burley` for the *direct* term at the
//!   first vertex only, so that the direct-only image can be checked against Bevy pixel for pixel. All
//!   indirect transport stays Lambertian, as the metrics require.
//!
//! * **Culling**: camera rays skip the faces a material's `cull_mode` culls, so the tracer sees what Bevy
//!   shows; light transport treats every surface as opaque and two-sided.
//!
//! * **Environment**: a path that escapes the scene after a reflection gathers the radiance of
//!   [`SceneSnapshot::environment`] (the GI camera's `EnvironmentMapLight`, [`crate::scene::Environment`])
//!   in its direction. Environment light reflected once is binned with the indirect light, as emission
//!   is: Bevy lights every surface with the environment's diffuse map *unoccluded*, so the occluded sky
//!   light a room gets through its openings is light a GI method must add (`radiosity` does; see its
//!   docs for the diffuse map). Camera rays that miss see black (no skybox).
//!
//! Not modelled: specular reflection, transmission, emissive textures, alpha masks and ambient light.

use std::f32::consts::PI;
use std::time::Instant;

use bevy::camera::{Exposure, Projection};
use bevy::math::{Quat, Vec2, Vec3};
use bevy::prelude::GlobalTransform;
use rayon::prelude::*;

use crate::hdr_image::HdrImage;
use crate::sampling::{SobolStream, cosine_hemisphere};
use crate::scene::{SceneSnapshot, SurfacePoint};

/// Which diffuse lobe shades the direct light at the first vertex.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum DiffuseModel {
    /// `ρ/π`, the BRDF the metrics use everywhere.
    #[default]
    Lambert,
    /// Bevy's `Fd_Burley` (`pbr_lighting.wgsl`), for checking the direct image against Bevy.
    Burley,
}

/// A pinhole camera in Bevy's conventions: looks along its local −Z with +Y up.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ReferenceCamera {
    pub position: Vec3,
    pub rotation: Quat,
    pub projection: CameraProjection,
    /// Bevy's `Exposure::exposure()`: `2^−ev100 / 1.2`. Every output value is radiance × this.
    pub exposure: f32,
}

/// The projection of a [`ReferenceCamera`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub enum CameraProjection {
    /// Vertical field of view in radians; the aspect ratio is the image's.
    Perspective { fov_y: f32 },
    /// The view-space rectangle the image covers, in metres (Bevy's `OrthographicProjection::area`).
    Orthographic { min: Vec2, max: Vec2 },
}

impl ReferenceCamera {
    /// The camera of a Bevy entity. `None` for custom projections.
    pub fn from_bevy(transform: &GlobalTransform, projection: &Projection, exposure: Option<&Exposure>) -> Option<Self> {
        let projection = match projection {
            Projection::Perspective(p) => CameraProjection::Perspective { fov_y: p.fov },
            Projection::Orthographic(o) => CameraProjection::Orthographic {
                min: o.area.min,
                max: o.area.max,
            },
            Projection::Custom(_) => return None,
        };
        let (_, rotation, position) = transform.to_scale_rotation_translation();
        Some(Self {
            position,
            rotation,
            projection,
            exposure: exposure.copied().unwrap_or_default().exposure(),
        })
    }

    /// The world-space ray through image position `(x, y)` in pixels from the top-left corner.
    pub fn ray(&self, x: f32, y: f32, width: u32, height: u32) -> (Vec3, Vec3) {
        let ndc = Vec2::new(2.0 * x / width as f32 - 1.0, 1.0 - 2.0 * y / height as f32);
        match self.projection {
            CameraProjection::Perspective { fov_y } => {
                let tan = (0.5 * fov_y).tan();
                let aspect = width as f32 / height as f32;
                let d = Vec3::new(ndc.x * tan * aspect, ndc.y * tan, -1.0).normalize();
                (self.position, self.rotation * d)
            }
            CameraProjection::Orthographic { min, max } => {
                let t = (ndc + 1.0) * 0.5;
                let local = min + (max - min) * t;
                (self.position + self.rotation * local.extend(0.0), self.rotation * Vec3::NEG_Z)
            }
        }
    }
}

/// What to render.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ReferenceSettings {
    pub width: u32,
    pub height: u32,
    /// Paths per pixel. Two seeds of `cornell`'s indirect light at 256² agree within 3 % block relative
    /// RMSE from about 1100; the default 2048 gives about 2.2 %.
    pub samples_per_pixel: u32,
    /// Seed of every random stream; renders with different seeds are independent.
    pub seed: u64,
    /// Keep indirect paths with at most this many diffuse bounces before the last one towards the eye.
    /// `None` keeps all of them (Russian roulette ends paths without bias).
    pub max_bounces: Option<u32>,
    /// Diffuse lobe of the direct light at the first vertex.
    pub direct_model: DiffuseModel,
    /// Shoot every camera ray through the pixel centre, as the rasteriser shades, instead of box-filtering
    /// the pixel. Direct light from Bevy's (delta) lights is then noise-free and aligns with Bevy's edges.
    pub pixel_centers: bool,
    /// First vertex at which Russian roulette may end a path.
    pub russian_roulette_depth: u32,
    /// Hard cap on path length, a guard against pathological scenes (albedo ≥ 1).
    pub max_depth: u32,
}

impl Default for ReferenceSettings {
    fn default() -> Self {
        Self {
            width: 256,
            height: 256,
            samples_per_pixel: 2048,
            seed: 0,
            max_bounces: None,
            direct_model: DiffuseModel::Lambert,
            pixel_centers: false,
            russian_roulette_depth: 3,
            max_depth: 256,
        }
    }
}

/// The images of one render, each already multiplied by the camera's exposure.
#[derive(Clone, Debug)]
pub struct ReferenceImages {
    /// Everything: emission + direct + indirect (limited by `max_bounces`).
    pub full: HdrImage,
    /// Paths with exactly one reflecting vertex.
    pub direct: HdrImage,
    /// Paths with two or more reflecting vertices.
    pub indirect: HdrImage,
    /// Wall-clock seconds the render took.
    pub seconds: f64,
    /// Contributions dropped because they were not finite (should be 0).
    pub dropped_samples: u64,
}

#[derive(Clone, Copy, Default)]
struct PixelSum {
    emission: Vec3,
    direct: Vec3,
    indirect: Vec3,
    hits: u32,
    dropped: u32,
}

impl PixelSum {
    fn add(&mut self, reflecting_vertices: u32, value: Vec3) {
        if !value.is_finite() {
            self.dropped += 1;
            return;
        }
        match reflecting_vertices {
            0 => self.emission += value,
            1 => self.direct += value,
            _ => self.indirect += value,
        }
    }
}

/// Bevy's `Fd_Burley` divided by the Lambertian `1/π`: the factor by which Bevy's direct diffuse light
/// differs from Lambert's for these unit vectors.
pub fn burley_over_lambert(n: Vec3, v: Vec3, l: Vec3, perceptual_roughness: f32) -> f32 {
    // perceptualRoughnessToRoughness: clamp to [0.089, 1], then square.
    let roughness = perceptual_roughness.clamp(0.089, 1.0).powi(2);
    let n_dot_v = n.dot(v).max(1e-4);
    let n_dot_l = n.dot(l).clamp(0.0, 1.0);
    let h = (l + v).try_normalize().unwrap_or(n);
    let l_dot_h = l.dot(h).clamp(0.0, 1.0);
    let f90 = 0.5 + 2.0 * roughness * l_dot_h * l_dot_h;
    let schlick = |c: f32| 1.0 + (f90 - 1.0) * (1.0 - c).powi(5);
    schlick(n_dot_l) * schlick(n_dot_v)
}

/// Renders `scene` through `camera`. Deterministic for a given seed, whatever the thread count.
pub fn render(scene: &SceneSnapshot, camera: &ReferenceCamera, settings: &ReferenceSettings) -> ReferenceImages {
    let start = Instant::now();
    let (width, height) = (settings.width.max(1), settings.height.max(1));
    let spp = settings.samples_per_pixel.max(1);
    let exposure = if camera.exposure.is_finite() && camera.exposure > 0.0 { camera.exposure } else { 1.0 };
    // The longest class to keep: NEE at a vertex adds one reflecting vertex.
    let max_reflecting = settings
        .max_bounces
        .map_or(settings.max_depth, |b| (b + 1).min(settings.max_depth))
        .max(1);
    let scale = scene
        .bounds()
        .map_or(1.0, |(lo, hi)| lo.abs().max(hi.abs()).max_element().max(1.0));
    let epsilon = 1e-4 * scale;

    let rows: Vec<Vec<PixelSum>> = (0..height)
        .into_par_iter()
        .map(|y| {
            (0..width)
                .map(|x| {
                    let pixel = y as u64 * width as u64 + x as u64;
                    let stream = SobolStream::new(settings.seed, pixel);
                    let mut sum = PixelSum::default();
                    for index in 0..spp {
                        let sample = PathSample { stream, index };
                        let j = if settings.pixel_centers {
                            Vec2::splat(0.5)
                        } else {
                            let u = sample.vertex(0);
                            Vec2::new(u[0], u[1])
                        };
                        let (origin, dir) = camera.ray(x as f32 + j.x, y as f32 + j.y, width, height);
                        trace_path(scene, origin, dir, settings, max_reflecting, exposure, epsilon, sample, &mut sum);
                    }
                    sum
                })
                .collect()
        })
        .collect();

    let mut full = HdrImage::new(width, height);
    let mut direct = HdrImage::new(width, height);
    let mut indirect = HdrImage::new(width, height);
    let mut dropped = 0u64;
    let inv = 1.0 / spp as f32;
    for (y, row) in rows.iter().enumerate() {
        for (x, s) in row.iter().enumerate() {
            let coverage = s.hits as f32 * inv;
            let (x, y) = (x as u32, y as u32);
            let px = |v: Vec3| [v.x * inv * exposure, v.y * inv * exposure, v.z * inv * exposure, coverage];
            full.set(x, y, px(s.emission + s.direct + s.indirect));
            direct.set(x, y, px(s.direct));
            indirect.set(x, y, px(s.indirect));
            dropped += s.dropped as u64;
        }
    }
    ReferenceImages {
        full,
        direct,
        indirect,
        seconds: start.elapsed().as_secs_f64(),
        dropped_samples: dropped,
    }
}

/// The random numbers of one path: sample `index` of the pixel's Sobol stream.
#[derive(Clone, Copy)]
struct PathSample {
    stream: SobolStream,
    index: u32,
}

impl PathSample {
    /// Four numbers for path vertex `vertex` (0 = the camera).
    #[inline]
    fn vertex(&self, vertex: u32) -> [f32; 4] {
        self.stream.vertex_4d(self.index, vertex)
    }
}

/// Radiance arriving at `origin` from `direction` (unit), split by reflecting vertices exactly as the
/// images are (`[emission, direct, indirect]`, no exposure), averaged over `samples` paths with seed
/// `seed`. Used to path-trace the radiance field of the GI methods' probes.
pub fn incident_radiance(
    scene: &SceneSnapshot,
    origin: Vec3,
    direction: Vec3,
    settings: &ReferenceSettings,
    samples: u32,
    stream: u64,
) -> [Vec3; 3] {
    let max_reflecting = settings
        .max_bounces
        .map_or(settings.max_depth, |b| (b + 1).min(settings.max_depth))
        .max(1);
    let scale = scene.bounds().map_or(1.0, |(lo, hi)| lo.abs().max(hi.abs()).max_element().max(1.0));
    let mut sum = PixelSum::default();
    let stream = SobolStream::new(settings.seed, stream);
    for index in 0..samples.max(1) {
        let sample = PathSample { stream, index };
        trace_path_from(scene, origin, direction, settings, max_reflecting, 1.0, 1e-4 * scale, sample, &mut sum, false);
    }
    let n = samples.max(1) as f32;
    [sum.emission / n, sum.direct / n, sum.indirect / n]
}

/// The [`PixelSum`] class of light from an emissive surface or the environment after `reflecting`
/// reflections: light reflected once is not Bevy's direct light (see the module docs), so it joins the
/// indirect class.
fn source_class(reflecting: u32) -> u32 {
    if reflecting == 1 { 2 } else { reflecting }
}

/// Normals at a hit facing the side the ray came from.
fn facing_normals(surface: &SurfacePoint, incoming: Vec3) -> (Vec3, Vec3) {
    let ng = if surface.geometric_normal.dot(incoming) > 0.0 {
        -surface.geometric_normal
    } else {
        surface.geometric_normal
    };
    let ns = if surface.normal.dot(ng) < 0.0 { -surface.normal } else { surface.normal };
    (ng, ns)
}

#[expect(clippy::too_many_arguments, reason = "the inner loop of the tracer, kept free of allocations")]
fn trace_path(
    scene: &SceneSnapshot,
    origin: Vec3,
    direction: Vec3,
    settings: &ReferenceSettings,
    max_reflecting: u32,
    exposure: f32,
    epsilon: f32,
    sample: PathSample,
    sum: &mut PixelSum,
) {
    trace_path_from(scene, origin, direction, settings, max_reflecting, exposure, epsilon, sample, sum, true);
}

#[expect(clippy::too_many_arguments, reason = "the inner loop of the tracer, kept free of allocations")]
fn trace_path_from(
    scene: &SceneSnapshot,
    origin: Vec3,
    direction: Vec3,
    settings: &ReferenceSettings,
    max_reflecting: u32,
    exposure: f32,
    epsilon: f32,
    sample: PathSample,
    sum: &mut PixelSum,
    camera_ray: bool,
) {
    // The camera sees what Bevy rasterises: culled faces are transparent to camera rays only.
    let first = if camera_ray {
        scene.intersect_visible(origin, direction, 0.0, f32::INFINITY)
    } else {
        scene.intersect(origin, direction, 0.0, f32::INFINITY)
    };
    let Some(mut hit) = first else {
        // A probe's ray that escapes sees the environment; the camera does not (Bevy draws no skybox here).
        if let (false, Some(environment)) = (camera_ray, scene.environment.as_deref()) {
            sum.add(0, environment.radiance(direction));
        }
        return;
    };
    sum.hits += 1;
    let mut ray_origin = origin;
    let mut ray_dir = direction;
    let mut throughput = Vec3::ONE;
    // Number of surface vertices on the path so far, including this one.
    let mut depth = 1u32;
    loop {
        let surface = scene.surface(ray_origin, ray_dir, &hit);
        let (ng, ns) = facing_normals(&surface, ray_dir);

        // Emission at this vertex has been reflected by the `depth − 1` vertices before it.
        let emission = surface.material.emission(exposure);
        if emission != Vec3::ZERO && depth - 1 <= max_reflecting {
            sum.add(source_class(depth - 1), throughput * emission);
        }

        let p = surface.position + ng * epsilon;
        let albedo = surface.diffuse;
        // Next-event estimation: light reflected here has `depth` reflecting vertices.
        if depth <= max_reflecting && albedo != Vec3::ZERO {
            for entry in &scene.lights {
                let Some((l, distance, irradiance)) = entry.light.incident(surface.position) else {
                    continue;
                };
                let cos = ns.dot(l);
                if cos <= 0.0 || ng.dot(l) <= 0.0 {
                    continue;
                }
                let t_max = if distance.is_finite() { distance - 2.0 * epsilon } else { f32::INFINITY };
                if scene.occluded(p, l, 0.0, t_max) {
                    continue;
                }
                let mut brdf = albedo / PI;
                if depth == 1 && settings.direct_model == DiffuseModel::Burley {
                    brdf *= burley_over_lambert(ns, -ray_dir, l, surface.material.perceptual_roughness);
                }
                sum.add(depth, throughput * brdf * irradiance * cos);
            }
        }

        // Continue only while a longer path can still be kept (its emission has `depth` reflecting
        // vertices).
        if depth > max_reflecting || depth >= settings.max_depth {
            return;
        }
        let u = sample.vertex(depth);
        if depth >= settings.russian_roulette_depth {
            let survive = throughput.max_element().min(0.95);
            if survive <= 0.0 || u[2] >= survive {
                return;
            }
            throughput /= survive;
        }
        let next = cosine_hemisphere(ns, Vec2::new(u[0], u[1]));
        if next.dot(ng) <= 0.0 {
            return;
        }
        throughput *= albedo;
        if throughput == Vec3::ZERO {
            return;
        }
        let Some(next_hit) = scene.intersect(p, next, 0.0, f32::INFINITY) else {
            // The path escaped: the environment's light, reflected by the `depth` vertices so far.
            if let Some(environment) = scene.environment.as_deref() {
                sum.add(source_class(depth), throughput * environment.radiance(next));
            }
            return;
        };
        hit = next_hit;
        ray_origin = p;
        ray_dir = next;
        depth += 1;
    }
}

#[cfg(test)]
mod tests;
