//! Hierarchical radiosity with implicit visibility (Dong, Kautz, Theobalt, Seidel, "Interactive Global
//! Illumination Using Implicit Visibility", Pacific Graphics 2007): multi-bounce diffuse light between
//! surface elements at mesh vertices, whose visibility comes from the link structure itself instead of
//! shadow maps or rays. It needs no reflective shadow map and no volume, so it also lights scenes whose
//! only light is an emissive mesh.
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! # fn setup(mut commands: Commands) {
//! commands.spawn((Camera3d::default(), DiffuseGi { method: GiMethod::Radiosity, ..default() }, RadiositySettings::MEDIUM));
//! commands.spawn((SpotLight { shadow_maps_enabled: true, ..default() }, GiLight::default()));
//! # }
//! ```
//!
//! # Algorithm (the paper's Algorithm 1, on the CPU with rayon: [`solver`])
//! The rendering equation (Eq. 1) is split over `N_bin` directional bins (Eq. 2); within a bin the
//! integral over surfaces (Eq. 3) becomes a sum over surface elements (Eq. 4), and under the last
//! assumption, that the closest element covers its bin, only the closest element counts (Eq. 5): the
//! bins of a cube map around each element keep the *shortest* link in their direction, which is the
//! implicit visibility.
//! 1. **Surface elements** (§4.1): every mesh of the [scene snapshot](crate::scene) is welded (vertices
//!    sharing a position and normal) and cut so that no triangle edge is longer than
//!    [`element_size`](RadiositySettings::element_size); each vertex is an oriented disc of ⅓ of the area
//!    of its triangles. Each connected smooth piece of a mesh is a *segment*, the coarsest level of the
//!    hierarchy (the paper uses UV charts; the snapshot keeps no charts, and these are what a chart
//!    layout would give for the usual meshes). A **quadtree** per segment splits its elements twice at
//!    the median of the widest axis into up to four children; nodes carry the area-weighted position,
//!    the mean normal and the total area, refitted bottom-up when elements move (§4.2.1).
//! 2. **Links** (§4.2.2) in `6 × N × N` world-aligned cube-map bins per node ([`bins`](RadiositySettings::bins)):
//!    all segments are linked pairwise (and each with itself), going down the hierarchy while a node's
//!    solid angle `A / r²` exceeds [`subdivision_threshold`](RadiositySettings::subdivision_threshold) ×
//!    the bin's solid angle, the larger node first, and each bin keeps its shortest link. Links are made
//!    from both ends with the same subdivisions, so they sit in a bin at one end and the opposite bin at
//!    the other.
//! 3. **Refine and push down** (§4.2.3–4.2.4): each leaf ends with, per bin, the shortest of its own and
//!    its ancestors' links.
//! 4. **Gather and pull up** (§4.3), bounce after bounce: each leaf sums `L_y cos θ Ω_bin` over its bins
//!    (Eq. 2 with Eq. 5; [`LinkTransfer`] also offers Eq. 5's element area as printed), from the nodes'
//!    outgoing radiance `L = L_e + ρ/π E`, pulled up area-weighted; the light a bounce adds decides when
//!    to stop ([`stop_threshold`](RadiositySettings::stop_threshold): the mean relative change of the
//!    lit elements, continued geometrically, so that a bright exterior does not end a dim room's
//!    bounces). Empty bins see the environment
//!    (§4.4): the GI camera's `EnvironmentMapLight` ([`SceneSnapshot::environment`], its specular map's
//!    radiance averaged over each world-aligned bin once per change) plus the constant
//!    [`sky`](RadiositySettings::sky). This is the environment's *direct* light on the elements, with
//!    the occlusion Bevy's own image-based lighting lacks (see [`occluded_environment`]).
//! 5. **Sources** (§4.4): emissive meshes are elements with `L_e > 0` (area lights); the GI lights
//!    ([`GiLight`](crate::light::GiLight), every kind) give each element its direct irradiance through a
//!    shadow ray against the snapshot's BVH (the one place rays are used: the paper's sources are
//!    geometry). The direct light itself is Bevy's; the frame shows what arrives over links.
//! 6. **Display**: each view draws the elements' triangles into the frame's indirect-light target with the
//!    gathered irradiance at their corners, keeping only fragments on the surface the depth prepass saw
//!    (`shaders/radiosity/display.wgsl`); the frame's filter, upsampling and composite do the rest.
//!
//! # Where this departs from the paper, and why
//! * **Where an element samples light**: at the centroid of its dual cell, not at the vertex, so that an
//!   element on a mesh border (where a floor meets a wall) does not look at the back of the wall.
//! * **Rasterised links**: a sender spanning several bins is stored in each bin it covers: a leaf in
//!   the bin of its centre and in every bin whose *centre ray* meets its dual cell (the quads of vertex,
//!   edge midpoints and centroid in its triangles), as a rasteriser samples pixel centres; a cluster in
//!   the bins of its children's centres. An ancestor's link is re-binned by its direction from the leaf
//!   during the push-down, and holes left between covered bins are filled from their neighbours. With one
//!   bin per link (the paper), 15 % of a closed box's bins stayed empty; with every bin a leaf's disc
//!   touched, each silhouette was half a bin too wide and a roof closed a quarter of the sky through its
//!   opening (the roof-opening unit test: −18 % against the form factor then, −4.7 % now).
//! * **Senders seen from behind still occlude** (one-sided culling only at the receiver), so single-sided
//!   walls stop light.
//! * **Bin solid angle** instead of the element's area in Eq. 5 (the paper's own last assumption), with
//!   the bins above a receiver's horizon normalised to π. Eq. 5 as printed loses all but the closest
//!   element of each bin.
//! * Analytic lights (point, spot, directional) are not geometry: their direct light reaches elements
//!   through shadow rays.
//!
//! # Cost
//! Nothing runs without an active camera using [`GiMethod::Radiosity`](crate::camera::GiMethod::Radiosity).
//! The solve never runs on the main thread: it is a task on the crate's background thread pool (its
//! rayon loops stay on that pool) over a copy of the scene snapshot ([`crate::background`]), started
//! when what it depends on changed since the last solve began, and only one at a time: changes made
//! while a solve runs are coalesced into the next. Until a solve finishes the previous solution is drawn; a new one
//! is blended in over [`BLEND_FRAMES`](crate::background::BLEND_FRAMES) frames, and the drawn elements
//! of an instance that moved since its solve follow its transform. Within a solve, each stage runs
//! only when its inputs changed: the elements are rebuilt when meshes are added, removed or re-meshed
//! (a skinned mesh's new pose) and moved by a transform when an instance moves (O(its elements), then
//! a bottom-up refit); links are rebuilt whenever any geometry changes; lighting alone (a light, the
//! sky, the bounces) redoes only the illumination; [`intensity`](RadiositySettings::intensity) only
//! rescales what is drawn. The main thread pays for polling the task, copying the snapshot when one
//! starts (O(instances)) and rewriting the drawn vertices while a solution blends in or an instance
//! moves (O(elements)): [`MainThreadCost::radiosity_ms`](crate::MainThreadCost). The GPU draws the
//! element triangles once per view (time span `diffuse_gi/radiosity_display`). [`RadiosityActivity`]
//! and the diagnostics `diffuse_gi/radiosity_{update_elements,links,refine_push,illumination}` report
//! the paper's Table 1 stages per solve (milliseconds of the background task).
//!
//! # Measured (`docs/radiosity.md`, 256², lavapipe for the display, two CPU cores for the solve)
//! Default preset (6 × 16 × 16 bins, 8 bounces), block relative RMSE / energy against the full
//! path-traced truth: `cornell` 0.159 / 1.09, `cellar` 0.27 / 0.81, `sponza_like` 0.20 / 0.98,
//! `dynamic` 0.058 / 1.00, `emissive_panel` 0.35 / 0.86, `open_field` 0.54 / 1.22, `sky_room` (an
//! environment map only) 0.37 / 0.68. Bins matter most: `cornell` at 8, 12, 16 bins is 0.49, 0.26,
//! 0.16 (the high preset: 0.13). Eq. 5 with the element's area loses more than half the light (0.74 /
//! 0.46). The meshes' own vertices as elements (the paper's) leak: `cellar`'s second room gets 2.1
//! times its light through the dividing wall (2.35 block RMSE), which cutting the meshes removes and the
//! subdivision threshold cannot (leaves do not subdivide).
//!
//! A still frame (the solution reused) costs 1.25 × the frame without GI at 256² and 1.29 × at 512² on
//! `cornell`, 1.4–1.6 × on `sponza_like`: the display pass draws every element triangle once per view.
//!
//! One full solve of `cornell` (5 352 elements) takes 0.6 s at 6 × 8 × 8 bins, 1.6 s at 12, 3.0 s at 16;
//! `sponza_like` (25 198 elements) 3.0, 6.9 and 13.4 s. Link creation is 70–91 % of it (the paper's
//! Table 1 has it at 21–38 %, with its illumination on the GPU); time per stage grows about linearly with
//! the elements (log-log slopes 0.87–0.98; refine & push 1.6). Why the CPU: the link creation is a
//! recursive, data-dependent descent of two hierarchies whose every step branches, which rayon runs per
//! receiving segment without atomics; a GPU port would need a work queue per pair and atomic minima
//! per bin, and the gather (1 % here) is not worth moving alone. (Not measured on a GPU: no GPU machine
//! was lent to this work.)
//!
//! # Known issues
//! * Elements are one-sided: the back of a single-sided surface (a plane seen from below) gets no light.
//! * A *cluster*'s silhouette still covers the bins it grazes (its children's centres are binned, not
//!   its shape): the rim of an opening seen from far away closes some of it, and `sky_room`'s floor
//!   gets about 70 % of the sky the truth gives it. Two facing squares exchange about 10 % too much.
//! * Links are rebuilt from scratch on any geometry change, O(N log N) in the elements of the whole
//!   scene and seconds for a room of 20 000 elements on two cores: the frame does not wait for them,
//!   but the light of a moving mesh lags by one solve (the paper's §4 update, keeping the links of
//!   elements that did not move, is not implemented yet).
//! * A small bright source (an emissive panel) covers few bins from most receivers: its light on the
//!   walls is blotchy, more so with fewer bins.
//! * Bevy lights every surface with an `EnvironmentMapLight`'s *diffuse* map itself, unoccluded; with
//!   radiosity reading the same light, the sky is counted twice. Give the camera a black diffuse map
//!   ([`occluded_environment`]) and keep the specular map for reflections and for radiosity.
//! * An environment map whose image has no CPU data (`RenderAssetUsages::RENDER_WORLD` only, as
//!   `EnvironmentMapLight::hemispherical_gradient` makes it) can only be read in the frame it is
//!   created; after that it is reported once and not used.

