//! Radiosity's settings component: `LOW`/`MEDIUM`/`HIGH`, the solver's parameters and their
//! validation.

use bevy::prelude::*;

use super::solver::{LinkTransfer, SolveParams};
use crate::settings::{Clamped, GiSettings};

/// The settings of implicit-visibility radiosity, on a camera with
/// [`DiffuseGi`](crate::camera::DiffuseGi) `{ method: GiMethod::Radiosity, .. }`. A camera without it
/// uses [`RadiositySettings::default`] (the medium preset). The solution is the scene's, not the view's:
/// with several radiosity cameras, the first active one's settings apply. Invalid values are clamped to
/// their range with one warning.
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component, Default, Clone)]
pub struct RadiositySettings {
    /// Bins along each side of each face of an element's cube map (`6 N²` bins). Range 2–24; low 12,
    /// medium 16 (the default), high 20. On `cornell` (default elements) 8 bins give 0.41 block RMSE,
    /// 12 (the paper's compromise) 0.22, 16 0.16, 20 0.11: a bin that a surface only partly covers counts
    /// as covered, so fine bins matter more than fine elements. Cost: memory of `6 N² × 8` bytes per
    /// element for the leaves' links plus as much per hierarchy node while links are made (16 bins:
    /// 12 KiB each, 0.5 GiB for `sponza_like`'s 25 000 elements; 24 bins 2.25 times that), and while
    /// meshes move twice as much per node again (the links kept among the still segments and the merged
    /// ones, [`RadiositySolver::relink`](super::RadiositySolver::relink)); while nothing moves, the node
    /// links' filled bins are kept for the first move (about 10 bytes each, 63 MiB in `dynamic`'s
    /// 18 700 elements); the gather is linear in `N²`,
    /// link creation grows faster (`cornell`: 8 bins 0.37 s, 12 1.0 s, 16 2.2 s on two cores). A change:
    /// new links and lighting, in the background.
    pub bins: u32,
    /// Light bounces: 1 is light reflected once (the GI lights' and emitters' light gathered once); each
    /// more adds one more reflection. Range 1–16; default 8 (low 4, high 16): the second room of
    /// `cellar`, lit through a door, is 0.57 block RMSE with 4 and 0.27 with 8; `cornell` 0.145 and
    /// 0.159. Cost: per bounce one weighted sum over each element's linked senders (`dynamic`'s 18 700
    /// elements: about 25 ms a bounce on two cores), and only when the lighting or the links change.
    /// A change: new lighting only (no new links), in the background.
    pub bounces: u32,
    /// Stop bouncing when the bounces still to come would add less than this fraction of the light
    /// (each lit element's relative change in the last bounce, averaged, and continued geometrically by
    /// the ratio of the last two bounces). Range 0–1; default 0.01. Cost: none; it saves bounces. A
    /// change: new lighting only, in the background.
    pub stop_threshold: f32,
    /// A node is subdivided when its solid angle exceeds this many bin solid angles (§4.2.2). Range
    /// 0.05–8; default 1 (the paper's rule). Lower: finer links, fewer light leaks, more links. Cost:
    /// link creation grows roughly with its inverse. A change: new links and lighting, in the background.
    pub subdivision_threshold: f32,
    /// Longest triangle edge of the element mesh as a fraction of the scene's bounding-box diagonal;
    /// longer triangles are cut (0 keeps the meshes' own vertices, the paper's choice, which leaks light
    /// on coarse meshes: its Fig. 10d). Range 0–0.5; default 1/32 (low 1/20, high 1/32). Finer elements
    /// need finer bins: on `cornell` with 16 bins, 1/48 is worse than 1/32 (0.21 against 0.16). Cost:
    /// the element count grows with the inverse square; everything else with the element count. A
    /// change: new elements, links and lighting (a full solve), in the background.
    pub element_size: f32,
    /// How a link's sender contributes. Default [`LinkTransfer::BinSolidAngle`] (`ElementArea`, Eq. 5
    /// as printed, loses half of `cornell`'s light). No difference in cost worth measuring. A change:
    /// new lighting only, in the background.
    pub transfer: LinkTransfer,
    /// Radiance of a constant sky seen through empty bins, linear RGB in cd/m² (before exposure), added
    /// to the camera's `EnvironmentMapLight` where it has one. Default black (no sky). Each component
    /// 0–10⁶. Cost: none (empty bins are visited anyway). A change: new lighting only, in the background.
    pub sky: Vec3,
    /// The most memory the links may take, MiB: `6 N² × 8` bytes per hierarchy node and per element
    /// (twice per node while meshes move). A scene whose elements need more is not solved (one warning
    /// says how much it needs; raise [`element_size`](Self::element_size), lower [`bins`](Self::bins) or
    /// raise this), and when the links kept while meshes move would not fit, none are kept (every solve
    /// a full one), nor the still scene's links for the first move. Range 16–1 048 576; default 4096 (16 bins, about 1.55 nodes per element: 130 000
    /// elements, 80 000 with kept links). Cost: none. A change: a new solve.
    pub max_link_memory_mib: u32,
    /// Multiplies the indirect light. Range 0–1000; default 1. Cost: none; a change runs no solve, it
    /// rescales the drawn light in the same frame.
    pub intensity: f32,
}

