//! The live tuning panel (feature `egui`): every GI camera, volume and light, with the per-pass GPU times.
//!
//! ```no_run
//! # use bevy::prelude::*;
//! # use bevy_diffuse_gi::prelude::*;
//! App::new().add_plugins((DefaultPlugins, DiffuseGiPlugin::default(), DiffuseGiInspectorPlugin));
//! ```
//! Adds `bevy_egui`'s `EguiPlugin` unless the app already has it. The panel draws on egui's primary
//! context (by default the first camera spawned). F1 hides and shows it; the [`DiffuseGiInspector`]
//! resource sets the key (or none) and whether it starts visible. A game that wants no panel leaves the
//! plugin out (the `egui` feature is optional).

use bevy::diagnostic::DiagnosticsStore;
use bevy::prelude::*;
use bevy_egui::{EguiContexts, EguiPlugin, EguiPrimaryContextPass, egui};

use crate::camera::{DiffuseGi, GiDebugView, GiMethod, GiOutput};
use crate::drm::{DrmSettings, DrmSolidAngle};
use crate::radiosity::{LinkTransfer, RadiosityActivity, RadiositySettings};
use crate::photon_grid::{PhotonGridActivity, PhotonGridSettings};
use crate::rsm_gather::{RsmGatherSettings, RsmSampleWeights};
use crate::vpl::VplSettings;
use crate::light::GiLight;
use crate::radiance_hints::{DepthOcclusion, GridSizing, IrradianceReconstruction, RadianceHintsActivity, RadianceHintsVolume, RhVolumeActivity};
use crate::sh::ShOrder;

/// Adds the "Diffuse GI" window.
pub struct DiffuseGiInspectorPlugin;

impl Plugin for DiffuseGiInspectorPlugin {
    fn build(&self, app: &mut App) {
        if !app.is_plugin_added::<EguiPlugin>() {
            app.add_plugins(EguiPlugin::default());
        }
        // The "GPU passes" section reads the per-pass time spans this plugin records.
        if !app.is_plugin_added::<bevy::render::diagnostic::RenderDiagnosticsPlugin>() {
            app.add_plugins(bevy::render::diagnostic::RenderDiagnosticsPlugin);
        }
        app.init_resource::<DiffuseGiInspector>()
            .add_systems(Update, toggle_inspector)
            .add_systems(EguiPrimaryContextPass, inspector_ui.run_if(|i: Res<DiffuseGiInspector>| i.visible));
    }
}

/// Whether the "Diffuse GI" window shows, and the key that toggles it.
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct DiffuseGiInspector {
    /// The window shows. Default `true`.
    pub visible: bool,
    /// The key that hides and shows it; `None`: no key. Default F1.
    pub toggle_key: Option<KeyCode>,
}

impl Default for DiffuseGiInspector {
    fn default() -> Self {
        Self { visible: true, toggle_key: Some(KeyCode::F1) }
    }
}

fn toggle_inspector(keys: Option<Res<ButtonInput<KeyCode>>>, mut inspector: ResMut<DiffuseGiInspector>) {
    if let (Some(keys), Some(key)) = (keys, inspector.toggle_key)
        && keys.just_pressed(key)
    {
        inspector.visible = !inspector.visible;
    }
}

/// One line on what a volume did in the last frame: updating (and why) or reusing its field, and the
/// bounces its last full update ran.
pub fn activity_line(activity: Option<&RhVolumeActivity>) -> String {
    let Some(a) = activity else {
        return "inactive: no camera uses Radiance Hints".into();
    };
    let state = match (a.updating, a.amortised) {
        (true, true) => "updating every frame (moving inputs: one bounce a frame)".to_string(),
        (true, false) => format!("updating ({} update{} to converge)", a.updates_left, if a.updates_left == 1 { "" } else { "s" }),
        (false, _) => format!("reused for {} frame{}", a.frames_reused, if a.frames_reused == 1 { "" } else { "s" }),
    };
    let bounces = match a.extra_bounces_run {
        Some(k) => format!("bounces run: 1 + {k} extra of {}", a.extra_bounces_max),
        None if a.extra_bounces_max == 0 => "bounces run: 1 (no extra bounces)".to_string(),
        None => format!("bounces run: not read back yet (up to 1 + {})", a.extra_bounces_max),
    };
    format!("{}×{}×{} hints; {state}; {bounces}", a.resolution.x, a.resolution.y, a.resolution.z)
}