pub mod solver;
mod render;

use std::sync::Arc;

use bevy::camera::Exposure;
use bevy::diagnostic::{Diagnostic, DiagnosticPath, Diagnostics, RegisterDiagnostic};
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::extract_resource::{ExtractResource, ExtractResourcePlugin};
use bevy::render::render_resource::ShaderType;
use rayon::prelude::*;

pub use solver::{LinkTransfer, RadiositySolver, SolveParams, StageTimes};

use crate::background::{self, BackgroundJob, Blend};
use crate::camera::{DiffuseGi, GiMethod};
use crate::light::GiLight;
use crate::scene::{SceneSnapshot, SceneSnapshotSystems};
use crate::settings::{Clamped, GiSettings};
use solver::{Elements, PatchTriangle, RadiosityPatch};

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
    /// 12 KiB each, 0.5 GiB for `sponza_like`'s 25 000 elements; 24 bins 2.25 times that); the gather is
    /// linear in `N²`, link creation grows faster (`cornell`: 8 bins 0.37 s, 12 1.0 s, 16 2.2 s on two
    /// cores). A change: new links and lighting, in the background.
    pub bins: u32,
    /// Light bounces: 1 is light reflected once (the GI lights' and emitters' light gathered once); each
    /// more adds one more reflection. Range 1–16; default 8 (low 4, high 16): the second room of
    /// `cellar`, lit through a door, is 0.57 block RMSE with 4 and 0.27 with 8; `cornell` 0.145 and
    /// 0.159. Cost: one gather over all bins of all elements per bounce (a few percent of a solve), and
    /// only when the lighting changes. A change: new lighting only (no new links), in the background.
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

    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
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
        c.float(&mut s.intensity, 0.0, 1000.0, 1.0, "intensity");
        (s, c.fields)
    }
}

