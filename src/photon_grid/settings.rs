//! The photon grid's settings component: `LOW`/`MEDIUM`/`HIGH` and their validation; which fields the
//! background preparation reads and which only the gather.

use bevy::prelude::*;

use crate::settings::{Clamped, GiSettings};

/// The settings of the photon grid, on a camera with [`DiffuseGi`](crate::camera::DiffuseGi)
/// `{ method: GiMethod::PhotonGrid, .. }`. A camera without it uses [`PhotonGridSettings::default`] (the
/// medium preset). The field is the scene's, not the view's: with several photon-grid cameras, the first
/// active one's settings apply. Invalid values are clamped to their range with one warning.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
pub struct PhotonGridSettings {
    /// SH-grid cells along the longest side of the scene's bounding box (the V-grid has four times as
    /// many; one more cell pads each side). Range 4–96; low 16, medium 32 (the default, the paper's for
    /// rooms), high 64 (the paper's for Sponza). Cost: memory and voxelisation grow with the cube; the
    /// field's probes with the square (they follow the surfaces). A change: a new preparation (V-grid
    /// included), in the background.
    pub resolution: u32,
    /// Photons emitted per update over all sources. Range 1 024 – 4 194 304; low 65 536, medium 262 144
    /// (the paper's), high 1 048 576. Cost: linear (tracing and the R-grid's sort); once a mesh has
    /// moved, about 100 bytes a path are kept so that a moved mesh re-traces only the paths that ran
    /// near it. A change: new photons, R-grid and field (the V-grid is kept), in the background.
    pub photons: u32,
    /// Stored reflections per photon path (the final gather adds one more bounce); Russian roulette ends
    /// most paths earlier. Range 1–32; low 4 (the paper's), medium 8 (the default), high 16. The paper
    /// saw no visual difference beyond four, but light is lost: in `cornell` (albedo about 0.75) the
    /// surfaces' radiance is 0.85 of the path tracer's with 4 and 0.97 with 8. Cost: at most linear in
    /// the stored photons (`cornell`: 2.0 N with 4, 2.6 N with 8). A change: new photons, R-grid and
    /// field, in the background.
    pub max_reflections: u32,
    /// Ray directions per SH probe (`N_sh`). Range 16–2048; low 128, medium 256, high 400 (the
    /// paper's). Cost: linear in the field's construction; once a mesh has moved, 4 bytes a ray are kept
    /// so that a moved mesh marches only the rays that ran near it. A change: a new field (every ray
    /// marched; the photons are kept), in the background.
    pub sh_directions: u32,
    /// The coarsest R-grid level the radiance filter of §3.4.3 may read for a far hit (level `k` has
    /// cells `2^k` times the SH cell's side); 0 reads the base level only. Range 0–5; default 1 (the
    /// paper's filter is unbounded). A coarse cell mixes the light of surfaces on both sides of a wall
    /// and spreads a small surface's flux over its whole face: block RMSE / energy on `cornell` 0.109 /
    /// 0.96 with 0, 0.141 / 0.92 with 1, 0.211 / 0.86 unbounded; on `cellar` 0.199 / 0.88, 0.181 / 1.02,
    /// 0.290 / 1.10 (the base level alone is darker where photons are few). Cost: none per frame; a
    /// change: a new field, in the background (the photons are kept; after a mesh has moved, so are
    /// the probe rays' hits, and only their radiance is read again).
    pub filter_levels: u32,
    /// Hemisphere directions of the final gather (`N_d`, §4.2); 0 integrates the nine coefficients
    /// exactly. Range 0–256; default 0. Cost: per pixel, linear (0 costs about as much as 4). A change
    /// runs no preparation: the gather reads it in the same frame.
    pub gather_samples: u32,
    /// Extent of the gather's distance weight `w_sh`, in SH cells. Range 1–3; default 1.75 (the
    /// paper's). Cost: none; a change runs no preparation.
    pub r_max: f32,
    /// Distance in metres at which the obscurance of §4.4 (`ρ(d) = min(d / D, 1)` over the distance
    /// field) stops darkening; 0 turns it off. Range 0–1000; default 0 (it is not physically based).
    /// The field keeps distances up to four SH cells, so a larger `D` darkens everything.
    /// Cost: per pixel, a second pass over the gather's directions. A change runs no preparation.
    pub obscurance_distance: f32,
    /// Multiplies the indirect light. Range 0–1000; default 1. Cost: none; a change runs no preparation.
    pub intensity: f32,
    /// Where the SH field (§3.4, most of the preparation's time) is built: on the CPU's threads or on
    /// the GPU the frame renders with (as the paper does), from the background task either way. Default
    /// [`FieldDevice::Auto`]. The two give the same field (up to the order of floating-point sums).
    /// Cost: see [`FieldDevice`]; a change: a new field, in the background (the photons are kept).
    pub field_device: FieldDevice,
}

