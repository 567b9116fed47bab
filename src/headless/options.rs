//! Command-line options of the headless renderer.

use std::path::PathBuf;

use bevy::math::{UVec2, UVec3, Vec3};
use bevy::prelude::default;

use crate::camera::{GiMethod, GiOutput};
use crate::vpl::VplSettings;
use crate::drm::{DrmSettings, DrmSolidAngle};
use crate::radiosity::{LinkTransfer, RadiositySettings};
use crate::photon_grid::PhotonGridSettings;
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
    pub const NAMES: &'static [&'static str] = &["none", "reference", "rh", "vpl", "rsm", "drm", "radiosity", "photon-grid"];

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
    /// Radiosity settings (`--preset` and the `--radiosity-*` overrides), passed on unclamped.
    #[serde(skip)]
    pub radiosity: RadiositySettings,
    /// Photon-grid settings (`--preset` and the `--photon-*` overrides), passed on unclamped.
    #[serde(skip)]
    pub photon_grid: PhotonGridSettings,
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
    /// a 2 cm circle each frame (a directional light: tilt it by 0.5° around its direction), so that the
    /// RSM and the GI volume are recomputed every frame as they are for a moving light (the dynamic-light
    /// timing case).
    pub animate_light: bool,
    /// `dynamic` scene: how many of its objects move (from object 0; 0–10).
    pub animate_meshes: u32,
    /// `dynamic` scene: the pose frame it starts at (the ground truth of frame K is `--pose-frame K`).
    pub pose_frame: f32,
    /// `dynamic` scene: the pose frame where the motion stops.
    pub stop_animation_at: Option<f32>,
    /// `dynamic` scene: static triangles added along the back wall.
    pub extra_triangles: u32,
    /// Scales the whole scene (every root entity's place and size, the lights' ranges and the camera's
    /// planes) by this factor once it has loaded: the same scene in other units. An emissive-lit scene's
    /// image does not change with it; a scene lit by lights of fixed intensity gets `1/scale²` of the
    /// light. A factor (no unit); default 1, which leaves the scene as it is; valid 10⁻⁴–10⁶ (others are
    /// clamped with a warning, a non-finite one is 1). Cost: none beyond the scene's own at that scale.
    pub scene_scale: f32,
    /// After the `frames`, go on rendering until the CPU methods' background work (radiosity's solve,
    /// the photon grid's preparation) has caught up with the scene and been blended in, for at most
    /// this many seconds from the start of rendering, and read back then: the converged image after a
    /// change. The extra frames are the sidecar's `background_wait_frames`; `background_timed_out` says
    /// whether the limit ended the wait. It also caps the wait for the first solution before the
    /// measured frames begin (otherwise [`MAX_BACKGROUND_SECONDS`](super::MAX_BACKGROUND_SECONDS)).
    pub wait_background: Option<u32>,
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
            radiosity: RadiositySettings::default(),
            photon_grid: PhotonGridSettings::default(),
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
            scene_scale: 1.0,
            wait_background: None,
            switch_method: None,
        }
    }
}