/// One vertex of the element mesh the frame draws (`RadiosityVertex` in
/// `shaders/radiosity/display.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct RadiosityVertex {
    /// World position (xyz), w = 1.
    pub position: Vec4,
    /// Gathered irradiance over π, `E/π` (rgb, before exposure, times the intensity); w unused.
    pub irradiance: Vec4,
}

/// The solution the frame draws: the element mesh with its light. Extracted to the render world.
#[derive(Resource, Clone, Debug, Default, ExtractResource)]
pub struct RadiosityOutput {
    /// Bumped whenever the vertices or triangles change.
    pub generation: u64,
    pub vertices: Arc<Vec<RadiosityVertex>>,
    /// Three vertex indices per triangle.
    pub indices: Arc<Vec<u32>>,
}

/// What the last radiosity solve did, for the panel, the tools and the tests.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct RadiosityActivity {
    /// Surface elements (vertices after subdivision) and hierarchy nodes.
    pub elements: usize,
    pub nodes: usize,
    /// The stages of the last solve, ms of the background task (the paper's Table 1 rows); zero for a
    /// stage that did not run.
    pub times: StageTimes,
    /// Solves finished so far (background tasks that recomputed anything).
    pub solves: u64,
    /// What the last finished solve redid.
    pub last: RadiosityWork,
    /// Whether the light shown is not yet the solution of the scene as it is now: a solve is running
    /// or due, or a new solution is still being blended in.
    pub busy: bool,
    /// Whether a result is drawn: false from the method's activation until its first background
    /// result arrives (the frame shows no bounced light from it until then).
    pub ready: bool,
    /// Frames since the last solve was started from the scene as it was then (0 while none ran).
    pub frames_since_start: u32,
}

