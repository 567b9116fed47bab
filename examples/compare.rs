//! Compares two linear EXRs with the metrics of `shared/METRICS.md` and writes a false-colour difference PNG.
//!
//! `cargo run --release --features tools --example compare -- METHOD.exr GROUND_TRUTH.exr [--diff OUT.png] [--scale S]`
//!
//! Prints the block relative RMSE (the headline number), the per-pixel relative RMSE, the energy ratio,
//! the share of 4×4 blocks more than 50 % off and, with the `flip` feature, the mean FLIP error. The difference image maps `|a − r|` divided by the mean of
//! the reference to black → blue → green → yellow → red at `S` (default 1.0); it goes beside the first
//! image as `A.diff.png` unless `--diff` names it. `--blocks N` prints, for N × N pixel blocks, the ratio of
//! the image's luminance to the reference's (one row of numbers per row of blocks): where a method is
//! too dark or too bright.

use std::path::PathBuf;
use std::process::ExitCode;

use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::metrics;

/// The command line.
#[derive(clap::Parser)]
#[command(name = "compare", about = "Compares a linear EXR with a reference (shared/METRICS.md) and writes a difference PNG.")]
struct Cli {
    /// The method's image
    image: PathBuf,
    /// The ground truth
    reference: PathBuf,
    /// Where the false-colour difference PNG goes [default: IMAGE.diff.png]
    #[arg(long, value_name = "OUT.png")]
    diff: Option<PathBuf>,
    /// |a − r| / mean(r) that maps to red; positive
    #[arg(long, value_name = "S", default_value_t = 1.0, value_parser = positive)]
    scale: f32,
    /// Print the luminance ratio image / reference per block of N × N pixels
    #[arg(long, value_name = "N")]
    blocks: Option<u32>,
}

fn positive(text: &str) -> Result<f32, String> {
    text.parse::<f32>().ok().filter(|s| *s > 0.0 && s.is_finite()).ok_or_else(|| format!("`{text}` is not a positive number"))
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("compare: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    use clap::Parser;
    // Bad flags: clap's message and status 2; --help: status 0.
    let Cli { image: a_path, reference: r_path, diff, scale, blocks } = Cli::try_parse().unwrap_or_else(|e| e.exit());
    let a = HdrImage::read(&a_path).map_err(|e| e.to_string())?;
    let r = HdrImage::read(&r_path).map_err(|e| e.to_string())?;

    #[cfg(feature = "flip")]
    let m = metrics::compare_with_flip(&a, &r, 1.0).map_err(|e| e.to_string())?;
    #[cfg(not(feature = "flip"))]
    let m = metrics::compare(&a, &r).map_err(|e| e.to_string())?;

    println!("image            {}", a_path.display());
    println!("reference        {}", r_path.display());
    println!("block rel. RMSE  {:.4}   ({} blocks of 4x4)", m.block_relative_rmse, m.blocks);
    println!("pixel rel. RMSE  {:.4}   ({} pixels)", m.relative_rmse, m.pixels);
    println!("energy ratio     {:.4}", m.energy_ratio);
    println!("blocks > 50 % off {:.4}", m.blocks_over_half_off);
    match m.flip {
        Some(flip) => println!("mean FLIP        {flip:.4}"),
        None => println!("mean FLIP        (build with --features flip)"),
    }

    if let Some(n) = blocks.filter(|n| *n > 0) {
        let luminance = |c: [f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
        println!("luminance ratio per {n}×{n} block (image / reference; · where the reference is black or uncovered):");
        for y in (0..r.height).step_by(n as usize) {
            let row: Vec<String> = (0..r.width)
                .step_by(n as usize)
                .map(|x| match (a.region_mean(x, y, x + n, y + n), r.region_mean(x, y, x + n, y + n)) {
                    (Some(av), Some(rv)) if luminance(rv) > 0.0 => format!("{:5.2}", luminance(av) / luminance(rv)),
                    _ => "    ·".to_string(),
                })
                .collect();
            println!("{}", row.join(" "));
        }
    }

    let diff_path = diff.unwrap_or_else(|| bevy_diffuse_gi::headless::sibling(&a_path, "diff", "png"));
    let picture = metrics::difference_image(&a, &r, scale).map_err(|e| e.to_string())?;
    if let Some(parent) = diff_path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    }
    picture.save(&diff_path).map_err(|e| format!("{}: {e}", diff_path.display()))?;
    println!("difference       {}", diff_path.display());
    Ok(())
}
