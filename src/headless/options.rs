//! Command-line options of the headless renderer.

use std::path::PathBuf;

use bevy::math::{UVec2, Vec3};
use bevy::prelude::default;

use crate::camera::{GiMethod, GiOutput};
use crate::vpl::VplSettings;
use crate::drm::{DrmSettings, DrmSolidAngle};
use crate::rsm_gather::RsmGatherSettings;
use crate::radiance_hints::{DepthOcclusion, GridSizing, IrradianceReconstruction, RadianceHintsVolume};
use crate::scenes::StandardScene;
use crate::sh::ShOrder;

/// What produces the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeadlessMethod {
    /// Bevy's own direct lighting, no GI.
    None,
    /// The CPU path tracer ([`crate::reference`]).
    Reference,
    /// One of the plugin's GI methods, on the scene camera's [`DiffuseGi`](crate::camera::DiffuseGi)
    /// (Radiance Hints gets a volume fitted to the scene's bounds).
    Gi(GiMethod),
}

impl HeadlessMethod {
    /// Every accepted `--method` value.
    pub const NAMES: &'static [&'static str] = &["none", "reference", "rh", "vpl", "rsm", "drm"];

    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "none" => Ok(Self::None),
            "reference" => Ok(Self::Reference),
            "radiance_hints" => Ok(Self::Gi(GiMethod::RadianceHints)),
            other => GiMethod::ALL
                .into_iter()
                .find(|m| m.name() == other)
                .map(Self::Gi)
                .ok_or_else(|| format!("unknown method `{other}`: expected one of {}", Self::NAMES.join(", "))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Reference => "reference",
            Self::Gi(method) => method.name(),
        }
    }

    /// The GI method, if this is one.
    pub fn gi(self) -> Option<GiMethod> {
        match self {
            Self::Gi(method) => Some(method),
            _ => None,
        }
    }
}

impl serde::Serialize for HeadlessMethod {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
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
    /// Radiance Hints settings (`--preset` and the `--rh-*` overrides). Out-of-range values are passed
    /// on: the plugin clamps them with one warning, as it would for a game.
    #[serde(skip)]
    pub rh: RadianceHintsVolume,
    /// VPL settings (`--preset` and the `--vpl-*`/`--ssbc-*` overrides), passed on unclamped like `rh`.
    #[serde(skip)]
    pub vpl: VplSettings,
    /// RSM gather settings (`--preset` and the `--rsm-*` overrides), passed on unclamped like `rh`.
    #[serde(skip)]
    pub rsm_gather: RsmGatherSettings,
    /// Direct Radiance Mapping settings (`--preset` and the `--drm-*` overrides), passed on unclamped.
    #[serde(skip)]
    pub drm: DrmSettings,
    /// Fit the hint counts to the scene's proportions (cubic cells), unless `--rh-resolution` was given.
    pub rh_fit_cells: bool,
    /// Radiance Hints: a camera-centred cascade of this many levels (`--rh-cascade N`, innermost box
    /// `--rh-cascade-extent XxYxZ` metres) instead of one volume fitted to the scene.
    pub rh_cascade: Option<(u32, Vec3)>,
    /// GI cameras: reconstruct at half resolution.
    pub half_resolution: bool,
    /// GI cameras: where the bounced light goes.
    #[serde(skip)]
    pub gi_output: GiOutput,
    /// Radiance Hints: write the volume's field to this JSON file after the last frame.
    pub dump_volume: Option<PathBuf>,
    /// GI cameras: a debug view instead of the image (`--indirect-only` selects `IndirectOnly`).
    #[serde(skip)]
    pub debug_view: Option<crate::camera::GiDebugView>,
    /// `dynamic` scene: orbit its light one step per rendered frame. Other scenes: move every GI light on
    /// a 2 cm circle each frame, so that the RSM and the GI volume are recomputed every frame as they are
    /// for a moving light (the dynamic-light timing case).
    pub animate_light: bool,
    /// `dynamic` scene: how many of its objects move (from object 0; 0–10).
    pub animate_meshes: u32,
    /// `dynamic` scene: the pose frame it starts at (the ground truth of frame K is `--pose-frame K`).
    pub pose_frame: f32,
    /// `dynamic` scene: the pose frame where the motion stops.
    pub stop_animation_at: Option<f32>,
    /// `dynamic` scene: static triangles added along the back wall.
    pub extra_triangles: u32,
    /// GI methods: after this many frames of the `--frames`, switch the camera to another method (the
    /// run-time switch a game makes from its settings menu). The new method's settings come from the
    /// same `--preset` and overrides.
    pub switch_method: Option<(u32, GiMethod)>,
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
            rh: RadianceHintsVolume::default(),
            vpl: VplSettings::default(),
            rsm_gather: RsmGatherSettings::default(),
            drm: DrmSettings::default(),
            rh_fit_cells: true,
            rh_cascade: None,
            half_resolution: crate::camera::DiffuseGi::default().half_resolution,
            gi_output: GiOutput::Composite,
            debug_view: None,
            dump_volume: None,
            animate_light: false,
            animate_meshes: 0,
            pose_frame: 0.0,
            stop_animation_at: None,
            extra_triangles: 0,
            switch_method: None,
        }
    }
}