#[expect(clippy::too_many_arguments, reason = "the panel reads every component and resource it shows")]
fn inspector_ui(
    mut contexts: EguiContexts,
    mut commands: Commands,
    mut cameras: Query<(
        Entity,
        Option<&Name>,
        &mut DiffuseGi,
        Option<&mut VplSettings>,
        Option<&mut RsmGatherSettings>,
        Option<&mut DrmSettings>,
        Option<&mut RadiositySettings>,
        Option<&mut PhotonGridSettings>,
    )>,
    mut volumes: Query<(Entity, Option<&Name>, &mut RadianceHintsVolume, &GlobalTransform, Option<&crate::radiance_hints::RhMeanChord>)>,
    mut lights: Query<(Entity, Option<&Name>, &mut GiLight)>,
    diagnostics: Option<Res<DiagnosticsStore>>,
    warnings: Option<Res<crate::DiffuseGiWarnings>>,
    timing: Option<Res<crate::GiDeviceTiming>>,
    activity: Option<Res<RadianceHintsActivity>>,
    pipeline_errors: Option<Res<crate::GiPipelineErrors>>,
    radiosity: Option<Res<RadiosityActivity>>,
    photon_grid: Option<Res<PhotonGridActivity>>,
    status: Option<Res<crate::method::GiMethodStatus>>,
    vpl_set: Option<Res<crate::vpl::VplSet>>,
) -> Result {
    let label = |entity: Entity, name: Option<&Name>| name.map_or_else(|| format!("{entity}"), |n| n.to_string());
    let ctx = contexts.ctx_mut()?;
    // At the right edge, scrolling within the window's height, so that the view stays visible.
    let screen = ctx.content_rect();
    egui::Window::new("Diffuse GI")
        .default_width(330.0)
        .pivot(egui::Align2::RIGHT_TOP)
        .default_pos([screen.right() - 8.0, screen.top() + 8.0])
        .max_height((screen.height() - 16.0).max(100.0))
        .vscroll(true)
        .show(ctx, |ui| {
        egui::CollapsingHeader::new("Cameras").default_open(true).show(ui, |ui| {
            for (entity, name, mut gi, vpl, rsm_gather, drm, radiosity_settings, photon_settings) in &mut cameras {
                ui.label(label(entity, name));
                let mut g = gi.clone();
                ui.checkbox(&mut g.enabled, "bounced light (G)");
                egui::ComboBox::from_label("method (M)")
                    .selected_text(format!("{:?}", g.method))
                    .show_ui(ui, |ui| {
                        for method in GiMethod::ALL {
                            ui.selectable_value(&mut g.method, method, format!("{method:?}"));
                        }
                    });
                egui::ComboBox::from_label("debug view (V)")
                    .selected_text(format!("{:?}", g.debug_view))
                    .show_ui(ui, |ui| {
                        for view in GiDebugView::ALL {
                            ui.selectable_value(&mut g.debug_view, view, format!("{view:?}"));
                        }
                    });
                egui::ComboBox::from_label("output")
                    .selected_text(format!("{:?}", g.output))
                    .show_ui(ui, |ui| {
                        ui.selectable_value(&mut g.output, GiOutput::Composite, "Composite (per pixel)");
                        ui.selectable_value(&mut g.output, GiOutput::IrradianceVolume, "IrradianceVolume (Radiance Hints only)");
                    });
                ui.checkbox(&mut g.half_resolution, "half resolution (every method)");
                commit(g, &mut gi);
                if gi.enabled {
                    ui.label(status_line(status.as_ref().and_then(|s| s.get(gi.method))));
                }
                if gi.method.gathers_rsm_per_pixel() && lights.is_empty() {
                    ui.colored_label(
                        egui::Color32::YELLOW,
                        "no GiLight: this method bounces only GiLights' light (not emissive surfaces)",
                    );
                }
                match gi.method {
                    GiMethod::Vpl => {
                        method_settings(ui, &mut commands, entity, vpl, "tune VPL settings (adds VplSettings::MEDIUM)", VplSettings::MEDIUM, vpl_ui);
                        if let Some(set) = &vpl_set {
                            ui.label(vpl_set_line(set));
                        }
                    }
                    GiMethod::RsmGather => {
                        method_settings(ui, &mut commands, entity, rsm_gather, "tune RSM gather settings (adds RsmGatherSettings::MEDIUM)", RsmGatherSettings::MEDIUM, rsm_gather_ui);
                    }
                    GiMethod::Drm => {
                        method_settings(ui, &mut commands, entity, drm, "tune DRM settings (adds DrmSettings::MEDIUM)", DrmSettings::MEDIUM, drm_ui);
                    }
                    GiMethod::Radiosity => {
                        method_settings(ui, &mut commands, entity, radiosity_settings, "tune radiosity settings (adds RadiositySettings::MEDIUM)", RadiositySettings::MEDIUM, radiosity_ui);
                        if let Some(activity) = radiosity.as_deref() {
                            radiosity_activity_ui(ui, activity);
                        }
                    }
                    GiMethod::PhotonGrid => {
                        method_settings(ui, &mut commands, entity, photon_settings, "tune photon grid settings (adds PhotonGridSettings::MEDIUM)", PhotonGridSettings::MEDIUM, photon_grid_ui);
                        if let Some(activity) = photon_grid.as_deref() {
                            photon_grid_activity_ui(ui, activity);
                        }
                    }
                    GiMethod::RadianceHints => {}
                }
                ui.separator();
            }
        });
        egui::CollapsingHeader::new("Radiance Hints volumes").default_open(true).show(ui, |ui| {
            for (entity, name, mut volume, transform, chord) in &mut volumes {
                let now = activity.as_ref().and_then(|a| a.get(entity));
                ui.label(activity_line(now.as_ref()));
                ui.push_id(entity, |ui| volume_ui(ui, &label(entity, name), &mut volume, transform, chord.and_then(|c| c.metres)));
                ui.separator();
            }
        });
        egui::CollapsingHeader::new("GI lights").show(ui, |ui| {
            for (entity, name, mut light) in &mut lights {
                let mut r = light.rsm_resolution;
                ui.add(
                    egui::Slider::new(&mut r, GiLight::MIN_RSM_RESOLUTION..=GiLight::MAX_RSM_RESOLUTION)
                        .logarithmic(true)
                        .text(format!("{} RSM size", label(entity, name))),
                );
                if r != light.rsm_resolution {
                    light.rsm_resolution = r;
                }
            }
        });
        let broken = pipeline_errors.as_ref().map(|e| e.messages()).unwrap_or_default();
        let logged = warnings.as_ref().map_or(0, |w| w.messages.len()) + broken.len();
        egui::CollapsingHeader::new(format!("Warnings ({logged})")).default_open(logged > 0).show(ui, |ui| {
            for message in &broken {
                ui.colored_label(egui::Color32::LIGHT_RED, message);
            }
            match warnings.as_deref() {
                Some(w) if !w.messages.is_empty() => {
                    for message in &w.messages {
                        ui.label(message.strip_prefix("bevy_diffuse_gi: ").unwrap_or(message));
                    }
                }
                _ if !broken.is_empty() => {}
                _ => {
                    ui.label("none: every setting is in range and the GPU has what the methods need");
                }
            }
        });
        egui::CollapsingHeader::new("GPU passes (ms)").default_open(true).show(ui, |ui| {
            if let Some(timing) = timing.as_deref().filter(|t| !t.per_pass_times) {
                ui.label(format!(
                    "not measurable on this device ({}): its timestamps do not bracket compute work; \
                     compare frame times instead",
                    timing.device
                ));
                return;
            }
            let Some(store) = diagnostics else {
                ui.label("no diagnostics");
                return;
            };
            let mut rows: Vec<(String, f64)> = store
                .iter()
                .filter_map(|d| {
                    let path = d.path().as_str();
                    let pass = path.strip_prefix("render/diffuse_gi/")?.strip_suffix("/elapsed_gpu")?;
                    Some((pass.to_string(), d.smoothed()?))
                })
                .collect();
            rows.sort_by(|a, b| a.0.cmp(&b.0));
            if rows.is_empty() {
                ui.label("no GPU timings (timestamp queries unavailable, or no pass ran)");
            }
            for (pass, ms) in rows {
                ui.label(format!("{pass:<16} {ms:7.3}"));
            }
        });
    });
    Ok(())
}