/// The headless renderer's command line (clap derive). `--help` lists every flag with its unit and default;
/// [`HeadlessArgs::into_options`] applies `--preset` first, then every override, and checks the
/// combinations. Tools that add flags of their own flatten it (`ground_truth`).
#[derive(clap::Args, Clone, Debug)]
pub struct HeadlessArgs {
    /// cornell, cellar, sponza_like, dynamic, emissive_panel, open_field, near_light, sky_room, or a glTF 2.0 file
    #[arg(long, value_name = "NAME|PATH.glb", default_value = "cornell", value_parser = StandardScene::parse)]
    pub scene: StandardScene,
    /// Image size in pixels, 1..=8192 each
    #[arg(long, value_name = "WxH", default_value = "256x256", value_parser = parse_size)]
    pub size: UVec2,
    /// Frames rendered once the scene shows, before the image is kept
    #[arg(long, value_name = "N", default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// The linear float EXR to write; FILE.json goes beside it [default: out/SCENE_METHOD.exr]
    #[arg(long, value_name = "FILE.exr", value_parser = parse_exr_path)]
    pub out: Option<PathBuf>,
    /// none = Bevy's direct light; reference = the CPU path tracer; rh = Radiance Hints over a volume
    /// fitted to the scene; vpl = VPLs with imperfect shadow maps and SSBC; rsm = the RSM gather;
    /// drm = Direct Radiance Mapping; radiosity = implicit-visibility hierarchical radiosity;
    /// photon-grid = the photon grid and SH field
    #[arg(long, value_name = "METHOD", default_value = "none", value_parser = HeadlessMethod::parse)]
    pub method: HeadlessMethod,
    /// Write only the indirect light the method adds
    #[arg(long)]
    pub indirect_only: bool,
    /// Path-tracer samples per pixel, 1..=1048576
    #[arg(long, value_name = "N", default_value_t = 2048, value_parser = clap::value_parser!(u32).range(1..=1 << 20))]
    pub spp: u32,
    /// Path-tracer random seed
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub seed: u64,
    /// Path tracer: keep indirect light of at most N bounces, 1..=1000 [default: all]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub max_bounces: Option<u32>,
    /// Exposure override in EV100, -64..=64 [default: the scene's]
    #[arg(long, value_name = "EV", allow_negative_numbers = true, value_parser = parse_ev100)]
    pub ev100: Option<f32>,
    /// Path tracer: shade direct light with Bevy's Burley lobe (for the direct check)
    #[arg(long)]
    pub burley_direct: bool,
    /// Path tracer: one ray through each pixel centre, no pixel filter (for the direct check)
    #[arg(long)]
    pub pixel_centers: bool,
    /// The method's preset: RadianceHintsVolume, VplSettings, RsmGatherSettings, DrmSettings,
    /// RadiositySettings or PhotonGridSettings
    #[arg(long, value_name = "PRESET", default_value = "medium", value_parser = ["low", "medium", "high"])]
    pub preset: String,
    /// Compute the bounced light at half resolution (the default)
    #[arg(long, conflicts_with = "full_res")]
    pub half_res: bool,
    /// Compute the bounced light at full resolution
    #[arg(long)]
    pub full_res: bool,
    /// composite (per pixel) or irradiance-volume (Bevy's light probe)
    #[arg(long, value_name = "OUTPUT", default_value = "composite", value_parser = ["composite", "irradiance-volume"])]
    pub gi_output: String,
    /// indirect, irradiance, hint-grid, rsm-flux, rsm-normal, rsm-position, vpl-clamped,
    /// vpl-compensation or vpl-positions [default: the lit image; --indirect-only: indirect]
    #[arg(long, value_name = "VIEW", value_parser = [
        "indirect", "irradiance", "hint-grid", "rsm-flux", "rsm-normal", "rsm-position", "vpl-clamped",
        "vpl-compensation", "vpl-positions",
    ])]
    pub debug_view: Option<String>,
    /// dynamic scene: orbit its light one step per rendered frame; other scenes: move the GI lights on a
    /// 2 cm circle (a sun: tilt it by 0.5°) every frame (times the dynamic-light case)
    #[arg(long)]
    pub animate_light: bool,
    /// dynamic scene: move its first N objects one step per rendered frame, 0..=10
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=10))]
    pub animate_meshes: u32,
    /// dynamic scene: the pose frame to start at (the ground truth of a pose), 0..=1e6
    #[arg(long, value_name = "K", default_value_t = 0.0, value_parser = parse_pose)]
    pub pose_frame: f32,
    /// dynamic scene: stop the motion at this pose frame, 0..=1e6
    #[arg(long, value_name = "K", value_parser = parse_pose)]
    pub stop_animation_at: Option<f32>,
    /// dynamic scene: add about N static triangles (spheres along the back wall), 0..=5000000
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=5_000_000))]
    pub extra_triangles: u32,
    /// Scale the whole scene by S once it has loaded (the same scene in other units: lights keep their
    /// intensity, emission its radiance), 1e-4..=1e6
    #[arg(long, value_name = "S", default_value_t = 1.0, value_parser = parse_scene_scale)]
    pub scene_scale: f32,
    /// After the --frames, go on rendering until the CPU methods (radiosity, photon grid) have finished
    /// their background work on the scene as it is, then read back; at most SECONDS from the start of
    /// rendering, 1..=3600
    #[arg(long, value_name = "SECONDS", value_parser = clap::value_parser!(u32).range(1..=3600))]
    pub wait_background: Option<u32>,
    /// After FRAMES of the --frames, switch the camera to the given GI method (rh, vpl, rsm, drm,
    /// radiosity or photon-grid)
    #[arg(long, value_name = "FRAMES:METHOD", value_parser = parse_switch)]
    pub switch_method: Option<(u32, GiMethod)>,
    // The methods' overrides last: each group's help heading then covers only its own flags.
    #[command(flatten)]
    pub rh: RhArgs,
    #[command(flatten)]
    pub vpl: VplArgs,
    #[command(flatten)]
    pub one_bounce: OneBounceArgs,
    #[command(flatten)]
    pub radiosity: RadiosityArgs,
    #[command(flatten)]
    pub photon_grid: PhotonGridArgs,
}

/// Photon-grid overrides of [`HeadlessArgs`] (each sets one `PhotonGridSettings` field after the preset).
#[derive(clap::Args, Clone, Debug, Default)]
#[command(next_help_heading = "Photon grid (--method photon-grid; each overrides one PhotonGridSettings field)")]
pub struct PhotonGridArgs {
    /// SH-grid cells along the scene's longest side
    #[arg(long, value_name = "N")]
    pub photon_resolution: Option<u32>,
    /// Photons per update
    #[arg(long, value_name = "N")]
    pub photon_count: Option<u32>,
    /// Stored reflections per photon path
    #[arg(long, value_name = "N")]
    pub photon_reflections: Option<u32>,
    /// Ray directions per SH probe (N_sh)
    #[arg(long, value_name = "N")]
    pub photon_sh_directions: Option<u32>,
    /// Gather directions N_d (0 = the exact integral)
    #[arg(long, value_name = "N")]
    pub photon_gather_samples: Option<u32>,
    /// Coarsest R-grid level of the radiance filter (0 = the base level only)
    #[arg(long, value_name = "N")]
    pub photon_filter_levels: Option<u32>,
    /// Extent of the gather's distance weight, SH cells
    #[arg(long, value_name = "R")]
    pub photon_r_max: Option<f32>,
    /// Obscurance distance in metres (0 = off)
    #[arg(long, value_name = "D")]
    pub photon_obscurance: Option<f32>,
    /// Where the SH field is built: auto (the GPU on hardware GPUs), cpu or gpu
    #[arg(long, value_parser = ["auto", "cpu", "gpu"])]
    pub photon_field: Option<String>,
}

