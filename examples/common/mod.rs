//! What the examples share: the headless fallback of the windowed examples, and the command line, the
//! Markdown section replacement and the medians of the report examples.
#![allow(dead_code, reason = "each example uses a different subset")]

use std::path::{Path, PathBuf};

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::headless::{HeadlessMethod, HeadlessOptions, HeadlessReport, run_and_write};
use bevy_diffuse_gi::scenes::StandardScene;

/// No display: renders one 512² frame of `scene` with `method` headless on the first Vulkan device and
/// writes `out/{tool}.exr` and a tonemapped `out/{tool}.png`.
pub fn render_headless(tool: &str, scene: StandardScene, method: GiMethod) -> AppExit {
    let out = PathBuf::from(format!("out/{tool}.exr"));
    let options = HeadlessOptions {
        scene,
        method: HeadlessMethod::Gi(method),
        size: UVec2::new(512, 512),
        out: out.clone(),
        ..default()
    };
    println!("{tool}: no display found; rendering headless on the first Vulkan device");
    match run_and_write(&options) {
        Ok(report) => {
            let png = out.with_extension("png");
            if let Err(e) = report.image.write_png_tonemapped(&png, 1.0) {
                eprintln!("{tool}: {e}");
                return AppExit::error();
            }
            println!("{tool}: wrote {} (and {}, linear)", png.display(), out.display());
            AppExit::Success
        }
        Err(message) => {
            eprintln!("{tool}: {message}");
            AppExit::error()
        }
    }
}

/// The command line of a report example.
pub struct ReportArgs {
    pub sections: Vec<String>,
    pub rounds: usize,
    pub docs: Option<PathBuf>,
}

/// Parses `[--section NAME]... [--rounds N] [--docs FILE.md]` (default: every section, 3 rounds);
/// `--help` prints `usage` and exits with status 0.
pub fn parse_report_args(sections: &[&str], usage: &str) -> Result<ReportArgs, String> {
    let mut args = ReportArgs { sections: Vec::new(), rounds: 3, docs: None };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--section" => {
                let name = value()?;
                if !sections.contains(&name.as_str()) {
                    return Err(format!("--section: unknown section `{name}`; {usage}"));
                }
                args.sections.push(name);
            }
            "--rounds" => {
                let text = value()?;
                args.rounds = text
                    .parse()
                    .ok()
                    .filter(|r| (1..=20).contains(r))
                    .ok_or_else(|| format!("--rounds: `{text}` is not 1..=20"))?;
            }
            "--docs" => args.docs = Some(PathBuf::from(value()?)),
            "--help" | "-h" => {
                println!("{usage}");
                std::process::exit(0);
            }
            other => return Err(format!("unknown flag `{other}`; {usage}")),
        }
    }
    if args.sections.is_empty() {
        args.sections = sections.iter().map(|s| s.to_string()).collect();
    }
    Ok(args)
}

/// Replaces the text between `<!-- {tool}:{name} -->` and `<!-- /{tool}:{name} -->` in `path`.
pub fn replace_section(path: &Path, tool: &str, name: &str, body: &str) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (open, close) = (format!("<!-- {tool}:{name} -->"), format!("<!-- /{tool}:{name} -->"));
    let (Some(start), Some(end)) = (text.find(&open), text.find(&close)) else {
        return Err(format!("{}: no {open} … {close} markers", path.display()));
    };
    let updated = format!("{}{open}\n{body}{}", &text[..start], &text[end..]);
    std::fs::write(path, updated).map_err(|e| format!("{}: {e}", path.display()))
}

pub fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// Median of the last `timed` frame intervals of a headless run, in milliseconds.
pub fn frame_ms(report: &HeadlessReport, timed: usize) -> f64 {
    let frames: Vec<f64> =
        report.sidecar["frame_ms"].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default();
    median(&frames[frames.len().saturating_sub(timed)..])
}