/// Writes the values the widgets edited back into the component, only when they differ, so that opening
/// the panel marks nothing changed (the plugin redoes work on a change). Every widget of the panel edits
/// a copy of its component and commits it through here; tests drive settings changes the same way.
pub fn commit<T: Component<Mutability = bevy::ecs::component::Mutable> + PartialEq>(edited: T, component: &mut Mut<T>) {
    if edited != **component {
        **component = edited;
    }
}

/// The widgets of a camera's [`VplSettings`]; each range is the field's valid range.
fn vpl_ui(ui: &mut egui::Ui, settings: &mut Mut<VplSettings>) {
    let mut v = (**settings).clone();
    ui.horizontal(|ui| {
        ui.label("VPL preset");
        for (name, preset) in [("Low", VplSettings::LOW), ("Medium", VplSettings::MEDIUM), ("High", VplSettings::HIGH)] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    ui.add(egui::Slider::new(&mut v.light_paths, 1..=16384).logarithmic(true).text("light paths"));
    ui.add(egui::Slider::new(&mut v.bounces, 1..=32).text("max bounces"));
    ui.add(egui::DragValue::new(&mut v.seed).prefix("seed "));
    ui.add(egui::Slider::new(&mut v.geometry_bound, 0.0..=1000.0).logarithmic(true).text("bound b (1/m², 0 = auto)"));
    ui.horizontal(|ui| {
        ui.label("shadow maps");
        ui.radio_value(&mut v.visibility, crate::vpl::VplVisibility::Traced, "traced (CPU rays)");
        ui.radio_value(&mut v.visibility, crate::vpl::VplVisibility::Imperfect, "imperfect (splats)");
    });
    ui.add(egui::Slider::new(&mut v.ism_resolution, 8..=128).text("shadow map side (texels)"));
    ui.add(egui::Slider::new(&mut v.ism_points, 64..=65536).logarithmic(true).text("points per shadow map"));
    ui.add(egui::Slider::new(&mut v.ism_bias, 0.0..=1.0).text("shadow bias (× distance)"));
    ui.add(egui::Slider::new(&mut v.ssbc_steps, 0..=3).text("SSBC steps"));
    ui.add(egui::Slider::new(&mut v.ssbc_solid_angle, 0.001..=1.0).logarithmic(true).text("SSBC refine above (sr)"));
    ui.add(
        egui::Slider::new(&mut v.ssbc_discontinuity_solid_angle, 0.001..=1.0)
            .logarithmic(true)
            .text("SSBC refine at edges above (sr)"),
    );
    ui.add(egui::Slider::new(&mut v.ssbc_levels, 1..=8).text("SSBC levels"));
    ui.checkbox(&mut v.ssbc_blur, "SSBC blur");
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=1000.0).logarithmic(true).text("intensity"));
    commit(v, settings);
}

