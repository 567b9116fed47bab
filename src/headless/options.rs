//! Command-line options of the headless renderer.

use std::path::PathBuf;

use bevy::math::UVec2;

use crate::scenes::StandardScene;

/// What produces the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HeadlessMethod {
    /// Bevy's own direct lighting, no GI.
    None,
    /// The CPU path tracer ([`crate::reference`]).
    Reference,
}

impl HeadlessMethod {
    /// Every accepted `--method` value.
    pub const NAMES: &'static [&'static str] = &["none", "reference"];

    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "none" => Ok(Self::None),
            "reference" => Ok(Self::Reference),
            other => Err(format!(
                "unknown method `{other}`: expected one of {}",
                Self::NAMES.join(", ")
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Reference => "reference",
        }
    }
}

/// Everything the headless renderer can be told.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HeadlessOptions {
    pub scene: StandardScene,
    /// Image size in pixels.
    pub size: UVec2,
    /// Frames rendered before the image is kept (GPU methods), so that temporal smoothing settles. They
    /// are counted once Bevy draws the scene steadily (see [`super::SETTLE_READBACKS`]).
    pub frames: u32,
    /// The EXR to write; a JSON sidecar goes beside it.
    pub out: PathBuf,
    pub method: HeadlessMethod,
    /// Write only what the GI method adds (`shared/METRICS.md`).
    pub indirect_only: bool,
    /// Path-tracer samples per pixel.
    pub spp: u32,
    /// Random seed of the path tracer.
    pub seed: u64,
    /// Path tracer: keep indirect light with at most this many bounces.
    pub max_bounces: Option<u32>,
    /// Exposure override (EV100); the scene's own otherwise.
    pub ev100: Option<f32>,
    /// Path tracer only: shade the direct light with Bevy's Burley lobe instead of Lambert's, to compare
    /// the direct image with Bevy's pixel for pixel.
    pub burley_direct: bool,
    /// Path tracer only: trace through pixel centres (no pixel filter), as the rasteriser does.
    pub pixel_centers: bool,
}

impl Default for HeadlessOptions {
    fn default() -> Self {
        Self {
            scene: StandardScene::Cornell,
            size: UVec2::splat(256),
            frames: 8,
            out: PathBuf::from("out/render.exr"),
            method: HeadlessMethod::None,
            indirect_only: false,
            spp: 2048,
            seed: 0,
            max_bounces: None,
            ev100: None,
            burley_direct: false,
            pixel_centers: false,
        }
    }
}

/// Usage text of the `headless` example.
pub const USAGE: &str = "\
usage: headless [--scene cornell|PATH.glb] [--size WxH] [--frames N] [--out FILE.exr]
                [--method none|reference] [--indirect-only] [--spp N] [--seed S]
                [--max-bounces N] [--ev100 EV] [--burley-direct] [--pixel-centers]

  --scene          a standard scene name or a glTF 2.0 file            (default cornell)
  --size           image size in pixels, 1..=8192 each                  (default 256x256)
  --frames         frames to render once the scene shows, before the image is kept (default 8)
  --out            the linear float EXR to write; FILE.json goes beside it (default out/render.exr)
  --method         none = Bevy's direct light; reference = CPU path tracer (default none)
  --indirect-only  write only the indirect light the method adds
  --spp            path-tracer samples per pixel, 1..=1048576            (default 2048)
  --seed           path-tracer random seed                               (default 0)
  --max-bounces    path tracer: keep indirect light of at most N bounces (default all)
  --ev100          exposure override in EV100                            (default: the scene's)
  --burley-direct  path tracer: shade direct light with Bevy's Burley lobe (for the direct check)
  --pixel-centers  path tracer: one ray through each pixel centre, no pixel filter (for the direct check)";

fn value<'a>(flag: &str, args: &mut impl Iterator<Item = &'a str>) -> Result<&'a str, String> {
    args.next().ok_or_else(|| format!("{flag} needs a value"))
}

fn number<T: std::str::FromStr>(flag: &str, text: &str, min: T, max: T) -> Result<T, String>
where
    T: PartialOrd + std::fmt::Display + Copy,
{
    let v: T = text
        .parse()
        .map_err(|_| format!("{flag}: `{text}` is not a valid number"))?;
    // Written so that NaN fails too.
    if !(v >= min && v <= max) {
        return Err(format!("{flag}: {v} is outside {min}..={max}"));
    }
    Ok(v)
}