/// Usage text of the `headless` example.
pub const USAGE: &str = "\
usage: headless [--scene cornell|PATH.glb] [--size WxH] [--frames N] [--out FILE.exr]
                [--method none|reference|rh|vpl|rsm|drm] [--indirect-only] [--spp N] [--seed S]
                [--max-bounces N] [--ev100 EV] [--burley-direct] [--pixel-centers]
                [--preset low|medium|high] [--rh-resolution N|XxYxZ] [--rh-longest N]
                [--rh-cell M] [--rh-hints N] [--rh-max-hints N] [--rh-cascade LEVELS]
                [--rh-cascade-extent XxYxZ] [--rh-order 2|3]
                [--rh-samples N] [--rh-bounces N] [--rh-secondary N] [--rh-rmax M]
                [--rh-coverage C] [--rh-jitter J] [--rh-blend A] [--rh-threshold T]
                [--rh-albedo on|off] [--rh-depth-occlusion STEPS] [--rh-reconstruction N]
                [--rh-irradiance linear|nonlinear] [--rh-near-field CELLS]
                [--rh-visibility voxels|none] [--rh-secondary-transport voxel|paper] [--rh-refinement N]
                [--dump-volume FILE.json]
                [--vpl-paths N] [--vpl-bounces N] [--vpl-seed S] [--vpl-bound B] [--vpl-ism-resolution N]
                [--vpl-ism-points N] [--vpl-ism-bias F] [--ssbc-steps N] [--ssbc-solid-angle SR]
                [--ssbc-levels N] [--ssbc-blur on|off]
                [--rsm-samples N] [--rsm-radius R] [--rsm-weights paper|density]
                [--drm-samples N] [--drm-solid-angle 11|14|15]
                [--drm-mip on|off]
                [--half-res|--full-res] [--gi-output composite|irradiance-volume] [--debug-view VIEW]
                [--animate-light] [--animate-meshes N] [--pose-frame K] [--stop-animation-at K]
                [--extra-triangles N] [--switch-method FRAMES:rh|vpl|rsm|drm]

  --scene          cornell, cellar, sponza_like, dynamic or a glTF 2.0 file (default cornell)
  --size           image size in pixels, 1..=8192 each                  (default 256x256)
  --frames         frames to render once the scene shows, before the image is kept (default 8)
  --out            the linear float EXR to write; FILE.json goes beside it (default out/render.exr)
  --method         none = Bevy's direct light; reference = CPU path tracer;
                   rh = Radiance Hints over a volume fitted to the scene;
                   vpl = VPLs with imperfect shadow maps and SSBC;
                   rsm = the RSM gather; drm = Direct Radiance Mapping      (default none)
  --indirect-only  write only the indirect light the method adds
  --spp            path-tracer samples per pixel, 1..=1048576            (default 2048)
  --seed           path-tracer random seed                               (default 0)
  --max-bounces    path tracer: keep indirect light of at most N bounces (default all)
  --ev100          exposure override in EV100                            (default: the scene's)
  --burley-direct  path tracer: shade direct light with Bevy's Burley lobe (for the direct check)
  --pixel-centers  path tracer: one ray through each pixel centre, no pixel filter (for the direct check)
  --preset         the method's preset (RadianceHintsVolume, VplSettings, RsmGatherSettings or
                   DrmSettings)                                          (default medium)
  --rh-*           override one RadianceHintsVolume field (see its docs); the plugin clamps
                   out-of-range values with a warning. --rh-depth-occlusion 0 turns §8 off.
                   The grid: --rh-resolution (fixed counts), --rh-longest N (fixed cubic cells, N
                   along the longest side), --rh-cell/--rh-hints/--rh-max-hints (the adaptive rule's
                   largest cell in m, small-room hints, most hints), --rh-cascade LEVELS and
                   --rh-cascade-extent XxYxZ (a camera-centred cascade instead of one fitted volume)
  --vpl-*          override one VplSettings field: paths, bounces, seed, bound (b in 1/m², 0 = automatic),
                   ism-resolution (texels), ism-points, ism-bias (fraction of the distance)
  --ssbc-*         override an SSBC field of VplSettings: steps (0 = clamped only), solid-angle (sr),
                   levels, blur (on|off)
  --rsm-*          override one RsmGatherSettings field: samples (per pixel and light), radius (fraction
                   of the RSM's side), weights (paper: ξ₁², density: ξ₁)
  --drm-*          override one DrmSettings field: samples (photons per axis of each light face, M = N²),
                   solid-angle (the paper's Eq. 11, 14 or 15), mip (on|off: mip-mapped photons)
  --half-res       compute the bounced light at half resolution (the default)
  --full-res       compute the bounced light at full resolution
  --gi-output      composite (per pixel, default) or irradiance-volume (Bevy's light probe)
  --debug-view     indirect, irradiance, hint-grid, rsm-flux, rsm-normal, rsm-position,
                   vpl-clamped, vpl-compensation or vpl-positions
  --animate-light  dynamic scene: orbit its light one step per rendered frame; other scenes: move the
                   GI lights on a 2 cm circle every frame (times the dynamic-light case)
  --animate-meshes dynamic scene: move its first N objects (0..=10) one step per rendered frame
  --pose-frame     dynamic scene: the pose frame to start at (default 0; the ground truth of a pose)
  --stop-animation-at  dynamic scene: stop the motion at this pose frame
  --extra-triangles    dynamic scene: add about N static triangles (spheres along the back wall)
  --switch-method  after FRAMES of the --frames, switch the camera to the given GI method";

fn value<'a>(flag: &str, args: &mut impl Iterator<Item = &'a str>) -> Result<&'a str, String> {
    args.next().ok_or_else(|| format!("{flag} needs a value"))
}

fn number<T>(flag: &str, text: &str, min: T, max: T) -> Result<T, String>
where
    T: std::str::FromStr + PartialOrd + std::fmt::Display + Copy,
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

/// `on` or `off`.
fn on_off(flag: &str, text: &str) -> Result<bool, String> {
    match text {
        "on" => Ok(true),
        "off" => Ok(false),
        other => Err(format!("{flag}: `{other}` is not on or off")),
    }
}

/// A number of any value (the plugin validates it, as it would a game's settings).
fn any_number<T: std::str::FromStr>(flag: &str, text: &str) -> Result<T, String> {
    text.parse().map_err(|_| format!("{flag}: `{text}` is not a valid number"))
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
            "--preset" => {
                (options.rh, options.vpl, options.rsm_gather, options.drm) = match value(flag, &mut args)? {
                    "low" => (RadianceHintsVolume::LOW, VplSettings::LOW, RsmGatherSettings::LOW, DrmSettings::LOW),
                    "medium" => (RadianceHintsVolume::MEDIUM, VplSettings::MEDIUM, RsmGatherSettings::MEDIUM, DrmSettings::MEDIUM),
                    "high" => (RadianceHintsVolume::HIGH, VplSettings::HIGH, RsmGatherSettings::HIGH, DrmSettings::HIGH),
                    other => return Err(format!("--preset: unknown preset `{other}` (low, medium, high)")),
                }
            }
            "--rsm-samples" => options.rsm_gather.samples = any_number(flag, value(flag, &mut args)?)?,
            "--rsm-radius" => options.rsm_gather.radius = any_number(flag, value(flag, &mut args)?)?,
            "--rsm-weights" => {
                use crate::rsm_gather::RsmSampleWeights as W;
                options.rsm_gather.weights = match value(flag, &mut args)? {
                    "paper" => W::Paper,
                    "density" => W::Density,
                    other => return Err(format!("--rsm-weights: `{other}` is not paper or density")),
                }
            }
            "--drm-samples" => options.drm.samples_per_axis = any_number(flag, value(flag, &mut args)?)?,
            "--drm-solid-angle" => {
                options.drm.solid_angle = match value(flag, &mut args)? {
                    "11" => DrmSolidAngle::Constant,
                    "14" => DrmSolidAngle::TexelArea,
                    "15" => DrmSolidAngle::SceneDiagonal,
                    other => return Err(format!("--drm-solid-angle: `{other}` is not 11, 14 or 15 (the paper's equations)")),
                }
            }
            "--drm-mip" => options.drm.mip_mapped = on_off(flag, value(flag, &mut args)?)?,
            "--vpl-paths" => options.vpl.light_paths = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-bounces" => options.vpl.bounces = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-seed" => options.vpl.seed = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-bound" => options.vpl.geometry_bound = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-ism-resolution" => options.vpl.ism_resolution = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-ism-points" => options.vpl.ism_points = any_number(flag, value(flag, &mut args)?)?,
            "--vpl-ism-bias" => options.vpl.ism_bias = any_number(flag, value(flag, &mut args)?)?,
            "--ssbc-steps" => options.vpl.ssbc_steps = any_number(flag, value(flag, &mut args)?)?,
            "--ssbc-solid-angle" => options.vpl.ssbc_solid_angle = any_number(flag, value(flag, &mut args)?)?,
            "--ssbc-levels" => options.vpl.ssbc_levels = any_number(flag, value(flag, &mut args)?)?,
            "--ssbc-blur" => {
                options.vpl.ssbc_blur = on_off(flag, value(flag, &mut args)?)?
            }
            "--rh-resolution" => {
                let text = value(flag, &mut args)?;
                let parts: Vec<&str> = text.split(['x', 'X']).collect();
                let n = |t: &str| t.parse::<u32>().map_err(|_| format!("--rh-resolution: `{text}` is not N or XxYxZ"));
                options.rh_fit_cells = false;
                options.rh.sizing = GridSizing::Fixed;
                options.rh.resolution = match parts.as_slice() {
                    [a] => bevy::math::UVec3::splat(n(a)?),
                    [x, y, z] => bevy::math::UVec3::new(n(x)?, n(y)?, n(z)?),
                    _ => return Err(format!("--rh-resolution: `{text}` is not N or XxYxZ")),
                };
            }
            "--rh-cascade" => {
                let levels = number(flag, value(flag, &mut args)?, 1, 6)?;
                let extent = options.rh_cascade.map_or(crate::radiance_hints::RadianceHintsCascade::default().extent, |c| c.1);
                options.rh_cascade = Some((levels, extent));
            }
            "--rh-cascade-extent" => {
                let text = value(flag, &mut args)?;
                let parts: Vec<f32> = text.split(['x', 'X']).map(|t| any_number(flag, t)).collect::<Result<_, _>>()?;
                let [x, y, z] = parts[..] else {
                    return Err(format!("{flag}: `{text}` is not XxYxZ"));
                };
                options.rh_cascade = Some((options.rh_cascade.map_or(3, |c| c.0), Vec3::new(x, y, z)));
            }
            "--rh-longest" => {
                // The old fixed presets: cubic cells, N hints along the longest side of the scene.
                options.rh.sizing = GridSizing::Fixed;
                options.rh.resolution = bevy::math::UVec3::splat(number(flag, value(flag, &mut args)?, 2, 128)?);
                options.rh_fit_cells = true;
            }
            "--rh-cell" | "--rh-hints" | "--rh-max-hints" => {
                let text = value(flag, &mut args)?;
                let (mut hints, mut max_cell, mut max_hints) = match options.rh.sizing {
                    GridSizing::Adaptive { hints, max_cell, max_hints } => (hints, max_cell, max_hints),
                    // Start from the default rule.
                    GridSizing::Fixed => match GridSizing::MEDIUM {
                        GridSizing::Adaptive { hints, max_cell, max_hints } => (hints, max_cell, max_hints),
                        GridSizing::Fixed => unreachable!("the default rule is adaptive"),
                    },
                };
                match flag {
                    "--rh-cell" => max_cell = any_number(flag, text)?,
                    "--rh-hints" => hints = any_number(flag, text)?,
                    _ => max_hints = any_number(flag, text)?,
                }
                options.rh.sizing = GridSizing::Adaptive { hints, max_cell, max_hints };
            }
            "--rh-order" => {
                options.rh.sh_order = match value(flag, &mut args)? {
                    "2" => ShOrder::Two,
                    "3" => ShOrder::Three,
                    other => return Err(format!("--rh-order: `{other}` is not 2 or 3")),
                }
            }
            "--rh-samples" => options.rh.rsm_samples = any_number(flag, value(flag, &mut args)?)?,
            "--rh-bounces" => options.rh.extra_bounces = any_number(flag, value(flag, &mut args)?)?,
            "--rh-secondary" => options.rh.secondary_samples = any_number(flag, value(flag, &mut args)?)?,
            "--rh-rmax" => options.rh.r_max = any_number(flag, value(flag, &mut args)?)?,
            "--rh-coverage" => options.rh.rsm_coverage = any_number(flag, value(flag, &mut args)?)?,
            "--rh-jitter" => options.rh.jitter = any_number(flag, value(flag, &mut args)?)?,
            "--rh-blend" => options.rh.temporal_blend = any_number(flag, value(flag, &mut args)?)?,
            "--rh-threshold" => options.rh.bounce_threshold = any_number(flag, value(flag, &mut args)?)?,
            "--rh-reconstruction" => options.rh.reconstruction_samples = any_number(flag, value(flag, &mut args)?)?,
            "--rh-near-field" => options.rh.near_field_occlusion = any_number(flag, value(flag, &mut args)?)?,
            "--rh-irradiance" => {
                options.rh.irradiance = match value(flag, &mut args)? {
                    "linear" => IrradianceReconstruction::Linear,
                    "nonlinear" => IrradianceReconstruction::NonLinear,
                    other => return Err(format!("--rh-irradiance: `{other}` is not linear or nonlinear")),
                }
            }
            "--rh-albedo" => {
                options.rh.albedo_volume = on_off(flag, value(flag, &mut args)?)?
            }
            "--rh-depth-occlusion" => {
                let steps: u32 = any_number(flag, value(flag, &mut args)?)?;
                options.rh.depth_occlusion = (steps > 0).then_some(DepthOcclusion { samples: steps, ..default() });
            }
            "--rh-visibility" => {
                options.rh.voxel_visibility = match value(flag, &mut args)? {
                    "voxels" => true,
                    "none" => false,
                    other => return Err(format!("--rh-visibility: `{other}` is not voxels or none")),
                }
            }
            "--rh-secondary-transport" => {
                use crate::radiance_hints::SecondaryTransport as T;
                options.rh.secondary = match value(flag, &mut args)? {
                    "voxel" => T::VoxelMarch,
                    "paper" => T::Paper,
                    other => return Err(format!("--rh-secondary-transport: `{other}` is not voxel or paper")),
                }
            }
            "--rh-refinement" => options.rh.refinement_updates = any_number(flag, value(flag, &mut args)?)?,
            "--dump-volume" => options.dump_volume = Some(PathBuf::from(value(flag, &mut args)?)),
            "--half-res" => options.half_resolution = true,
            "--full-res" => options.half_resolution = false,
            "--animate-light" => options.animate_light = true,
            "--animate-meshes" => options.animate_meshes = number(flag, value(flag, &mut args)?, 0, 10)?,
            "--pose-frame" => options.pose_frame = number(flag, value(flag, &mut args)?, 0.0, 1.0e6)?,
            "--stop-animation-at" => {
                options.stop_animation_at = Some(number(flag, value(flag, &mut args)?, 0.0, 1.0e6)?)
            }
            "--extra-triangles" => options.extra_triangles = number(flag, value(flag, &mut args)?, 0, 5_000_000)?,
            "--switch-method" => {
                let text = value(flag, &mut args)?;
                let (frames, method) = text
                    .split_once(':')
                    .ok_or_else(|| format!("--switch-method: `{text}` is not FRAMES:METHOD"))?;
                let frames = number(flag, frames, 1, 100_000)?;
                let Some(method) = HeadlessMethod::parse(method)?.gi() else {
                    return Err(format!("--switch-method: `{method}` is not a GI method"));
                };
                options.switch_method = Some((frames, method));
            }
            "--debug-view" => {
                use crate::camera::GiDebugView as V;
                options.debug_view = Some(match value(flag, &mut args)? {
                    "indirect" => V::IndirectOnly,
                    "irradiance" => V::Irradiance,
                    "hint-grid" => V::HintGrid,
                    "rsm-flux" => V::RsmFlux,
                    "rsm-normal" => V::RsmNormal,
                    "rsm-position" => V::RsmPosition,
                    "vpl-clamped" => V::VplClampedOnly,
                    "vpl-compensation" => V::VplCompensationOnly,
                    "vpl-positions" => V::VplPositions,
                    other => {
                        return Err(format!(
                            "--debug-view: `{other}` is not indirect, irradiance, hint-grid, rsm-flux, rsm-normal, \
                             rsm-position, vpl-clamped, vpl-compensation or vpl-positions"
                        ))
                    }
                })
            }
            "--gi-output" => {
                options.gi_output = match value(flag, &mut args)? {
                    "composite" => GiOutput::Composite,
                    "irradiance-volume" => GiOutput::IrradianceVolume,
                    other => return Err(format!("--gi-output: `{other}` is not composite or irradiance-volume")),
                }
            }
            "--help" | "-h" => return Err(USAGE.to_string()),
            other => return Err(format!("unknown flag `{other}`\n{USAGE}")),
        }
    }
    if options.switch_method.is_some_and(|(frames, _)| frames >= options.frames) {
        return Err("--switch-method: the switch must come before the last of --frames".into());
    }
    if options.switch_method.is_some() && options.method.gi().is_none() {
        return Err("--switch-method: switches from a GI method (--method rh, vpl, rsm or drm)".into());
    }
    if options.indirect_only && options.gi_output == GiOutput::IrradianceVolume {
        return Err("--indirect-only measures the per-pixel reconstruction; render the IrradianceVolume output \
                    in full and subtract a --method none render"
            .into());
    }
    let dynamic_only = options.animate_meshes > 0
        || options.pose_frame != 0.0
        || options.stop_animation_at.is_some()
        || options.extra_triangles > 0;
    if dynamic_only && options.scene != StandardScene::Dynamic {
        return Err("--animate-meshes, --pose-frame, --stop-animation-at and --extra-triangles need --scene dynamic".into());
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
    fn methods_are_selected_through_gi_method() {
        let o = parse_args("--method vpl --preset high --ssbc-steps 3 --vpl-bounces 4".split_whitespace()).unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::Vpl));
        assert_eq!((o.vpl.ssbc_steps, o.vpl.bounces, o.vpl.light_paths), (3, 4, VplSettings::HIGH.light_paths));
        assert_eq!(parse_args(["--method", "rh"]).unwrap().method, HeadlessMethod::Gi(GiMethod::RadianceHints));
        for name in HeadlessMethod::NAMES {
            assert_eq!(HeadlessMethod::parse(name).unwrap().name(), *name);
        }
    }

    #[test]
    fn one_bounce_methods_take_presets_and_overrides() {
        let o = parse_args("--method drm --preset high --drm-solid-angle 11 --drm-mip off".split_whitespace()).unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::Drm));
        assert_eq!((o.drm.samples_per_axis, o.drm.solid_angle, o.drm.mip_mapped), (16, DrmSolidAngle::Constant, false));
        let o = parse_args("--method rsm --preset low --rsm-radius 0.2 --rsm-samples 50".split_whitespace()).unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::RsmGather));
        assert_eq!((o.rsm_gather.samples, o.rsm_gather.radius), (50, 0.2));
        let err = |s: &str| parse_args(s.split_whitespace()).unwrap_err();
        assert!(err("--drm-solid-angle 12").contains("11, 14 or 15"));
        assert!(err("--drm-mip maybe").contains("on or off"));
    }

    #[test]
    fn grid_flags_choose_fixed_adaptive_or_cascaded_grids() {
        let o = parse_args("--method rh --rh-longest 24".split_whitespace()).unwrap();
        assert_eq!((o.rh.sizing, o.rh.resolution, o.rh_fit_cells), (GridSizing::Fixed, bevy::math::UVec3::splat(24), true));
        let o = parse_args("--method rh --rh-resolution 4x5x6".split_whitespace()).unwrap();
        assert_eq!((o.rh.sizing, o.rh_fit_cells), (GridSizing::Fixed, false));
        let o = parse_args("--method rh --rh-longest 8 --rh-cell 0.5 --rh-max-hints 1000".split_whitespace()).unwrap();
        let GridSizing::Adaptive { max_cell, max_hints, hints } = o.rh.sizing else {
            panic!("--rh-cell makes the grid adaptive");
        };
        assert_eq!((max_cell, max_hints), (0.5, 1000));
        assert!(matches!(GridSizing::MEDIUM, GridSizing::Adaptive { hints: h, .. } if h == hints));
        let o = parse_args("--method rh --rh-cascade 2 --rh-cascade-extent 8x4x8".split_whitespace()).unwrap();
        assert_eq!(o.rh_cascade, Some((2, Vec3::new(8.0, 4.0, 8.0))));
        let err = |s: &str| parse_args(s.split_whitespace()).unwrap_err();
        assert!(err("--rh-cascade 9").contains("--rh-cascade"));
        assert!(err("--rh-cascade-extent 8x4").contains("XxYxZ"));
    }

    #[test]
    fn default_output_name_follows_scene_and_method() {
        let o = parse_args("--method reference --indirect-only".split_whitespace()).unwrap();
        assert_eq!(o.out, PathBuf::from("out/cornell_reference_indirect.exr"));
    }
}