/// Where the photon grid builds its SH field ([`PhotonGridSettings::field_device`]).
#[derive(Reflect, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum FieldDevice {
    /// On hardware GPUs, measured at run time: the first field on the GPU, the second on the CPU, then
    /// on whichever built its last field faster per probe ray ([`PhotonGridActivity::field_timings`](super::PhotonGridActivity));
    /// one field built on the slower device is the cost of knowing. On software rasterisers the CPU,
    /// always: lavapipe shares the CPU's cores, and the CPU measured faster there (`cornell` 2.0–2.2 s
    /// against 2.4–3.0 s, `cellar` 0.4 s against 1.0–1.2 s; `docs/photon_grid.md`); a trial would also
    /// delay the frames queued behind its dispatches.
    #[default]
    Auto,
    /// The CPU's threads (rayon), in the background task. After a mesh moved, only the probe rays that
    /// ran near it are marched again (4 bytes a ray are kept for that).
    Cpu,
    /// The GPU, dispatched from the background task in chunks of about 2¹⁸ rays (the frame's own work
    /// runs between them), every ray each time. A device without the limits the pass needs (eight
    /// storage buffers per stage, 9 KiB of workgroup memory) builds on the CPU, with one warning.
    Gpu,
}

impl PhotonGridSettings {
    /// 16 cells, 65 536 photons, four reflections, 128 probe directions.
    pub const LOW: Self = Self {
        resolution: 16,
        photons: 65_536,
        max_reflections: 4,
        sh_directions: 128,
        filter_levels: 1,
        gather_samples: 0,
        r_max: 1.75,
        obscurance_distance: 0.0,
        intensity: 1.0,
        field_device: FieldDevice::Auto,
    };
    /// 32 cells, 262 144 photons, eight reflections, 256 probe directions (the default).
    pub const MEDIUM: Self = Self { resolution: 32, photons: 262_144, max_reflections: 8, sh_directions: 256, ..Self::LOW };
    /// 64 cells, 1 048 576 photons, sixteen reflections, 400 probe directions.
    pub const HIGH: Self = Self { resolution: 64, photons: 1_048_576, max_reflections: 16, sh_directions: 400, ..Self::LOW };
}

impl Default for PhotonGridSettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for PhotonGridSettings {
    const NAME: &'static str = "PhotonGridSettings";

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        c.uint(&mut s.resolution, 4, 96, "resolution");
        c.uint(&mut s.photons, 1024, 4_194_304, "photons");
        c.uint(&mut s.max_reflections, 1, 32, "max_reflections");
        c.uint(&mut s.sh_directions, 16, 2048, "sh_directions");
        c.uint(&mut s.filter_levels, 0, 5, "filter_levels");
        c.uint(&mut s.gather_samples, 0, 256, "gather_samples");
        c.float(&mut s.r_max, 1.0, 3.0, 1.75, "r_max");
        c.float(&mut s.obscurance_distance, 0.0, 1000.0, 0.0, "obscurance_distance");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
    }
}

impl PhotonGridSettings {
    /// The settings the preparation reads: the gather-only fields set to their defaults.
    pub(super) fn preparation(&self) -> Self {
        let d = Self::default();
        Self { gather_samples: d.gather_samples, r_max: d.r_max, obscurance_distance: d.obscurance_distance, intensity: d.intensity, ..self.clone() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        let presets = [PhotonGridSettings::LOW, PhotonGridSettings::MEDIUM, PhotonGridSettings::HIGH];
        for preset in &presets {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
        }
        assert!(presets.windows(2).all(|w| w[0].resolution < w[1].resolution
            && w[0].photons < w[1].photons
            && w[0].sh_directions < w[1].sh_directions));
        assert_eq!(PhotonGridSettings::default(), PhotonGridSettings::MEDIUM);
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = PhotonGridSettings { resolution: 0, photons: u32::MAX, r_max: f32::NAN, intensity: -1.0, ..default() };
        let (clean, bad) = s.sanitized();
        let names: Vec<_> = bad.iter().map(|b| b.0).collect();
        assert_eq!(names, ["resolution", "photons", "r_max", "intensity"]);
        assert_eq!((clean.resolution, clean.photons, clean.r_max, clean.intensity), (4, 4_194_304, 1.75, 0.0));
    }
}
