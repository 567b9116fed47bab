//! CPU side of the VPL method: the virtual point lights (random walks from the GI lights through the
//! scene snapshot's BVH, as in Novák et al. §5 and Keller 1997), the point set the imperfect shadow maps
//! are splatted from (Ritschel et al. 2008, §3.1), and the automatic bound `b` of the clamping (the
//! bounded and residual geometry terms themselves are in [`crate::ssbc`]).
//!
//! Everything here is a pure function of the snapshot and the settings, so that a still scene gets the same
//! VPLs every frame (no shimmer) and tests can check the estimators without a GPU.

use std::f32::consts::{PI, TAU};

use bevy::math::{Vec2, Vec3};

use crate::emitters::GpuEmitter;
use crate::sampling::{SobolStream, cosine_hemisphere, orthonormal_basis};
#[cfg(test)]
use crate::ssbc::bounding_radius;
use crate::scene::{SceneSnapshot, SnapshotLight, range_falloff, triangle_area};

/// One virtual point light: a diffuse emitter at a surface point.
///
/// Its radiant intensity towards `ω` is `flux / π · max(0, n·ω)`, so a receiver at distance `d` with
/// cosines `cos θ_x`, `cos θ_y` gets irradiance `flux / π · G` with `G = cos θ_x cos θ_y / d²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vpl {
    /// World position, pushed off the surface by the snapshot's epsilon.
    pub position: Vec3,
    /// Unit normal of the side the light arrived on.
    pub normal: Vec3,
    /// Reflected flux `ρ · Φ_in` in lumens (RGB).
    pub flux: Vec3,
    /// Reflections along the light path up to and including this one (1 = a directly lit surface).
    pub bounce: u32,
}

/// What [`generate_vpls`] is asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkSettings {
    /// Light paths traced in all, split between the lights by their power.
    pub paths: u32,
    /// Most reflections per path: a path leaves one VPL at each surface hit until Russian roulette ends
    /// it or it reaches `bounces` hits.
    pub bounces: u32,
    /// Scrambles the quasi-random sequence.
    pub seed: u32,
}

/// A light's emission, sampled by direction: what one light path starts with.
struct Emission {
    origin: Vec3,
    direction: Vec3,
    /// Flux the path carries, before the range falloff at its first hit (lumens).
    flux: Vec3,
}

/// The power of a light in lumens (photometric maximum channel), which splits the paths between lights.
/// Directional lights count the flux through `scene_area_across` m² across the beam.
fn light_power(light: &SnapshotLight, scene_area_across: f32) -> f32 {
    match *light {
        SnapshotLight::Directional { illuminance, .. } => illuminance.max_element() * scene_area_across,
        SnapshotLight::Point { intensity, .. } => intensity.max_element() * 4.0 * PI,
        SnapshotLight::Spot { intensity, spot_scale, spot_offset, .. } => {
            let cos_outer = (-spot_offset / spot_scale.max(1e-12)).clamp(-1.0, 1.0);
            intensity.max_element() * TAU * (1.0 - cos_outer)
        }
    }
}

/// The rectangle across a directional light's beam that covers `bounds`: origin corner, the two edge
/// vectors, and the distance behind the scene to start the rays.
fn beam_rectangle(direction: Vec3, (lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3, Vec3) {
    let d = direction.try_normalize().unwrap_or(Vec3::NEG_Y);
    let (t, b) = orthonormal_basis(d);
    let corners = (0..8).map(|i| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    });
    let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for c in corners {
        let local = Vec3::new(c.dot(t), c.dot(b), c.dot(d));
        min = min.min(local);
        max = max.max(local);
    }
    let margin = 1e-3 * (max - min).max_element().max(1e-3);
    let origin = t * (min.x - margin) + b * (min.y - margin) + d * (min.z - margin);
    (origin, t * (max.x - min.x + 2.0 * margin), b * (max.y - min.y + 2.0 * margin))
}

/// Emission sample `u ∈ [0,1)²` of `light`, one of `count` paths of this light.
fn emit(light: &SnapshotLight, u: Vec2, count: u32, bounds: (Vec3, Vec3)) -> Option<Emission> {
    let n = count.max(1) as f32;
    match *light {
        SnapshotLight::Directional { direction, illuminance } => {
            // Parallel rays over the beam's cross-section: Φ = E⊥ · A⊥ / N each.
            let (origin, e1, e2) = beam_rectangle(direction, bounds);
            let area = e1.cross(e2).length();
            Some(Emission {
                origin: origin + e1 * u.x + e2 * u.y,
                direction: direction.try_normalize()?,
                flux: illuminance * area / n,
            })
        }
        SnapshotLight::Point { position, intensity, .. } => {
            // Uniform over the sphere: Φ = I · 4π / N.
            let z = 1.0 - 2.0 * u.x;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = TAU * u.y;
            Some(Emission {
                origin: position,
                direction: Vec3::new(r * phi.cos(), r * phi.sin(), z),
                flux: intensity * 4.0 * PI / n,
            })
        }
        SnapshotLight::Spot { position, direction, intensity, spot_scale, spot_offset, .. } => {
            // Uniform over the outer cone's solid angle Ω, weighted by Bevy's cone falloff:
            // Φ = I · cone(θ) · Ω / N.
            let axis = direction.try_normalize()?;
            let cos_outer = (-spot_offset / spot_scale.max(1e-12)).clamp(-1.0, 1.0);
            let cos_theta = 1.0 - u.x * (1.0 - cos_outer);
            let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
            let phi = TAU * u.y;
            let (t, b) = orthonormal_basis(axis);
            let dir = (t * phi.cos() + b * phi.sin()) * sin_theta + axis * cos_theta;
            let cone = (cos_theta * spot_scale + spot_offset).clamp(0.0, 1.0);
            let omega = TAU * (1.0 - cos_outer);
            Some(Emission {
                origin: position,
                direction: dir,
                flux: intensity * cone * cone * omega / n,
            })
        }
    }
}

/// Bevy's range window at the first hit of a local light's path.
fn first_hit_falloff(light: &SnapshotLight, distance: f32) -> f32 {
    match *light {
        SnapshotLight::Directional { .. } => 1.0,
        SnapshotLight::Point { inverse_range_squared, .. } | SnapshotLight::Spot { inverse_range_squared, .. } => {
            range_falloff(distance * distance, inverse_range_squared)
        }
    }
}

/// Side of the pilot grid over each light's emission domain (see [`EmissionGuide`]).
pub const PILOT_GRID: u32 = 32;
/// Weight of a pilot cell whose first surface faces away from every viewer: kept above zero, so that the
/// guided estimator stays unbiased (those paths are only made rarer and heavier).
pub const UNSEEN_WEIGHT: f32 = 0.02;

/// Where a light's paths go: the first surface its [`PILOT_GRID`]² pilot rays reach (position and the
/// normal facing the light), traced once per light and geometry.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PilotHits(pub Vec<Option<(Vec3, Vec3)>>);

/// A 2D importance distribution over a light's emission domain `[0, 1)²`, piecewise constant over the
/// pilot grid. Light paths are drawn from it and weighted by `1/pdf`, so any weights give an unbiased
/// estimate; good weights put the paths where their VPLs can light what the cameras see.
#[derive(Clone, Debug, PartialEq)]
pub struct EmissionGuide {
    /// Cell weights, row-major over the pilot grid.
    pub weights: Vec<f32>,
}

impl EmissionGuide {
    /// Weight 1 for cells whose first surface faces at least one viewer (a VPL there can light the
    /// viewer's side of the scene), [`UNSEEN_WEIGHT`] otherwise (the outer side of a roof under the sun,
    /// the back of a wall). Without viewers every cell weighs 1 (uniform sampling).
    pub fn from_pilots(hits: &PilotHits, viewers: &[Vec3]) -> Self {
        let weights = hits
            .0
            .iter()
            .map(|hit| match hit {
                _ if viewers.is_empty() => 1.0,
                Some((p, n)) if viewers.iter().any(|v| n.dot(*v - *p) > 0.0) => 1.0,
                _ => UNSEEN_WEIGHT,
            })
            .collect();
        Self { weights }
    }

    /// The mean weight: the share of the light's power the guide keeps "useful" (1 without pilots).
    pub fn mean(&self) -> f32 {
        if self.weights.is_empty() {
            return 1.0;
        }
        self.weights.iter().sum::<f32>() / self.weights.len() as f32
    }

