//! Renders a standard scene with no window and writes a linear float EXR plus a JSON sidecar.
//!
//! `cargo run --release --features tools --example headless -- --scene cornell --method reference --spp 256 --out out/c.exr`
//! Run with `--help` for every flag, its unit and its default.

use std::process::ExitCode;

use bevy_diffuse_gi::headless::{parse_args, run_and_write};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    // Bad flags: clap's message and status 2; --help: the flags and status 0.
    let options = parse_args(args.iter().map(String::as_str)).unwrap_or_else(|e| e.exit());
    match run_and_write(&options) {
        Ok(report) => {
            println!("wrote {} and {}", options.out.display(), options.out.with_extension("json").display());
            for (suffix, _) in &report.extra_images {
                println!("wrote {}", bevy_diffuse_gi::headless::sibling(&options.out, suffix, "exr").display());
            }
            ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("headless: {message}");
            ExitCode::FAILURE
        }
    }
}
