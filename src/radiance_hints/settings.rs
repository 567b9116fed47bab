//! [`RadianceHintsVolume`]: where Radiance Hints apply and how they are computed.

use bevy::math::UVec3;
use bevy::prelude::*;

use crate::settings::{Clamped, GiSettings};
use crate::sh::ShOrder;

/// A box of space lit by Radiance Hints (Papaioannou 2011): a grid of radiance probes ("hints") that sample
/// the reflective shadow maps of every [`GiLight`](crate::light::GiLight), exchange light among themselves
/// for extra bounces, and light the surfaces inside the box.
///
/// The box is the unit cube centred on the entity, transformed by its [`Transform`]: use the scale to give
/// its size in metres (`Transform::from_scale(Vec3::new(20.0, 6.0, 20.0))`), as for Bevy's
/// `IrradianceVolume`. Hints sit at the centres of the grid cells. Surfaces outside every volume receive no
/// bounced light. Rotation is honoured.
///
/// Invalid values (zero or huge sizes, NaN, absurd sample counts) are clamped to the documented range with
/// one warning per field; see [`RadianceHintsVolume::sanitized`].
///
/// Memory per volume ([`memory_bytes`](Self::memory_bytes)):
/// `hints × (4 × 3 × (SH coefficients + 2) × 4 B + 64 B)` (two bounce increments, a running sum, the
/// displayed result, each with the two vertical irradiance terms; distances, albedo and the 32-byte packed
/// irradiance of the reconstruction) plus 9 bits per occupancy voxel (4× the hint resolution: the occupancy
/// bit and the 8-bit visibility mask): 16³ with SH order 2 is 1.7 MiB, 24³ 5.6 MiB, the default over a
/// 60 m field (93 × 14 × 93 hints) 45 MiB.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
#[require(Transform, Visibility)]
#[doc(alias = "RH")]
#[doc(alias = "RadianceHints")]
pub struct RadianceHintsVolume {
    /// How many hints the box gets: [`GridSizing::Adaptive`] (every preset, and the default) fits cubic
    /// cells to the box's size and proportions; [`GridSizing::Fixed`] uses [`resolution`](Self::resolution)
    /// as given.
    ///
    /// Default: [`MEDIUM`](Self::MEDIUM)'s adaptive rule (see [`GridSizing`] for it and its measured error).
    pub sizing: GridSizing,
    /// Hints along x, y and z of the box with [`GridSizing::Fixed`]; with [`GridSizing::Adaptive`] it is
    /// ignored, and [`resolved`](Self::resolved) (what the plugin runs) holds the counts in use.
    ///
    /// Valid range 2–128 per axis and at most 2¹⁸ hints in all. Cost: injection and each bounce are
    /// O(hints); memory is O(hints). Finer grids resolve smaller features and leak less; the cell should be
    /// smaller than the rooms it lights and under about twice the thickness of the walls that must stop
    /// light.
    pub resolution: UVec3,
    /// Spherical-harmonics order of each hint's radiance: [`ShOrder::Two`] (4 coefficients per channel) or
    /// [`ShOrder::Three`] (9).
    ///
    /// Default `Two`. Cost: order 3 writes and reads 2.25× the data in every pass. On `cornell` it is not
    /// more accurate (see `docs/radiance_hints.md`).
    pub sh_order: ShOrder,
    /// RSM samples per hint, `N_s` of the paper (Eq. 4), shared among the GI lights in proportion to their
    /// power.
    ///
    /// Default 64. Valid range 1–1024. Cost: injection is O(hints × samples). Fewer samples are noisier
    /// (temporal accumulation averages it over a few frames); beyond 64 the error is bias, not noise.
    pub rsm_samples: u32,
    /// Fraction of a *directional* light's RSM area sampled around each hint's projection, `c_RSM` of §4.
    ///
    /// Default 1.0 (the whole RSM). Valid range 0.01–1. The paper suggests 0.05–0.15 for sunlight over large
    /// areas, where bounced light travels only a few metres. Spot and point lights always sample their whole
    /// RSM: a hint beside or above such a light has no meaningful projection into it. No cost difference.
    pub rsm_coverage: f32,
    /// How far each RSM sample's receiving point is jittered inside the hint's cell, as a fraction of the
    /// cell (§4: samples "drawn from jittered positions inside the cell").
    ///
    /// Default 0.5 (the middle half of the cell). Valid range 0–1; a non-finite value falls back to the
    /// default. On `cornell` (medium preset) the whole cell (1.0) measured block RMSE 0.110 against 0.119
    /// for 0.5, but it was worse before the receivers were kept in the surfaces' voxels and is not measured
    /// on the other scenes, so the default stays (`docs/radiance_hints.md`, § ablation). Free.
    pub jitter: f32,
    /// Extra diffuse bounces after the first, exchanged between hints (§6–7, Eq. 8–10).
    ///
    /// Default 8. Valid range 0–16. In a closed bright room (cornell) bounces three and later carry a
    /// quarter of the indirect energy, and in two rooms joined by a door (cellar) most of the light that
    /// reaches the unlit room has bounced four times or more: stopping at four left `cellar` at 0.75 of its
    /// energy (block RMSE 0.38), eight reach 0.90 (0.24). Cost: one pass over all hints per bounce, each reading
    /// [`secondary_samples`](Self::secondary_samples) hints. Bounces stop early once one adds less than
    /// [`bounce_threshold`](Self::bounce_threshold) of the light so far.
    pub extra_bounces: u32,
    /// Directions (or, with [`SecondaryTransport::Paper`], points) sampled per hint and per extra bounce,
    /// `N_b` of Eq. 8.
    ///
    /// Default 24. Valid range 1–256. Cost: each bounce is O(hints × samples).
    pub secondary_samples: u32,
    /// Range of the secondary-bounce exchange and the distance normaliser of the confidence (Eq. 9) and
    /// visibility (Eq. 11) terms, `r_max`, in metres. `0` picks it from the volume: half its diagonal, at
    /// least two cell diagonals.
    ///
    /// Default 0 (automatic). Valid range 0 or 0.01–10 000. A fixed small `r_max` starves large rooms of
    /// bounced light; a large one leaks more. Free.
    pub r_max: f32,
    /// Stop extra bounces once one adds less than this fraction of the light gathered so far.
    ///
    /// Default 0.01. Valid range 0–1 (0 runs every bounce). Saves the remaining bounce passes.
    pub bounce_threshold: f32,
    /// Weight of the newest update when the hints are blended over time while lights or geometry change
    /// (§9.1): `1` disables smoothing.
    ///
    /// Default 0.5 (the paper's). Valid range 0.05–1. Free.
    pub temporal_blend: f32,
    /// Once lights, geometry and settings are still, the volume keeps updating this many more times and
    /// averages the updates since the change (weights 1, 1/2, 1/3, …): each update draws fresh RSM samples
    /// and jitter, so the average converges to the noise-free field. Then it stops until something changes.
    ///
    /// Default 16. Valid range 0–256; 0 updates only until the temporal blend has settled (the paper's
    /// behaviour). Cost: that many more updates after every change; none while still.
    pub refinement_updates: u32,
    /// While lights or meshes move, each update recomputes the extra bounces of one hint in this many
    /// (whole workgroups of hints in turn); the others keep the bounce they gathered last. The first
    /// update after the motion starts, and every update of a volume that scrolled, recomputes them all.
    ///
    /// Default 4. Valid range 1–16; 1 recomputes every hint's bounce every frame. While things move each
    /// update injects the first bounce anew and gathers one more bounce from the displayed field (see
    /// [`extra_bounces`](Self::extra_bounces)); that gather was the larger part of a moving light's
    /// frame: on `cornell` at 256² on lavapipe 3.9× the frame without GI with 1, 2.9× with 4
    /// (`docs/radiance_hints.md`, § timing), the image while moving within 0.002 block RMSE of 1's.
    /// Cost: the moving frame's bounce pass is 1/period of a full one; the light of the second and later
    /// bounces follows the motion up to `period` frames late. No effect on a still scene.
    pub motion_bounce_period: u32,
    /// While lights or meshes move, the most hints each update injects and gathers a bounce for: a
    /// volume with more hints than this updates its workgroups of hints in turns, `⌈hints / this⌉` frames
    /// for a round (at least [`motion_bounce_period`](Self::motion_bounce_period)), each hint keeping the
    /// light of its last turn meanwhile. The first update after the motion starts, and every update of a
    /// volume that scrolled, update every hint.
    ///
    /// Default 16 384 (four times a small room's 4 096 hints: rooms up to about 13 × 13 × 4 m at the
    /// default 0.35 m cells update whole). Valid range 256–2¹⁸ (2¹⁸: every hint, every update). Cost: a
    /// moving light's update over a large volume costs about what one over this many hints does:
    /// `open_field`'s 60 m volume (121 000 hints, eight turns) with its sun moving, 256² on lavapipe,
    /// 2.3–2.9 s → 0.69–0.79 s a frame (the still frame: 0.10 s). The light of a hint follows the motion
    /// up to `⌈hints / this⌉` frames late, and the bounces gather fewer times: over six frames while
    /// the sun moves the image was a median 0.56 block RMSE from the path-traced truth (0.46–0.81)
    /// against 0.50 (0.43–0.71) with every hint every frame, 0.33 when still. No effect on a still
    /// scene, nor on volumes of at most this many hints.
    pub motion_hints_per_update: u32,
    /// How the extra bounces find the surfaces that reflect light. Default
    /// [`SecondaryTransport::VoxelMarch`].
    pub secondary: SecondaryTransport,
    /// Test each RSM sample's path to the point receiving it against the volume's voxelised scene, so
    /// that light does not pass through walls (the first bounce is otherwise unoccluded, §7).
    ///
    /// Default `true`. Cost: a 3D DDA through the occupancy grid (4× the hint resolution) per RSM sample,
    /// the largest part of the injection's time; the voxelisation is redone only when geometry changes.
    pub voxel_visibility: bool,
    /// Reflect secondary bounces with the colour of nearby surfaces (§6's optional albedo volume) instead
    /// of white (Eq. 10).
    ///
    /// Default `true`. The albedo volume is voxelised on the CPU from the scene snapshot when geometry
    /// changes (O(triangles)), and read once per secondary sample.
    pub albedo_volume: bool,
    /// Attenuate each RSM sample's light by the camera depth buffer along its path to the hint (§8).
    /// View-dependent; `None` turns it off.
    ///
    /// Default `None`. Cost: O(hints × samples × steps) depth reads, and the volume is recomputed
    /// whenever the camera moves.
    pub depth_occlusion: Option<DepthOcclusion>,
    /// Hint samples per shaded pixel, `N_RH` of Eq. 6: the first at the centre of the hemisphere (on the
    /// normal, half of [`reconstruction_reach`](Self::reconstruction_reach)'s cell diagonals off the surface),
    /// the rest on a cone 80° from the normal around it, rotated per pixel (§5).
    ///
    /// Default 4. Valid range 1–16. Cost: the reconstruction is O(pixels × samples).
    pub reconstruction_samples: u32,
    /// How far off the surface the reconstruction reads the field, in cell diagonals `r`: the hemisphere
    /// of samples is centred `reach · r/2` off the surface and has radius `reach · r` (§5 uses 1).
    ///
    /// Default 0.5. Valid range 0.1–2. Closer samples read the light a surface actually receives rather
    /// than the light up to one and a half cells in front of it (a point nearer a bright wall, or one that
    /// sees through a door the surface does not); the exact vertical irradiance of floors and ceilings
    /// needs them. Measured at the defaults (block relative RMSE, reach 1 → 0.5 → 0.25): `cornell`
    /// 0.157 → 0.119 → 0.116, `cellar` 0.214 → 0.200 → 0.191, `open_field` (0.65 m cells) 0.343 → 0.297
    /// → 0.471 (`docs/radiance_hints.md`, § reconstruction). With [`HIGH`](Self::HIGH)'s smaller cells
    /// `cellar` prefers reach 1 (0.198 against 0.241): the best reach is not yet scale-free. Free.
    pub reconstruction_reach: f32,
    /// Range of the near-field occlusion, in cell diagonals (0 turns it off): the hints lie half a cell
    /// and more off a surface, so the field cannot know that the floor beside a box's base sees less of
    /// the room than the floor in the open. Each pixel marches a few cosine-distributed rays this far
    /// through the voxels and darkens its indirect light by the share that is blocked, with the
    /// multi-bounce correction of Jimenez et al. 2016 (occluders reflect part of the light they block).
    ///
    /// Default 0 (off) in every preset: measured against the path-traced ground truth it raises the error
    /// more than it removes (0.5 diagonals: `cornell` 0.119 → 0.212 block relative RMSE with 5 % less
    /// energy, `cellar` 0.200 → 0.227): the occupancy voxels, a quarter of a cell, are too coarse for
    /// contact occlusion and darken whole surfaces near others. Valid range 0–2. Needs
    /// [`voxel_visibility`](Self::voxel_visibility). Cost: four short voxel marches per pixel.
    pub near_field_occlusion: f32,
    /// How each pixel turns the interpolated SH radiance into irradiance (§5, Eq. 7).
    ///
    /// Default [`IrradianceReconstruction::NonLinear`]. With SH order 3 the linear form is always used.
    /// Free (one `pow` per channel and pixel).
    pub irradiance: IrradianceReconstruction,
    /// Multiplier on the bounced light, for art direction. 1 is physically based.
    ///
    /// Default 1. Valid range 0–100. Free.
    pub intensity: f32,
}