/// The widgets of a camera's [`RsmGatherSettings`]; each range is the field's valid range.
pub fn rsm_gather_ui(ui: &mut egui::Ui, settings: &mut Mut<RsmGatherSettings>) {
    let mut v = (**settings).clone();
    ui.horizontal(|ui| {
        ui.label("RSM gather preset");
        for (name, preset) in [("Low", RsmGatherSettings::LOW), ("Medium", RsmGatherSettings::MEDIUM), ("High", RsmGatherSettings::HIGH)] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    ui.add(
        egui::Slider::new(&mut v.samples, 1..=RsmGatherSettings::MAX_SAMPLES)
            .logarithmic(true)
            .text("samples per pixel and light"),
    );
    ui.add(egui::Slider::new(&mut v.radius, 0.01..=1.0).text("disk radius r_max (× RSM side)"));
    let mut paper = v.weights == RsmSampleWeights::Paper;
    ui.checkbox(&mut paper, "the paper's sample weights (xi1^2; default: by density, xi1)");
    v.weights = if paper { RsmSampleWeights::Paper } else { RsmSampleWeights::Density };
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=1000.0).logarithmic(true).text("intensity"));
    commit(v, settings);
}

/// The widgets of a camera's [`DrmSettings`]; each range is the field's valid range.
pub fn drm_ui(ui: &mut egui::Ui, settings: &mut Mut<DrmSettings>) {
    let mut v = (**settings).clone();
    ui.horizontal(|ui| {
        ui.label("DRM preset");
        for (name, preset) in [("Low", DrmSettings::LOW), ("Medium", DrmSettings::MEDIUM), ("High", DrmSettings::HIGH)] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    ui.add(
        egui::Slider::new(&mut v.samples_per_axis, 1..=DrmSettings::MAX_SAMPLES_PER_AXIS)
            .text("photons per axis n (M = n² per light face)"),
    );
    ui.horizontal(|ui| {
        ui.label("solid angle:");
        for (choice, label) in [
            (DrmSolidAngle::TexelArea, "Eq. 14 (area)"),
            (DrmSolidAngle::SceneDiagonal, "Eq. 15 (diagonal)"),
            (DrmSolidAngle::Constant, "Eq. 11 (2π/M)"),
        ] {
            ui.radio_value(&mut v.solid_angle, choice, label);
        }
    });
    ui.checkbox(&mut v.mip_mapped, "mip-mapped photons (§5, no flashing)");
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=1000.0).logarithmic(true).text("intensity"));
    commit(v, settings);
}