/// How much of the solution a solve recomputed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RadiosityWork {
    /// Nothing changed.
    #[default]
    Reused,
    /// Only the lighting (lights, settings of the illumination).
    Illumination,
    /// Moved instances: elements moved and refitted, links and lighting rebuilt.
    Refit,
    /// New elements (meshes added, removed or re-meshed; element settings), links and lighting.
    Rebuild,
}

/// The solver and what it was built from: the state a background solve takes and hands back.
#[derive(Default)]
pub struct RadiosityCore {
    pub solver: RadiositySolver,
    /// Per snapshot instance: key, version and `world_from_local` the elements were made with, and their
    /// element range.
    instances: Vec<(u64, u64, Affine3A, std::ops::Range<usize>)>,
    /// Each instance's own elements by key, with the instance version they were made from: a rebuild
    /// re-makes only the instances whose version changed.
    cache: bevy::platform::collections::HashMap<u64, (u64, Arc<Elements>)>,
    /// What the elements were built from: layout generation, element size and exposure (bits; the
    /// emission of `emissive.alpha < 1` materials depends on it).
    elements_key: Option<(u64, u32, u32)>,
    /// What the links were built from: geometry generation, bins and subdivision threshold (bits).
    links_key: Option<(u64, u32, u32)>,
    /// What the lighting was computed from.
    lighting_key: Option<SolveKey>,
}

/// The main-world state: the solver (in a background task while one runs), the running solve and the
/// solution shown.
#[derive(Resource, Default)]
pub struct RadiosityState {
    /// `None` while a background solve holds it.
    core: Option<Box<RadiosityCore>>,
    job: BackgroundJob<SolveKey, Solution>,
    shown: Option<Shown>,
}

/// Everything a solve depends on: what the snapshot's generations say of the world, and the settings
/// that change the solution (not `intensity`, which only scales what is drawn).
#[derive(Clone, Debug, PartialEq)]
struct SolveKey {
    geometry: u64,
    lights: u64,
    gi_lights: Vec<Entity>,
    exposure: u32,
    environment: u64,
    settings: RadiositySettings,
}

/// What a background solve hands back.
struct Solution {
    core: Box<RadiosityCore>,
    work: RadiosityWork,
    times: StageTimes,
    /// Gathered irradiance per element, lux (empty when nothing was recomputed).
    gathered: Vec<Vec3>,
    /// The drawn element vertices, world space, as solved.
    vertices: Vec<Vec3>,
    indices: Arc<Vec<u32>>,
    /// Per instance: key, `world_from_local` as solved and element range, so that the drawn elements
    /// follow instances that move on while the next solve runs.
    instances: Vec<(u64, Affine3A, std::ops::Range<usize>)>,
}

/// The solution drawn, blending from the previous one.
struct Shown {
    from: Vec<Vec3>,
    to: Vec<Vec3>,
    blend: Blend,
    vertices: Vec<Vec3>,
    indices: Arc<Vec<u32>>,
    instances: Vec<(u64, Affine3A, std::ops::Range<usize>)>,
    /// The snapshot generation and intensity last drawn with.
    drawn: Option<(u64, u32)>,
}

pub use crate::scene::environment::occluded_environment;