/// How the hint grid of a [`RadianceHintsVolume`] follows the size of its box.
///
/// A fixed count is right for one size only: 16³ hints give `cornell` (2 m) cells of 12.5 cm and block
/// RMSE 0.20, but a 12 m atrium cells of 75 cm that blur its light across columns and walls (`sponza_like`
/// 0.57 in the issue that introduced this). The adaptive rule sizes cells in two regimes:
/// * **small volumes** get `hints` hints in cubic cells, `cell = (V / hints)^⅓` for a box of volume `V`:
///   the resolution that suits rooms of a few metres;
/// * **large volumes** would then get cells too coarse for their walls and rooms, so the cell never exceeds
///   `max_cell` metres, and the grid grows (cost grows with it) up to `max_hints`, beyond which cells
///   grow again. Very large worlds want several volumes (they blend where they overlap).
///
/// `max_cell` is a length in metres, right for rooms at game scale, but a scene is not always modelled in
/// metres: Bevy's own `CornellBox.glb` is a 557 m box, and `max_cell` gave it 51 × 50 × 51 hints (55 MB,
/// 20 s of bounces per frame on lavapipe) where the same box at 2 m gets 16³. So the cap is also at least
/// [`GridSizing::MEAN_CHORD_CELL`] times the volume's mean chord, the mean distance between its surfaces
/// ([`SceneSnapshot::mean_chord`](crate::scene::SceneSnapshot::mean_chord), measured once per layout of
/// the scene): a length of the scene's own, so a scene's hints do not depend on its units. Every room of
/// the standard scenes and the generated family has a mean chord under 1.6 m, where the metres rule is
/// the tighter one and nothing changes; a wide open hall or a scene in other units gets the hints its
/// geometry needs.
///
/// Every axis gets at least 2 hints. `docs/radiance_hints.md` (§ game scale) measures the rule on
/// `cornell`, `cellar`, `sponza_like` and `open_field`.
#[derive(Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Clone)]
pub enum GridSizing {
    /// [`RadianceHintsVolume::resolution`] hints per axis, whatever the box.
    Fixed,
    /// Cubic cells fitted to the box (see the type's docs).
    Adaptive {
        /// Hints of a small volume. Default 4096 ([`GridSizing::MEDIUM`]). Valid range 8–2¹⁸. Cost: the
        /// volume's updates and memory are O(hints).
        hints: u32,
        /// The largest cell edge in metres before the grid grows beyond `hints`. Default 0.35. Valid
        /// range 0.01–100. Smaller cells cost more hints in large volumes (up to `max_hints`).
        max_cell: f32,
        /// Most hints the grid grows to. Default 131 072 (2¹⁷): cells stay at `max_cell` up to a level of
        /// about 30 × 6 × 30 m, and a 60 m field gets 0.65 m cells. Valid range `hints`–2¹⁸. Cost: a volume
        /// this large takes about 45 MiB and updates about 30× slower than a 4096-hint one; the per-pixel
        /// reconstruction does not depend on it.
        max_hints: u32,
    },
}