/// The widgets of a camera's [`RadiositySettings`]; each range is the field's valid range. ASCII labels
/// only (see `rsm_gather_ui`).
pub fn radiosity_ui(ui: &mut egui::Ui, settings: &mut Mut<RadiositySettings>) {
    let mut v = (**settings).clone();
    ui.horizontal(|ui| {
        ui.label("radiosity preset");
        for (name, preset) in [("Low", RadiositySettings::LOW), ("Medium", RadiositySettings::MEDIUM), ("High", RadiositySettings::HIGH)] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    ui.add(egui::Slider::new(&mut v.bins, 2..=24).text("bins per cube side N (6 N x N per element)"));
    ui.add(egui::Slider::new(&mut v.bounces, 1..=16).text("bounces"));
    ui.add(egui::Slider::new(&mut v.stop_threshold, 0.0..=1.0).logarithmic(true).text("stop below this share"));
    ui.add(egui::Slider::new(&mut v.subdivision_threshold, 0.05..=8.0).logarithmic(true).text("subdivide above x bin"));
    ui.add(egui::Slider::new(&mut v.element_size, 0.0..=0.5).logarithmic(true).text("element size (of the scene)"));
    ui.add(egui::Slider::new(&mut v.max_link_memory_mib, 16..=1 << 20).logarithmic(true).text("most link memory (MiB)"));
    let mut area = v.transfer == LinkTransfer::ElementArea;
    ui.checkbox(&mut area, "Eq. 5 with the element's area (as printed)");
    v.transfer = if area { LinkTransfer::ElementArea } else { LinkTransfer::BinSolidAngle };
    ui.horizontal(|ui| {
        ui.label("sky (cd/m2)");
        for c in [&mut v.sky.x, &mut v.sky.y, &mut v.sky.z] {
            ui.add(egui::DragValue::new(c).speed(0.05).range(0.0..=1e6));
        }
    });
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=1000.0).logarithmic(true).text("intensity"));
    commit(v, settings);
}

/// A method's settings on camera `entity`: their panel when it has them, otherwise a button (`label`)
/// that adds `preset`.
fn method_settings<T: Component>(
    ui: &mut egui::Ui,
    commands: &mut Commands,
    entity: Entity,
    settings: Option<Mut<T>>,
    label: &str,
    preset: T,
    panel: impl FnOnce(&mut egui::Ui, &mut Mut<T>),
) {
    match settings {
        Some(mut settings) => {
            ui.push_id(entity, |ui| panel(ui, &mut settings));
        }
        None => {
            if ui.button(label).clicked() {
                commands.entity(entity).insert(preset);
            }
        }
    }
}