impl PhotonGridArgs {
    fn apply(self, s: &mut PhotonGridSettings) {
        let PhotonGridArgs {
            photon_resolution,
            photon_count,
            photon_reflections,
            photon_sh_directions,
            photon_gather_samples,
            photon_filter_levels,
            photon_r_max,
            photon_obscurance,
            photon_field,
        } = self;
        s.resolution = photon_resolution.unwrap_or(s.resolution);
        s.photons = photon_count.unwrap_or(s.photons);
        s.max_reflections = photon_reflections.unwrap_or(s.max_reflections);
        s.sh_directions = photon_sh_directions.unwrap_or(s.sh_directions);
        s.gather_samples = photon_gather_samples.unwrap_or(s.gather_samples);
        s.filter_levels = photon_filter_levels.unwrap_or(s.filter_levels);
        s.r_max = photon_r_max.unwrap_or(s.r_max);
        s.obscurance_distance = photon_obscurance.unwrap_or(s.obscurance_distance);
        if let Some(device) = photon_field {
            use crate::photon_grid::FieldDevice as D;
            s.field_device = match device.as_str() {
                "cpu" => D::Cpu,
                "gpu" => D::Gpu,
                _ => D::Auto,
            };
        }
    }
}

/// Radiosity overrides of [`HeadlessArgs`] (each sets one `RadiositySettings` field after the preset).
#[derive(clap::Args, Clone, Debug, Default)]
#[command(next_help_heading = "Radiosity (--method radiosity; each overrides one RadiositySettings field)")]
pub struct RadiosityArgs {
    /// Bins along each cube-face side (6N² bins per element)
    #[arg(long, value_name = "N")]
    pub radiosity_bins: Option<u32>,
    /// Light bounces, 1 = light reflected once
    #[arg(long, value_name = "N")]
    pub radiosity_bounces: Option<u32>,
    /// Stop bouncing below this fraction of added light
    #[arg(long, value_name = "F")]
    pub radiosity_stop: Option<f32>,
    /// Subdivide a node above this many bin solid angles
    #[arg(long, value_name = "T")]
    pub radiosity_subdivision: Option<f32>,
    /// Longest element-mesh edge, fraction of the scene's diagonal (0 = the meshes' vertices)
    #[arg(long, value_name = "F")]
    pub radiosity_element_size: Option<f32>,
    /// Eq. 5 transfer: bin (the bin's solid angle) or area (the element's, as printed)
    #[arg(long, value_parser = ["bin", "area"])]
    pub radiosity_transfer: Option<String>,
}

impl RadiosityArgs {
    fn apply(self, s: &mut RadiositySettings) {
        let RadiosityArgs {
            radiosity_bins,
            radiosity_bounces,
            radiosity_stop,
            radiosity_subdivision,
            radiosity_element_size,
            radiosity_transfer,
        } = self;
        s.bins = radiosity_bins.unwrap_or(s.bins);
        s.bounces = radiosity_bounces.unwrap_or(s.bounces);
        s.stop_threshold = radiosity_stop.unwrap_or(s.stop_threshold);
        s.subdivision_threshold = radiosity_subdivision.unwrap_or(s.subdivision_threshold);
        s.element_size = radiosity_element_size.unwrap_or(s.element_size);
        if let Some(t) = radiosity_transfer {
            s.transfer = if t == "area" { LinkTransfer::ElementArea } else { LinkTransfer::BinSolidAngle };
        }
    }
}