impl RadiositySettings {
    /// 6 × 12 × 12 bins (the paper's compromise), four bounces, elements of 1/20 of the scene.
    pub const LOW: Self = Self {
        bins: 12,
        bounces: 4,
        stop_threshold: 0.01,
        subdivision_threshold: 1.0,
        element_size: 1.0 / 20.0,
        transfer: LinkTransfer::BinSolidAngle,
        sky: Vec3::ZERO,
        max_link_memory_mib: 4096,
        intensity: 1.0,
    };
    /// 6 × 16 × 16 bins, eight bounces, elements of 1/32 of the scene (the default).
    pub const MEDIUM: Self = Self { bins: 16, bounces: 8, element_size: 1.0 / 32.0, ..Self::LOW };
    /// 6 × 20 × 20 bins, sixteen bounces, elements of 1/32 of the scene.
    pub const HIGH: Self = Self { bins: 20, bounces: 16, ..Self::MEDIUM };

    /// The solver's parameters.
    pub fn params(&self) -> SolveParams {
        SolveParams {
            bins: self.bins,
            bounces: self.bounces,
            stop_threshold: self.stop_threshold,
            subdivision_threshold: self.subdivision_threshold,
            transfer: self.transfer,
            environment: self.sky,
        }
    }
}

impl Default for RadiositySettings {
    fn default() -> Self {
        Self::MEDIUM
    }
}

impl GiSettings for RadiositySettings {
    const NAME: &'static str = "RadiositySettings";

    fn clamp(&mut self, c: &mut Clamped) {
        let s = self;
        c.uint(&mut s.bins, 2, 24, "bins");
        c.uint(&mut s.bounces, 1, 16, "bounces");
        c.float(&mut s.stop_threshold, 0.0, 1.0, 0.01, "stop_threshold");
        c.float(&mut s.subdivision_threshold, 0.05, 8.0, 1.0, "subdivision_threshold");
        c.float(&mut s.element_size, 0.0, 0.5, Self::MEDIUM.element_size, "element_size");
        let (mut r, mut g, mut b) = (s.sky.x, s.sky.y, s.sky.z);
        for v in [&mut r, &mut g, &mut b] {
            c.float(v, 0.0, 1e6, 0.0, "sky");
        }
        s.sky = Vec3::new(r, g, b);
        c.uint(&mut s.max_link_memory_mib, 16, 1 << 20, "max_link_memory_mib");
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_grow_in_cost() {
        let presets = [RadiositySettings::LOW, RadiositySettings::MEDIUM, RadiositySettings::HIGH];
        for preset in &presets {
            assert!(preset.sanitized().1.is_empty(), "{preset:?}");
        }
        // Bins per element and elements both grow (or stay) from low to high, bounces too.
        assert!(presets.windows(2).all(|w| w[0].bins < w[1].bins && w[0].element_size >= w[1].element_size && w[0].bounces < w[1].bounces));
        assert_eq!(RadiositySettings::default(), RadiositySettings::MEDIUM);
        assert_eq!(RadiositySettings::MEDIUM.bins, 16);
    }

    #[test]
    fn invalid_settings_are_clamped_and_named() {
        let s = RadiositySettings {
            bins: 0,
            bounces: 100,
            stop_threshold: f32::NAN,
            element_size: -1.0,
            sky: Vec3::new(f32::INFINITY, 1.0, -2.0),
            ..default()
        };
        let (clean, bad) = s.sanitized();
        let names: Vec<_> = bad.iter().map(|b| b.0).collect();
        assert_eq!(names, ["bins", "bounces", "stop_threshold", "element_size", "sky", "sky"]);
        assert_eq!((clean.bins, clean.bounces, clean.stop_threshold, clean.element_size), (2, 16, 0.01, 0.0));
        assert_eq!(clean.sky, Vec3::new(0.0, 1.0, 0.0));
        // A negative intensity is clamped to 0 (no light; the GPU test of absurd settings checks the light).
        assert_eq!(RadiositySettings { intensity: -1.0, ..default() }.sanitized().0.intensity, 0.0);
    }
}