/// The VPL set in use and what its last walk redid.
pub fn vpl_set_line(set: &crate::vpl::VplSet) -> String {
    let r = set.last_redone;
    format!(
        "{} VPLs; last walk {:.0} ms in the background: {} of {} light paths walked, {} of {} shadow-map texels traced{}",
        set.vpls.len(),
        set.last_walk_ms,
        r.paths,
        r.paths_total,
        r.texels,
        r.texels_total,
        if set.busy { "; the next is due" } else { "" }
    )
}

/// What the last radiosity solve did: its elements and the paper's Table 1 stages.
fn radiosity_activity_ui(ui: &mut egui::Ui, a: &RadiosityActivity) {
    let t = &a.times;
    ui.label(format!("{} elements, {} nodes, {} links; last solve: {:?}", a.elements, a.nodes, t.links, a.last));
    if let Some(mib) = a.over_budget_mib {
        ui.colored_label(egui::Color32::YELLOW, format!("not solved: the links need {mib} MiB (see max_link_memory_mib)"));
    }
    ui.label(format!(
        "in the background: update {:.1} ms, links {:.1} ms, refine+push {:.1} ms, illumination {:.1} ms ({} bounces)",
        t.update_elements_ms, t.create_links_ms, t.refine_push_ms, t.illumination_ms, t.bounces_run
    ));
    if a.kept_links_derived + a.kept_links_made > 0 {
        let last = match (t.kept_bins_relinked, t.kept_links_made) {
            (Some(bins), _) => format!("; last solve derived them, relinking {bins} bins"),
            (None, true) => "; last solve made them anew".to_string(),
            (None, false) => String::new(),
        };
        ui.label(format!(
            "links kept among the still meshes: derived {} times, made anew {} times{last}; {} solves stopped after them (the meshes had moved on)",
            a.kept_links_derived, a.kept_links_made, a.superseded
        ));
    }
}

/// The widgets of a camera's [`PhotonGridSettings`]; each range is the field's valid range. ASCII
/// labels only (see `rsm_gather_ui`).
pub fn photon_grid_ui(ui: &mut egui::Ui, settings: &mut Mut<PhotonGridSettings>) {
    let mut v = (**settings).clone();
    ui.horizontal(|ui| {
        ui.label("photon grid preset");
        for (name, preset) in [("Low", PhotonGridSettings::LOW), ("Medium", PhotonGridSettings::MEDIUM), ("High", PhotonGridSettings::HIGH)] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    ui.add(egui::Slider::new(&mut v.resolution, 4..=96).text("SH cells along the scene"));
    ui.add(egui::Slider::new(&mut v.photons, 1024..=4_194_304).logarithmic(true).text("photons"));
    ui.add(egui::Slider::new(&mut v.max_reflections, 1..=8).text("stored reflections"));
    ui.add(egui::Slider::new(&mut v.sh_directions, 16..=2048).logarithmic(true).text("probe directions N_sh"));
    ui.add(egui::Slider::new(&mut v.filter_levels, 0..=5).text("coarsest R-grid level read"));
    ui.add(egui::Slider::new(&mut v.gather_samples, 0..=256).text("gather directions N_d (0: exact)"));
    ui.add(egui::Slider::new(&mut v.r_max, 1.0..=3.0).text("r_max (cells)"));
    ui.add(egui::Slider::new(&mut v.obscurance_distance, 0.0..=1000.0).logarithmic(true).text("obscurance distance (m, 0 off)"));
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=1000.0).logarithmic(true).text("intensity"));
    ui.horizontal(|ui| {
        use crate::photon_grid::FieldDevice;
        ui.label("SH field built on");
        for (name, device) in [("auto", FieldDevice::Auto), ("CPU", FieldDevice::Cpu), ("GPU", FieldDevice::Gpu)] {
            ui.radio_value(&mut v.field_device, device, name);
        }
    });
    commit(v, settings);
}

