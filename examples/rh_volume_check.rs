//! Where a Radiance Hints volume's error comes from: the hints' field, the basis it is stored in, or where
//! the reconstruction reads it. Checks a volume read back from the GPU against the path-traced radiance
//! field at the same hints, and reconstructs every pixel on the CPU as `reconstruct.wgsl` does, from either
//! field, with several bases and sample layouts, against the committed ground truth.
//!
//! ```sh
//! cargo run --release --features tools --example headless -- --scene cellar --method rh --frames 32 --dump-volume out/cellar.json
//! cargo run --release --features tools --example rh_volume_check -- out/cellar.json --scene cellar [--images out/check]
//! # also `--scene room_SEED`, a generated room (its truth in assets/ground_truth/rooms/)
//! ```
//! For every valid hint it traces the radiance arriving from `--directions` directions (origins jittered
//! over the free part of the cell as the injection's receivers are; all bounces, or `--bounces N`) and
//! prints how the GPU's field compares: its band-0 irradiance (the mean over all normals, which no basis
//! changes) and the irradiance on the six axes, in total and as quantiles over the hints; `--list` the
//! hints furthest off, `--region` every hint in a box, `--split-x` the totals on either side of a plane.
//!
//! With `--images DIR` it also reconstructs the image: a pixel's irradiance is read from the eight hints
//! around each reconstruction sample (trilinear, hints behind a surface as seen from the sample left out,
//! samples pulled back before surfaces), with the traced field integrated exactly, as SH order 2 (Eq. 7's
//! linear form, Hazel's, Hazel's with the exact vertical irradiance the plugin stores), SH order 3 or an
//! ambient cube, and with the GPU's field in the plugin's forms, for the paper's sample layout and the
//! plugin's; it prints the metrics of each against the ground truth and writes the EXRs.
//!
//! This is how the departures in `docs/radiance_hints.md` (§ the field near surfaces) were found: with the
//! traced field the plugin's reconstruction reaches block relative RMSE 0.12 on `cornell` and 0.23 on
//! `open_field`, so what was left was the GPU field near surfaces.

use std::path::PathBuf;
use std::process::ExitCode;

use bevy::math::{Mat4, Quat, UVec3, Vec3, Vec4};
use bevy::prelude::Transform;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::reference::{CameraProjection, ReferenceCamera, ReferenceSettings, incident_radiance};
use bevy_diffuse_gi::sampling::{SobolStream, fibonacci_sphere, orthonormal_basis};
use bevy_diffuse_gi::scene::SceneSnapshot;
use bevy_diffuse_gi::scenes;
use bevy_diffuse_gi::sh::{self, ShOrder, ShRgb};
use rayon::prelude::*;

/// The command line.
#[derive(clap::Parser)]
#[command(name = "rh_volume_check", about = "Checks a dumped Radiance Hints volume (--dump-volume) against the path tracer at the hints.")]
struct Cli {
    /// The volume dump written by `headless --dump-volume`
    volume: PathBuf,
    /// The scene the volume was made in: cornell, cellar, sponza_like, open_field or room_SEED
    #[arg(long, default_value = "cornell", value_parser = parse_scene)]
    scene: String,
    /// Directions traced per hint
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(4..=65536))]
    directions: u32,
    /// Paths per direction
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=1024))]
    paths: u32,
    /// Trace light of at most N extra bounces (what a volume with N extra bounces holds) [default: all]
    #[arg(long, value_name = "N")]
    bounces: Option<u32>,
    /// List the 15 hints furthest below the traced field: by ratio, or by missing light
    #[arg(long, value_parser = ["ratio", "deficit"])]
    list: Option<String>,
    /// Print every hint inside the world box X0,Y0,Z0,X1,Y1,Z1: GPU and traced irradiance on the six axes
    #[arg(long, value_name = "BOX", value_parser = parse_box)]
    region: Option<[Vec3; 2]>,
    /// Band-0 totals on either side of the plane x = X
    #[arg(long, value_name = "X")]
    split_x: Option<f32>,
    /// Reconstruct the image with each basis and layout, write the EXRs here and print their metrics
    #[arg(long, value_name = "DIR")]
    images: Option<PathBuf>,
}