/// Radiance Hints overrides of [`HeadlessArgs`]: each sets one `RadianceHintsVolume` field after the
/// preset; out-of-range values are passed on, and the plugin clamps them with one warning as it would a
/// game's.
#[derive(clap::Args, Clone, Debug, Default)]
#[command(next_help_heading = "Radiance Hints (--method rh; each overrides one RadianceHintsVolume field)")]
pub struct RhArgs {
    /// Fixed hint counts, N or XxYxZ (no cell fitting)
    #[arg(long, value_name = "N|XxYxZ", value_parser = parse_counts, conflicts_with_all = ["rh_longest", "rh_cell", "rh_hints", "rh_max_hints"])]
    pub rh_resolution: Option<UVec3>,
    /// Fixed cubic cells, N hints along the scene's longest side, 2..=128
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(2..=128), conflicts_with_all = ["rh_cell", "rh_hints", "rh_max_hints"])]
    pub rh_longest: Option<u32>,
    /// The adaptive grid's largest cell, metres [default: the preset's]
    #[arg(long, value_name = "M")]
    pub rh_cell: Option<f32>,
    /// The adaptive grid's hints in a small room [default: the preset's]
    #[arg(long, value_name = "N")]
    pub rh_hints: Option<u32>,
    /// The adaptive grid's most hints [default: the preset's]
    #[arg(long, value_name = "N")]
    pub rh_max_hints: Option<u32>,
    /// A camera-centred cascade of LEVELS volumes (1..=6) instead of one volume fitted to the scene
    #[arg(long, value_name = "LEVELS", value_parser = clap::value_parser!(u32).range(1..=6))]
    pub rh_cascade: Option<u32>,
    /// The cascade's innermost box, metres, XxYxZ [default: RadianceHintsCascade's; implies --rh-cascade 3]
    #[arg(long, value_name = "XxYxZ", value_parser = parse_extent)]
    pub rh_cascade_extent: Option<Vec3>,
    /// Spherical-harmonics order, 2 or 3
    #[arg(long, value_name = "2|3", value_parser = ["2", "3"])]
    pub rh_order: Option<String>,
    /// RSM samples per hint N_s
    #[arg(long, value_name = "N")]
    pub rh_samples: Option<u32>,
    /// Extra bounces between hints
    #[arg(long, value_name = "N")]
    pub rh_bounces: Option<u32>,
    /// Secondary samples per hint and bounce N_b
    #[arg(long, value_name = "N")]
    pub rh_secondary: Option<u32>,
    /// r_max in metres (0 = automatic)
    #[arg(long, value_name = "M")]
    pub rh_rmax: Option<f32>,
    /// RSM coverage c_RSM of directional lights, 0..1
    #[arg(long, value_name = "C")]
    pub rh_coverage: Option<f32>,
    /// Jitter of the receiving points, cells
    #[arg(long, value_name = "J")]
    pub rh_jitter: Option<f32>,
    /// Temporal blend factor
    #[arg(long, value_name = "A")]
    pub rh_blend: Option<f32>,
    /// Bounce stop threshold
    #[arg(long, value_name = "T")]
    pub rh_threshold: Option<f32>,
    /// Reconstruction samples per pixel N_RH
    #[arg(long, value_name = "N")]
    pub rh_reconstruction: Option<u32>,
    /// How far off the surface the reconstruction reads the field, cell diagonals (§5: 1)
    #[arg(long, value_name = "CELLS")]
    pub rh_reach: Option<f32>,
    /// Near-field occlusion reach in cell diagonals (0 = off)
    #[arg(long, value_name = "CELLS")]
    pub rh_near_field: Option<f32>,
    /// Irradiance from the SH: linear (Eq. 7) or nonlinear (Hazel)
    #[arg(long, value_parser = ["linear", "nonlinear"])]
    pub rh_irradiance: Option<String>,
    /// The albedo volume (coloured extra bounces): on or off
    #[arg(long, value_name = "on|off", value_parser = parse_on_off)]
    pub rh_albedo: Option<bool>,
    /// §8 camera-depth occlusion with STEPS samples per path (0 = off)
    #[arg(long, value_name = "STEPS")]
    pub rh_depth_occlusion: Option<u32>,
    /// First-bounce visibility: voxels or none
    #[arg(long, value_parser = ["voxels", "none"])]
    pub rh_visibility: Option<String>,
    /// Secondary bounces' transport: voxel or paper
    #[arg(long, value_parser = ["voxel", "paper"])]
    pub rh_secondary_transport: Option<String>,
    /// Refinement updates after a change
    #[arg(long, value_name = "N")]
    pub rh_refinement: Option<u32>,
    /// While things move, recompute the bounce of one hint in N per update, 1..=16
    #[arg(long, value_name = "N")]
    pub rh_motion_period: Option<u32>,
    /// While things move, inject and gather at most about N hints per update (larger volumes update in turns), 256..=262144
    #[arg(long, value_name = "N")]
    pub rh_motion_hints: Option<u32>,
    /// Write the volume's field to this JSON file after the last frame
    #[arg(long, value_name = "FILE.json")]
    pub dump_volume: Option<PathBuf>,
}

/// VPL and SSBC overrides of [`HeadlessArgs`] (each sets one `VplSettings` field after the preset).
#[derive(clap::Args, Clone, Debug, Default)]
#[command(next_help_heading = "VPLs (--method vpl; each overrides one VplSettings field)")]
pub struct VplArgs {
    /// Light paths
    #[arg(long, value_name = "N")]
    pub vpl_paths: Option<u32>,
    /// Most VPLs per path
    #[arg(long, value_name = "N")]
    pub vpl_bounces: Option<u32>,
    /// Seed of the light paths
    #[arg(long, value_name = "S")]
    pub vpl_seed: Option<u32>,
    /// Bound b of the clamped geometry term, 1/m² (0 = automatic)
    #[arg(long, value_name = "B")]
    pub vpl_bound: Option<f32>,
    /// Shadow maps: traced (ray-traced on the CPU, the default) or imperfect (splatted points)
    #[arg(long, value_name = "MODE", value_parser = parse_vpl_visibility)]
    pub vpl_visibility: Option<crate::vpl::VplVisibility>,
    /// Shadow map side, texels
    #[arg(long, value_name = "N")]
    pub vpl_ism_resolution: Option<u32>,
    /// Points per imperfect shadow map
    #[arg(long, value_name = "N")]
    pub vpl_ism_points: Option<u32>,
    /// Shadow-map depth tolerance, fraction of the distance
    #[arg(long, value_name = "F")]
    pub vpl_ism_bias: Option<f32>,
    /// SSBC steps (0 = the clamped gather alone)
    #[arg(long, value_name = "N")]
    pub ssbc_steps: Option<u32>,
    /// SSBC refinement threshold, steradians
    #[arg(long, value_name = "SR")]
    pub ssbc_solid_angle: Option<f32>,
    /// SSBC levels
    #[arg(long, value_name = "N")]
    pub ssbc_levels: Option<u32>,
    /// SSBC blur: on or off
    #[arg(long, value_name = "on|off", value_parser = parse_on_off)]
    pub ssbc_blur: Option<bool>,
}

/// RSM gather and DRM overrides of [`HeadlessArgs`] (each sets one field after the preset).
#[derive(clap::Args, Clone, Debug, Default)]
#[command(next_help_heading = "One-bounce gathers (--method rsm|drm; each overrides one RsmGatherSettings or DrmSettings field)")]
pub struct OneBounceArgs {
    /// RSM gather: samples per pixel and light
    #[arg(long, value_name = "N")]
    pub rsm_samples: Option<u32>,
    /// RSM gather: disk radius, fraction of the RSM's side
    #[arg(long, value_name = "R")]
    pub rsm_radius: Option<f32>,
    /// RSM gather: sample weights, paper (ξ₁²) or density (ξ₁)
    #[arg(long, value_parser = ["paper", "density"])]
    pub rsm_weights: Option<String>,
    /// DRM: photons per axis of each light face (M = N²)
    #[arg(long, value_name = "N")]
    pub drm_samples: Option<u32>,
    /// DRM: the paper's solid-angle approximation, Eq. 11, 14 or 15
    #[arg(long, value_name = "EQ", value_parser = ["11", "14", "15"])]
    pub drm_solid_angle: Option<String>,
    /// DRM: mip-mapped photons, on or off
    #[arg(long, value_name = "on|off", value_parser = parse_on_off)]
    pub drm_mip: Option<bool>,
}

