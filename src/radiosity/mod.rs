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
//!    **When meshes move** (§4: "we only need to update the links of elements that moved"): the links
//!    among the segments that stand still are kept, and each solve links only the moving segments with
//!    everything and the still segments with the moving ones, merging those links into the kept ones
//!    bin by bin ([`RadiositySolver::relink`]); the result is the links made from scratch (each bin
//!    keeps the shortest link whatever order it is found in), at O(moving × scene) instead of
//!    O(scene²). The kept links are made once, when a segment starts moving, from the links of the
//!    still scene, which the solver keeps sparse for that (only the filled bins, [`FullLinks`](solver::FullLinks)):
//!    a bin keeps its link unless it leads into the segment that starts moving, and only those bins
//!    are linked again, skipping every node pair whose directions cannot reach one of them (per node,
//!    a cone around the bins it and its descendants must fill, one per moving segment they saw). The result is again the links made from scratch
//!    (a unit test compares every bin); in `dynamic` the first move relinks 37 000 bins in 0.5 s instead
//!    of making 6.6 million in 6.5 s.
//! 3. **Refine and push down** (§4.2.3–4.2.4): each leaf ends with, per bin, the shortest of its own and
//!    its ancestors' links. After a move only the leaves below a node whose links changed are pushed
//!    down again.
//! 4. **Gather and pull up** (§4.3), bounce after bounce: each leaf sums `L_y cos θ Ω_bin` over its bins
//!    (Eq. 2 with Eq. 5; [`LinkTransfer`] also offers Eq. 5's element area as printed), from the nodes'
//!    outgoing radiance `L = L_e + ρ/π E`, pulled up area-weighted (the bins of one sender are summed
//!    into one weight before the first bounce, so a bounce is a short weighted sum per leaf); the light
//!    a bounce adds decides when
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
//!   during the push-down, and holes left between covered bins are filled from their neighbours (the
//!   filled bins are remembered, so that a later push-down can update the rest in part). With one
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
//! a bottom-up refit); the links of the moved segments are redone and merged into the kept links of the
//! still ones (made from scratch on new elements, bins or threshold, and once when a segment starts
//! moving); lighting alone (a light, the sky, the bounces) redoes only the illumination;
//! [`intensity`](RadiositySettings::intensity) only rescales what is drawn. The main thread pays for polling the task, copying the snapshot when one
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
//! * The light of a moving mesh lags by one solve. In `dynamic` (18 700 elements, one sphere moving)
//!   a solve takes about 1.1 s on two cores shared with lavapipe (links 0.3, push-down 0.5,
//!   illumination 0.2 s; 5 000 of the leaves pushed down again), and the light catches up 15–18 frames
//!   after the sphere stops (`docs/dynamic.md`). The first solve after a segment starts moving derives
//!   the kept links from the still scene's: 2.2 s there (links 1.3 s, of which 0.5 s relinking the
//!   37 000 bins that saw the sphere; push-down 0.6 s) instead of the 8 s of a full solve. With ten
//!   meshes starting at once, 231 000 bins to relink: links 3.5–3.8 s, half a full solve (the cost per
//!   relinked bin is that of one mesh: the pairs left to visit grow with the bins to fill). When the
//!   meshes moved on while those links were made (the main thread marks the running solve superseded,
//!   [`crate::background::Superseded`]), that solve stops right after the kept links, before linking
//!   the moving meshes at poses already stale ([`RadiositySolver::relink_unless`];
//!   `RadiosityWork::Superseded`: no push-down, no light, at most once in a row) and the next, from the
//!   newest poses, reuses them: after a move of 10 frames the light catches up in 19–22 frames with ten
//!   meshes (three runs at 256²; 26–35 in seven runs when the stale poses were still linked, 45–55
//!   before the solve stopped at all).
//! * The push-down re-bins, for each leaf, every sender its ancestors link (once per sender since
//!   12a076e): small meshes beside large elements (50 000 triangles of small spheres on `dynamic`'s
//!   floor) make that the larger part of a solve, 15 s of 24 from scratch. After a move a leaf below a
//!   changed node is updated in part when every change above it is known bin by bin (the still nodes'
//!   bins that a moving sender took or gave back, the bins a first move linked again): each bin keeps
//!   its link unless its sender moved or left, only those bins are rasterised again (from the senders
//!   whose direction can reach them), and only the senders that moved or came are rasterised into
//!   every bin; the links are the full push-down's bit for bit (the relink unit tests compare every
//!   step). In that 42 k scene the last push-down after a 48-frame move redoes 13 000 leaves, 12 400
//!   of them in part, in 1.2–1.7 s (4.1–5.5 s before), and the light catches up 14–23 frames after
//!   the move (ten single runs; 33–67 before).
//! * While nothing moves, the still scene's links are kept sparse for the first move (about 10 bytes per
//!   filled bin: 63 MiB in `dynamic`, where the leaves' links take 219 MiB); while meshes move, the kept
//!   and the merged links together take twice the node links' memory
//!   ([`bins`](RadiositySettings::bins)). Links are dense (`6N²` bins per node and element, 12 KiB at
//!   the default): a scene whose links would pass
//!   [`max_link_memory_mib`](RadiositySettings::max_link_memory_mib) is not solved (one warning), so a
//!   level of hundreds of thousands of small triangles needs coarser elements or fewer bins.
//! * A small bright source (an emissive panel) covers few bins from most receivers: its light on the
//!   walls is blotchy, more so with fewer bins.
//! * Bevy lights every surface with an `EnvironmentMapLight`'s *diffuse* map itself, unoccluded; with
//!   radiosity reading the same light, the sky is counted twice. Give the camera a black diffuse map
//!   ([`occluded_environment`]) and keep the specular map for reflections and for radiosity.
//! * An environment map whose image has no CPU data (`RenderAssetUsages::RENDER_WORLD` only, as
//!   `EnvironmentMapLight::hemispherical_gradient` makes it) can only be read in the frame it is
//!   created; after that it is reported once and not used.