    /// Maps a uniform `u` to the guided domain: the point and `1 / pdf` (1 for uniform weights).
    fn warp(&self, u: Vec2) -> (Vec2, f32) {
        let total: f32 = self.weights.iter().sum();
        let n = self.weights.len();
        if n == 0 || total <= 0.0 || self.weights.iter().all(|w| *w == self.weights[0]) {
            return (u, 1.0);
        }
        let target = u.x * total;
        let mut acc = 0.0;
        let mut cell = n - 1;
        for (i, w) in self.weights.iter().enumerate() {
            if acc + w > target {
                cell = i;
                break;
            }
            acc += w;
        }
        let w = self.weights[cell].max(1e-12);
        let frac = ((target - acc) / w).clamp(0.0, 0.999_999);
        let g = PILOT_GRID as f32;
        let (cx, cy) = ((cell as u32 % PILOT_GRID) as f32, (cell as u32 / PILOT_GRID) as f32);
        let point = Vec2::new((cx + frac) / g, (cy + u.y) / g);
        // pdf over [0,1)² = (w / total) · n.
        (point, total / (w * n as f32))
    }
}

/// The pilot rays of `light`: one through the centre of each cell of the [`PILOT_GRID`].
///
/// Only directional lights get them (point and spot lights return none, and are sampled uniformly): their
/// beam is fitted to the whole scene, so most of it can land where no camera looks (the outside of a roof
/// around a skylight), while a local light's emission stays in its surroundings, where a viewer test on
/// the first surface would starve light that reaches the camera after more bounces.
pub fn pilot_hits(snapshot: &SceneSnapshot, light: &SnapshotLight) -> PilotHits {
    let Some(bounds) = snapshot.bounds() else {
        return PilotHits::default();
    };
    if !matches!(light, SnapshotLight::Directional { .. }) {
        return PilotHits::default();
    }
    let g = PILOT_GRID;
    PilotHits(
        (0..g * g)
            .map(|i| {
                let u = Vec2::new(((i % g) as f32 + 0.5) / g as f32, ((i / g) as f32 + 0.5) / g as f32);
                let e = emit(light, u, 1, bounds)?;
                let hit = snapshot.intersect(e.origin, e.direction, 0.0, f32::INFINITY)?;
                let surface = snapshot.surface(e.origin, e.direction, &hit);
                let n = surface.geometric_normal;
                let n = if n.dot(e.direction) < 0.0 { n } else { -n };
                Some((surface.position, n))
            })
            .collect(),
    )
}

/// Traces `settings.paths` light paths from `lights` and the emissive surfaces' point samples `emitters`
/// ([`crate::emitters`]) through `snapshot` and returns a VPL at each surface hit of every path, up to
/// `settings.bounces` hits. With `guides` (one per light), the lights' paths are drawn from each light's
/// [`EmissionGuide`] and split between the lights by power times the guide's mean weight; without,
/// uniformly and by power.
///
/// Paths are split between the sources by power (at least one each) and start from an Owen-scrambled
/// Sobol sequence, so the set is stratified and the same for the same inputs. A light's path has its first
/// VPL at the first surface it reaches, with the light's flux reflected there (what the light's reflective
/// shadow map stores for that texel, `ρ·Φ_T`); each further VPL continues in a cosine-distributed
/// direction, which is the distribution of a diffuse VPL's emitted flux, so the flux it carries is the
/// previous VPL's flux times the new surface's albedo (no division by a pdf is needed: cosine sampling is
/// exact for a Lambertian emitter). Paths end by Russian roulette on the albedo (Keller 1997), so a room
/// with albedo ρ gets about `1/(1 − ρ)` VPLs per path and every bounce order up to `bounces` without bias:
/// the sum over bounce-`k` VPLs estimates the flux reflected by the `k`-th surfaces light reaches.
///
/// An emissive surface is itself a diffuse emitter, which is what a VPL is: an emitter path starts with a
/// VPL of bounce 0 on one of the emitter samples (two-sided, as the tracer's emitters are: a random face,
/// with twice the sample's one-sided flux `π L_e A / M`; one-sided where the other face lies inside a
/// closed mesh), and walks on from it like a VPL (Keller 1997
/// starts instant radiosity's paths on area lights the same way). Bevy draws no light from emissive
/// materials, so these VPLs carry the emitters' direct light as well as its bounces.
pub fn generate_vpls(
    snapshot: &SceneSnapshot,
    lights: &[SnapshotLight],
    emitters: &[GpuEmitter],
    guides: Option<&[EmissionGuide]>,
    settings: WalkSettings,
) -> Vec<Vpl> {
    VplPaths::walk(snapshot, lights, emitters, guides, settings).vpls
}

/// The light paths of [`generate_vpls`], each with its VPLs and the points its rays ran between, kept
/// so that after a few meshes moved only the paths whose rays ran through them are walked again
/// ([`rewalk`](Self::rewalk)). Each path draws its numbers from its own index of its source's Sobol
/// stream, so a path walked again in an unchanged scene is the same path.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VplPaths {
    /// Every VPL, path after path (what [`generate_vpls`] returns).
    pub vpls: Vec<Vpl>,
    /// Where each path's VPLs start in `vpls` (one more entry than paths).
    vpl_offsets: Vec<u32>,
    /// The points each path's rays ran between: its origin, then the end of every ray it traced (the
    /// surface hit, or a point beyond the scene for a ray that left it).
    points: Vec<Vec3>,
    /// Where each path's points start in `points` (one more entry than paths).
    point_offsets: Vec<u32>,
    /// The scene's bounds the paths were walked in (a directional light's beam is fitted to them).
    bounds: Option<(Vec3, Vec3)>,
}

/// One path's VPLs and ray end points.
type WalkedPath = (Vec<Vpl>, Vec<Vec3>);

impl VplPaths {
    /// Walks every path ([`generate_vpls`]), in parallel.
    pub fn walk(
        snapshot: &SceneSnapshot,
        lights: &[SnapshotLight],
        emitters: &[GpuEmitter],
        guides: Option<&[EmissionGuide]>,
        settings: WalkSettings,
    ) -> Self {
        use rayon::prelude::*;
        let Some(walker) = Walker::new(snapshot, lights, emitters, guides, settings) else {
            return Self::default();
        };
        let walked: Vec<WalkedPath> = walker.starts.par_iter().map(|&start| walker.walk_path(start)).collect();
        let mut paths = Self { bounds: Some(walker.bounds), ..Self::default() };
        paths.vpls.reserve(walked.iter().map(|p| p.0.len()).sum());
        walked.iter().for_each(|p| paths.push(p));
        paths.finish();
        paths
    }

    /// Paths held.
    pub fn len(&self) -> usize {
        self.vpl_offsets.len().saturating_sub(1)
    }

    /// Whether no path is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn push(&mut self, (vpls, points): &WalkedPath) {
        self.vpl_offsets.push(self.vpls.len() as u32);
        self.point_offsets.push(self.points.len() as u32);
        self.vpls.extend_from_slice(vpls);
        self.points.extend_from_slice(points);
    }

    /// Closes the offset tables.
    fn finish(&mut self) {
        self.vpl_offsets.push(self.vpls.len() as u32);
        self.point_offsets.push(self.points.len() as u32);
    }

    /// Whether path `k` ran a ray through one of `boxes`.
    fn touches(&self, k: usize, boxes: &[(Vec3, Vec3)]) -> bool {
        let points = &self.points[self.point_offsets[k] as usize..self.point_offsets[k + 1] as usize];
        points.windows(2).any(|w| boxes.iter().any(|&b| crate::scene::changes::segment_meets_box(w[0], w[1], b)))
    }

    /// Brings the paths up to date with a scene in which only what lies in `changed` (world boxes: the
    /// old and new bounds of the meshes that moved) differs from the scene they were walked in, with the
    /// same sources, guides and settings: the paths whose rays ran through a box are walked again, the
    /// others kept. The result is [`walk`](Self::walk)'s. Where that cannot hold (other sources or
    /// settings, so another number of paths; other scene bounds, which a directional light's beam is
    /// fitted to) every path is walked.
    ///
    /// Returns, per VPL of the result, the index it had before when its path was kept (`None` for the
    /// VPLs of the paths walked again), and how many paths were walked again; `None` when all were.
    pub fn rewalk(
        &mut self,
        snapshot: &SceneSnapshot,
        lights: &[SnapshotLight],
        emitters: &[GpuEmitter],
        guides: Option<&[EmissionGuide]>,
        settings: WalkSettings,
        changed: &[(Vec3, Vec3)],
    ) -> Option<(Vec<Option<u32>>, usize)> {
        use rayon::prelude::*;
        let walker = Walker::new(snapshot, lights, emitters, guides, settings);
        let Some(walker) = walker.filter(|w| w.starts.len() == self.len() && self.bounds == Some(w.bounds)) else {
            *self = Self::walk(snapshot, lights, emitters, guides, settings);
            return None;
        };
        // The rays start a ray epsilon off the surfaces their segments are recorded from.
        let margin = Vec3::splat(4.0 * walker.epsilon);
        let boxes: Vec<(Vec3, Vec3)> = changed.iter().map(|&(lo, hi)| (lo - margin, hi + margin)).collect();
        let redo: Vec<usize> = (0..self.len()).into_par_iter().filter(|&k| self.touches(k, &boxes)).collect();
        let walked: Vec<WalkedPath> = redo.par_iter().map(|&k| walker.walk_path(walker.starts[k])).collect();
        let old = std::mem::take(self);
        *self = Self { bounds: old.bounds, ..Self::default() };
        let mut origin = Vec::with_capacity(old.vpls.len());
        let mut redone = redo.iter().zip(&walked).peekable();
        for k in 0..old.len() {
            if let Some((_, path)) = redone.next_if(|item| *item.0 == k) {
                self.push(path);
                origin.extend(std::iter::repeat_n(None, path.0.len()));
            } else {
                let (v0, v1) = (old.vpl_offsets[k] as usize, old.vpl_offsets[k + 1] as usize);
                let (p0, p1) = (old.point_offsets[k] as usize, old.point_offsets[k + 1] as usize);
                self.vpl_offsets.push(self.vpls.len() as u32);
                self.point_offsets.push(self.points.len() as u32);
                self.vpls.extend_from_slice(&old.vpls[v0..v1]);
                self.points.extend_from_slice(&old.points[p0..p1]);
                origin.extend((v0..v1).map(|i| Some(i as u32)));
            }
        }
        self.finish();
        Some((origin, redo.len()))
    }
}