fn parse_box(text: &str) -> Result<[Vec3; 2], String> {
    let v: Vec<f32> = text.split(',').map(|t| t.trim().parse::<f32>().map_err(|e| e.to_string())).collect::<Result<_, _>>()?;
    if v.len() != 6 {
        return Err("six numbers: X0,Y0,Z0,X1,Y1,Z1".into());
    }
    Ok([Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5])])
}

/// How each reconstructed image turns the field into irradiance.
const BASES: [&str; 9] = [
    "traced_exact",
    "traced_sh2_linear",
    "traced_sh2_hazel",
    "traced_hazel_vertical",
    "traced_sh3_linear",
    "traced_ambient_cube",
    "gpu_sh2_linear",
    "gpu_sh2_hazel",
    "gpu_hazel_vertical",
];
const AXES: [Vec3; 6] = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z];
const PI: f32 = std::f32::consts::PI;
/// π Y₀₀ and (2π/3) Y₁: the band-0 and band-1 weights of the irradiance (Eq. 7; `rh_packed.wgsl`).
const BAND0: f32 = sh::COSINE_LOBE[0] * sh::Y00;
const BAND1: f32 = sh::COSINE_LOBE[1] * sh::Y1;

fn lum(v: Vec3) -> f32 {
    v.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

struct Hint {
    valid: bool,
    /// Traced radiance arriving from each of the shared directions.
    radiance: Vec<Vec3>,
    /// The traced field projected on SH order 3 (order 2 is its first four coefficients).
    sh3: ShRgb,
    /// Traced irradiance on the six axes.
    cube: [Vec3; 6],
    /// The GPU's field: SH coefficients and the exact irradiance facing up and down.
    gpu: ShRgb,
    gpu_vertical: [Vec3; 2],
}

struct Volume {
    res: UVec3,
    world_from_local: Mat4,
    local_from_world: Mat4,
    diagonal: f32,
    voxel: f32,
    hints: Vec<Hint>,
    directions: Vec<Vec3>,
}

/// Hazel's non-linear irradiance of one channel (`rh_packed.wgsl`).
fn hazel(a: f32, b: Vec3, n: Vec3) -> f32 {
    let len = b.length();
    if a <= 0.0 {
        return 0.0;
    }
    if len < 1e-6 * a {
        return a;
    }
    let r = (0.5 * len / a).min(1.0);
    let q = 0.5 * (1.0 + (b / len).dot(n));
    let p = 1.0 + 2.0 * r;
    let alpha = (1.0 - r) / (1.0 + r);
    a * (alpha + (1.0 - alpha) * (p + 1.0) * q.max(0.0).powf(p))
}

/// Irradiance at `n` of an order-2 field (the first four coefficients): Eq. 7 clamped, and Hazel's.
fn sh2_forms(sh: &ShRgb, n: Vec3) -> (Vec3, Vec3) {
    let c = &sh.coefficients;
    let a = (c[0] * BAND0).max(Vec3::ZERO);
    let b = [0, 1, 2].map(|ch| Vec3::new(c[3][ch], c[1][ch], c[2][ch]) * BAND1);
    let linear = Vec3::new(a.x + b[0].dot(n), a.y + b[1].dot(n), a.z + b[2].dot(n)).max(Vec3::ZERO);
    let nonlinear = Vec3::new(hazel(a.x, b[0], n), hazel(a.y, b[1], n), hazel(a.z, b[2], n));
    (linear, nonlinear)
}

/// Hazel's form with the exact irradiance facing up and down (`rh_types::with_vertical`).
fn hazel_vertical(sh: &ShRgb, vertical: [Vec3; 2], n: Vec3) -> Vec3 {
    let (_, e) = sh2_forms(sh, n);
    let axis = if n.y >= 0.0 { Vec3::Y } else { Vec3::NEG_Y };
    let (_, e_axis) = sh2_forms(sh, axis);
    let exact = if n.y >= 0.0 { vertical[0] } else { vertical[1] };
    (e + n.y * n.y * (exact - e_axis)).max(Vec3::ZERO)
}

impl Volume {
    fn coords(&self, index: usize) -> UVec3 {
        let i = index as u32;
        UVec3::new(i % self.res.x, (i / self.res.x) % self.res.y, i / (self.res.x * self.res.y))
    }

    fn centre(&self, c: UVec3) -> Vec3 {
        self.world_from_local.transform_point3((c.as_vec3() + 0.5) / self.res.as_vec3() - 0.5)
    }

    fn index(&self, c: UVec3) -> usize {
        (c.x + self.res.x * (c.y + self.res.y * c.z)) as usize
    }

    /// The eight hints around `q` usable from it, with renormalised trilinear weights.
    fn stencil(&self, scene: &SceneSnapshot, q: Vec3) -> Vec<(usize, f32)> {
        let local = self.local_from_world.transform_point3(q);
        let res = self.res.as_vec3();
        let g = ((local + 0.5) * res - 0.5).clamp(Vec3::ZERO, res - 1.0);
        let base = g.floor().as_uvec3().min(self.res - 1);
        let f = (g - base.as_vec3()).clamp(Vec3::ZERO, Vec3::ONE);
        let mut out = Vec::new();
        let mut total = 0.0;
        for i in 0..8u32 {
            let o = UVec3::new(i & 1, (i >> 1) & 1, (i >> 2) & 1);
            let c = (base + o).min(self.res - 1);
            let w = Vec3::select(o.cmpeq(UVec3::ONE), f, 1.0 - f);
            let w = w.x * w.y * w.z;
            let k = self.index(c);
            if w <= 0.0 || !self.hints[k].valid {
                continue;
            }
            let to = self.centre(c) - q;
            let d = to.length();
            if d > 1e-5 && scene.occluded(q, to / d, 0.5 * self.voxel, d) {
                continue;
            }
            out.push((k, w));
            total += w;
        }
        if total < 1e-4 {
            return Vec::new();
        }
        for (_, w) in out.iter_mut() {
            *w /= total;
        }
        out
    }

    /// Irradiance at `n` of the field around `q` in each of [`BASES`], or `None` where no hint is usable.
    fn irradiance(&self, scene: &SceneSnapshot, q: Vec3, n: Vec3) -> Option<[Vec3; 9]> {
        let stencil = self.stencil(scene, q);
        if stencil.is_empty() {
            return None;
        }
        let m = self.directions.len() as f32;
        let mut exact = Vec3::ZERO;
        let mut cube = Vec3::ZERO;
        let mut traced = ShRgb::new(ShOrder::Three);
        let mut gpu = ShRgb::new(self.hints[0].gpu.order);
        let (mut traced_vertical, mut gpu_vertical) = ([Vec3::ZERO; 2], [Vec3::ZERO; 2]);
        for &(k, w) in &stencil {
            let h = &self.hints[k];
            let e: Vec3 = self.directions.iter().zip(&h.radiance).map(|(d, l)| *l * d.dot(n).max(0.0)).sum();
            exact += w * e * (4.0 * PI / m);
            cube += w * AXES.iter().zip(&h.cube).map(|(axis, v)| *v * axis.dot(n).max(0.0).powi(2)).sum::<Vec3>();
            traced.add_scaled(&h.sh3, w);
            gpu.add_scaled(&h.gpu, w);
            for side in 0..2 {
                traced_vertical[side] += w * h.cube[2 + side];
                gpu_vertical[side] += w * h.gpu_vertical[side];
            }
        }
        let (traced_linear, traced_hazel) = sh2_forms(&traced, n);
        let (gpu_linear, gpu_hazel) = sh2_forms(&gpu, n);
        Some([
            exact,
            traced_linear,
            traced_hazel,
            hazel_vertical(&traced, traced_vertical, n),
            traced.irradiance(n).max(Vec3::ZERO),
            cube,
            gpu_linear,
            gpu_hazel,
            hazel_vertical(&gpu, gpu_vertical, n),
        ])
    }
}

/// A sample layout of the reconstruction (`reconstruct.wgsl`), in cell diagonals `r`: the hemisphere's
/// centre `origin` off the surface, the cone samples `radius` from it at 80°, the first sample on the
/// normal `radius` further out (the paper) or at the centre (the plugin).
#[derive(Clone, Copy)]
struct Layout {
    name: &'static str,
    origin: f32,
    radius: f32,
    first_at_centre: bool,
}

const LAYOUTS: [Layout; 2] = [
    Layout { name: "paper", origin: 0.5, radius: 1.0, first_at_centre: false },
    Layout { name: "plugin", origin: 0.25, radius: 0.5, first_at_centre: true },
];

fn reconstruct(volume: &Volume, scene: &SceneSnapshot, p: Vec3, n: Vec3, layout: Layout, rotation: f32) -> [Vec3; 9] {
    let r = volume.diagonal;
    let origin = p + n * (layout.origin * r);
    let (t, b) = orthonormal_basis(n);
    let cone = 80f32.to_radians();
    let mut sum = [Vec3::ZERO; 9];
    let mut used = 0.0;
    for i in 0..4u32 {
        let (d, len) = if i == 0 {
            (n, if layout.first_at_centre { 0.0 } else { layout.radius * r })
        } else {
            let phi = rotation + std::f32::consts::TAU * (i - 1) as f32 / 3.0;
            (n * cone.cos() + (t * phi.cos() + b * phi.sin()) * cone.sin(), layout.radius * r)
        };
        let mut q = origin + d * len;
        if len > 0.0
            && let Some(hit) = scene.intersect(origin, d, 0.0, len)
        {
            q = origin + d * (hit.t - volume.voxel).max(0.0);
        }
        if let Some(e) = volume.irradiance(scene, q, n) {
            for (s, v) in sum.iter_mut().zip(e) {
                *s += v;
            }
            used += 1.0;
        }
    }
    if used == 0.0 {
        return volume.irradiance(scene, p + n * (0.1 * r), n).unwrap_or([Vec3::ZERO; 9]);
    }
    sum.map(|s| s / used)
}

fn parse_scene(text: &str) -> Result<String, String> {
    if ["cornell", "cellar", "sponza_like", "open_field"].contains(&text) || generated_room(text).is_some() {
        Ok(text.to_string())
    } else {
        Err(format!("`{text}`: expected cornell, cellar, sponza_like, open_field or room_SEED"))
    }
}

/// `room_SEED` → the generated room of that seed.
fn generated_room(scene: &str) -> Option<scenes::GeneratedRoom> {
    scene.strip_prefix("room_").and_then(|seed| seed.parse().ok()).map(scenes::GeneratedRoom::new)
}

fn camera(scene: &str) -> ReferenceCamera {
    use scenes::*;
    if let Some(room) = generated_room(scene) {
        return room.reference_camera();
    }
    let (position, target, fov, ev100) = match scene {
        "cornell" => (cornell::CAMERA_POSITION, Vec3::ZERO, cornell::FOV_Y_DEGREES, CORNELL_EV100),
        "cellar" => (cellar::CAMERA_POSITION, cellar::CAMERA_TARGET, cellar::FOV_Y_DEGREES, CELLAR_EV100),
        "sponza_like" => (sponza_like::CAMERA_POSITION, sponza_like::CAMERA_TARGET, sponza_like::FOV_Y_DEGREES, SPONZA_EV100),
        _ => (open_field::CAMERA_POSITION, open_field::CAMERA_TARGET, open_field::FOV_Y_DEGREES, OPEN_FIELD_EV100),
    };
    let rotation: Quat = Transform::from_translation(position).looking_at(target, Vec3::Y).rotation;
    ReferenceCamera {
        position,
        rotation,
        projection: CameraProjection::Perspective { fov_y: fov.to_radians() },
        exposure: bevy::camera::Exposure { ev100 }.exposure(),
    }
}

fn main() -> ExitCode {
    use clap::Parser;
    // Bad flags: clap's message and status 2; --help: status 0.
    let cli = Cli::try_parse().unwrap_or_else(|e| e.exit());
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rh_volume_check: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Reads the dump and traces the field at every valid hint.
fn load(cli: &Cli, scene: &SceneSnapshot) -> Result<Volume, String> {
    let text = std::fs::read_to_string(&cli.volume).map_err(|e| format!("{}: {e}", cli.volume.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let get = |k: &str| v[k].clone();
    let res = UVec3::from_array(serde_json::from_value(get("resolution")).map_err(|e| format!("resolution: {e}"))?);
    let occ = UVec3::from_array(serde_json::from_value(get("occupancy_resolution")).map_err(|e| format!("occupancy: {e}"))?);
    let coefficients = v["sh_coefficients"].as_u64().unwrap_or(4) as usize;
    // RGB terms per hint in "sh": the SH coefficients, then the irradiance facing up and down.
    let terms = v["field_terms"].as_u64().unwrap_or(coefficients as u64) as usize;
    let order = if coefficients == 9 { ShOrder::Three } else { ShOrder::Two };
    let matrix: Vec<f32> = serde_json::from_value(get("world_from_local")).map_err(|e| e.to_string())?;
    let world_from_local = Mat4::from_cols_slice(&matrix);
    let field: Vec<f32> = serde_json::from_value(get("sh")).map_err(|e| e.to_string())?;
    let validity: Vec<f32> = serde_json::from_value(get("albedo_validity")).map_err(|e| e.to_string())?;
    let extent = (world_from_local * Vec4::new(1.0, 1.0, 1.0, 0.0)).truncate().abs();
    let m = cli.directions;
    let directions: Vec<Vec3> = (0..m).map(|i| fibonacci_sphere(i, m)).collect();
    let settings = ReferenceSettings { seed: 5, max_bounces: cli.bounces.map(|b| b.max(1)), ..Default::default() };
    let first_bounce_only = cli.bounces == Some(0);
    let start = std::time::Instant::now();
    let count = (res.x * res.y * res.z) as usize;
    let hints: Vec<Hint> = (0..count)
        .into_par_iter()
        .map(|index| {
            let c = UVec3::new(index as u32 % res.x, (index as u32 / res.x) % res.y, index as u32 / (res.x * res.y));
            let read = |term: usize| {
                let b = index * 3 * terms + 3 * term;
                Vec3::new(field[b], field[b + 1], field[b + 2])
            };
            let mut gpu = ShRgb::new(order);
            for (i, c) in gpu.coefficients.iter_mut().take(coefficients).enumerate() {
                *c = read(i);
            }
            let gpu_vertical = if terms >= coefficients + 2 { [read(coefficients), read(coefficients + 1)] } else { [Vec3::ZERO; 2] };
            let valid = validity[index * 4 + 3] >= 0.5;
            let mut hint = Hint {
                valid,
                radiance: vec![Vec3::ZERO; m as usize],
                sh3: ShRgb::new(ShOrder::Three),
                cube: [Vec3::ZERO; 6],
                gpu,
                gpu_vertical,
            };
            if !valid {
                return hint;
            }
            let local = (c.as_vec3() + 0.5) / res.as_vec3() - 0.5;
            let centre = world_from_local.transform_point3(local);
            let stream = SobolStream::new(13, index as u64);
            for (k, d) in directions.iter().enumerate() {
                let (mut sum, mut used) = (Vec3::ZERO, 0u32);
                for j in 0..cli.paths {
                    // Receivers over the middle half of the cell (the default jitter), those the centre sees.
                    let u = stream.vertex_4d(k as u32 * cli.paths + j, 0);
                    let origin = world_from_local.transform_point3(local + (Vec3::new(u[0], u[1], u[2]) - 0.5) * 0.5 / res.as_vec3());
                    let to = origin - centre;
                    if to.length() > 1e-6 && scene.occluded(centre, to.normalize(), 0.0, to.length()) {
                        continue;
                    }
                    let stream_id = (index as u64) << 20 | (k as u64) << 8 | j as u64;
                    let [e, direct, indirect] = incident_radiance(scene, origin, *d, &settings, 1, stream_id);
                    sum += e + direct + if first_bounce_only { Vec3::ZERO } else { indirect };
                    used += 1;
                }
                let l = sum / used.max(1) as f32;
                hint.radiance[k] = l;
                hint.sh3.add_sample(*d, l * (4.0 * PI / m as f32));
                for (axis, value) in AXES.iter().zip(hint.cube.iter_mut()) {
                    *value += l * (d.dot(*axis).max(0.0) * 4.0 * PI / m as f32);
                }
            }
            hint
        })
        .collect();
    eprintln!(
        "traced {count} hints ({res} cells of {:.3} m) in {:.1} s",
        (extent / res.as_vec3()).max_element(),
        start.elapsed().as_secs_f32()
    );
    Ok(Volume {
        res,
        world_from_local,
        local_from_world: world_from_local.inverse(),
        diagonal: (extent / res.as_vec3()).length(),
        voxel: (extent / occ.as_vec3()).max_element(),
        hints,
        directions,
    })
}

fn quantiles(mut v: Vec<f32>) -> String {
    if v.is_empty() {
        return "–".into();
    }
    v.sort_by(f32::total_cmp);
    let q = |f: f32| v[((v.len() - 1) as f32 * f) as usize];
    format!("{:.2} {:.2} {:.2} {:.2} {:.2}", q(0.1), q(0.25), q(0.5), q(0.75), q(0.9))
}

/// The GPU field's irradiance on the six axes (the plugin's form: Hazel's, exact facing up and down).
fn gpu_axes(h: &Hint) -> [Vec3; 6] {
    AXES.map(|axis| hazel_vertical(&h.gpu, h.gpu_vertical, axis))
}

fn band0(sh: &ShRgb) -> f32 {
    lum(sh.coefficients[0]) * BAND0
}

/// Band-0 irradiance GPU / traced, summed over the hints binned by their distance to the nearest surface
/// (in cell diagonals, the minimum over 26 rays): whether the field is off near surfaces or everywhere.
fn report_by_distance(volume: &Volume, scene: &SceneSnapshot) {
    const EDGES: [f32; 5] = [0.125, 0.25, 0.5, 1.0, f32::INFINITY];
    let mut bins = [(0.0f64, 0.0f64, 0usize); 5];
    for (i, h) in volume.hints.iter().enumerate().filter(|(_, h)| h.valid) {
        let p = volume.centre(volume.coords(i));
        let nearest = (0..27)
            .filter(|&k| k != 13)
            .map(|k| Vec3::new((k % 3) as f32 - 1.0, ((k / 3) % 3) as f32 - 1.0, (k / 9) as f32 - 1.0).normalize())
            .filter_map(|d| scene.intersect(p, d, 0.0, f32::INFINITY).map(|hit| hit.t))
            .fold(f32::INFINITY, f32::min)
            / volume.diagonal;
        let bin = EDGES.iter().position(|&e| nearest < e).unwrap_or(4);
        bins[bin].0 += band0(&h.gpu) as f64;
        bins[bin].1 += band0(&h.sh3) as f64;
        bins[bin].2 += 1;
    }
    let mut lower = 0.0;
    let cells: Vec<String> = bins
        .iter()
        .zip(EDGES)
        .map(|(&(gpu, traced, n), upper)| {
            let text = format!("[{lower}, {upper}): {:.3} over {n}", gpu / traced.max(1e-30));
            lower = upper;
            text
        })
        .collect();
    println!("band 0 GPU / traced by distance to the nearest surface (cell diagonals): {}", cells.join("; "));
}

fn report_field(cli: &Cli, volume: &Volume) {
    let valid: Vec<(usize, &Hint)> = volume.hints.iter().enumerate().filter(|(_, h)| h.valid).collect();
    let total = |f: &dyn Fn(&Hint) -> f32| valid.iter().map(|(_, h)| f(h) as f64).sum::<f64>();
    let band0_ratio = total(&|h: &Hint| band0(&h.gpu)) / total(&|h: &Hint| band0(&h.sh3));
    println!(
        "{} valid hints; band-0 irradiance GPU / traced, summed: {band0_ratio:.3} ({:.4e} / {:.4e})",
        valid.len(),
        total(&|h: &Hint| band0(&h.gpu)),
        total(&|h: &Hint| band0(&h.sh3))
    );
    let ratios: Vec<f32> = valid.iter().filter(|(_, h)| band0(&h.sh3) > 1e-9).map(|(_, h)| band0(&h.gpu) / band0(&h.sh3)).collect();
    println!("  per hint, quantiles 10/25/50/75/90 %: {}", quantiles(ratios));
    let axes: Vec<String> = (0..6)
        .map(|a| format!("{:.2}", total(&|h: &Hint| lum(gpu_axes(h)[a])) / total(&|h: &Hint| lum(h.cube[a]))))
        .collect();
    println!("irradiance on the axes +X −X +Y −Y +Z −Z, GPU / traced, summed: {}", axes.join(" "));
    if let Some(x) = cli.split_x {
        for above in [false, true] {
            let side: Vec<&Hint> = valid.iter().filter(|(i, _)| (volume.centre(volume.coords(*i)).x > x) == above).map(|(_, h)| *h).collect();
            let ratio = side.iter().map(|h| band0(&h.gpu)).sum::<f32>() / side.iter().map(|h| band0(&h.sh3)).sum::<f32>();
            println!("  x {} {x}: band 0 GPU / traced {ratio:.3} over {} hints", if above { ">" } else { "<" }, side.len());
        }
    }
    let show = |i: usize| {
        let h = &volume.hints[i];
        let round = |v: [Vec3; 6]| v.map(|e| (lum(e) * 100.0).round() / 100.0);
        println!("  hint {} at {:.2}: GPU {:?}", volume.coords(i), volume.centre(volume.coords(i)), round(gpu_axes(h)));
        println!("  {:>28} traced {:?}", "", round(h.cube));
    };
    if let Some(by) = &cli.list {
        let mut listed: Vec<(f32, usize)> =
            valid.iter().filter(|(_, h)| band0(&h.sh3) > 1e-9).map(|(i, h)| (band0(&h.gpu) / band0(&h.sh3), *i)).collect();
        let key = |(r, i): &(f32, usize)| if by == "deficit" { -(1.0 - r) * band0(&volume.hints[*i].sh3) } else { *r };
        listed.sort_by(|a, b| key(a).total_cmp(&key(b)));
        println!("the hints furthest below the traced field (by {by}; irradiance on +X −X +Y −Y +Z −Z):");
        listed.iter().take(15).for_each(|&(_, i)| show(i));
    }
    if let Some([lo, hi]) = cli.region {
        println!("hints in {lo} … {hi} (irradiance on +X −X +Y −Y +Z −Z):");
        for &(i, _) in &valid {
            let p = volume.centre(volume.coords(i));
            if p.cmpge(lo).all() && p.cmple(hi).all() {
                show(i);
            }
        }
    }
}

fn run(cli: Cli) -> Result<(), String> {
    let scene = match cli.scene.as_str() {
        _ if let Some(room) = generated_room(&cli.scene) => room.snapshot(),
        "cornell" => scenes::cornell_snapshot(),
        "cellar" => scenes::cellar_snapshot(),
        "sponza_like" => scenes::sponza_like_snapshot(),
        _ => scenes::open_field_snapshot(),
    };
    let volume = load(&cli, &scene)?;
    report_field(&cli, &volume);
    report_by_distance(&volume, &scene);
    let Some(dir) = &cli.images else {
        return Ok(());
    };
    let folder = if generated_room(&cli.scene).is_some() { "assets/ground_truth/rooms" } else { "assets/ground_truth" };
    let truth_path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("{folder}/{}.exr", cli.scene));
    let truth = HdrImage::read(&truth_path).map_err(|e| e.to_string())?;
    let camera = camera(&cli.scene);
    let (width, height) = (truth.width, truth.height);
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for layout in LAYOUTS {
        let rows: Vec<Vec<Option<[Vec3; 9]>>> = (0..height)
            .into_par_iter()
            .map(|y| {
                (0..width)
                    .map(|x| {
                        let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5, width, height);
                        let hit = scene.intersect_visible(o, d, 0.0, f32::INFINITY)?;
                        let s = scene.surface(o, d, &hit);
                        let n = if s.geometric_normal.dot(d) > 0.0 { -s.geometric_normal } else { s.geometric_normal };
                        let rotation = std::f32::consts::TAU * ((x * 7 + y * 13) % 16) as f32 / 16.0;
                        let e = reconstruct(&volume, &scene, s.position + n * 1e-3, n, layout, rotation);
                        Some(e.map(|e| e * s.diffuse / PI * camera.exposure))
                    })
                    .collect()
            })
            .collect();
        for (b, name) in BASES.iter().enumerate() {
            let mut image = HdrImage::new(width, height);
            for (y, row) in rows.iter().enumerate() {
                for (x, px) in row.iter().enumerate() {
                    if let Some(px) = px {
                        let v = px[b].max(Vec3::ZERO);
                        image.set(x as u32, y as u32, [v.x, v.y, v.z, 1.0]);
                    }
                }
            }
            let m = metrics::compare(&image, &truth).map_err(|e| e.to_string())?;
            println!(
                "layout {:<7} {:<22} block {:.3}  pixel {:.3}  energy {:.3}  blocks > 50 % off {:.3}",
                layout.name, name, m.block_relative_rmse, m.relative_rmse, m.energy_ratio, m.blocks_over_half_off
            );
            image.write_exr(dir.join(format!("{}_{}_{}.exr", cli.scene, layout.name, name))).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