/// Milliseconds of the solve's stages in the background task, in Bevy's diagnostics (a measurement per
/// solve).
pub const DIAGNOSTIC_UPDATE_ELEMENTS: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_update_elements");
pub const DIAGNOSTIC_LINKS: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_links");
pub const DIAGNOSTIC_REFINE_PUSH: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_refine_push");
pub const DIAGNOSTIC_ILLUMINATION: DiagnosticPath = DiagnosticPath::const_new("diffuse_gi/radiosity_illumination");

/// Implicit-visibility radiosity: settings validation, the CPU solve, the per-view display. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct RadiosityPlugin;

impl Plugin for RadiosityPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "radiosity/display.wgsl", include_str!("../../shaders/radiosity/display.wgsl"));
        for path in [DIAGNOSTIC_UPDATE_ELEMENTS, DIAGNOSTIC_LINKS, DIAGNOSTIC_REFINE_PUSH, DIAGNOSTIC_ILLUMINATION] {
            app.register_diagnostic(Diagnostic::new(path).with_suffix(" ms"));
        }
        app.register_type::<RadiositySettings>()
            .init_resource::<RadiosityState>()
            .init_resource::<RadiosityOutput>()
            .init_resource::<RadiosityActivity>()
            .add_plugins(ExtractResourcePlugin::<RadiosityOutput>::default())
            .add_systems(
                PostUpdate,
                (
                    crate::settings::validate_settings::<RadiositySettings>,
                    update_radiosity.after(SceneSnapshotSystems::Update),
                ),
            );
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(render::RadiosityShader(shader));
        }
    }

    fn finish(&self, app: &mut App) {
        use bevy::render::render_resource::DownlevelFlags;
        let supported = crate::gpu_supports(app, "Radiosity", |limits, flags| {
            missing_capabilities(limits, flags.contains(DownlevelFlags::VERTEX_STORAGE))
        });
        let Some(render_app) = app.get_sub_app_mut(RenderApp).filter(|_| supported) else {
            return;
        };
        render::add_render_systems(render_app);
    }
}

/// The GPU capabilities the display needs, as `(name, required, found)` for every shortfall: storage
/// buffers read by the vertex shader (the element mesh is pulled from two of them).
pub fn missing_capabilities(limits: &bevy::render::settings::WgpuLimits, vertex_storage: bool) -> Vec<crate::Shortfall> {
    let mut missing = Vec::new();
    if !vertex_storage {
        missing.push(("storage buffers in vertex shaders (DownlevelFlags::VERTEX_STORAGE)", 1, 0));
    }
    if limits.max_storage_buffers_per_shader_stage < 2 {
        missing.push(("max_storage_buffers_per_shader_stage", 2, limits.max_storage_buffers_per_shader_stage as u64));
    }
    missing
}

use bevy::math::Affine3A;

/// The elements of one snapshot instance: its triangles in world space with their colours at the
/// corners, welded and cut at `max_edge` metres.
fn instance_elements(snapshot: &SceneSnapshot, instance: &crate::scene::SnapshotInstance, exposure: f32, max_edge: f32) -> Elements {
    let material = snapshot.materials.get(instance.material as usize);
    let emission = material.map_or(Vec3::ZERO, |m| m.emission(exposure));
    let emission = if emission.is_finite() { emission.max(Vec3::ZERO) } else { Vec3::ZERO };
    let mirrored = instance.world_from_local().matrix3.determinant() < 0.0;
    let triangles = (0..instance.triangle_count())
        .map(|i| {
            let positions = instance.triangle(i);
            let attributes = instance.attributes(i);
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)];
            let mut albedo =
                corners.map(|(u, v)| material.map_or(Vec3::splat(0.5), |m| m.diffuse_at(&snapshot.textures, &attributes, u, v)));
            let mut normals = attributes.normals;
            // `triangle` swaps vertices 1 and 2 of a mirrored instance; its attributes keep the local
            // order.
            if mirrored {
                albedo.swap(1, 2);
                normals.swap(1, 2);
            }
            PatchTriangle { positions, normals, albedo, emission }
        })
        .collect();
    let mut elements = Elements::default();
    elements.add_patch(&RadiosityPatch { triangles }, max_edge);
    elements
}