/// The `headless` example's command line.
#[derive(clap::Parser, Clone, Debug)]
#[command(name = "headless", about = "Renders a standard scene or a glTF file with no window and writes a linear EXR and a JSON sidecar.")]
pub struct HeadlessCli {
    #[command(flatten)]
    pub args: HeadlessArgs,
}

fn parse_size(text: &str) -> Result<UVec2, String> {
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(|| format!("`{text}` is not WIDTHxHEIGHT"))?;
    let side = |t: &str| t.parse::<u32>().ok().filter(|v| (1..=8192).contains(v)).ok_or_else(|| format!("`{text}`: each side must be 1..=8192"));
    Ok(UVec2::new(side(w)?, side(h)?))
}

fn parse_exr_path(text: &str) -> Result<PathBuf, String> {
    if text.ends_with(".exr") { Ok(PathBuf::from(text)) } else { Err(format!("`{text}` must end in .exr")) }
}

fn parse_vpl_visibility(text: &str) -> Result<crate::vpl::VplVisibility, String> {
    match text {
        "traced" => Ok(crate::vpl::VplVisibility::Traced),
        "imperfect" => Ok(crate::vpl::VplVisibility::Imperfect),
        other => Err(format!("`{other}`: expected traced or imperfect")),
    }
}

fn parse_ev100(text: &str) -> Result<f32, String> {
    text.parse::<f32>().ok().filter(|v| (-64.0..=64.0).contains(v)).ok_or_else(|| format!("`{text}` is not a number in -64..=64"))
}

fn parse_scene_scale(text: &str) -> Result<f32, String> {
    text.parse::<f32>().ok().filter(|v| (1e-4..=1e6).contains(v)).ok_or_else(|| format!("`{text}` is not a number in 1e-4..=1e6"))
}

fn parse_pose(text: &str) -> Result<f32, String> {
    text.parse::<f32>().ok().filter(|v| (0.0..=1.0e6).contains(v)).ok_or_else(|| format!("`{text}` is not a number in 0..=1000000"))
}

fn parse_on_off(text: &str) -> Result<bool, String> {
    match text {
        "on" => Ok(true),
        "off" => Ok(false),
        other => Err(format!("`{other}` is not on or off")),
    }
}

fn parse_counts(text: &str) -> Result<UVec3, String> {
    let n = |t: &str| t.parse::<u32>().map_err(|_| format!("`{text}` is not N or XxYxZ"));
    match text.split(['x', 'X']).collect::<Vec<_>>().as_slice() {
        [a] => Ok(UVec3::splat(n(a)?)),
        [x, y, z] => Ok(UVec3::new(n(x)?, n(y)?, n(z)?)),
        _ => Err(format!("`{text}` is not N or XxYxZ")),
    }
}

fn parse_extent(text: &str) -> Result<Vec3, String> {
    let parts: Vec<f32> =
        text.split(['x', 'X']).map(|t| t.parse::<f32>().map_err(|_| format!("`{text}` is not XxYxZ"))).collect::<Result<_, _>>()?;
    match parts[..] {
        [x, y, z] => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("`{text}` is not XxYxZ")),
    }
}

fn parse_switch(text: &str) -> Result<(u32, GiMethod), String> {
    let (frames, method) = text.split_once(':').ok_or_else(|| format!("`{text}` is not FRAMES:METHOD"))?;
    let frames = frames.parse::<u32>().ok().filter(|f| (1..=100_000).contains(f)).ok_or_else(|| format!("`{frames}` is not 1..=100000 frames"))?;
    let method = HeadlessMethod::parse(method)?.gi().ok_or_else(|| format!("`{method}` is not a GI method"))?;
    Ok((frames, method))
}