/// What the last photon-grid update did: grid, photons and the paper's Table 1 stages.
fn photon_grid_activity_ui(ui: &mut egui::Ui, a: &PhotonGridActivity) {
    let t = &a.times;
    ui.label(format!(
        "{}x{}x{} cells, {} boundary ({} V-cells), {} probes ({} inside walls), {} photons stored",
        a.dims.x, a.dims.y, a.dims.z, a.boundary_sh_cells, a.boundary_v_cells, a.probes, a.inside, a.photons
    ));
    ui.label(format!(
        "in the background: voxelize {:.1} ms, photons {:.1} ms, R-grid {:.1} ms, SH field {:.1} ms ({})",
        t.voxelize_ms,
        t.trace_ms,
        t.rgrid_ms,
        t.field_ms,
        if a.field_on_gpu { "GPU" } else { "CPU" }
    ));
}

/// Where a camera's method stands, one line of the same shape for the six methods.
pub fn status_line(status: Option<crate::method::MethodStatus>) -> String {
    match status {
        None => "not running yet".into(),
        Some(s) if !s.ready => "no light yet: pipelines compiling or the first background update running".into(),
        Some(s) if s.busy => format!(
            "updating in the background ({} frames since the last start); {} updates done, {} views drawn",
            s.frames_since_start, s.updates, s.views_drawn
        ),
        Some(s) => format!("current: {} background updates, {} views drawn", s.updates, s.views_drawn),
    }
}