/// Where one light path starts: its source (a light's index, or `lights.len()` for the emissive
/// surfaces) and its index among that source's paths.
#[derive(Clone, Copy, Debug)]
struct PathStart {
    source: usize,
    index: u32,
}

/// What every path of one generation shares.
struct Walker<'a> {
    snapshot: &'a SceneSnapshot,
    lights: &'a [SnapshotLight],
    emitters: &'a [GpuEmitter],
    guides: Option<&'a [EmissionGuide]>,
    settings: WalkSettings,
    bounds: (Vec3, Vec3),
    epsilon: f32,
    /// Paths per source: each light's, then the emitters'.
    counts: Vec<u32>,
    /// Every path, source after source.
    starts: Vec<PathStart>,
}

impl<'a> Walker<'a> {
    fn new(
        snapshot: &'a SceneSnapshot,
        lights: &'a [SnapshotLight],
        emitters: &'a [GpuEmitter],
        guides: Option<&'a [EmissionGuide]>,
        settings: WalkSettings,
    ) -> Option<Self> {
        let bounds = snapshot.bounds()?;
        if (lights.is_empty() && emitters.is_empty()) || settings.paths == 0 || settings.bounces == 0 {
            return None;
        }
        let extent = bounds.1 - bounds.0;
        let across = extent.x * extent.z + extent.x * extent.y + extent.y * extent.z;
        let guide = |i: usize| guides.and_then(|g| g.get(i));
        // One power per light, then the emitters' (their open faces), in lumens of the brightest channel.
        let emitter_power = emitters.iter().map(|e| e.flux.truncate().max_element().max(0.0) * e.normal.w).sum::<f32>();
        let mut powers: Vec<f32> = lights
            .iter()
            .enumerate()
            .map(|(i, l)| light_power(l, across).max(0.0) * guide(i).map_or(1.0, EmissionGuide::mean))
            .collect();
        if !emitters.is_empty() {
            powers.push(if emitter_power.is_finite() { emitter_power } else { 0.0 });
        }
        let counts = split_paths(settings.paths, &powers);
        let starts = counts.iter().enumerate().flat_map(|(source, &count)| (0..count).map(move |index| PathStart { source, index })).collect();
        Some(Self { snapshot, lights, emitters, guides, settings, bounds, epsilon: snapshot.ray_epsilon(), counts, starts })
    }

    /// One path's VPLs and the points its rays ran between.
    fn walk_path(&self, PathStart { source, index: i }: PathStart) -> WalkedPath {
        let (mut vpls, mut points) = (Vec::new(), Vec::new());
        let count = self.counts[source];
        let epsilon = self.epsilon;
        if let Some(light) = self.lights.get(source) {
            let stream = SobolStream::new(self.settings.seed as u64, source as u64);
            let u = stream.vertex_4d(i, 0);
            let guide = self.guides.and_then(|g| g.get(source));
            let (u, weight) = guide.map_or((Vec2::new(u[0], u[1]), 1.0), |g| g.warp(Vec2::new(u[0], u[1])));
            let Some(mut emission) = emit(light, u, count, self.bounds) else {
                return (vpls, points);
            };
            emission.flux *= weight;
            self.walk(Some(light), emission, &stream, i, &mut vpls, &mut points);
            return (vpls, points);
        }
        let stream = SobolStream::new(self.settings.seed as u64, 0xE417 + self.lights.len() as u64);
        let m = self.emitters.len();
        let u = stream.vertex_4d(i, 0);
        let e = self.emitters[((u[0] * m as f32) as usize).min(m - 1)];
        // A random one of its open faces (the normal's side when only one is).
        let sides = e.normal.w;
        let face = if sides < 1.5 || u[1] < 0.5 { 1.0 } else { -1.0 };
        let normal = e.normal.truncate() * face;
        // Each sample is one of M with `π L_e A / M` per open face; this path stands for M / count of
        // them.
        let flux = e.flux.truncate() * (sides * m as f32 / count as f32);
        if normal == Vec3::ZERO || !flux.is_finite() || flux.max_element() <= 0.0 {
            return (vpls, points);
        }
        let position = e.position.truncate() + normal * epsilon;
        vpls.push(Vpl { position, normal, flux, bounce: 0 });
        let emission = Emission {
            origin: position,
            direction: cosine_hemisphere(normal, Vec2::new(u[2], u[3])),
            flux,
        };
        self.walk(None, emission, &stream, i, &mut vpls, &mut points);
        (vpls, points)
    }

    /// The walk of one path from its emission: a VPL at each surface hit, up to `bounces` hits; its
    /// origin and the end of every ray into `points`.
    fn walk(&self, light: Option<&SnapshotLight>, emission: Emission, stream: &SobolStream, index: u32, out: &mut Vec<Vpl>, points: &mut Vec<Vec3>) {
        let (snapshot, epsilon) = (self.snapshot, self.epsilon);
        let (mut origin, mut direction, mut flux) = (emission.origin, emission.direction, emission.flux);
        points.push(origin);
        for bounce in 1..=self.settings.bounces {
            let Some(hit) = snapshot.intersect(origin, direction, 0.0, f32::INFINITY) else {
                // Past the far side of the scene's bounds.
                let centre = (self.bounds.0 + self.bounds.1) * 0.5;
                let far = origin.distance(centre) + (self.bounds.1 - self.bounds.0).length();
                points.push(origin + direction * far);
                return;
            };
            points.push(origin + direction * hit.t);
            let surface = snapshot.surface(origin, direction, &hit);
            if let Some(light) = light.filter(|_| bounce == 1) {
                flux *= first_hit_falloff(light, hit.t);
            }
            // The side the light arrives on.
            let ng = if surface.geometric_normal.dot(direction) < 0.0 { surface.geometric_normal } else { -surface.geometric_normal };
            let mut ns = if surface.normal.dot(ng) > 0.0 { surface.normal } else { -surface.normal };
            if ns.dot(ng) <= 1e-3 {
                ns = ng;
            }
            flux *= surface.diffuse;
            if flux.max_element() <= 0.0 || !flux.is_finite() {
                return;
            }
            let position = surface.position + ng * epsilon;
            out.push(Vpl { position, normal: ns, flux, bounce });
            if bounce == self.settings.bounces {
                return;
            }
            let u = stream.vertex_4d(index, bounce);
            // Russian roulette by the surface's albedo: a path survives with probability q and carries
            // flux / q, so every bounce order stays unbiased and the VPLs keep about the same flux each.
            let survive = surface.diffuse.max_element().min(0.95);
            if survive <= 0.0 || u[2] >= survive {
                return;
            }
            flux /= survive;
            let next = cosine_hemisphere(ns, Vec2::new(u[0], u[1]));
            if next.dot(ng) <= 0.0 {
                return;
            }
            origin = position;
            direction = next;
        }
    }
}

/// `paths` split between sources of `powers` in proportion, at least one each (the last takes the
/// remainder), as long as there are paths for all.
fn split_paths(paths: u32, powers: &[f32]) -> Vec<u32> {
    let total: f32 = powers.iter().sum::<f32>().max(1e-20);
    let mut assigned = 0u32;
    powers
        .iter()
        .enumerate()
        .map(|(index, power)| {
            let remaining = (powers.len() - index) as u32;
            let count = if index + 1 == powers.len() {
                paths.saturating_sub(assigned).max(1)
            } else {
                ((paths as f32 * power / total).round() as u32).clamp(1, paths.saturating_sub(assigned + remaining - 1).max(1))
            };
            assigned += count;
            count
        })
        .collect()
}

/// One point of the imperfect shadow maps' point set: a surface sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsmPoint {
    pub position: Vec3,
}