impl HeadlessArgs {
    /// The options these flags ask for: the preset, then each override, then the checks that involve
    /// several flags.
    pub fn into_options(self) -> Result<HeadlessOptions, String> {
        let mut o = HeadlessOptions {
            scene: self.scene,
            size: self.size,
            frames: self.frames,
            method: self.method,
            indirect_only: self.indirect_only,
            spp: self.spp,
            seed: self.seed,
            max_bounces: self.max_bounces,
            ev100: self.ev100,
            burley_direct: self.burley_direct,
            pixel_centers: self.pixel_centers,
            animate_light: self.animate_light,
            animate_meshes: self.animate_meshes,
            pose_frame: self.pose_frame,
            stop_animation_at: self.stop_animation_at,
            extra_triangles: self.extra_triangles,
            scene_scale: self.scene_scale,
            wait_background: self.wait_background,
            switch_method: self.switch_method,
            ..HeadlessOptions::default()
        };
        o.photon_grid = match self.preset.as_str() {
            "low" => PhotonGridSettings::LOW,
            "high" => PhotonGridSettings::HIGH,
            _ => PhotonGridSettings::MEDIUM,
        };
        (o.rh, o.vpl, o.rsm_gather, o.drm, o.radiosity) = match self.preset.as_str() {
            "low" => (RadianceHintsVolume::LOW, VplSettings::LOW, RsmGatherSettings::LOW, DrmSettings::LOW, RadiositySettings::LOW),
            "high" => {
                (RadianceHintsVolume::HIGH, VplSettings::HIGH, RsmGatherSettings::HIGH, DrmSettings::HIGH, RadiositySettings::HIGH)
            }
            _ => (
                RadianceHintsVolume::MEDIUM,
                VplSettings::MEDIUM,
                RsmGatherSettings::MEDIUM,
                DrmSettings::MEDIUM,
                RadiositySettings::MEDIUM,
            ),
        };
        if self.full_res {
            o.half_resolution = false;
        } else if self.half_res {
            o.half_resolution = true;
        }
        o.gi_output = if self.gi_output == "irradiance-volume" { GiOutput::IrradianceVolume } else { GiOutput::Composite };
        o.debug_view = self.debug_view.as_deref().map(|view| {
            use crate::camera::GiDebugView as V;
            match view {
                "irradiance" => V::Irradiance,
                "hint-grid" => V::HintGrid,
                "rsm-flux" => V::RsmFlux,
                "rsm-normal" => V::RsmNormal,
                "rsm-position" => V::RsmPosition,
                "vpl-clamped" => V::VplClampedOnly,
                "vpl-compensation" => V::VplCompensationOnly,
                "vpl-positions" => V::VplPositions,
                _ => V::IndirectOnly,
            }
        });
        self.rh.apply(&mut o);
        self.vpl.apply(&mut o.vpl);
        self.one_bounce.apply(&mut o);
        self.radiosity.apply(&mut o.radiosity);
        self.photon_grid.apply(&mut o.photon_grid);

        if o.switch_method.is_some_and(|(frames, _)| frames >= o.frames) {
            return Err("--switch-method: the switch must come before the last of --frames".into());
        }
        if o.switch_method.is_some() && o.method.gi().is_none() {
            return Err("--switch-method: switches from a GI method (--method rh, vpl, rsm, drm, radiosity or photon-grid)".into());
        }
        if o.indirect_only && o.gi_output == GiOutput::IrradianceVolume {
            return Err("--indirect-only measures the per-pixel reconstruction; render the IrradianceVolume output \
                        in full and subtract a --method none render"
                .into());
        }
        let dynamic_only = o.animate_meshes > 0 || o.pose_frame != 0.0 || o.stop_animation_at.is_some() || o.extra_triangles > 0;
        if dynamic_only && o.scene != StandardScene::Dynamic {
            return Err("--animate-meshes, --pose-frame, --stop-animation-at and --extra-triangles need --scene dynamic".into());
        }
        o.out = match self.out {
            Some(out) => out,
            None => {
                let scene = match &o.scene {
                    StandardScene::Gltf(path) => path.file_stem().map_or("gltf".into(), |s| s.to_string_lossy().into_owned()),
                    other => other.name(),
                };
                let suffix = if o.indirect_only { "_indirect" } else { "" };
                PathBuf::from(format!("out/{scene}_{}{suffix}.exr", o.method.name()))
            }
        };
        Ok(o)
    }
}

impl RhArgs {
    fn apply(self, o: &mut HeadlessOptions) {
        let rh = &mut o.rh;
        if let Some(resolution) = self.rh_resolution {
            o.rh_fit_cells = false;
            rh.sizing = GridSizing::Fixed;
            rh.resolution = resolution;
        }
        if let Some(longest) = self.rh_longest {
            // The old fixed presets: cubic cells, N hints along the longest side of the scene.
            rh.sizing = GridSizing::Fixed;
            rh.resolution = UVec3::splat(longest);
            o.rh_fit_cells = true;
        }
        if self.rh_cell.is_some() || self.rh_hints.is_some() || self.rh_max_hints.is_some() {
            // Start from the preset's adaptive rule (or the default one).
            let (hints, max_cell, max_hints) = match (rh.sizing, GridSizing::MEDIUM) {
                (GridSizing::Adaptive { hints, max_cell, max_hints }, _) | (GridSizing::Fixed, GridSizing::Adaptive { hints, max_cell, max_hints }) => {
                    (hints, max_cell, max_hints)
                }
                (GridSizing::Fixed, GridSizing::Fixed) => unreachable!("the default rule is adaptive"),
            };
            rh.sizing = GridSizing::Adaptive {
                hints: self.rh_hints.unwrap_or(hints),
                max_cell: self.rh_cell.unwrap_or(max_cell),
                max_hints: self.rh_max_hints.unwrap_or(max_hints),
            };
        }
        if self.rh_cascade.is_some() || self.rh_cascade_extent.is_some() {
            let extent = self.rh_cascade_extent.unwrap_or(crate::radiance_hints::RadianceHintsCascade::default().extent);
            o.rh_cascade = Some((self.rh_cascade.unwrap_or(3), extent));
        }
        if let Some(order) = self.rh_order {
            rh.sh_order = if order == "3" { ShOrder::Three } else { ShOrder::Two };
        }
        macro_rules! set {
            ($($field:ident <- $flag:ident),* $(,)?) => {
                $(if let Some(v) = self.$flag { rh.$field = v; })*
            };
        }
        set!(
            rsm_samples <- rh_samples,
            extra_bounces <- rh_bounces,
            secondary_samples <- rh_secondary,
            r_max <- rh_rmax,
            rsm_coverage <- rh_coverage,
            jitter <- rh_jitter,
            temporal_blend <- rh_blend,
            bounce_threshold <- rh_threshold,
            reconstruction_samples <- rh_reconstruction,
            reconstruction_reach <- rh_reach,
            near_field_occlusion <- rh_near_field,
            albedo_volume <- rh_albedo,
            refinement_updates <- rh_refinement,
            motion_bounce_period <- rh_motion_period,
            motion_hints_per_update <- rh_motion_hints,
        );
        if let Some(irradiance) = self.rh_irradiance {
            rh.irradiance = if irradiance == "linear" { IrradianceReconstruction::Linear } else { IrradianceReconstruction::NonLinear };
        }
        if let Some(steps) = self.rh_depth_occlusion {
            rh.depth_occlusion = (steps > 0).then_some(DepthOcclusion { samples: steps, ..default() });
        }
        if let Some(visibility) = self.rh_visibility {
            rh.voxel_visibility = visibility == "voxels";
        }
        if let Some(transport) = self.rh_secondary_transport {
            use crate::radiance_hints::SecondaryTransport as T;
            rh.secondary = if transport == "paper" { T::Paper } else { T::VoxelMarch };
        }
        o.dump_volume = self.dump_volume;
    }
}

