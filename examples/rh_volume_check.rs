//! Compares a Radiance Hints volume read back from the GPU with the path-traced radiance field at the
//! hints (the ground truth *of the volume*, before reconstruction), on `cornell`.
//!
//! ```sh
//! cargo run --release --example headless -- --scene cornell --method rh --frames 40 --dump-volume out/volume.json
//! cargo run --release --example rh_volume_check -- out/volume.json [--bounces N] [--stride S]
//! ```
//! For every `S`-th hint per axis it traces the radiance arriving from 128 directions (paths with at most
//! `N + 1` reflections, the light an RH volume with `N` extra bounces holds; origins jittered over the cell
//! as the injection does), projects it onto the same SH, and prints the ratio RH / truth of the irradiance
//! on the six axis-aligned normals, grouped by how many cells the hint is from the volume's boundary.

use std::process::ExitCode;

use bevy::math::{Mat4, UVec3, Vec2, Vec3};
use bevy_diffuse_gi::reference::{ReferenceSettings, incident_radiance};
use bevy_diffuse_gi::sampling::{SobolStream, uniform_sphere};
use bevy_diffuse_gi::scenes::{cellar_snapshot, cornell_snapshot};
use bevy_diffuse_gi::sh::{ShOrder, ShRgb};
use rayon::prelude::*;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rh_volume_check: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The command line.
#[derive(clap::Parser)]
#[command(name = "rh_volume_check", about = "Checks a dumped Radiance Hints volume (--dump-volume) against the path tracer at the hints.")]
struct Cli {
    /// The volume dump written by `headless --dump-volume`
    volume: std::path::PathBuf,
    /// Bounces of the traced radiance at the hints
    #[arg(long, value_name = "N", default_value_t = 2)]
    bounces: u32,
    /// Check every S-th hint along each axis
    #[arg(long, value_name = "S", default_value_t = 2)]
    stride: u32,
    /// The scene the volume was made in
    #[arg(long, default_value = "cornell", value_parser = ["cornell", "cellar"])]
    scene: String,
    /// List every checked hint
    #[arg(long)]
    list: bool,
}

