//! Renders the path-traced ground truth of a scene as the average of several independent seeds, and
//! measures how converged it is.
//!
//! `cargo run --release --features tools --example ground_truth -- --scene cornell --spp 512 --seeds 8 --out assets/ground_truth/cornell.exr`
//!
//! Accepts every flag of the `headless` example (`--size`, `--max-bounces`, `--ev100`, …) plus `--seeds N`
//! (default 4); `--seed S` is the first seed. Writes `OUT` (the indirect-only image, what GI methods are
//! compared with), `OUT.full.exr` and `OUT.direct.exr` (not with `--indirect-only`), and `OUT.json` with:
//! * `seed_vs_seed`: metrics of the first seed's indirect image against the second's — the convergence of
//!   one render (`shared/METRICS.md` asks for < 3 % block relative RMSE);
//! * `half_vs_half`: the average of the even seeds against the average of the odd ones. Each half carries
//!   twice the variance of the full average, so the average's own noise is about half this number.

use std::process::ExitCode;

use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, sibling};
use bevy_diffuse_gi::metrics;
use serde_json::json;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("ground_truth: {message}");
            ExitCode::FAILURE
        }
    }
}

fn average(images: &[&HdrImage]) -> Result<HdrImage, String> {
    HdrImage::average(images).map_err(|e| e.to_string())
}

/// The ground-truth tool's command line: every flag of the headless renderer plus `--seeds`.
#[derive(clap::Parser)]
#[command(name = "ground_truth", about = "Renders a path-traced ground truth as the average of several seeds.")]
struct Cli {
    /// Independent seeds to average, 2..=1024 (from --seed on)
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u64).range(2..=1024))]
    seeds: u64,
    #[command(flatten)]
    headless: headless::HeadlessArgs,
}

fn run() -> Result<(), String> {
    use clap::Parser;
    // Bad flags: clap's message and status 2; --help: the flags and status 0.
    let cli = Cli::try_parse().unwrap_or_else(|e| e.exit());
    let seeds = cli.seeds;
    let mut options = cli.headless.into_options()?;
    options.method = HeadlessMethod::Reference;
    let first_seed = options.seed;

    let mut renders = Vec::new();
    let mut seconds = Vec::new();
    for k in 0..seeds {
        let mut o = options.clone();
        o.seed = first_seed + k;
        let report = headless::run(&o)?;
        let trace_seconds = report.sidecar["reference"]["seconds"].as_f64().unwrap_or(f64::NAN);
        eprintln!("seed {}: traced in {trace_seconds:.1} s", o.seed);
        seconds.push(trace_seconds);
        let get = |name: &str| {
            report
                .extra_images
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, i)| i.clone())
                .ok_or_else(|| format!("the tracer did not return a {name} image"))
        };
        renders.push((get("full")?, get("direct")?, get("indirect")?));
    }

    let pick = |f: fn(&(HdrImage, HdrImage, HdrImage)) -> &HdrImage, filter: &dyn Fn(usize) -> bool| {
        renders.iter().enumerate().filter(|(i, _)| filter(*i)).map(|(_, r)| f(r)).collect::<Vec<_>>()
    };
    let all = |_: usize| true;
    let full = average(&pick(|r| &r.0, &all))?;
    let direct = average(&pick(|r| &r.1, &all))?;
    let indirect = average(&pick(|r| &r.2, &all))?;
    let even = average(&pick(|r| &r.2, &|i| i % 2 == 0))?;
    let odd = average(&pick(|r| &r.2, &|i| i % 2 == 1))?;
    let seed_vs_seed = metrics::compare(&renders[0].2, &renders[1].2).map_err(|e| e.to_string())?;
    let half_vs_half = metrics::compare(&even, &odd).map_err(|e| e.to_string())?;

    indirect.write_exr(&options.out).map_err(|e| e.to_string())?;
    if !options.indirect_only {
        for (suffix, image) in [("full", &full), ("direct", &direct)] {
            image.write_exr(sibling(&options.out, suffix, "exr")).map_err(|e| e.to_string())?;
        }
    }
    let command: Vec<String> = std::env::args().skip(1).collect();
    let sidecar = json!({
        "command": format!("cargo run --release --features tools --example ground_truth -- {}", command.join(" ")),
        "scene": options.scene.name(),
        "size": [options.size.x, options.size.y],
        "spp_per_seed": options.spp,
        "seeds": (first_seed..first_seed + seeds).collect::<Vec<_>>(),
        "total_spp": options.spp as u64 * seeds,
        "max_bounces": options.max_bounces,
        "trace_seconds_per_seed": seconds,
        "seed_vs_seed": seed_vs_seed,
        "half_vs_half": half_vs_half,
        "estimated_block_noise_of_average": half_vs_half.block_relative_rmse / 2.0,
    });
    let json_path = options.out.with_extension("json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&sidecar).map_err(|e| e.to_string())?)
        .map_err(|e| format!("{}: {e}", json_path.display()))?;
    println!(
        "seed vs seed: block rel. RMSE {:.4} (pixel {:.4}); half vs half {:.4} → average ≈ {:.4} block noise",
        seed_vs_seed.block_relative_rmse,
        seed_vs_seed.relative_rmse,
        half_vs_half.block_relative_rmse,
        half_vs_half.block_relative_rmse / 2.0
    );
    println!("wrote {} and its .json", options.out.display());
    Ok(())
}