impl VplArgs {
    fn apply(self, vpl: &mut VplSettings) {
        macro_rules! set {
            ($($field:ident <- $flag:ident),* $(,)?) => {
                $(if let Some(v) = self.$flag { vpl.$field = v; })*
            };
        }
        set!(
            light_paths <- vpl_paths,
            bounces <- vpl_bounces,
            seed <- vpl_seed,
            geometry_bound <- vpl_bound,
            visibility <- vpl_visibility,
            ism_resolution <- vpl_ism_resolution,
            ism_points <- vpl_ism_points,
            ism_bias <- vpl_ism_bias,
            ssbc_steps <- ssbc_steps,
            ssbc_solid_angle <- ssbc_solid_angle,
            ssbc_levels <- ssbc_levels,
            ssbc_blur <- ssbc_blur,
        );
    }
}

impl OneBounceArgs {
    fn apply(self, o: &mut HeadlessOptions) {
        if let Some(v) = self.rsm_samples {
            o.rsm_gather.samples = v;
        }
        if let Some(v) = self.rsm_radius {
            o.rsm_gather.radius = v;
        }
        if let Some(w) = self.rsm_weights {
            use crate::rsm_gather::RsmSampleWeights as W;
            o.rsm_gather.weights = if w == "paper" { W::Paper } else { W::Density };
        }
        if let Some(v) = self.drm_samples {
            o.drm.samples_per_axis = v;
        }
        if let Some(eq) = self.drm_solid_angle {
            o.drm.solid_angle = match eq.as_str() {
                "11" => DrmSolidAngle::Constant,
                "15" => DrmSolidAngle::SceneDiagonal,
                _ => DrmSolidAngle::TexelArea,
            };
        }
        if let Some(v) = self.drm_mip {
            o.drm.mip_mapped = v;
        }
    }
}

