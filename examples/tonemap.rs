//! Writes a viewable PNG of a linear EXR: `scale · rgb`, Reinhard `x / (1 + x)`, then sRGB.
//!
//! `cargo run --release --features tools --example tonemap -- IN.exr OUT.png [--scale S]` (default scale 1).

use std::process::ExitCode;

use bevy_diffuse_gi::hdr_image::HdrImage;

/// The command line.
#[derive(clap::Parser)]
#[command(name = "tonemap", about = "Writes a viewable PNG of a linear EXR: scale · rgb, Reinhard, then sRGB.")]
struct Cli {
    /// The linear EXR to read
    input: std::path::PathBuf,
    /// The PNG to write
    output: std::path::PathBuf,
    /// Multiplies the linear values first; positive
    #[arg(long, value_name = "S", default_value_t = 1.0, value_parser = positive)]
    scale: f32,
}

fn positive(text: &str) -> Result<f32, String> {
    text.parse::<f32>().ok().filter(|s| *s > 0.0 && s.is_finite()).ok_or_else(|| format!("`{text}` is not a positive number"))
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("tonemap: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    use clap::Parser;
    // Bad flags: clap's message and status 2; --help: status 0.
    let Cli { input, output, scale } = Cli::try_parse().unwrap_or_else(|e| e.exit());
    let image = HdrImage::read(&input).map_err(|e| e.to_string())?;
    image.write_png_tonemapped(&output, scale).map_err(|e| e.to_string())
}