/// Direct irradiance (lux) from the GI lights at each element, with a shadow ray each.
fn direct_irradiance(snapshot: &SceneSnapshot, elements: &Elements, gi_lights: &[Entity]) -> Vec<Vec3> {
    let epsilon = snapshot.ray_epsilon();
    let lights: Vec<_> = snapshot.lights.iter().filter(|l| gi_lights.contains(&l.entity)).map(|l| l.light).collect();
    (0..elements.len())
        .into_par_iter()
        .map(|e| {
            let (p, n) = (elements.positions[e], elements.normals[e]);
            let origin = p + n * epsilon;
            let mut sum = Vec3::ZERO;
            for light in &lights {
                let Some((l, distance, irradiance)) = light.incident(origin) else {
                    continue;
                };
                let cos = n.dot(l);
                if cos > 0.0 && !snapshot.occluded(origin, l, epsilon, distance - epsilon) {
                    sum += irradiance * cos;
                }
            }
            if sum.is_finite() { sum } else { Vec3::ZERO }
        })
        .collect()
}

/// Keeps the radiosity solution current for the first active radiosity camera, without waiting for it:
/// takes a finished background solve, starts the next when the scene or the settings changed since the
/// last one began, and draws the solution shown (blending a new one in, following moved instances).
#[expect(clippy::too_many_arguments, reason = "the solve reads the cameras, the lights and the snapshot")]
fn update_radiosity(
    mut commands: Commands,
    cameras: Query<(&Camera, &DiffuseGi, Option<&RadiositySettings>, Option<&Exposure>)>,
    gi_lights: Query<Entity, With<GiLight>>,
    snapshot: Option<Res<SceneSnapshot>>,
    mut state: ResMut<RadiosityState>,
    mut output: ResMut<RadiosityOutput>,
    mut activity: ResMut<RadiosityActivity>,
    mut cost: ResMut<crate::MainThreadCost>,
    mut diagnostics: Diagnostics,
) {
    cost.radiosity_ms = 0.0;
    let frame_start = std::time::Instant::now();
    let camera = cameras
        .iter()
        .find(|(camera, gi, _, _)| camera.is_active && gi.enabled && gi.method == GiMethod::Radiosity);
    let Some((_, _, settings, exposure)) = camera else {
        if state.shown.is_some() || state.job.is_running() || state.core.is_some() {
            state.job.reset();
            (state.core, state.shown) = (None, None);
            let generation = output.generation + 1;
            *output = RadiosityOutput { generation, ..default() };
            (activity.busy, activity.ready) = (false, false);
        }
        return;
    };
    let Some(snapshot) = snapshot else {
        commands.init_resource::<SceneSnapshot>();
        return;
    };
    let settings = settings.cloned().unwrap_or_default().sanitized().0;
    let exposure = exposure.copied().unwrap_or_default().exposure();
    let mut lights: Vec<Entity> = gi_lights.iter().collect();
    lights.sort();
    let key = SolveKey {
        geometry: snapshot.geometry_generation,
        lights: snapshot.light_generation,
        gi_lights: lights,
        exposure: exposure.to_bits(),
        environment: snapshot.environment_generation,
        settings: RadiositySettings { intensity: 1.0, ..settings.clone() },
    };
    let state = &mut *state;

    // 1. A finished solve: its solver comes back, its solution is blended in.
    if let Some((_, solution)) = state.job.poll() {
        let Solution { core, work, times, gathered, vertices, indices, instances } = solution;
        *activity = RadiosityActivity {
            elements: core.solver.elements.len(),
            nodes: core.solver.hierarchy.nodes.len(),
            times,
            solves: activity.solves + (work != RadiosityWork::Reused) as u64,
            last: work,
            ..activity.clone()
        };
        state.core = Some(core);
        background::record_stages(
            &mut diagnostics,
            &[
                (&DIAGNOSTIC_UPDATE_ELEMENTS, times.update_elements_ms),
                (&DIAGNOSTIC_LINKS, times.create_links_ms),
                (&DIAGNOSTIC_REFINE_PUSH, times.refine_push_ms),
                (&DIAGNOSTIC_ILLUMINATION, times.illumination_ms),
            ],
        );
        if work != RadiosityWork::Reused {
            // Blend from what is on screen when the elements are the same ones; otherwise show it whole.
            let from = state.shown.as_ref().filter(|s| s.to.len() == gathered.len()).map(|s| s.current());
            let blend = if from.is_some() { Blend::start() } else { Blend::DONE };
            let from = from.unwrap_or_else(|| gathered.clone());
            state.shown = Some(Shown { from, to: gathered, blend, vertices, indices, instances, drawn: None });
        }
    }

    // 2. The scene or the settings changed since the last solve began: start the next one.
    if state.job.wants(&key) {
        let mut core = state.core.take().unwrap_or_default();
        let snapshot = snapshot.clone();
        let solve_key = key.clone();
        state.job.start(key.clone(), move || {
            let (work, times, gathered) = solve(&mut core, &snapshot, &solve_key);
            let elements = &core.solver.elements;
            let vertices = elements.vertices.clone();
            let indices = Arc::new(elements.triangles.iter().flatten().copied().collect());
            let instances = core.instances.iter().map(|(key, _, transform, range)| (*key, *transform, range.clone())).collect();
            Solution { core, work, times, gathered, vertices, indices, instances }
        });
        activity.frames_since_start = 0;
    } else {
        activity.frames_since_start += 1;
    }

    // 3. Draw the shown solution when it, the intensity or an instance's transform changed.
    if let Some(shown) = &mut state.shown {
        let weight = shown.blend.advance();
        let drawn = Some((snapshot.geometry_generation, settings.intensity.to_bits()));
        if weight.is_some() || shown.drawn != drawn {
            shown.follow(&snapshot);
            shown.drawn = drawn;
            let scale = settings.intensity / std::f32::consts::PI;
            let vertices = shown
                .current()
                .into_iter()
                .zip(&shown.vertices)
                .map(|(irradiance, position)| RadiosityVertex {
                    position: position.extend(1.0),
                    irradiance: (irradiance * scale).extend(0.0),
                })
                .collect();
            let generation = output.generation + 1;
            *output = RadiosityOutput { generation, vertices: Arc::new(vertices), indices: shown.indices.clone() };
        }
    }
    activity.busy = state.job.is_running() || !state.job.is_current(&key) || state.shown.as_ref().is_some_and(|s| !s.blend.is_done());
    activity.ready = state.shown.is_some();
    cost.radiosity_ms = frame_start.elapsed().as_secs_f32() * 1e3;
}