fn run() -> Result<(), String> {
    use clap::Parser;
    let cli = Cli::try_parse().unwrap_or_else(|e| e.exit());
    let path = &cli.volume.display().to_string();
    let bounces = cli.bounces;
    let stride = cli.stride.max(1);
    let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let res = UVec3::from_array(serde_json::from_value(v["resolution"].clone()).map_err(|e| e.to_string())?);
    let coefficients = v["sh_coefficients"].as_u64().unwrap_or(4) as usize;
    let order = if coefficients == 9 { ShOrder::Three } else { ShOrder::Two };
    let matrix: Vec<f32> = serde_json::from_value(v["world_from_local"].clone()).map_err(|e| e.to_string())?;
    let world_from_local = Mat4::from_cols_slice(&matrix);
    let sh: Vec<f32> = serde_json::from_value(v["sh"].clone()).map_err(|e| e.to_string())?;
    let validity: Vec<f32> = serde_json::from_value(v["albedo_validity"].clone()).map_err(|e| e.to_string())?;

    let scene = if cli.scene == "cellar" { cellar_snapshot() } else { cornell_snapshot() };
    let list = cli.list;
    let settings = ReferenceSettings {
        max_bounces: Some(bounces.max(1)),
        seed: 7,
        ..Default::default()
    };
    let normals = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z];
    let mut hints = Vec::new();
    for z in (0..res.z).step_by(stride as usize) {
        for y in (0..res.y).step_by(stride as usize) {
            for x in (0..res.x).step_by(stride as usize) {
                hints.push(UVec3::new(x, y, z));
            }
        }
    }
    const DIRECTIONS: u32 = 128;
    let rows: Vec<(u32, [f32; 6], [f32; 6], Vec3)> = hints
        .par_iter()
        .filter_map(|&c| {
            let index = (c.x + res.x * (c.y + res.y * c.z)) as usize;
            if validity[index * 4 + 3] < 0.5 {
                return None;
            }
            let cell = 1.0 / res.as_vec3();
            let local = (c.as_vec3() + 0.5) * cell - 0.5;
            let stream = SobolStream::new(11, index as u64);
            let mut truth = ShRgb::new(order);
            let centre = world_from_local.transform_point3(local);
            let mut used = 0u32;
            for k in 0..DIRECTIONS {
                let u = stream.vertex_4d(k, 0);
                // Half-cell jitter, as the injection's default, and only origins the centre sees (the hint
                // stands for the free part of its cell).
                let jitter = (Vec3::new(u[2], u[3], stream.vertex_4d(k, 1)[0]) - 0.5) * 0.5;
                let origin = world_from_local.transform_point3(local + jitter * cell);
                let to = origin - centre;
                if to.length() > 1e-6 && scene.occluded(centre, to.normalize(), 0.0, to.length()) {
                    continue;
                }
                used += 1;
                let d = uniform_sphere(Vec2::new(u[0], u[1]));
                let [_, direct, indirect] = incident_radiance(&scene, origin, d, &settings, 8, index as u64 * 1000 + k as u64);
                // Light reflected once is the tracer's direct class; each extra bounce adds indirect light.
                let radiance = if bounces == 0 { direct } else { direct + indirect };
                // Incident radiance × 4π solid angle per direction (divided by the directions used below).
                truth.add_sample(d, radiance * (4.0 * std::f32::consts::PI));
            }
            for c in truth.coefficients.iter_mut() {
                *c /= used.max(1) as f32;
            }
            let mut rh = ShRgb::new(order);
            for i in 0..coefficients {
                let base = index * 3 * coefficients + 3 * i;
                rh.coefficients[i] = Vec3::new(sh[base], sh[base + 1], sh[base + 2]);
            }
            let luminance = |e: Vec3| e.dot(Vec3::new(0.2126, 0.7152, 0.0722));
            let ring = c.min(res - 1 - c).min_element();
            Some((
                ring,
                normals.map(|n| luminance(rh.irradiance(n).max(Vec3::ZERO))),
                normals.map(|n| luminance(truth.irradiance(n).max(Vec3::ZERO))),
                world_from_local.transform_point3(local),
            ))
        })
        .collect();

    if list {
        // The hints where RH exceeds the truth most (sum over the six normals).
        let mut sorted: Vec<_> = rows.iter().collect();
        sorted.sort_by(|a, b| {
            let excess = |r: &&(u32, [f32; 6], [f32; 6], Vec3)| r.1.iter().sum::<f32>() - r.2.iter().sum::<f32>();
            excess(b).total_cmp(&excess(a))
        });
        for r in sorted.iter().take(12) {
            println!("hint at {:>6.2}: RH {:?}\n           truth {:?}", r.3, r.1.map(|v| (v * 100.0).round() / 100.0), r.2.map(|v| (v * 100.0).round() / 100.0));
        }
    }
    println!("RH / path-traced irradiance at the hints ({} hints, {bounces} extra bounces)", rows.len());
    println!("cells from boundary |   +X     -X     +Y     -Y     +Z     -Z  | hints");
    let max_ring = rows.iter().map(|r| r.0).max().unwrap_or(0);
    for ring in 0..=max_ring {
        let group: Vec<_> = rows.iter().filter(|r| r.0 == ring).collect();
        if group.is_empty() {
            continue;
        }
        let mut line = format!("{ring:>19} |");
        for axis in 0..6 {
            let rh: f32 = group.iter().map(|r| r.1[axis]).sum();
            let truth: f32 = group.iter().map(|r| r.2[axis]).sum();
            line += &format!(" {:6.3}", rh / truth.max(1e-12));
        }
        println!("{line} | {}", group.len());
    }
    let (rh, truth): (f32, f32) = rows.iter().fold((0.0, 0.0), |(a, b), r| (a + r.1.iter().sum::<f32>(), b + r.2.iter().sum::<f32>()));
    println!("all                 | {:.3}", rh / truth.max(1e-12));
    for (name, side) in [("x < 0", -1.0f32), ("x > 0", 1.0)] {
        let (rh, truth): (f32, f32) = rows
            .iter()
            .filter(|r| r.3.x * side > 0.0)
            .fold((0.0, 0.0), |(a, b), r| (a + r.1.iter().sum::<f32>(), b + r.2.iter().sum::<f32>()));
        println!("{name:<19} | {:.3}  (RH {rh:.1}, truth {truth:.1})", rh / truth.max(1e-12));
    }
    Ok(())
}