/// Parses the command line (without the program name). Errors name the flag and the problem.
pub fn parse_args<'a>(args: impl IntoIterator<Item = &'a str>) -> Result<HeadlessOptions, String> {
    let mut options = HeadlessOptions::default();
    let mut out_given = false;
    let mut args = args.into_iter();
    while let Some(flag) = args.next() {
        match flag {
            "--scene" => options.scene = StandardScene::parse(value(flag, &mut args)?)?,
            "--size" => {
                let text = value(flag, &mut args)?;
                let (w, h) = text
                    .split_once(['x', 'X'])
                    .ok_or_else(|| format!("--size: `{text}` is not WIDTHxHEIGHT"))?;
                options.size = UVec2::new(number("--size", w, 1, 8192)?, number("--size", h, 1, 8192)?);
            }
            "--frames" => options.frames = number(flag, value(flag, &mut args)?, 1, 100_000)?,
            "--out" => {
                let text = value(flag, &mut args)?;
                if !text.ends_with(".exr") {
                    return Err(format!("--out: `{text}` must end in .exr"));
                }
                options.out = PathBuf::from(text);
                out_given = true;
            }
            "--method" => options.method = HeadlessMethod::parse(value(flag, &mut args)?)?,
            "--indirect-only" => options.indirect_only = true,
            "--spp" => options.spp = number(flag, value(flag, &mut args)?, 1, 1 << 20)?,
            "--seed" => options.seed = number(flag, value(flag, &mut args)?, 0, u64::MAX)?,
            "--max-bounces" => options.max_bounces = Some(number(flag, value(flag, &mut args)?, 1, 1000)?),
            "--ev100" => {
                let v: f32 = number(flag, value(flag, &mut args)?, -64.0, 64.0)?;
                options.ev100 = Some(v);
            }
            "--burley-direct" => options.burley_direct = true,
            "--pixel-centers" => options.pixel_centers = true,
            "--help" | "-h" => return Err(USAGE.to_string()),
            other => return Err(format!("unknown flag `{other}`\n{USAGE}")),
        }
    }
    if !out_given {
        let scene = match &options.scene {
            StandardScene::Gltf(path) => path.file_stem().map_or("gltf".into(), |s| s.to_string_lossy().into_owned()),
            other => other.name(),
        };
        let suffix = if options.indirect_only { "_indirect" } else { "" };
        options.out = PathBuf::from(format!("out/{scene}_{}{suffix}.exr", options.method.name()));
    }
    Ok(options)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_full_command_line() {
        let o = parse_args(
            "--scene cornell --size 128x64 --frames 3 --out a/b.exr --method reference --indirect-only \
             --spp 32 --seed 7 --max-bounces 2 --ev100 1.5"
                .split_whitespace(),
        )
        .unwrap();
        assert_eq!(o.size, UVec2::new(128, 64));
        assert_eq!((o.frames, o.spp, o.seed, o.max_bounces), (3, 32, 7, Some(2)));
        assert_eq!(o.method, HeadlessMethod::Reference);
        assert!(o.indirect_only);
        assert_eq!(o.out, PathBuf::from("a/b.exr"));
        assert_eq!(o.ev100, Some(1.5));
    }

    #[test]
    fn bad_input_names_the_problem() {
        let err = |s: &str| parse_args(s.split_whitespace()).unwrap_err();
        assert!(err("--size 0x10").contains("--size"));
        assert!(err("--size big").contains("WIDTHxHEIGHT"));
        assert!(err("--method magic").contains("unknown method `magic`"));
        assert!(err("--scene nowhere.glb").contains("does not exist"));
        assert!(err("--scene kitchen").contains("unknown scene"));
        assert!(err("--frames").contains("needs a value"));
        assert!(err("--spp -3").contains("not a valid number"));
        assert!(err("--out x.png").contains(".exr"));
        assert!(err("--wat").contains("unknown flag"));
        assert!(err("--ev100 NaN").contains("--ev100"));
    }

    #[test]
    fn default_output_name_follows_scene_and_method() {
        let o = parse_args("--method reference --indirect-only".split_whitespace()).unwrap();
        assert_eq!(o.out, PathBuf::from("out/cornell_reference_indirect.exr"));
    }
}