impl Shown {
    /// The irradiance per element on screen now.
    fn current(&self) -> Vec<Vec3> {
        self.blend.mix(&self.from, &self.to, Vec3::lerp)
    }

    /// Moves the drawn elements of instances whose transform changed since they were solved, so that the
    /// light drawn on a moving mesh stays on it until the next solution arrives: O(the moved elements).
    fn follow(&mut self, snapshot: &SceneSnapshot) {
        for (key, solved, range) in &mut self.instances {
            let Some(instance) = snapshot.instance(*key) else {
                continue;
            };
            let now = instance.world_from_local();
            if now == *solved {
                continue;
            }
            let change = now * solved.inverse();
            if !change.is_finite() {
                continue;
            }
            for v in &mut self.vertices[range.clone()] {
                *v = change.transform_point3(*v);
            }
            *solved = now;
        }
    }
}

/// One solve, on a background task: elements, links and lighting, each only when what it depends on
/// changed since `core` last solved. Returns what it redid, the stage times and the gathered irradiance
/// per element (empty when nothing was redone).
fn solve(core: &mut RadiosityCore, snapshot: &SceneSnapshot, key: &SolveKey) -> (RadiosityWork, StageTimes, Vec<Vec3>) {
    let settings = &key.settings;
    let exposure = f32::from_bits(key.exposure);
    let params = settings.params();
    let diagonal = snapshot.bounds().map_or(1.0, |(lo, hi)| (hi - lo).length()).max(1e-6);
    let mut work = RadiosityWork::Reused;
    let mut times = StageTimes::default();

    // 1. Elements: rebuilt on a new layout or element size, moved with instances otherwise.
    let elements_key = Some((snapshot.layout_generation, settings.element_size.to_bits(), key.exposure));
    let moved = core.links_key.is_none_or(|k| k.0 != snapshot.geometry_generation);
    if core.elements_key != elements_key || (moved && !move_instances(core, snapshot)) {
        let start = std::time::Instant::now();
        // The cached elements were cut at another size or carry another exposure's emission.
        let made_as = (settings.element_size.to_bits(), key.exposure);
        if core.elements_key.is_none_or(|k| (k.1, k.2) != made_as) {
            core.cache.clear();
        }
        // Only the instances that changed are re-made (a deforming mesh costs its own elements).
        let max_edge = settings.element_size * diagonal;
        let cache = &core.cache;
        let per_instance: Vec<(u64, u64, Arc<Elements>)> = snapshot
            .instances()
            .par_iter()
            .map(|instance| {
                let reuse = cache.get(&instance.key).filter(|(version, _)| *version == instance.version);
                let elements = reuse.map_or_else(|| Arc::new(instance_elements(snapshot, instance, exposure, max_edge)), |(_, e)| e.clone());
                (instance.key, instance.version, elements)
            })
            .collect();
        let mut elements = Elements::default();
        core.instances.clear();
        core.cache.clear();
        for ((key, version, part), instance) in per_instance.into_iter().zip(snapshot.instances()) {
            let first = elements.len();
            elements.append(&part);
            core.instances.push((key, version, instance.world_from_local(), first..elements.len()));
            core.cache.insert(key, (version, part));
        }
        core.solver = RadiositySolver::new(elements);
        core.elements_key = elements_key;
        core.links_key = None;
        times.update_elements_ms = start.elapsed().as_secs_f32() * 1e3;
        work = RadiosityWork::Rebuild;
    } else if moved {
        let start = std::time::Instant::now();
        core.solver.hierarchy.refit(&core.solver.elements);
        times.update_elements_ms = start.elapsed().as_secs_f32() * 1e3;
        work = RadiosityWork::Refit;
    }

    // 2. Links, whenever any geometry changed.
    let links_key = Some((snapshot.geometry_generation, settings.bins, settings.subdivision_threshold.to_bits()));
    if core.links_key != links_key {
        core.solver.create_links(&params);
        core.solver.refine_and_push();
        times.create_links_ms = core.solver.times.create_links_ms;
        times.refine_push_ms = core.solver.times.refine_push_ms;
        times.links = core.solver.times.links;
        core.links_key = links_key;
        core.lighting_key = None;
        if work == RadiosityWork::Reused {
            work = RadiosityWork::Refit;
        }
    }

    // 3. Lighting.
    if core.lighting_key.as_ref() == Some(key) {
        return (work, times, Vec::new());
    }
    let start = std::time::Instant::now();
    core.solver.environment = match (snapshot.environment.as_deref(), core.solver.bins.as_ref()) {
        // The camera's environment map (plus the constant sky), averaged over each world-aligned bin
        // with about two samples per environment texel across a bin.
        (Some(environment), Some(bins)) => {
            let samples = (2 * environment.face_size()).div_ceil(bins.n).clamp(2, 16);
            bins.average(samples, |d| environment.radiance(d) + settings.sky)
        }
        _ => Vec::new(),
    };
    let direct = direct_irradiance(snapshot, &core.solver.elements, &key.gi_lights);
    core.solver.illuminate(&direct, &params);
    times.illumination_ms = start.elapsed().as_secs_f32() * 1e3;
    times.bounces_run = core.solver.times.bounces_run;
    core.lighting_key = Some(key.clone());
    if work == RadiosityWork::Reused {
        work = RadiosityWork::Illumination;
    }
    (work, times, core.solver.gathered.clone())
}