mod extract;
mod prepare;
mod render;
mod settings;
pub mod solver;

use bevy::app::SubApp;
use bevy::prelude::*;

pub use extract::{
    DIAGNOSTIC_ILLUMINATION, DIAGNOSTIC_LINKS, DIAGNOSTIC_REFINE_PUSH, DIAGNOSTIC_UPDATE_ELEMENTS, RadiosityActivity, RadiosityCore,
    RadiosityOutput, RadiosityState, RadiosityWork,
};
pub use prepare::RadiosityVertex;
pub use settings::RadiositySettings;
pub use solver::{LinkTransfer, RadiositySolver, SolveParams, StageTimes};
pub use crate::scene::environment::occluded_environment;

use crate::camera::GiMethod;
use crate::method::{GiMethodModule, GpuCapabilities, Shortfall};

/// Implicit-visibility radiosity: settings validation, the CPU solve, the per-view display. Added by
/// [`crate::DiffuseGiPlugin`].
pub struct RadiosityPlugin;

impl Plugin for RadiosityPlugin {
    fn build(&self, app: &mut App) {
        let display = crate::add_shader(app, "radiosity/display.wgsl", include_str!("../../shaders/radiosity/display.wgsl"));
        crate::method::build_method::<Self>(app);
        crate::background::add_cpu_method::<RadiosityState, RadiosityOutput, RadiosityActivity, _>(
            app,
            &[DIAGNOSTIC_UPDATE_ELEMENTS, DIAGNOSTIC_LINKS, DIAGNOSTIC_REFINE_PUSH, DIAGNOSTIC_ILLUMINATION],
            extract::update_radiosity,
        );
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(prepare::RadiosityShaders { display });
        }
    }

    fn finish(&self, app: &mut App) {
        crate::method::finish_method::<Self>(app);
    }
}

impl GiMethodModule for RadiosityPlugin {
    const METHOD: GiMethod = GiMethod::Radiosity;
    const NAME: &'static str = "Radiosity";
    type Settings = RadiositySettings;

    /// Storage buffers read by the vertex shader (the element mesh is pulled from two of them).
    fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        use bevy::render::render_resource::DownlevelFlags;
        gpu.require()
            .feature("storage buffers in vertex shaders (DownlevelFlags::VERTEX_STORAGE)", DownlevelFlags::VERTEX_STORAGE)
            .storage_buffers(2)
            .missing()
    }

    fn add_render_systems(render_app: &mut SubApp) {
        render::add_render_systems(render_app);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_with_webgpu_default_limits_runs_radiosity_and_one_without_vertex_storage_does_not() {
        assert!(RadiosityPlugin::missing_capabilities(&GpuCapabilities::desktop()).is_empty());
        let names: Vec<_> = RadiosityPlugin::missing_capabilities(&GpuCapabilities::webgl2()).iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("VERTEX_STORAGE")), "{names:?}");
    }
}