fn volume_ui(ui: &mut egui::Ui, label: &str, volume: &mut Mut<RadianceHintsVolume>, transform: &GlobalTransform, mean_chord: Option<f32>) {
    ui.label(label);
    let mut v = (**volume).clone();
    ui.horizontal(|ui| {
        for (name, preset) in [
            ("Low", RadianceHintsVolume::LOW),
            ("Medium", RadianceHintsVolume::MEDIUM),
            ("High", RadianceHintsVolume::HIGH),
        ] {
            if ui.button(name).clicked() {
                v = preset;
            }
        }
    });
    let mut adaptive = matches!(v.sizing, GridSizing::Adaptive { .. });
    ui.checkbox(&mut adaptive, "adaptive grid (cubic cells fitted to the box)");
    match (adaptive, &mut v.sizing) {
        (true, GridSizing::Adaptive { hints, max_cell, max_hints }) => {
            ui.add(egui::Slider::new(hints, 8..=65536).logarithmic(true).text("hints of a small volume"));
            ui.add(egui::Slider::new(max_cell, 0.05..=4.0).logarithmic(true).text("largest cell (m)"));
            ui.add(egui::Slider::new(max_hints, 8..=RadianceHintsVolume::MAX_HINTS).logarithmic(true).text("most hints"));
        }
        (true, GridSizing::Fixed) => v.sizing = RadianceHintsVolume::MEDIUM.sizing,
        (false, GridSizing::Adaptive { .. }) => v.sizing = GridSizing::Fixed,
        (false, GridSizing::Fixed) => {
            ui.horizontal(|ui| {
                ui.label("hints");
                for axis in 0..3 {
                    ui.add(egui::DragValue::new(&mut v.resolution[axis]).range(2..=128));
                }
            });
        }
    }
    ui.horizontal(|ui| {
        ui.label("SH order");
        ui.radio_value(&mut v.sh_order, ShOrder::Two, "2 (4 coeffs)");
        ui.radio_value(&mut v.sh_order, ShOrder::Three, "3 (9 coeffs)");
    });
    ui.add(egui::Slider::new(&mut v.rsm_samples, 1..=512).logarithmic(true).text("RSM samples N_s"));
    ui.add(egui::Slider::new(&mut v.rsm_coverage, 0.01..=1.0).text("coverage c_RSM (directional)"));
    ui.add(egui::Slider::new(&mut v.jitter, 0.0..=1.0).text("jitter (cells)"));
    ui.add(egui::Slider::new(&mut v.extra_bounces, 0..=16).text("extra bounces"));
    ui.add(egui::Slider::new(&mut v.secondary_samples, 1..=128).text("secondary samples N_b"));
    ui.add(egui::Slider::new(&mut v.r_max, 0.0..=50.0).text("r_max (m, 0 = auto)"));
    ui.add(egui::Slider::new(&mut v.bounce_threshold, 0.0..=0.2).text("bounce stop threshold"));
    ui.add(egui::Slider::new(&mut v.temporal_blend, 0.05..=1.0).text("temporal blend"));
    ui.add(egui::Slider::new(&mut v.motion_bounce_period, 1..=16).text("bounce refresh while moving (frames)"));
    ui.add(
        egui::Slider::new(&mut v.motion_hints_per_update, 256..=RadianceHintsVolume::MAX_HINTS)
            .logarithmic(true)
            .text("hints updated per frame while moving"),
    );
    ui.checkbox(&mut v.albedo_volume, "albedo volume (coloured extra bounces)");
    let mut occlusion = v.depth_occlusion.is_some();
    ui.checkbox(&mut occlusion, "§8 camera-depth occlusion");
    match (occlusion, &mut v.depth_occlusion) {
        (true, Some(o)) => {
            ui.add(egui::Slider::new(&mut o.samples, 1..=16).text("occlusion steps"));
            ui.add(egui::Slider::new(&mut o.strength, 0.0..=1.0).text("occlusion strength"));
        }
        (true, None) => v.depth_occlusion = Some(DepthOcclusion::default()),
        (false, _) => v.depth_occlusion = None,
    }
    ui.add(egui::Slider::new(&mut v.reconstruction_samples, 1..=16).text("reconstruction samples N_RH"));
    ui.add(egui::Slider::new(&mut v.reconstruction_reach, 0.1..=2.0).text("reconstruction reach (cell diagonals)"));
    ui.add(egui::Slider::new(&mut v.near_field_occlusion, 0.0..=2.0).text("near-field occlusion (cell diagonals, 0 = off)"));
    ui.horizontal(|ui| {
        ui.label("irradiance from SH:");
        ui.radio_value(&mut v.irradiance, IrradianceReconstruction::NonLinear, "non-linear (Hazel)");
        ui.radio_value(&mut v.irradiance, IrradianceReconstruction::Linear, "linear (Eq. 7)");
    });
    ui.add(egui::Slider::new(&mut v.intensity, 0.0..=4.0).text("intensity"));
    let running = v.effective(transform.to_matrix(), mean_chord);
    let r = running.resolution;
    ui.label(format!(
        "{}×{}×{} = {} hints, {:.2} MiB",
        r.x,
        r.y,
        r.z,
        running.hint_count(),
        running.memory_bytes() as f64 / (1024.0 * 1024.0)
    ));
    commit(v, volume);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn committing_unchanged_values_changes_nothing() {
        // Opening the panel must not rewrite a value set in code: committing an identical copy leaves the
        // component untouched (no change detection), so the plugin redoes nothing.
        let mut world = World::new();
        let entity = world.spawn(RsmGatherSettings { samples: 77, ..default() }).id();
        world.clear_trackers();
        let edit = |samples: u32, world: &mut World| {
            world
                .run_system_cached_with(
                    |In(samples): In<u32>, mut q: Query<&mut RsmGatherSettings>| {
                        let mut settings = q.single_mut().unwrap();
                        let edited = RsmGatherSettings { samples, ..(*settings).clone() };
                        commit(edited, &mut settings);
                    },
                    samples,
                )
                .unwrap();
            let changed = world.query_filtered::<Entity, Changed<RsmGatherSettings>>().iter(world).count();
            world.clear_trackers();
            changed
        };
        assert_eq!(edit(77, &mut world), 0);
        assert_eq!(edit(78, &mut world), 1);
        assert_eq!(world.get::<RsmGatherSettings>(entity).unwrap().samples, 78);
    }

    #[test]
    fn the_vpl_line_says_what_the_last_walk_redid() {
        let set = crate::vpl::VplSet {
            last_walk_ms: 34.6,
            last_redone: crate::vpl::VplRedone { paths: 5, paths_total: 160, texels: 40_000, texels_total: 478_208 },
            ..default()
        };
        let line = vpl_set_line(&set);
        assert!(line.contains("35 ms") && line.contains("5 of 160 light paths") && line.contains("40000 of 478208"), "{line}");
        assert!(!line.contains("due"), "{line}");
        assert!(vpl_set_line(&crate::vpl::VplSet { busy: true, ..default() }).contains("the next is due"));
    }
}