/// Moves the elements of instances whose transform changed (same instances, same meshes) by the
/// change of their transform. Returns `false` when the snapshot's instances are not those the elements
/// were made from (then everything is rebuilt).
fn move_instances(core: &mut RadiosityCore, snapshot: &SceneSnapshot) -> bool {
    let instances = snapshot.instances();
    if instances.len() != core.instances.len() {
        return false;
    }
    let elements = &mut core.solver.elements;
    for (instance, (key, version, transform, range)) in instances.iter().zip(core.instances.iter_mut()) {
        if instance.key != *key {
            return false;
        }
        if instance.version == *version {
            continue;
        }
        let now = instance.world_from_local();
        let change = now * transform.inverse();
        // A new version in place without a move is a new material or texture: rebuild.
        if !change.is_finite() || now == *transform {
            return false;
        }
        let normal_matrix = Mat3::from(change.matrix3).inverse().transpose();
        for e in range.clone() {
            elements.positions[e] = change.transform_point3(elements.positions[e]);
            elements.vertices[e] = change.transform_point3(elements.vertices[e]);
            elements.normals[e] = (normal_matrix * elements.normals[e]).normalize_or(elements.normals[e]);
        }
        (*version, *transform) = (instance.version, now);
    }
    true
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

    #[test]
    fn a_device_with_webgpu_default_limits_runs_radiosity_and_one_without_vertex_storage_does_not() {
        use bevy::render::settings::WgpuLimits;
        assert!(missing_capabilities(&WgpuLimits::default(), true).is_empty());
        let names: Vec<_> = missing_capabilities(&WgpuLimits::downlevel_webgl2_defaults(), false).iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("VERTEX_STORAGE")), "{names:?}");
    }
}