impl GridSizing {
    /// The default rule ([`RadianceHintsVolume::MEDIUM`]'s): 4096 hints in a small room, cells up to
    /// 0.35 m, at most 131 072 hints.
    pub const MEDIUM: Self = Self::Adaptive {
        hints: 4096,
        max_cell: 0.35,
        max_hints: 131072,
    };

    /// The largest cell, as a fraction of the volume's mean chord, that the adaptive rule keeps cells
    /// under whatever `max_cell` says: about five cells across the mean distance between surfaces (see the
    /// type's docs).
    pub const MEAN_CHORD_CELL: f32 = 0.2;

    /// The hints per axis for a box of `size` metres whose surfaces are `mean_chord` metres apart on
    /// average (`None`: unknown, the `max_cell` rule alone).
    pub fn resolution_for(&self, fixed: UVec3, size: Vec3, mean_chord: Option<f32>) -> UVec3 {
        let GridSizing::Adaptive { hints, max_cell, max_hints } = *self else {
            return fixed;
        };
        let size = if size.is_finite() { size.max(Vec3::splat(1e-3)) } else { Vec3::ONE };
        let volume = size.x * size.y * size.z;
        let chord_cell = mean_chord.filter(|c| c.is_finite() && *c > 0.0).map_or(0.0, |c| c * Self::MEAN_CHORD_CELL);
        let mut cell = (volume / hints.max(1) as f32).cbrt().min(max_cell.max(chord_cell).max(1e-3));
        let counts = |cell: f32| (size / cell).round().max(Vec3::splat(2.0)).min(Vec3::splat(128.0));
        // Grow the cells until the grid fits the budget (the rounding may overshoot by a little).
        while counts(cell).x * counts(cell).y * counts(cell).z > max_hints.max(8) as f32 {
            cell *= 1.02;
        }
        counts(cell).as_uvec3()
    }
}