/// `count` points spread over the snapshot's surfaces uniformly by area (stratified through a Sobol
/// sequence over the area CDF), in a shuffled order so that any contiguous run of them is itself spread
/// over the whole scene: each VPL's imperfect shadow map splats its own run (Ritschel et al. 2008, §3.1).
pub fn ism_points(snapshot: &SceneSnapshot, count: u32, seed: u32) -> Vec<IsmPoint> {
    ism_positions(snapshot, &ism_samples(snapshot, count, seed))
}

/// Where an ISM point sits: a global triangle and barycentrics, so that points follow moving meshes
/// without drawing them again ([`ism_positions`], O(points)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsmSample {
    pub triangle: u32,
    pub s: f32,
    pub r: f32,
}

/// The world positions of `samples` in the snapshot now (its layout must be the one they were drawn in).
pub fn ism_positions(snapshot: &SceneSnapshot, samples: &[IsmSample]) -> Vec<IsmPoint> {
    let n = snapshot.triangle_count() as u32;
    samples
        .iter()
        .filter(|p| p.triangle < n)
        .map(|p| {
            let [a, b, c] = snapshot.triangle(p.triangle);
            IsmPoint { position: a + (b - a) * p.s + (c - a) * p.r }
        })
        .collect()
}

/// The samples behind [`ism_points`]: O(triangles) for the area CDF.
pub fn ism_samples(snapshot: &SceneSnapshot, count: u32, seed: u32) -> Vec<IsmSample> {
    let n = snapshot.triangle_count();
    if n == 0 || count == 0 {
        return Vec::new();
    }
    let mut cdf = Vec::with_capacity(n);
    let mut total = 0.0f64;
    for (_, t) in snapshot.triangles() {
        total += triangle_area(&t).max(0.0) as f64;
        cdf.push(total);
    }
    if total <= 0.0 {
        return Vec::new();
    }
    let stream = SobolStream::new(seed as u64, 0x15A);
    let mut points: Vec<(u32, IsmSample)> = (0..count)
        .map(|i| {
            let u = stream.vertex_4d(i, 0);
            let target = (i as f64 + u[0] as f64) / count as f64 * total;
            let t = cdf.partition_point(|c| *c < target).min(n - 1);
            let Vec2 { x: s, y: r } = crate::sampling::uniform_triangle(Vec2::new(u[1], u[2]));
            // Shuffle key: a hash of the index.
            let key = (i.wrapping_mul(0x9E37_79B9) ^ seed).rotate_left(13).wrapping_mul(0x85EB_CA6B);
            (key, IsmSample { triangle: t as u32, s, r })
        })
        .collect();
    points.sort_by_key(|(key, _)| *key);
    points.into_iter().map(|(_, p)| p).collect()
}

/// The automatic bound `b` (1/m²) when the settings leave it at 0: the VPL density over the scene's
/// surfaces, `b = N / A`, so that the bounding radius `1/√b` is the mean spacing of the VPLs — closer
/// than that, one VPL stands for light that many nearby ones would share, and its `G` peak would show.
pub fn automatic_bound(vpl_count: usize, surface_area: f32) -> f32 {
    (vpl_count.max(1) as f32 / surface_area.max(1e-6)).max(1e-6)
}

/// The orthonormal basis `(t, b, n)` of `shaders/vpl/vpl_types.wgsl`'s `basis` (Duff et al. 2017): the
/// shadow maps are laid out in it, so the CPU and the GPU must agree to the bit.
pub fn shadow_map_basis(n: Vec3) -> [Vec3; 3] {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    [Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x), Vec3::new(b, s + n.y * n.y * a, -n.y), n]
}

/// The world direction through the centre of texel `(x, y)` of a `side`² paraboloid map over the
/// hemisphere of `normal` (the inverse of `paraboloid_coords` in `vpl_types.wgsl`), or `None` for the
/// corners outside the paraboloid's disk.
pub fn paraboloid_direction(normal: Vec3, side: u32, x: u32, y: u32) -> Option<Vec3> {
    let uv = Vec2::new((x as f32 + 0.5) / side as f32, (y as f32 + 0.5) / side as f32) * 2.0 - 1.0;
    let r2 = uv.length_squared();
    if r2 > 1.0 {
        return None;
    }
    // uv = xy / (1 + z) on the unit sphere: z = (1 − r²) / (1 + r²), xy = uv (1 + z).
    let z = (1.0 - r2) / (1.0 + r2);
    let xy = uv * (1.0 + z);
    let [t, b, n] = shadow_map_basis(normal);
    Some((t * xy.x + b * xy.y + n * z).normalize())
}

/// Ray-traced shadow maps: for every VPL, a `side`² paraboloid map of the distances, through each
/// texel's centre, to the first occluder and to its far side ([`encode_traced_texel`]; 0 where nothing
/// is there), VPL after VPL with `side²` words each. The gather tests receivers with
/// [`traced_visibility`].
///
/// Imperfect shadow maps splat a few thousand points per VPL: a wall thinner than the gaps between its
/// points lets light through, and a generated two-room family showed it on most rooms lit next door (a
/// 28 cm wall: the camera's room at 1.9× its light, `docs/unseen_rooms.md`). One ray per texel through
/// the snapshot's BVH sees every wall, whatever its thickness. The rays run with the walks, in the
/// background: VPLs × side² × 2 rays (about 650 000 for the medium preset's VPLs at 32²).
///
/// The far side of a solid occluder is the second surface the ray meets, its exit (second-depth shadow
/// maps, Wang & Molnar 1994): the first surface stays lit across the texel whatever its slope. A sheet
/// (a quad without a back, such as Bevy's `Plane3d`: the ray's next surface is not an exit from it) has no
/// far side; its own depth plus the spread of its depth over the gather's 2×2 texels ([`sheet_depth`]) is
/// stored instead. With the second surface behind a sheet, an emissive panel hung 1 mm under a ceiling
/// let the ceiling's light from the panel's upper face through into the room (`emissive_panel` at 1.19×
/// its energy).
pub fn traced_shadow_maps(snapshot: &SceneSnapshot, vpls: &[Vpl], side: u32) -> Vec<u32> {
    use rayon::prelude::*;
    let texels = (side * side) as usize;
    let mut maps = vec![0u32; vpls.len() * texels];
    maps.par_chunks_mut(texels).zip(vpls.par_iter()).for_each(|(map, vpl)| {
        for (t, texel) in map.iter_mut().enumerate() {
            *texel = traced_texel(snapshot, vpl, side, t as u32 % side, t as u32 / side);
        }
    });
    maps
}

/// [`traced_shadow_maps`] of `vpls` in a scene in which only what lies in `changed` (world boxes: the
/// old and new bounds of what moved) differs from the scene `old` was traced in for the VPLs `origin`
/// names (per VPL, its index in `old`'s VPLs, or `None` for a VPL that is new): a kept VPL keeps its
/// texels whose ray does not pass through a box (their first and second surfaces are where they were)
/// and traces the others; a new VPL traces all. The result is [`traced_shadow_maps`]'. Returns the
/// maps and the texels traced.
pub fn traced_shadow_maps_update(snapshot: &SceneSnapshot, vpls: &[Vpl], side: u32, old: &[u32], origin: &[Option<u32>], changed: &[(Vec3, Vec3)]) -> (Vec<u32>, usize) {
    use rayon::prelude::*;
    let texels = (side * side) as usize;
    let margin = Vec3::splat(4.0 * snapshot.ray_epsilon());
    let boxes: Vec<(Vec3, Vec3)> = changed.iter().map(|&(lo, hi)| (lo - margin, hi + margin)).collect();
    let mut maps = vec![0u32; vpls.len() * texels];
    let traced: usize = maps
        .par_chunks_mut(texels)
        .zip(vpls.par_iter())
        .zip(origin.par_iter())
        .map(|((map, vpl), origin)| {
            let kept = origin.and_then(|o| old.get(o as usize * texels..(o as usize + 1) * texels));
            let mut traced = 0;
            for (t, texel) in map.iter_mut().enumerate() {
                let (x, y) = (t as u32 % side, t as u32 / side);
                if let Some(kept) = kept {
                    let through = paraboloid_direction(vpl.normal, side, x, y)
                        .is_some_and(|d| boxes.iter().any(|&b| crate::scene::changes::ray_meets_box(vpl.position, d, f32::INFINITY, b)));
                    if !through {
                        *texel = kept[t];
                        continue;
                    }
                }
                *texel = traced_texel(snapshot, vpl, side, x, y);
                traced += 1;
            }
            traced
        })
        .sum();
    (maps, traced)
}