/// Parses the headless renderer's command line (without the program name). Errors are clap's (their
/// `exit()` prints the message and exits with status 2, or prints `--help` and exits with 0), or a
/// check that involves several flags, as a clap validation error.
pub fn parse_args<'a>(args: impl IntoIterator<Item = &'a str>) -> Result<HeadlessOptions, clap::Error> {
    use clap::{CommandFactory, Parser};
    let cli = HeadlessCli::try_parse_from(std::iter::once("headless").chain(args))?;
    cli.args.into_options().map_err(|message| HeadlessCli::command().error(clap::error::ErrorKind::ValueValidation, message))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(line: &str) -> Result<HeadlessOptions, String> {
        parse_args(line.split_whitespace()).map_err(|e| e.to_string())
    }

    #[test]
    fn parses_a_full_command_line() {
        let o = parse(
            "--scene cornell --size 128x64 --frames 3 --out a/b.exr --method reference --indirect-only \
             --spp 32 --seed 7 --max-bounces 2 --ev100 1.5",
        )
        .unwrap();
        assert_eq!(o.size, UVec2::new(128, 64));
        assert_eq!((o.frames, o.spp, o.seed, o.max_bounces), (3, 32, 7, Some(2)));
        assert_eq!(o.method, HeadlessMethod::Reference);
        assert!(o.indirect_only);
        assert_eq!(o.out, PathBuf::from("a/b.exr"));
        assert_eq!(o.ev100, Some(1.5));
        assert_eq!(parse("--ev100 -2").unwrap().ev100, Some(-2.0));
        assert_eq!(parse("--scene-scale 250").unwrap().scene_scale, 250.0);
        assert_eq!(parse("").unwrap().scene_scale, 1.0);
        assert!(parse("--scene-scale 0").unwrap_err().contains("--scene-scale"));
    }

    #[test]
    fn defaults_match_headless_options() {
        let o = parse("").unwrap();
        let d = HeadlessOptions::default();
        assert_eq!((o.scene, o.size, o.frames, o.spp, o.method), (d.scene, d.size, d.frames, d.spp, d.method));
        assert_eq!((o.half_resolution, o.rh, o.vpl), (d.half_resolution, d.rh, d.vpl));
    }

    #[test]
    fn bad_input_names_the_problem() {
        let err = |s: &str| parse(s).unwrap_err();
        assert!(err("--size 0x10").contains("--size"));
        assert!(err("--size big").contains("WIDTHxHEIGHT"));
        assert!(err("--method magic").contains("unknown method `magic`"));
        assert!(err("--scene nowhere.glb").contains("does not exist"));
        assert!(err("--scene kitchen").contains("unknown scene"));
        assert!(err("--frames").contains("--frames"));
        assert!(err("--spp 0").contains("--spp"));
        assert!(parse("--spp -3").is_err());
        assert!(err("--out x.png").contains(".exr"));
        assert!(err("--wat").contains("--wat"));
        assert!(err("--ev100 NaN").contains("--ev100"));
        assert!(err("--half-res --full-res").contains("cannot be used with"));
    }

    #[test]
    fn help_lists_every_flag_with_its_default_and_exits_zero() {
        let e = parse_args(["--help"]).unwrap_err();
        assert_eq!(e.kind(), clap::error::ErrorKind::DisplayHelp);
        assert_eq!(e.exit_code(), 0);
        let help = e.to_string();
        for flag in ["--scene", "--size", "--frames", "--method", "--rh-samples", "--vpl-paths", "--ssbc-steps", "--rsm-radius", "--drm-solid-angle", "--switch-method"] {
            assert!(help.contains(flag), "{flag} missing from --help");
        }
        assert!(help.contains("[default: 256x256]") && help.contains("[default: 2048]"), "{help}");
        assert_eq!(parse_args(["--wat"]).unwrap_err().exit_code(), 2);
    }

    #[test]
    fn methods_are_selected_through_gi_method() {
        let o = parse("--method vpl --preset high --ssbc-steps 3 --vpl-bounces 4").unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::Vpl));
        assert_eq!((o.vpl.ssbc_steps, o.vpl.bounces, o.vpl.light_paths), (3, 4, VplSettings::HIGH.light_paths));
        // The preset applies first whatever the order of the flags.
        let o = parse("--ssbc-steps 3 --preset high").unwrap();
        assert_eq!(o.vpl.ssbc_steps, 3);
        assert_eq!(parse("--method rh").unwrap().method, HeadlessMethod::Gi(GiMethod::RadianceHints));
        for name in HeadlessMethod::NAMES {
            assert_eq!(HeadlessMethod::parse(name).unwrap().name(), *name);
        }
        let o = parse("--method rh --switch-method 2:vpl --frames 4").unwrap();
        assert_eq!(o.switch_method, Some((2, GiMethod::Vpl)));
        assert!(parse("--method rh --switch-method 4:vpl --frames 4").unwrap_err().contains("before the last"));
    }

    #[test]
    fn one_bounce_methods_take_presets_and_overrides() {
        let o = parse("--method drm --preset high --drm-solid-angle 11 --drm-mip off").unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::Drm));
        assert_eq!((o.drm.samples_per_axis, o.drm.solid_angle, o.drm.mip_mapped), (16, DrmSolidAngle::Constant, false));
        let o = parse("--method rsm --preset low --rsm-radius 0.2 --rsm-samples 50 --rsm-weights paper").unwrap();
        assert_eq!(o.method, HeadlessMethod::Gi(GiMethod::RsmGather));
        assert_eq!((o.rsm_gather.samples, o.rsm_gather.radius), (50, 0.2));
        assert_eq!(o.rsm_gather.weights, crate::rsm_gather::RsmSampleWeights::Paper);
        assert!(parse("--drm-solid-angle 12").unwrap_err().contains("12"));
        assert!(parse("--drm-mip maybe").unwrap_err().contains("on or off"));
    }

    #[test]
    fn grid_flags_choose_fixed_adaptive_or_cascaded_grids() {
        let o = parse("--method rh --rh-longest 24").unwrap();
        assert_eq!((o.rh.sizing, o.rh.resolution, o.rh_fit_cells), (GridSizing::Fixed, UVec3::splat(24), true));
        let o = parse("--method rh --rh-resolution 4x5x6").unwrap();
        assert_eq!((o.rh.sizing, o.rh.resolution, o.rh_fit_cells), (GridSizing::Fixed, UVec3::new(4, 5, 6), false));
        let o = parse("--method rh --rh-cell 0.5 --rh-max-hints 1000").unwrap();
        let GridSizing::Adaptive { max_cell, max_hints, hints } = o.rh.sizing else {
            panic!("--rh-cell makes the grid adaptive");
        };
        assert_eq!((max_cell, max_hints), (0.5, 1000));
        assert!(matches!(GridSizing::MEDIUM, GridSizing::Adaptive { hints: h, .. } if h == hints));
        let o = parse("--method rh --rh-cascade 2 --rh-cascade-extent 8x4x8").unwrap();
        assert_eq!(o.rh_cascade, Some((2, Vec3::new(8.0, 4.0, 8.0))));
        assert!(parse("--rh-cascade 9").unwrap_err().contains("--rh-cascade"));
        assert!(parse("--rh-cascade-extent 8x4").unwrap_err().contains("XxYxZ"));
        assert!(parse("--rh-longest 8 --rh-cell 0.5").unwrap_err().contains("cannot be used with"));
        let o = parse("--method rh --rh-depth-occlusion 4 --rh-irradiance linear --rh-albedo off --rh-order 3").unwrap();
        assert_eq!(o.rh.depth_occlusion.map(|d| d.samples), Some(4));
        assert_eq!((o.rh.irradiance, o.rh.albedo_volume, o.rh.sh_order), (IrradianceReconstruction::Linear, false, ShOrder::Three));
    }

    #[test]
    fn default_output_name_follows_scene_and_method() {
        let o = parse("--method reference --indirect-only").unwrap();
        assert_eq!(o.out, PathBuf::from("out/cornell_reference_indirect.exr"));
    }
}