/// How the extra bounces (§6–7) find the surfaces that reflect light back to a hint.
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum SecondaryTransport {
    /// March [`secondary_samples`](RadianceHintsVolume::secondary_samples) uniformly distributed
    /// directions through the voxelised scene to the first surface, and reflect the previous bounce's
    /// light there: `ΔL_lm = 4π/N_b Σ_j ρ_j/π · E_j(−ω_j) Y_lm(ω_j)`. Monte Carlo over directions with real
    /// visibility, so the energy each bounce adds follows the scene (this is not in the paper).
    #[default]
    VoxelMarch,
    /// The paper's Eq. 8–11: hints sampled in a ball of `r_max`, weighted by the distance-based visibility
    /// (Eq. 11) and confidence (Eq. 9), read as a weighted Monte Carlo estimate. Needs no voxelisation, but
    /// the energy it adds depends strongly on `r_max`.
    Paper,
}

/// How the reconstruction turns SH radiance into the irradiance on a surface (§5).
///
/// Order-2 SH (four coefficients per channel) describe a hint's light as a mean and one linear lobe. Eq. 7
/// integrates that against the clamped cosine, which is linear in the coefficients: `E(n) = a + b·n`. When
/// one side of a hint is much brighter than the other (a hint above a sunlit floor, beside a bright box
/// face), the lobe is so strong that `a + b·n` goes negative on the dim side and is clamped to zero: the
/// light that side does receive is lost, and a dark or tinted smudge appears (the small box's top and the
/// floor by the red wall in `cornell`). Measured with the default settings at 256² (block relative RMSE,
/// linear → non-linear, half resolution): `cornell` 0.126 → 0.119, `cellar` 0.249 → 0.200,
/// `emissive_panel` 0.352 → 0.299; `sponza_like`, `open_field` and the point-lit `dynamic` room within
/// 0.01 (`docs/radiance_hints.md`, § reconstruction). Floors and ceilings also read each hint's exact
/// vertical irradiance, in both forms.
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[reflect(Clone, Default)]
pub enum IrradianceReconstruction {
    /// Eq. 7 as the paper has it (Ramamoorthi–Hanrahan's cosine convolution), clamped at zero.
    Linear,
    /// Hazel's non-linear reconstruction ("Reconstructing diffuse lighting from spherical harmonic data",
    /// Geomerics 2015), as light-probe systems use it: the same mean irradiance over all normals, exact
    /// for a single distant light, and never below zero, so a bright lobe does not eat the light on the
    /// other side. Used with SH order 2.
    #[default]
    NonLinear,
}