/// One texel of a VPL's traced shadow map ([`traced_shadow_maps`]).
fn traced_texel(snapshot: &SceneSnapshot, vpl: &Vpl, side: u32, x: u32, y: u32) -> u32 {
    let epsilon = snapshot.ray_epsilon();
    let Some(direction) = paraboloid_direction(vpl.normal, side, x, y) else {
        return 0;
    };
    // Nothing in this direction: the ray left the scene, and nothing further needs a shadow.
    let Some(first) = snapshot.intersect(vpl.position, direction, 0.0, f32::INFINITY) else {
        return 0;
    };
    // Only the faces' orientation is needed: the geometric normals, not the shaded surfaces.
    let cos_first = snapshot.geometric_normal(first.triangle).dot(direction);
    let second = snapshot.intersect(vpl.position, direction, first.t + epsilon, f32::INFINITY);
    let exit = second.as_ref().filter(|s| {
        // Entered at the first surface and left at the second: a solid's far side.
        cos_first < 0.0 && snapshot.geometric_normal(s.triangle).dot(direction) > 0.0
    });
    let far = match (exit, second) {
        (Some(exit), _) => exit.t,
        (None, second) => {
            let sheet = sheet_depth(first.t, cos_first.abs(), side) + epsilon;
            second.map_or(sheet, |s| s.t.min(sheet))
        }
    };
    if far > 0.0 && far.is_finite() { encode_traced_texel(far, first.t) } else { 0 }
}

/// A traced shadow map's texel: the distance to the far side of the first occluder in the low half and
/// the distance to its first surface in the high half, each an IEEE half float (WGSL's
/// `unpack2x16float`; 2⁻¹¹ relative precision, far below the test's 1 % tolerance; distances up to
/// 65 504 m). 0 where nothing is hit.
pub fn encode_traced_texel(far: f32, first: f32) -> u32 {
    let half = |d: f32| u32::from(half::f16::from_f32(d.clamp(1e-7, 65_504.0)).to_bits());
    half(far) | (half(first) << 16)
}

/// `(far side, first surface)` of a traced texel ([`encode_traced_texel`]), `None` where nothing is.
pub fn decode_traced_texel(word: u32) -> Option<(f32, f32)> {
    let half = |bits: u32| half::f16::from_bits(bits as u16).to_f32();
    (word != 0).then(|| (half(word & 0xFFFF), half(word >> 16)))
}

/// How far from the plane of a receiver, as a fraction of its distance from the point a traced texel's
/// centre ray hit, that point may lie and still count as the receiver's own surface (about 3°: bent
/// shading normals and gently curved meshes).
pub const TRACED_PLANE_TOLERANCE: f32 = 0.05;

/// A traced texel (`word`, centre ray `direction`) against the receiver `x` (normal `n`) of VPL
/// `vpl_position`: whether the receiver is nearer than the far side of the first occluder (with
/// `bias · d`), and, when it is not, whether the point the centre ray met lies in the receiver's plane.
/// The CPU twin of `traced_test` in `shaders/vpl/gather.wgsl`.
pub fn traced_test(word: u32, vpl_position: Vec3, direction: Vec3, x: Vec3, n: Vec3, bias: f32) -> (bool, bool) {
    let Some((far, first)) = decode_traced_texel(word) else {
        return (true, false);
    };
    let d = (x - vpl_position).length();
    if d <= far + bias * d {
        return (true, false);
    }
    let offset = vpl_position + direction * first - x;
    (false, offset.dot(n).abs() <= TRACED_PLANE_TOLERANCE * offset.length())
}

/// The gather's visibility of a receiver through a traced map's 2×2 texels `taps` (word, centre ray,
/// bilinear weight); the CPU twin of the traced branch of `visibility` in `shaders/vpl/gather.wgsl`.
///
/// Each texel lets the receiver's light through when the receiver is nearer than the far side of its
/// first occluder; and a receiver whose four texels all either do that or met its own surface (its plane
/// through their centre rays' hits) is lit whole. Across one lookup's texels a surface at a slant spans
/// more depth than its solid is thick (at 32², 4 m away and 45°, about 0.7 m): with the far-side test
/// alone the far part of every slanted surface's texels was shadowed, and a single spot-lit room got
/// 0.87 of its light (0.94 at 64², 0.95 at 128²). Stretching the far side over the slant instead lit the
/// next room through the wall wherever a texel saw the wall at a slant (a room lit through a door at twice
/// its light); and counting a texel that met the receiver's plane as lit on its own let a floor light
/// the floor behind a wall standing on it across a texel. A receiver behind a wall has a texel on the
/// wall among its four, which neither sees past it nor lies in its plane.
pub fn traced_visibility(taps: [(u32, Vec3, f32); 4], vpl_position: Vec3, x: Vec3, n: Vec3, bias: f32) -> f32 {
    let mut v = 0.0;
    let mut on_surface = true;
    for (word, direction, weight) in taps {
        let (nearer, in_plane) = traced_test(word, vpl_position, direction, x, n, bias);
        v += if nearer { weight } else { 0.0 };
        on_surface &= nearer || in_plane;
    }
    if on_surface { 1.0 } else { v }
}

/// The depth stored behind a sheet met at distance `d` with cosine `cos` between its normal and the ray:
/// `d (1 + 0.02 + (8/side) tan θ)`. A texel spans up to 4/side radians (the paraboloid's centre) and the
/// gather filters 2×2 texels, so a surface tilted by θ spans up to `d (8/side) tan θ` of depth across what
/// one lookup reads; `tan θ` is capped at 8 (the receivers beyond get less than an eighth of the light by
/// their cosine), and 2 % covers the ray's own precision.
pub fn sheet_depth(d: f32, cos: f32, side: u32) -> f32 {
    let cos = cos.clamp(1e-3, 1.0);
    let tan = ((1.0 - cos * cos).max(0.0).sqrt() / cos).min(8.0);
    d * (1.02 + 8.0 / side.max(1) as f32 * tan)
}

