//! Writes a viewable PNG of a linear EXR: `scale · rgb`, Reinhard `x / (1 + x)`, then sRGB.
//!
//! `cargo run --release --example tonemap -- IN.exr OUT.png [--scale S]` (default scale 1).

use std::process::ExitCode;

use bevy_diffuse_gi::hdr_image::HdrImage;

const USAGE: &str = "usage: tonemap IN.exr OUT.png [--scale S]   (S > 0, default 1)";

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("tonemap: {message}");
            ExitCode::from(2)
        }
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let mut files = Vec::new();
    let mut scale = 1.0f32;
    while let Some(arg) = args.next() {
        if arg == "--scale" {
            let text = args.next().ok_or("--scale needs a value")?;
            scale = text
                .parse()
                .ok()
                .filter(|s: &f32| *s > 0.0 && s.is_finite())
                .ok_or_else(|| format!("--scale: `{text}` is not a positive number"))?;
        } else {
            files.push(arg);
        }
    }
    let [input, output] = files.as_slice() else {
        return Err(USAGE.into());
    };
    let image = HdrImage::read(input).map_err(|e| e.to_string())?;
    image.write_png_tonemapped(output, scale).map_err(|e| e.to_string())
}