/// The optional camera-depth occlusion of RSM samples (paper §8).
#[derive(Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Clone, Default)]
pub struct DepthOcclusion {
    /// Points tested along each RSM-sample-to-hint segment.
    ///
    /// Default 4 (the paper uses 3–8). Valid range 1–16.
    pub samples: u32,
    /// Fraction of the sample's light removed for each tested point found behind the camera's depth
    /// buffer (the attenuation is `(1 − strength)^hidden`).
    ///
    /// Default 0.5. Valid range 0–1.
    pub strength: f32,
}

impl Default for DepthOcclusion {
    fn default() -> Self {
        Self {
            samples: 4,
            strength: 0.5,
        }
    }
}

impl RadianceHintsVolume {
    /// SH order 2, 32 RSM samples, two extra bounces of 16 samples: the cheapest useful setting.
    ///
    /// Adaptive grid: 512 hints (8³) in a small room, cells up to 0.7 m, at most 8192 hints.
    pub const LOW: Self = Self {
        sizing: GridSizing::Adaptive {
            hints: 512,
            max_cell: 0.7,
            max_hints: 8192,
        },
        resolution: UVec3::splat(8),
        sh_order: ShOrder::Two,
        rsm_samples: 32,
        rsm_coverage: 1.0,
        jitter: 0.5,
        extra_bounces: 2,
        secondary_samples: 16,
        r_max: 0.0,
        bounce_threshold: 0.01,
        temporal_blend: 0.5,
        refinement_updates: 16,
        motion_bounce_period: 4,
        motion_hints_per_update: 16384,
        albedo_volume: true,
        depth_occlusion: None,
        reconstruction_samples: 4,
        reconstruction_reach: 0.5,
        irradiance: IrradianceReconstruction::NonLinear,
        near_field_occlusion: 0.0,
        intensity: 1.0,
        secondary: SecondaryTransport::VoxelMarch,
        voxel_visibility: true,
    };

    /// SH order 2, 64 RSM samples, up to eight extra bounces of 24 samples (they stop once one adds under
    /// 1 %). The default.
    ///
    /// Adaptive grid: 4096 hints (16³) in a small room, cells up to 0.35 m, at most 131 072 hints.
    pub const MEDIUM: Self = Self {
        sizing: GridSizing::MEDIUM,
        resolution: UVec3::splat(16),
        rsm_samples: 64,
        extra_bounces: 8,
        secondary_samples: 24,
        ..Self::LOW
    };

    /// SH order 2, 96 RSM samples, up to twelve extra bounces of 32 samples.
    ///
    /// Adaptive grid: 13 824 hints (24³) in a small room, cells up to 0.25 m, at most 262 144 hints.
    pub const HIGH: Self = Self {
        sizing: GridSizing::Adaptive {
            hints: 13824,
            max_cell: 0.25,
            max_hints: 262144,
        },
        resolution: UVec3::splat(24),
        rsm_samples: 96,
        extra_bounces: 12,
        secondary_samples: 32,
        ..Self::MEDIUM
    };

    /// Most hints accepted in one volume.
    pub const MAX_HINTS: u32 = 1 << 18;