/// Total surface area of the snapshot, m².
pub fn surface_area(snapshot: &SceneSnapshot) -> f32 {
    snapshot.triangles().map(|(_, t)| triangle_area(&t).max(0.0)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{InputTriangle, SnapshotMaterial};

    /// `a ≈ b` within `rel` of `b`'s magnitude (plus a tiny absolute floor).
    fn close(a: f32, b: f32, rel: f32) -> bool {
        (a - b).abs() <= rel * b.abs().max(1e-12) + 1e-9
    }

    /// `paraboloid_coords` of `vpl_types.wgsl`, in Rust.
    fn paraboloid_coords(normal: Vec3, d: Vec3, side: u32) -> Vec2 {
        let [t, b, n] = shadow_map_basis(normal);
        let local = Vec3::new(d.dot(t), d.dot(b), d.dot(n));
        let uv = Vec2::new(local.x, local.y) / (1.0 + local.z.max(0.0));
        (uv * 0.5 + 0.5) * side as f32
    }

    #[test]
    fn paraboloid_directions_land_in_their_own_texels() {
        for normal in [Vec3::Y, -Vec3::Z, Vec3::new(0.3, -0.5, 0.8).normalize()] {
            let [t, b, n] = shadow_map_basis(normal);
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5 && close(t.length(), 1.0, 1e-5));
            let side = 16;
            let mut inside = 0;
            for y in 0..side {
                for x in 0..side {
                    let Some(d) = paraboloid_direction(normal, side, x, y) else { continue };
                    inside += 1;
                    assert!(d.dot(normal) >= 0.0);
                    let p = paraboloid_coords(normal, d, side);
                    assert!((p - Vec2::new(x as f32 + 0.5, y as f32 + 0.5)).length() < 1e-3, "{normal} ({x}, {y}) → {p}");
                }
            }
            // The disk covers π/4 of the square.
            assert!((inside as f32 / (side * side) as f32 - PI / 4.0).abs() < 0.03, "{inside}");
        }
    }

    /// The depth a traced shadow map of `vpl` (alone in `maps`) stores towards `p`, ∞ where nothing is.
    fn stored_depth(maps: &[u32], vpl: &Vpl, side: u32, p: Vec3) -> f32 {
        let uv = paraboloid_coords(vpl.normal, (p - vpl.position).normalize(), side);
        let stored = maps[(uv.y as u32 * side + uv.x as u32) as usize];
        decode_traced_texel(stored).map_or(f32::INFINITY, |(far, _)| far)
    }

    #[test]
    fn traced_shadow_maps_keep_the_first_surface_lit_and_shadow_what_lies_behind_a_thin_wall() {
        // A floor, and a 4 cm wall standing on it at x ∈ [1, 1.04].
        let mut triangles = quad([Vec3::new(-5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0)], 0).to_vec();
        let mesh = bevy::prelude::Mesh::from(bevy::math::primitives::Cuboid::from_corners(Vec3::new(1.0, 0.0, -5.0), Vec3::new(1.04, 3.0, 5.0)));
        triangles.extend(crate::scene::mesh_triangles(&mesh, &bevy::prelude::GlobalTransform::from_translation(Vec3::new(1.02, 1.5, 0.0)), 0).expect("mesh"));
        let snapshot = SceneSnapshot::build(triangles, vec![material(0.5)], vec![], vec![]);
        let vpl = Vpl { position: Vec3::new(0.0, 0.01, 0.0), normal: Vec3::Y, flux: Vec3::ONE, bounce: 1 };
        let side = 32;
        let maps = traced_shadow_maps(&snapshot, &[vpl], side);
        let lookup = |p: Vec3| stored_depth(&maps, &vpl, side, p);
        // The wall's own face (1 m away) is in front of its stored far side; a point on the floor behind
        // the wall (3 m away) is behind it; so is the back face of the wall itself.
        let face = Vec3::new(1.0, 0.5, 0.3);
        assert!((face - vpl.position).length() < lookup(face), "the lit face of the wall is shadowed");
        let behind = Vec3::new(3.0, 0.0, 0.3);
        assert!((behind - vpl.position).length() > lookup(behind) + 0.05, "light goes through the wall");
        let far_floor = Vec3::new(-3.0, 0.0, 0.5);
        assert!((far_floor - vpl.position).length() <= lookup(far_floor), "the open floor is shadowed");
    }

    /// The gather's visibility of `x` (normal `n`) through VPL `vpl`'s traced map (alone in `maps`), as
    /// `gather.wgsl` reads it (2×2 bilinear texels), with and without the receiver-plane test.
    fn gathered_visibility(maps: &[u32], vpl: &Vpl, side: u32, x: Vec3, n: Vec3) -> (f32, f32) {
        let p = paraboloid_coords(vpl.normal, (x - vpl.position).normalize(), side) - 0.5;
        let (base, f) = (p.floor(), p - p.floor());
        let taps = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(ox, oy)| {
            let t = (base + Vec2::new(ox as f32, oy as f32)).clamp(Vec2::ZERO, Vec2::splat(side as f32 - 1.0));
            let (tx, ty) = (t.x as u32, t.y as u32);
            let word = maps[(ty * side + tx) as usize];
            let direction = paraboloid_direction(vpl.normal, side, tx, ty).unwrap_or(vpl.normal);
            let weight = if ox == 1 { f.x } else { 1.0 - f.x } * if oy == 1 { f.y } else { 1.0 - f.y };
            (word, direction, weight)
        });
        let far_only = taps
            .iter()
            .filter(|(word, direction, _)| traced_test(*word, vpl.position, *direction, x, n, crate::vpl::prepare::TRACED_DEPTH_BIAS).0)
            .map(|t| t.2)
            .sum();
        (traced_visibility(taps, vpl.position, x, n, crate::vpl::prepare::TRACED_DEPTH_BIAS), far_only)
    }

    #[test]
    fn traced_maps_light_a_slanted_floor_whole_and_not_the_floor_behind_a_wall() {
        // A 10 cm floor slab and a 4 cm wall standing on it at x ∈ [1, 1.04]; a VPL on a wall at x = −2,
        // 1 m up, facing +x: it sees the floor at a slant up to the wall, and the wall hides the floor
        // beyond it.
        let slab = |lo: Vec3, hi: Vec3| {
            let mesh = bevy::prelude::Mesh::from(bevy::math::primitives::Cuboid::from_corners(lo, hi));
            crate::scene::mesh_triangles(&mesh, &bevy::prelude::GlobalTransform::from_translation((lo + hi) / 2.0), 0).expect("mesh")
        };
        let mut triangles = slab(Vec3::new(-2.0, -0.1, -5.0), Vec3::new(5.0, 0.0, 5.0));
        triangles.extend(slab(Vec3::new(1.0, 0.0, -5.0), Vec3::new(1.04, 3.0, 5.0)));
        let snapshot = SceneSnapshot::build(triangles, vec![material(0.5)], vec![], vec![]);
        let vpl = Vpl { position: Vec3::new(-1.99, 1.0, 0.0), normal: Vec3::X, flux: Vec3::ONE, bounce: 1 };
        let side = 32;
        let maps = traced_shadow_maps(&snapshot, &[vpl], side);
        let mut far_only_sum = 0.0;
        let mut count = 0;
        for i in 0..24 {
            for j in 0..9 {
                let x = Vec3::new(-1.5 + 2.35 * i as f32 / 23.0, 0.0, -2.0 + 0.5 * j as f32);
                let (v, far_only) = gathered_visibility(&maps, &vpl, side, x, Vec3::Y);
                assert!(v > 0.999, "the floor at {x} in front of the wall is shadowed: {v}");
                far_only_sum += far_only;
                count += 1;
            }
        }
        // Without the plane test, the far side of the 10 cm slab shadows part of the slanted floor: what
        // this test guards against.
        let far_only = far_only_sum / count as f32;
        assert!(far_only < 0.97, "the far-side test alone keeps {far_only} of the floor lit: the test sees no bias to fix");
        // Behind the wall, from just past the depth tolerance (1 % of 3 m) at its foot on, the plane test
        // adds nothing.
        let mut behind = 0.0;
        for i in 0..20 {
            for j in 0..9 {
                let x = Vec3::new(1.1 + 2.0 * i as f32 / 19.0, 0.0, -2.0 + 0.5 * j as f32);
                let (v, far_only) = gathered_visibility(&maps, &vpl, side, x, Vec3::Y);
                assert_eq!(v, far_only, "the floor behind the wall at {x} is lit through it by the plane test");
                behind += v;
            }
        }
        assert!(behind / 180.0 < 0.05, "{} of the floor behind the wall is lit", behind / 180.0);
    }

    #[test]
    fn traced_texels_keep_both_distances() {
        for (far, first) in [(1.0, 0.5), (123.4, 120.0), (0.011, 0.01), (4000.0, 3999.0)] {
            let (f, s) = decode_traced_texel(encode_traced_texel(far, first)).unwrap();
            assert!(close(f, far, 1e-3) && close(s, first, 1e-3), "({far}, {first}) → ({f}, {s})");
        }
        assert_eq!(decode_traced_texel(0), None);
    }

    #[test]
    fn traced_shadow_maps_shadow_behind_a_sheet_without_a_back() {
        // A 1 m sheet (one quad, as a `Plane3d` panel) 1 m over a floor, and a VPL 0.5 m over the sheet
        // facing down: the floor under the sheet is shadowed (its second surface, the floor, is no exit
        // from the sheet), the sheet itself and the open floor are lit.
        let mut triangles = quad([Vec3::new(-5.0, 0.0, -5.0), Vec3::new(-5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(5.0, 0.0, -5.0)], 0).to_vec();
        triangles.extend(quad([Vec3::new(-0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, 0.5), Vec3::new(-0.5, 1.0, 0.5)], 0));
        let snapshot = SceneSnapshot::build(triangles, vec![material(0.5)], vec![], vec![]);
        let vpl = Vpl { position: Vec3::new(0.0, 1.5, 0.0), normal: Vec3::NEG_Y, flux: Vec3::ONE, bounce: 1 };
        let side = 32;
        let maps = traced_shadow_maps(&snapshot, &[vpl], side);
        let lookup = |p: Vec3| stored_depth(&maps, &vpl, side, p);
        let distance = |p: Vec3| (p - vpl.position).length();
        for under in [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.2, 0.0, -0.3)] {
            assert!(distance(under) > lookup(under) + 0.5, "light goes through the sheet to {under}: stored {}", lookup(under));
        }
        for on in [Vec3::new(0.1, 1.0, 0.05), Vec3::new(-0.4, 1.0, 0.3)] {
            assert!(distance(on) <= lookup(on), "the sheet shadows itself at {on}");
        }
        let open = Vec3::new(2.5, 0.0, 0.0);
        assert!(distance(open) <= lookup(open), "the open floor is shadowed");
    }

    fn quad(corners: [Vec3; 4], material: u32) -> [InputTriangle; 2] {
        let [a, b, c, d] = corners;
        [InputTriangle::flat([a, b, c], material), InputTriangle::flat([a, c, d], material)]
    }

    /// The six inner faces of the box `[-h, h]³`, all with material 0.
    fn closed_box(h: f32) -> Vec<InputTriangle> {
        let p = |x: f32, y: f32, z: f32| Vec3::new(x * h, y * h, z * h);
        let mut t = Vec::new();
        t.extend(quad([p(-1., -1., -1.), p(1., -1., -1.), p(1., -1., 1.), p(-1., -1., 1.)], 0));
        t.extend(quad([p(-1., 1., -1.), p(-1., 1., 1.), p(1., 1., 1.), p(1., 1., -1.)], 0));
        t.extend(quad([p(-1., -1., -1.), p(-1., 1., -1.), p(1., 1., -1.), p(1., -1., -1.)], 0));
        t.extend(quad([p(-1., -1., 1.), p(1., -1., 1.), p(1., 1., 1.), p(-1., 1., 1.)], 0));
        t.extend(quad([p(-1., -1., -1.), p(-1., -1., 1.), p(-1., 1., 1.), p(-1., 1., -1.)], 0));
        t.extend(quad([p(1., -1., -1.), p(1., 1., -1.), p(1., 1., 1.), p(1., -1., 1.)], 0));
        t
    }

    fn material(albedo: f32) -> SnapshotMaterial {
        SnapshotMaterial { diffuse: Vec3::splat(albedo), ..SnapshotMaterial::DEFAULT_GREY }
    }

    fn snapshot(triangles: Vec<InputTriangle>, albedo: f32) -> SceneSnapshot {
        let mut s = SceneSnapshot::default();
        s.set_geometry(triangles, vec![material(albedo)]);
        s
    }

    /// A box moved inside a lit room: only the light paths whose rays ran near its old or new place are
    /// walked again, only the shadow-map texels whose rays pass there are traced, and the VPLs and maps
    /// are those of a walk from scratch.
    #[test]
    fn a_moved_box_rewalks_only_the_paths_and_texels_near_it_and_gives_the_full_result() {
        let mut scene = snapshot(closed_box(2.0), 0.7);
        let cube = crate::scene::MeshGeometry::new(
            crate::scene::mesh_local_triangles(&bevy::prelude::Mesh::from(bevy::prelude::Cuboid::new(0.8, 0.8, 0.8))).unwrap(),
        );
        let cube = std::sync::Arc::new(cube);
        scene.set_instance(100, cube, bevy::math::Affine3A::from_translation(Vec3::new(-1.0, -1.6, 0.6)), 0);
        scene.commit();
        let lights = [SnapshotLight::Point { position: Vec3::new(0.5, 1.5, -0.4), intensity: Vec3::splat(500.0), inverse_range_squared: 0.0 }];
        let settings = WalkSettings { paths: 400, bounces: 4, seed: 3 };
        let side = 16;
        let mut paths = VplPaths::walk(&scene, &lights, &[], None, settings);
        let maps = traced_shadow_maps(&scene, &paths.vpls, side);
        let still = paths.clone();

        let before = scene.instance(100).unwrap().bounds;
        scene.set_instance_transform(100, bevy::math::Affine3A::from_translation(Vec3::new(-0.5, -1.6, 0.6)));
        scene.commit();
        let after = scene.instance(100).unwrap().bounds;
        let changed = [before, after];
        let (origin, walked) = paths.rewalk(&scene, &lights, &[], None, settings, &changed).expect("the same paths, so kept where they can be");
        let full = VplPaths::walk(&scene, &lights, &[], None, settings);
        let differ = (0..full.len()).filter(|&k| full.vpls[full.vpl_offsets[k] as usize..full.vpl_offsets[k + 1] as usize] != still.vpls[still.vpl_offsets[k] as usize..still.vpl_offsets[k + 1] as usize]).count();
        assert!(differ >= 10, "the move changes {differ} paths: too few to tell");
        assert!(walked > 0 && walked < paths.len() / 2, "{walked} of {} paths walked again", paths.len());
        assert_eq!(paths, full, "the paths kept and walked again are the walk from scratch");
        assert_eq!(origin.len(), paths.vpls.len());

        let (updated, traced) = traced_shadow_maps_update(&scene, &paths.vpls, side, &maps, &origin, &changed);
        let total = paths.vpls.len() * (side * side) as usize;
        assert!(traced > 0 && traced < total / 2, "{traced} of {total} texels traced");
        let fresh = traced_shadow_maps(&scene, &paths.vpls, side);
        assert_eq!(updated.len(), fresh.len());
        let wrong = updated.iter().zip(&fresh).filter(|(a, b)| a != b).count();
        assert_eq!(wrong, 0, "texels that differ from the maps traced from scratch");

        // Other settings cannot keep any path.
        let more = WalkSettings { paths: 500, ..settings };
        assert!(paths.rewalk(&scene, &lights, &[], None, more, &changed).is_none());
        assert_eq!(paths, VplPaths::walk(&scene, &lights, &[], None, more));
    }

    /// A spot light at the centre of a floor-only scene: every path hits the floor, and the bounce-1 VPLs'
    /// total flux is the light's flux in its cone times the floor's albedo (what the RSM's texels sum to).
    #[test]
    fn first_bounce_vpls_carry_exactly_the_reflected_flux_of_the_light() {
        let floor = quad(
            [Vec3::new(-50., 0., -50.), Vec3::new(-50., 0., 50.), Vec3::new(50., 0., 50.), Vec3::new(50., 0., -50.)],
            0,
        )
        .to_vec();
        let rho = 0.6;
        let snap = snapshot(floor, rho);
        let (scale, offset) = SnapshotLight::spot_scale_offset(0.5, 0.5);
        let intensity = Vec3::new(100.0, 50.0, 25.0);
        let spot = SnapshotLight::Spot {
            position: Vec3::new(0.0, 1.0, 0.0),
            direction: Vec3::NEG_Y,
            intensity,
            inverse_range_squared: 0.0,
            spot_scale: scale,
            spot_offset: offset,
        };
        let vpls = generate_vpls(&snap, &[spot], &[], None, WalkSettings { paths: 1024, bounces: 1, seed: 3 });
        assert_eq!(vpls.len(), 1024);
        let total: Vec3 = vpls.iter().map(|v| v.flux).sum();
        // Hard cone (inner = outer): Φ = I · 2π(1 − cos 0.5).
        let expected = intensity * TAU * (1.0 - 0.5f32.cos()) * rho;
        for c in 0..3 {
            assert!(close(total[c], expected[c], 1e-4), "channel {c}: {} vs {}", total[c], expected[c]);
        }
        assert!(vpls.iter().all(|v| v.bounce == 1 && v.normal.y > 0.99 && v.position.y > 0.0));
        // Stable: the same inputs give the same VPLs.
        assert_eq!(vpls, generate_vpls(&snap, &[spot], &[], None, WalkSettings { paths: 1024, bounces: 1, seed: 3 }));
    }

    /// White furnace: inside a closed box of albedo ρ no light escapes, so the flux reflected by the k-th
    /// surfaces light reaches is exactly Φ·ρᵏ (the per-bounce energy a path tracer's k-th bounce carries
    /// in a closed scene). The bounce-k VPLs must carry it for every k: exactly for the first bounce, and
    /// within the Russian roulette's noise (1.5 % with 4096 stratified paths) for the others.
    #[test]
    fn random_walks_carry_the_per_bounce_energy_of_a_white_furnace() {
        let rho = 0.8;
        let snap = snapshot(closed_box(1.0), rho);
        let intensity = Vec3::splat(10.0);
        let point = SnapshotLight::Point { position: Vec3::new(0.1, 0.2, -0.1), intensity, inverse_range_squared: 0.0 };
        let bounces = 4;
        let vpls = generate_vpls(&snap, &[point], &[], None, WalkSettings { paths: 4096, bounces, seed: 1 });
        let emitted = intensity.x * 4.0 * PI;
        for k in 1..=bounces {
            let flux: f32 = vpls.iter().filter(|v| v.bounce == k).map(|v| v.flux.x).sum();
            let expected = emitted * rho.powi(k as i32);
            let tolerance = if k == 1 { 1e-3 } else { 0.015 };
            assert!(close(flux, expected, tolerance), "bounce {k}: {flux} vs {expected}");
        }
        // Every path reaches the first surface; about ρ of them survive each further bounce.
        assert_eq!(vpls.iter().filter(|v| v.bounce == 1).count(), 4096);
        let second = vpls.iter().filter(|v| v.bounce == 2).count() as f32;
        assert!(close(second, 4096.0 * rho, 0.02), "{second}");
    }

    /// The same furnace-like closed box seen by the path tracer: at a point inside, the irradiance of the
    /// light reflected once (the tracer's "direct" incident radiance) and twice ("indirect" with one extra
    /// bounce) equals what the bounce-1 and bounce-2 VPLs deliver there, `Σ Φ/π · G`.
    #[cfg(feature = "reference")]
    #[test]
    fn random_walks_agree_with_the_path_tracer_bounce_by_bounce() {
        use crate::reference::{ReferenceSettings, incident_radiance};
        use crate::scene::SnapshotLightEntry;
        use crate::ssbc::geometry_term;
        let rho = 0.7;
        let point = SnapshotLight::Point { position: Vec3::new(0.1, 0.2, -0.1), intensity: Vec3::splat(10.0), inverse_range_squared: 0.0 };
        let light = SnapshotLightEntry { entity: bevy::prelude::Entity::PLACEHOLDER, light: point, shadows_enabled: true };
        let snap = SceneSnapshot::build(closed_box(1.0), vec![material(rho)], vec![], vec![light]);
        let (p, n) = (Vec3::new(0.2, -0.3, 0.1), Vec3::Y);
        // The tracer: E = π · mean of the incident radiance over cosine-distributed directions.
        let mut rng = crate::sampling::rng_for(5, 0);
        let directions: Vec<Vec3> = (0..4096).map(|_| cosine_hemisphere(n, crate::sampling::uniform2(&mut rng))).collect();
        let traced = |max_bounces: Option<u32>, part: usize| {
            let settings = ReferenceSettings { max_bounces, ..Default::default() };
            let sum: f32 = directions
                .iter()
                .enumerate()
                .map(|(i, d)| incident_radiance(&snap, p, *d, &settings, 4, i as u64)[part].x)
                .sum();
            PI * sum / directions.len() as f32
        };
        let (once, twice) = (traced(None, 1), traced(Some(1), 2));
        let vpls = generate_vpls(&snap, &[point], &[], None, WalkSettings { paths: 4096, bounces: 2, seed: 9 });
        let gathered = |k: u32| -> f32 {
            vpls.iter().filter(|v| v.bounce == k).map(|v| v.flux.x / PI * geometry_term(p, n, v.position, v.normal)).sum()
        };
        let (e1, e2) = (gathered(1), gathered(2));
        eprintln!("reflected once: VPLs {e1}, tracer {once}; twice: VPLs {e2}, tracer {twice}");
        // ρ² of the light is left after two reflections: the second is about ρ times the first.
        assert!(once > 1.0 && twice > 0.4 * once && twice < once, "{once} {twice}");
        assert!(close(e1, once, 0.05), "light reflected once: VPLs {e1}, tracer {once}");
        assert!(close(e2, twice, 0.06), "light reflected twice: VPLs {e2}, tracer {twice}");
    }

    #[test]
    fn directional_light_paths_cover_the_beam_and_hit_the_floor_at_its_illuminance() {
        let floor = quad(
            [Vec3::new(-2., 0., -2.), Vec3::new(-2., 0., 2.), Vec3::new(2., 0., 2.), Vec3::new(2., 0., -2.)],
            0,
        )
        .to_vec();
        let snap = snapshot(floor, 0.5);
        let sun = SnapshotLight::Directional { direction: Vec3::NEG_Y, illuminance: Vec3::splat(1000.0) };
        let vpls = generate_vpls(&snap, &[sun], &[], None, WalkSettings { paths: 4096, bounces: 1, seed: 0 });
        let total: f32 = vpls.iter().map(|v| v.flux.x).sum();
        // 16 m² of floor at 1000 lx, albedo 0.5; the beam rectangle has a 0.1 % margin: within 1 %.
        assert!(close(total, 8000.0, 0.01), "{total}");
    }

    /// The sun over the atrium: most of its beam lands on the outside of the roof. Guided by a viewer
    /// inside, the paths go through the opening instead, and the flux that enters stays the same.
    #[test]
    fn guided_paths_go_where_the_viewer_is_and_keep_the_flux() {
        let snap = crate::scenes::sponza_like_snapshot();
        let sun = snap.lights[0].light;
        let inside = |v: &Vpl| v.position.y < 5.99 && v.position.x.abs() < 6.0 && v.position.z.abs() < 4.0;
        let settings = WalkSettings { paths: 2048, bounces: 1, seed: 2 };
        let uniform = generate_vpls(&snap, &[sun], &[], None, settings);
        let guide = EmissionGuide::from_pilots(&pilot_hits(&snap, &sun), &[crate::scenes::sponza_like::CAMERA_POSITION]);
        let guided = generate_vpls(&snap, &[sun], &[], Some(&[guide]), settings);
        let share = |v: &[Vpl]| v.iter().filter(|v| inside(v)).count() as f32 / v.len() as f32;
        let flux_in = |v: &[Vpl]| v.iter().filter(|v| inside(v)).map(|v| v.flux.x).sum::<f32>();
        assert!(share(&uniform) < 0.2, "uniform: {}", share(&uniform));
        assert!(share(&guided) > 0.6, "guided: {}", share(&guided));
        // Same expected flux through the opening (Monte Carlo noise of the uniform estimate: ~10 %).
        let (a, b) = (flux_in(&uniform), flux_in(&guided));
        assert!(close(b, a, 0.1), "{b} vs {a}");
        // The flux that enters is E⊥ × the opening's area across the beam, reflected by the floor (albedo
        // 0.45) and a column (0.8) it lands on: between the two albedos.
        let entering = crate::scenes::sponza_like::SUN_LUX * 12.0 * (-SUN.normalize().y);
        assert!(b > 0.45 * entering * 0.97 && b < 0.8 * entering, "{b} vs {entering}");
    }

    const SUN: Vec3 = crate::scenes::sponza_like::SUN_DIRECTION;

    #[test]
    fn ism_points_are_spread_by_area_and_every_run_covers_the_scene() {
        let snap = snapshot(closed_box(1.0), 0.5);
        let points = ism_points(&snap, 6000, 7);
        assert_eq!(points.len(), 6000);
        // Any run of 600 points puts about 100 on each of the six faces.
        for start in [0usize, 1234, 5400] {
            let mut faces = [0u32; 6];
            for p in &points[start..start + 600] {
                let q = p.position;
                let i = if q.y < -0.999 { 0 } else if q.y > 0.999 { 1 } else if q.z < -0.999 { 2 } else if q.z > 0.999 { 3 } else if q.x < -0.999 { 4 } else { 5 };
                faces[i] += 1;
            }
            assert!(faces.iter().all(|&f| (60..=140).contains(&f)), "{faces:?}");
        }
        assert!(close(surface_area(&snap), 24.0, 1e-5));
        assert!(close(bounding_radius(automatic_bound(600, 24.0)), 0.2, 1e-5));
    }

    #[test]
    fn an_emissive_panel_starts_paths_whose_vpls_give_its_closed_form_irradiance() {
        // A black 1 × 0.6 m panel of radiance Le, 0.8 m over a 40 m floor of albedo 0.5.
        let le = Vec3::new(30.0, 20.0, 10.0);
        let glow = SnapshotMaterial { emissive: le, diffuse: Vec3::ZERO, ..SnapshotMaterial::DEFAULT_GREY };
        let y = 0.8;
        let mut triangles =
            quad([Vec3::new(-0.5, y, -0.3), Vec3::new(0.5, y, -0.3), Vec3::new(0.5, y, 0.3), Vec3::new(-0.5, y, 0.3)], 1).to_vec();
        triangles.extend(quad([Vec3::new(-20.0, 0.0, -20.0), Vec3::new(-20.0, 0.0, 20.0), Vec3::new(20.0, 0.0, 20.0), Vec3::new(20.0, 0.0, -20.0)], 0));
        let snap = SceneSnapshot::build(triangles, vec![material(0.5), glow], vec![], vec![]);
        let (emitters, _) = crate::emitters::sample_emitters(&snap, 1.0, crate::emitters::MAX_EMITTER_SAMPLES);
        let settings = WalkSettings { paths: 4096, bounces: 1, seed: 5 };
        let vpls = generate_vpls(&snap, &[], &emitters, None, settings);
        assert_eq!(vpls, generate_vpls(&snap, &[], &emitters, None, settings), "the same inputs give the same VPLs");

        // Bounce 0: on the panel, both faces, with the panel's two-sided flux 2 π Le A in all.
        let direct: Vec<&Vpl> = vpls.iter().filter(|v| v.bounce == 0).collect();
        assert_eq!(direct.len(), 4096);
        let area = 0.6;
        let emitted: Vec3 = direct.iter().map(|v| v.flux).sum();
        let want = 2.0 * PI * le * area;
        assert!((emitted - want).abs().max_element() < 1e-3 * want.x, "{emitted} vs {want}");
        let down = direct.iter().filter(|v| v.normal.y < 0.0).count();
        assert!((down as i32 - 2048).abs() < 100, "{down} of 4096 face the floor");
        assert!(direct.iter().all(|v| (v.position.y - y).abs() < 1e-2 && v.normal.y.abs() > 0.999));

        // Their irradiance at the floor is the closed form's (what the gather adds, unclamped and unshadowed).
        for p in [Vec3::ZERO, Vec3::new(0.4, 0.0, 0.1), Vec3::new(-1.2, 0.0, 0.9)] {
            let e: Vec3 = direct
                .iter()
                .map(|v| {
                    let to = p - v.position;
                    let w = to.normalize();
                    v.flux / PI * v.normal.dot(w).max(0.0) * (-w.y).max(0.0) / to.length_squared()
                })
                .sum();
            for (channel, got) in [(le.x, e.x), (le.y, e.y), (le.z, e.z)] {
                let want = crate::emitters::parallel_rectangle_irradiance(channel, y, [-0.5 - p.x, 0.5 - p.x], [-0.3 - p.z, 0.3 - p.z]);
                assert!(close(got, want, 0.04), "at {p}: {got} lx vs {want} lx");
            }
        }
        // Bounce 1: the floor reflects ρ of the down face's flux π Le A (the floor catches nearly all of it).
        let reflected: Vec3 = vpls.iter().filter(|v| v.bounce == 1).map(|v| v.flux).sum();
        let want = 0.5 * PI * le * area;
        assert!(((reflected - want) / want).abs().max_element() < 0.03, "{reflected} vs {want}");
        assert!(vpls.iter().filter(|v| v.bounce == 1).all(|v| v.position.y.abs() < 1e-2 && v.normal.y > 0.99));
    }
}