    /// The settings the plugin runs for a box of `size` metres whose surfaces are `mean_chord` metres apart
    /// ([`RhMeanChord`](super::extract::RhMeanChord)): [`sizing`](Self::sizing) applied, so that
    /// [`resolution`](Self::resolution) holds the hints in use and the sizing is [`GridSizing::Fixed`].
    pub fn resolved(&self, size: Vec3, mean_chord: Option<f32>) -> Self {
        let mut s = self.clone();
        s.resolution = self.sizing.resolution_for(self.resolution, size, mean_chord);
        while s.hint_count() > Self::MAX_HINTS {
            s.resolution = (s.resolution.as_vec3() * 0.9).as_uvec3().max(UVec3::splat(2));
        }
        s.sizing = GridSizing::Fixed;
        s
    }

    /// The sanitized settings a volume with `world_from_local` (its unit cube to world) runs, in a scene
    /// whose surfaces in the volume are `mean_chord` metres apart (the volume's
    /// [`RhMeanChord`](super::extract::RhMeanChord); `None` before it is measured).
    pub fn effective(&self, world_from_local: Mat4, mean_chord: Option<f32>) -> Self {
        self.sanitized().0.resolved(box_size(world_from_local), mean_chord)
    }

    /// The same settings with a fixed resolution adapted to a box of `size` metres so that cells are about
    /// cubic: the preset's largest per-axis count goes along the longest side, the others in proportion
    /// (at least 2).
    pub fn with_cubic_cells(mut self, size: Vec3) -> Self {
        self.sizing = GridSizing::Fixed;
        let size = if size.is_finite() { size.max(Vec3::splat(1e-3)) } else { Vec3::ONE };
        let hints = self.resolution.max_element().max(2) as f32;
        let cell = size.max_element() / hints;
        self.resolution = (size / cell).round().as_uvec3().max(UVec3::splat(2));
        self
    }

    /// Hints in the grid.
    pub fn hint_count(&self) -> u32 {
        self.resolution.x * self.resolution.y * self.resolution.z
    }

    /// `r_max` in metres for a volume of size `size` (metres).
    pub fn effective_r_max(&self, size: Vec3) -> f32 {
        if self.r_max > 0.0 {
            return self.r_max;
        }
        let cell = size / self.resolution.max(UVec3::ONE).as_vec3();
        (0.5 * size.length()).max(2.0 * cell.length()).max(1e-3)
    }

    /// GPU memory of the volume's buffers in bytes: four SH buffers (two bounce increments, the running
    /// sum and the displayed result), the distances, albedo and packed irradiance per hint, the occupancy
    /// bits and the visibility masks.
    pub fn memory_bytes(&self) -> u64 {
        let hints = self.hint_count() as u64;
        let sh = hints * crate::radiance_hints::field_floats(self.sh_order) as u64 * 4;
        let occupancy = crate::radiance_hints::voxelize::occupancy_resolution(self.resolution);
        let occupancy_bytes = (occupancy.x as u64 * occupancy.y as u64 * occupancy.z as u64).div_ceil(32) * 4;
        // Two bounce increments, the sum, the result; distances and albedo (16 B each per hint), the packed
        // irradiance; the occupancy bits and the visibility masks (one byte per voxel).
        4 * sh + 2 * hints * 16 + hints * crate::radiance_hints::PACKED_BYTES + 9 * occupancy_bytes
    }
}

/// The edge lengths in metres of the box a unit-cube-to-world matrix spans.
pub fn box_size(world_from_local: Mat4) -> Vec3 {
    Vec3::new(
        world_from_local.x_axis.truncate().length(),
        world_from_local.y_axis.truncate().length(),
        world_from_local.z_axis.truncate().length(),
    )
}

impl Default for RadianceHintsVolume {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for RadianceHintsVolume {
    const NAME: &'static str = "RadianceHintsVolume";

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        let mut r = s.resolution;
        for axis in [&mut r.x, &mut r.y, &mut r.z] {
            *axis = (*axis).clamp(2, 128);
        }
        while r.x * r.y * r.z > Self::MAX_HINTS {
            r = (r.as_vec3() * 0.9).as_uvec3().max(UVec3::splat(2));
        }
        if r != s.resolution {
            s.resolution = r;
            c.fields.push(("resolution", r.to_string()));
        }
        if let GridSizing::Adaptive { hints, max_cell, max_hints } = &mut s.sizing {
            let before = (*hints, *max_cell, *max_hints);
            let mut ignored = Clamped::default();
            ignored.uint(hints, 8, Self::MAX_HINTS, "sizing");
            ignored.uint(max_hints, *hints, Self::MAX_HINTS, "sizing");
            ignored.float(max_cell, 0.01, 100.0, 0.35, "sizing");
            if before != (*hints, *max_cell, *max_hints) {
                c.fields.push(("sizing", format!("{:?}", s.sizing)));
            }
        }
        c.uint(&mut s.rsm_samples, 1, 1024, "rsm_samples");
        c.uint(&mut s.extra_bounces, 0, 16, "extra_bounces");
        c.uint(&mut s.secondary_samples, 1, 256, "secondary_samples");
        c.uint(&mut s.reconstruction_samples, 1, 16, "reconstruction_samples");
        c.float(&mut s.reconstruction_reach, 0.1, 2.0, 0.5, "reconstruction_reach");
        c.uint(&mut s.refinement_updates, 0, 256, "refinement_updates");
        c.uint(&mut s.motion_bounce_period, 1, 16, "motion_bounce_period");
        c.uint(&mut s.motion_hints_per_update, 256, Self::MAX_HINTS, "motion_hints_per_update");
        c.float(&mut s.rsm_coverage, 0.01, 1.0, 1.0, "rsm_coverage");
        c.float(&mut s.jitter, 0.0, 1.0, 0.5, "jitter");
        c.float(&mut s.bounce_threshold, 0.0, 1.0, 0.01, "bounce_threshold");
        c.float(&mut s.temporal_blend, 0.05, 1.0, 0.5, "temporal_blend");
        c.float(&mut s.intensity, 0.0, 100.0, 1.0, "intensity");
        c.float(&mut s.near_field_occlusion, 0.0, 2.0, 0.0, "near_field_occlusion");
        if s.r_max != 0.0 {
            c.float(&mut s.r_max, 0.01, 10_000.0, 0.0, "r_max");
        }
        if let Some(o) = &mut s.depth_occlusion {
            c.uint(&mut o.samples, 1, 16, "depth_occlusion.samples");
            c.float(&mut o.strength, 0.0, 1.0, 0.5, "depth_occlusion.strength");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_ordered() {
        for preset in [RadianceHintsVolume::LOW, RadianceHintsVolume::MEDIUM, RadianceHintsVolume::HIGH] {
            let (s, changed) = preset.sanitized();
            assert!(changed.is_empty(), "{changed:?}");
            assert_eq!(s, preset);
        }
        assert!(RadianceHintsVolume::LOW.hint_count() < RadianceHintsVolume::MEDIUM.hint_count());
        assert!(RadianceHintsVolume::MEDIUM.hint_count() < RadianceHintsVolume::HIGH.hint_count());
        assert_eq!(RadianceHintsVolume::default(), RadianceHintsVolume::MEDIUM);
    }

    #[test]
    fn invalid_values_are_clamped_and_named() {
        let bad = RadianceHintsVolume {
            resolution: UVec3::new(0, 100_000, 3),
            rsm_samples: 0,
            rsm_coverage: f32::NAN,
            jitter: -1.0,
            extra_bounces: 1000,
            secondary_samples: 0,
            r_max: -5.0,
            temporal_blend: 0.0,
            intensity: f32::INFINITY,
            depth_occlusion: Some(DepthOcclusion {
                samples: 0,
                strength: f32::NAN,
            }),
            near_field_occlusion: 7.0,
            motion_bounce_period: 0,
            motion_hints_per_update: 3,
            ..default()
        };
        let (s, changed) = bad.sanitized();
        assert!(s.resolution.min_element() >= 2 && s.hint_count() <= RadianceHintsVolume::MAX_HINTS);
        assert_eq!(s.rsm_samples, 1);
        assert_eq!(s.rsm_coverage, 1.0);
        assert_eq!(s.jitter, 0.0);
        assert_eq!(s.extra_bounces, 16);
        assert_eq!(s.secondary_samples, 1);
        assert_eq!(s.r_max, 0.01);
        assert_eq!(s.temporal_blend, 0.05);
        assert_eq!(s.intensity, 1.0, "a non-finite value takes the default");
        assert_eq!(s.depth_occlusion, Some(DepthOcclusion { samples: 1, strength: 0.5 }));
        assert_eq!(s.near_field_occlusion, 2.0);
        assert_eq!(s.motion_bounce_period, 1);
        assert_eq!(s.motion_hints_per_update, 256);
        assert_eq!(RadianceHintsVolume { near_field_occlusion: f32::NAN, ..default() }.sanitized().0.near_field_occlusion, 0.0);
        for name in ["resolution", "rsm_samples", "rsm_coverage", "jitter", "extra_bounces", "r_max", "intensity", "near_field_occlusion", "motion_bounce_period", "motion_hints_per_update"] {
            assert!(changed.iter().any(|(field, _)| *field == name), "{name} missing from {changed:?}");
        }
        let (_, jitter) = changed.iter().find(|(field, _)| *field == "jitter").unwrap();
        assert_eq!(jitter, "0", "the warning names the value used");
        // Clamping is idempotent.
        assert!(s.sanitized().1.is_empty());
    }

    #[test]
    fn cubic_cells_follow_the_box() {
        let v = RadianceHintsVolume::MEDIUM.with_cubic_cells(Vec3::new(8.0, 2.5, 4.0));
        assert_eq!(v.resolution, UVec3::new(16, 5, 8));
        let flat = RadianceHintsVolume::LOW.with_cubic_cells(Vec3::new(10.0, 0.0, 10.0));
        assert_eq!(flat.resolution, UVec3::new(8, 2, 8));
    }

    #[test]
    fn adaptive_grids_fit_cubic_cells_to_small_and_large_boxes() {
        let medium = RadianceHintsVolume::MEDIUM;
        let GridSizing::Adaptive { hints, max_cell, max_hints } = medium.sizing else {
            panic!("the default is adaptive");
        };
        // A 2 m room gets the small-volume budget in cubic cells.
        let small = medium.resolved(Vec3::splat(2.02), None);
        assert_eq!(small.sizing, GridSizing::Fixed);
        assert!((small.hint_count() as f32 / hints as f32 - 1.0).abs() < 0.1, "{}", small.resolution);
        // A long flat box keeps its proportions.
        let flat = medium.resolved(Vec3::new(8.0, 2.0, 4.0), None).resolution;
        assert_eq!((flat.x / flat.y, flat.x / flat.z), (4, 2), "{flat}");
        // A large room: cells no larger than max_cell, more hints than the small budget.
        let hall = medium.resolved(Vec3::new(12.6, 6.6, 8.6), None);
        let cell = Vec3::new(12.6, 6.6, 8.6) / hall.resolution.as_vec3();
        assert!(cell.max_element() <= max_cell * 1.1, "{cell}");
        assert!(hall.hint_count() > hints);
        // A huge world: the budget wins, cells grow.
        let field = medium.resolved(Vec3::new(60.0, 9.0, 60.0), None);
        assert!(field.hint_count() <= max_hints, "{}", field.hint_count());
        assert!(field.hint_count() as f32 > 0.8 * max_hints as f32);
        // Fixed sizing is left alone.
        let fixed = RadianceHintsVolume { sizing: GridSizing::Fixed, ..medium.clone() };
        assert_eq!(fixed.resolved(Vec3::splat(100.0), None).resolution, UVec3::splat(16));
        // Degenerate boxes still get at least 2 hints per axis.
        assert!(medium.resolved(Vec3::new(f32::NAN, 0.0, 1.0), None).resolution.min_element() >= 2);
    }

    #[test]
    fn the_adaptive_grid_of_a_scene_does_not_depend_on_its_units() {
        use crate::scene::{SceneSnapshot, SnapshotMaterial, mesh_triangles};
        use bevy::math::primitives::Cuboid;
        use bevy::prelude::{GlobalTransform, Mesh, Transform};
        // A closed 2 m box with a block in it, and the same 278.5 times larger (Bevy's CornellBox.glb is a
        // 557 m box): its surfaces are 278.5 times further apart, and it gets the same hints.
        let scene = |s: f32| {
            let mut t = mesh_triangles(&Mesh::from(Cuboid::new(2.0, 2.0, 2.0)), &GlobalTransform::from_scale(Vec3::splat(s)), 0).unwrap();
            let block = Transform::from_xyz(0.3 * s, -0.4 * s, 0.2 * s).with_scale(Vec3::splat(s));
            t.extend(mesh_triangles(&Mesh::from(Cuboid::new(0.6, 1.2, 0.6)), &GlobalTransform::from(block), 0).unwrap());
            SceneSnapshot::build(t, vec![SnapshotMaterial::DEFAULT_GREY], vec![], vec![])
        };
        let chord = |s: f32| scene(s).mean_chord(Vec3::splat(-s), Vec3::splat(s), 2048).expect("surfaces");
        let (small, large) = (chord(1.0), chord(278.5));
        assert!((0.3..1.5).contains(&small), "{small} m between the surfaces of a 2 m box");
        assert!((large / small / 278.5 - 1.0).abs() < 1e-3, "{large} m at 278.5× against {small} m");
        let medium = RadianceHintsVolume::MEDIUM;
        let at = |s: f32, c: Option<f32>| medium.resolved(Vec3::splat(2.0 * s), c).resolution;
        assert_eq!(at(1.0, Some(small)), UVec3::splat(16));
        assert_eq!(at(278.5, Some(large)), at(1.0, Some(small)));
        // Without the chord, `max_cell` in metres alone: the 557 m box got the largest grid.
        assert!(at(278.5, None).element_product() > 100_000, "{}", at(278.5, None));
        // At game scale the metres rule is the tighter one: the chord changes nothing.
        for size in [Vec3::new(12.6, 6.6, 8.6), Vec3::new(60.0, 9.0, 60.0), Vec3::new(20.0, 6.0, 12.0)] {
            assert_eq!(medium.resolved(size, Some(1.6)).resolution, medium.resolved(size, None).resolution, "{size}");
        }
    }

    #[test]
    fn automatic_r_max_scales_with_the_volume() {
        let v = RadianceHintsVolume::MEDIUM;
        let small = v.effective_r_max(Vec3::splat(2.0));
        let large = v.effective_r_max(Vec3::new(20.0, 6.0, 20.0));
        assert!((small - 3f32.sqrt()).abs() < 1e-5);
        assert!(large > 10.0 * small * 0.8);
        let fixed = RadianceHintsVolume { r_max: 1.5, ..v };
        assert_eq!(fixed.effective_r_max(Vec3::splat(100.0)), 1.5);
    }
}
