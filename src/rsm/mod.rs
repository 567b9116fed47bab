//! Reflective shadow maps (RSMs; Dachsbacher & Stamminger 2005): for every light with a
//! [`GiLight`](crate::light::GiLight), the surfaces it lights, seen from the light, with their world
//! position, normal and reflected flux. They are the input of the GI methods (Radiance Hints injection,
//! §4 of Papaioannou 2011, Eq. 4).
//!
//! # Layout
//! All RSMs live in one set of 2D array textures (the *atlas*), one layer per light face: one face for
//! directional lights and spot lights up to 60° half-angle, six cube faces for point lights and wider
//! spots. Each light renders into the top-left `rsm_resolution²` texels of its layers.
//!
//! | target     | format        | content                                                              |
//! |------------|---------------|----------------------------------------------------------------------|
//! | `position` | `Rgba32Float` | world position (xyz), surface area of the texel's patch in m² (w; 0 = empty) |
//! | `normal`   | `Rgba16Float` | unit normal turned towards the light                                  |
//! | `flux`     | `Rgba16Float` | reflected flux `ρ·Φ_T` (lumens) divided by the face's `flux_scale`     |
//!
//! Three targets keep within WebGPU's 32 bytes of colour attachments per sample.
//!
//! # Why rasterise the scene snapshot rather than add Bevy cameras at the lights
//! A prepass-only `Camera3d` at each light would reuse Bevy's materials exactly, but only *deferred*
//! materials write albedo, each such camera gets its own directional-light shadow cascades and clusters,
//! and point lights need six of them. Rasterising the [`SceneSnapshot`](crate::scene::SceneSnapshot)
//! ourselves works for forward and deferred apps alike, renders exactly the faces that changed, and is one
//! draw call per face. The cost: albedo is per triangle (base colour × the texture's mean over the
//! triangle), and skinned or morphed meshes appear in their bind pose.
//!
//! # Cost
//! Nothing without a `GiLight`. A face is re-rendered only when its light, the atlas size or (directional
//! lights) the volumes it is fitted to change, or when geometry changed inside its frustum (the old and
//! new bounds of a moved, added or removed mesh, [`frustum_overlaps`]); otherwise last frame's RSM is
//! reused. A moved mesh rewrites only its own range of the vertex buffer; adding or removing one uploads
//! the buffer again. A face's full render is one draw of every snapshot triangle at `rsm_resolution²`.
//!
//! A face that must be redrawn only because instances that are *moving* (changed within the last
//! [`MOVING_HOLD_FRAMES`](extract::MOVING_HOLD_FRAMES) frames) moved in front of it is not drawn from every
//! triangle: it keeps a *static layer*, the face drawn once without the moving instances, with its depth
//! ([`StaticLayers`]); each redraw copies that layer into the atlas and draws the moving instances alone
//! over it, depth-tested against it. So a character walking through a large level costs a copy of the
//! faces that see it and a draw of its own triangles, not of the level. The static layer is drawn anew
//! when the set of moving instances changes (one starts moving, or one has been still for the hold) or
//! the face itself changes (the light moved): that frame costs a full render, as before. Memory: the
//! static layers double the atlas once something moves in front of a GI light (36 B per texel: 2.4 MiB
//! per 256² face).

pub(crate) mod extract;

use bevy::math::{Mat4, Vec3, Vec4};
use bevy::mesh::VertexBufferLayout;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::uniform_buffer;
use bevy::render::render_resource::*;
use bevy::core_pipeline::schedule::camera_driver;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::renderer::{RenderContext, RenderDevice, RenderGraph, RenderGraphSystems, RenderQueue};
use bevy::render::{ExtractSchedule, Render, RenderApp, RenderStartup, RenderSystems};
use bevy::shader::Shader;

use crate::scene::SnapshotLight;
pub use extract::{ExtractedGiGeometry, ExtractedGiLight, ExtractedGiLights, RsmVertex};

/// Spot lights wider than this half-angle are rendered as cube maps (a single perspective face would
/// spread its texels too thin).
pub const MAX_SINGLE_FACE_SPOT_ANGLE: f32 = std::f32::consts::FRAC_PI_3;

/// Texture formats of the atlas targets.
pub const POSITION_FORMAT: TextureFormat = TextureFormat::Rgba32Float;
pub const NORMAL_FORMAT: TextureFormat = TextureFormat::Rgba16Float;
pub const FLUX_FORMAT: TextureFormat = TextureFormat::Rgba16Float;
pub const DEPTH_FORMAT: TextureFormat = TextureFormat::Depth32Float;

/// Light kinds as the shaders number them.
pub const KIND_DIRECTIONAL: u32 = 0;
pub const KIND_SPOT: u32 = 1;
pub const KIND_POINT: u32 = 2;

/// What the methods that read RSMs ask of them, written during extraction: whether any of them needs
/// them this frame (no consumer: no face is drawn), and the region the RSMs of directional lights are
/// fitted to (the union of every GI volume's bounds; the whole scene without volumes).
///
/// Each consumer writes only its own field: the volume methods `bounds` and `volumes_need`, the RSM module
/// itself `views_need` for the cameras whose method gathers from the RSMs per pixel
/// ([`GiMethod::gathers_rsm_per_pixel`]).
#[derive(Resource, Default, Clone, Copy, Debug, PartialEq)]
pub struct RsmFocus {
    pub bounds: Option<(Vec3, Vec3)>,
    /// A volume method (Radiance Hints) reads the RSMs this frame.
    pub volumes_need: bool,
    /// An active camera's method reads the RSMs per pixel this frame.
    pub views_need: bool,
}

impl RsmFocus {
    /// Whether any method reads the RSMs this frame.
    pub fn needed(&self) -> bool {
        self.volumes_need || self.views_need
    }
}

/// Sets [`RsmFocus::views_need`]: whether an active camera's method gathers from the RSMs per pixel.
pub(crate) fn extract_rsm_view_demand(
    cameras: bevy::render::Extract<Query<(&Camera, &crate::camera::DiffuseGi)>>,
    mut focus: ResMut<RsmFocus>,
) {
    let need = cameras
        .iter()
        .any(|(camera, gi)| camera.is_active && gi.enabled && gi.method.gathers_rsm_per_pixel());
    if focus.views_need != need {
        focus.views_need = need;
    }
}

/// Uniform of one RSM face (`RsmFace` in `shaders/rsm/rsm_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct RsmFaceUniform {
    pub clip_from_world: Mat4,
    pub light_position: Vec4,
    pub axis: Vec4,
    pub spot_direction: Vec4,
    pub color: Vec4,
    pub params: Vec4,
    /// [`KIND_DIRECTIONAL`], [`KIND_SPOT`] or [`KIND_POINT`].
    pub kind: u32,
}

/// One GI light as the passes that read the atlas see it (`GiLight` in `shaders/rsm/rsm_types.wgsl`).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuGiLight {
    /// Clip space of face 0 (used to centre the sampled disk of directional lights).
    pub clip_from_world: Mat4,
    /// Multiplies the stored flux back into lumens.
    pub flux_scale: f32,
    /// Share of the RSM samples of each hint, by light power.
    pub sample_fraction: f32,
    pub first_layer: u32,
    pub faces: u32,
    pub resolution: u32,
    pub kind: u32,
}

/// A light's faces, ready to draw: their uniforms and what the injection pass needs.
#[derive(Clone, Debug, PartialEq)]
pub struct RsmLightFaces {
    pub faces: Vec<RsmFaceUniform>,
    pub flux_scale: f32,
    /// Power estimate (lumens, photometric maximum channel) used to split samples between lights.
    pub power: f32,
    pub kind: u32,
}

/// Computes the faces of `light` for a scene with `scene_bounds`, directional lights fitted to `focus`.
pub fn light_faces(
    light: &SnapshotLight,
    resolution: u32,
    scene_bounds: (Vec3, Vec3),
    focus: Option<(Vec3, Vec3)>,
) -> RsmLightFaces {
    let res = resolution.max(1) as f32;
    let corners = |(lo, hi): (Vec3, Vec3)| {
        (0..8).map(move |i| Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        ))
    };
    let up_for = |dir: Vec3| if dir.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let max_component = |v: Vec3| v.max_element().max(1e-12);
    match *light {
        SnapshotLight::Directional { direction, illuminance } => {
            let dir = direction.try_normalize().unwrap_or(Vec3::NEG_Y);
            let view = Mat4::look_to_rh(Vec3::ZERO, dir, up_for(dir));
            let target = focus.unwrap_or(scene_bounds);
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for c in corners(target) {
                let v = view.transform_point3(c);
                lo = lo.min(v);
                hi = hi.max(v);
            }
            // Depth along −z of the light's view: keep every occluder between the light and the focus.
            let mut z_near = -hi.z;
            for c in corners(scene_bounds) {
                z_near = z_near.min(-view.transform_point3(c).z);
            }
            let z_far = -lo.z;
            let margin = 0.01 * (hi - lo).max_element().max(1e-3);
            let (left, right, bottom, top) = (lo.x - margin, hi.x + margin, lo.y - margin, hi.y + margin);
            let projection = Mat4::orthographic_rh(left, right, bottom, top, z_near - margin, z_far + margin);
            let texel_area = (right - left) * (top - bottom) / (res * res);
            let e_max = max_component(illuminance);
            let face = RsmFaceUniform {
                clip_from_world: projection * view,
                light_position: Vec4::ZERO,
                axis: dir.extend(0.0),
                spot_direction: dir.extend(0.0),
                color: (illuminance / e_max).extend(1.0),
                params: Vec4::new(0.0, 0.0, 0.0, texel_area),
                kind: KIND_DIRECTIONAL,
            };
            RsmLightFaces {
                faces: vec![face],
                flux_scale: e_max * texel_area,
                power: e_max * (right - left) * (top - bottom),
                kind: KIND_DIRECTIONAL,
            }
        }
        SnapshotLight::Spot { position, direction, intensity, inverse_range_squared, spot_scale, spot_offset } => {
            let cos_outer = (-spot_offset / spot_scale.max(1e-12)).clamp(-1.0, 1.0);
            let outer = cos_outer.acos();
            let i_max = max_component(intensity);
            let solid_angle = std::f32::consts::TAU * (1.0 - cos_outer);
            let base = local_light_params(position, intensity / i_max, inverse_range_squared, spot_scale, spot_offset, direction);
            if outer <= MAX_SINGLE_FACE_SPOT_ANGLE {
                let (face, omega) = perspective_face(position, direction, outer, res, scene_bounds, base, KIND_SPOT);
                RsmLightFaces { faces: vec![face], flux_scale: i_max * omega, power: i_max * solid_angle, kind: KIND_SPOT }
            } else {
                let (faces, omega) = cube_faces(position, res, scene_bounds, base, KIND_SPOT);
                RsmLightFaces { faces, flux_scale: i_max * omega, power: i_max * solid_angle, kind: KIND_SPOT }
            }
        }
        SnapshotLight::Point { position, intensity, inverse_range_squared } => {
            let i_max = max_component(intensity);
            let base = local_light_params(position, intensity / i_max, inverse_range_squared, 0.0, 1.0, Vec3::NEG_Y);
            let (faces, omega) = cube_faces(position, res, scene_bounds, base, KIND_POINT);
            RsmLightFaces {
                faces,
                flux_scale: i_max * omega,
                power: i_max * 4.0 * std::f32::consts::PI,
                kind: KIND_POINT,
            }
        }
    }
}

/// The fields shared by every face of a spot or point light.
fn local_light_params(
    position: Vec3,
    color: Vec3,
    inverse_range_squared: f32,
    spot_scale: f32,
    spot_offset: f32,
    spot_direction: Vec3,
) -> RsmFaceUniform {
    RsmFaceUniform {
        clip_from_world: Mat4::IDENTITY,
        light_position: position.extend(0.0),
        axis: Vec4::ZERO,
        spot_direction: spot_direction.extend(0.0),
        color: color.extend(1.0),
        params: Vec4::new(spot_scale, spot_offset, inverse_range_squared, 0.0),
        kind: 0,
    }
}

/// Near and far planes of a perspective face at `position` that sees all of the scene.
fn near_far(position: Vec3, (lo, hi): (Vec3, Vec3)) -> (f32, f32) {
    let far_corner = Vec3::new(
        if (position.x - lo.x).abs() > (position.x - hi.x).abs() { lo.x } else { hi.x },
        if (position.y - lo.y).abs() > (position.y - hi.y).abs() { lo.y } else { hi.y },
        if (position.z - lo.z).abs() > (position.z - hi.z).abs() { lo.z } else { hi.z },
    );
    let far = (far_corner - position).length() * 1.01 + 1e-3;
    (far * 1e-4, far)
}

fn perspective_face(
    position: Vec3,
    axis: Vec3,
    half_angle: f32,
    res: f32,
    scene_bounds: (Vec3, Vec3),
    base: RsmFaceUniform,
    kind: u32,
) -> (RsmFaceUniform, f32) {
    let axis = axis.try_normalize().unwrap_or(Vec3::NEG_Y);
    let up = if axis.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let view = Mat4::look_to_rh(position, axis, up);
    let (near, far) = near_far(position, scene_bounds);
    let half_angle = half_angle.clamp(1e-3, 1.5);
    let projection = Mat4::perspective_rh(2.0 * half_angle, 1.0, near, far);
    let t = half_angle.tan();
    let omega = (2.0 * t / res).powi(2);
    let mut face = base;
    face.clip_from_world = projection * view;
    face.kind = kind;
    face.axis = axis.extend(0.0);
    face.params.w = omega;
    (face, omega)
}

/// The six 90° faces of a cube around `position`, in the order +X, −X, +Y, −Y, +Z, −Z.
fn cube_faces(
    position: Vec3,
    res: f32,
    scene_bounds: (Vec3, Vec3),
    base: RsmFaceUniform,
    kind: u32,
) -> (Vec<RsmFaceUniform>, f32) {
    let axes = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z];
    let mut omega = 0.0;
    let faces = axes
        .iter()
        .map(|&axis| {
            let (face, o) = perspective_face(position, axis, std::f32::consts::FRAC_PI_4, res, scene_bounds, base, kind);
            omega = o;
            face
        })
        .collect();
    (faces, omega)
}

/// What a light's faces are rendered from: geometry generation, atlas generation, face uniforms, and the
/// bits of the flux scale (the faces store the light's colour normalised by its largest channel, so an
/// intensity change alone shows only there).
pub type RsmSlotKey = (u64, Vec<RsmFaceUniform>, u32);

/// Where one light's faces live in the atlas and what they were last drawn from.
#[derive(Clone, Debug, PartialEq)]
pub struct RsmSlot {
    pub entity: Entity,
    pub first_layer: u32,
    pub faces: u32,
    pub resolution: u32,
    pub light_faces: RsmLightFaces,
    /// What the faces should show now.
    pub current: RsmSlotKey,
    /// What they showed when last drawn (`None` = never drawn).
    pub drawn: Option<RsmSlotKey>,
    /// Faces (bit `i` = face `i`) whose frusta saw geometry change since they were drawn.
    pub stale_faces: u32,
}

/// The RSM atlas and everything the injection pass reads. See the [module docs](self).
#[derive(Resource)]
pub struct RsmAtlas {
    /// Side of every layer in texels (the largest light's resolution).
    pub size: u32,
    pub layers: u32,
    /// Bumped whenever the textures are reallocated.
    pub generation: u64,
    pub position: Texture,
    pub normal: Texture,
    pub flux: Texture,
    pub depth: Texture,
    /// Array views for sampling.
    pub position_view: TextureView,
    pub normal_view: TextureView,
    pub flux_view: TextureView,
    pub slots: Vec<RsmSlot>,
    /// The GI lights for the injection pass, in `slots` order.
    pub lights: StorageBuffer<Vec<GpuGiLight>>,
    /// Face uniforms, one per layer in use.
    pub face_uniforms: DynamicUniformBuffer<RsmFaceUniform>,
    /// The same faces as a storage array indexed by layer, for the passes that read every face (the
    /// per-pixel gathers project points into them).
    pub faces: StorageBuffer<Vec<RsmFaceUniform>>,
    /// The faces to draw this frame.
    pub dirty_faces: Vec<FaceDraw>,
    /// Faces drawn without the moving instances (allocated the first time a face needs one).
    pub static_layers: Option<StaticLayers>,
    /// Bumped whenever any RSM content changes; volumes compare it with what they were built from.
    pub version: u64,
    /// The uploaded snapshot geometry.
    pub vertices: Option<Buffer>,
    pub vertex_count: u32,
    pub geometry_generation: u64,
    pub scene_bounds: Option<(Vec3, Vec3)>,
}

/// How a face is drawn this frame.
#[derive(Clone, Debug, PartialEq)]
pub enum FaceMode {
    /// Every triangle: the face itself changed (its light, its fit, the atlas), or geometry changed
    /// with nothing recently moving.
    Full,
    /// Only geometry changed where it looks, and only the moving instances' (see
    /// [`ExtractedGiGeometry::moving`]): the face is copied from its static layer, drawn without them,
    /// and they alone are drawn over it. `rebuild`: the static layer is out of date (a new moving set, a
    /// changed face) and is first drawn from every other triangle, and then holds this key.
    Composite { rebuild: Option<Box<StaticKey>> },
}

/// One face to draw: its atlas layer, the dynamic offset of its uniform, its resolution and how.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceDraw {
    pub layer: u32,
    pub offset: u32,
    pub resolution: u32,
    pub mode: FaceMode,
}

/// What a static layer was drawn from: atlas generation, the face, the bits of its flux scale and the
/// [`moving_generation`](ExtractedGiGeometry::moving_generation) whose instances it leaves out.
pub type StaticKey = (u64, RsmFaceUniform, u32, u64);

/// A copy of the atlas's faces drawn without the moving instances, so that a face that sees only a
/// moving mesh is redrawn by a copy and a draw of that mesh: the cost of a move does not grow with the
/// rest of the scene. Same size and layers as the atlas; it doubles the atlas's memory once anything
/// moves in front of a GI light.
pub struct StaticLayers {
    pub position: Texture,
    pub normal: Texture,
    pub flux: Texture,
    pub depth: Texture,
    /// What each layer holds (`None`: nothing valid).
    pub keys: Vec<Option<StaticKey>>,
}

/// The four targets of an atlas (or of its static layers): position, normal, flux, depth.
fn layer_textures(device: &RenderDevice, size: u32, layers: u32, labels: [&'static str; 4]) -> [Texture; 4] {
    let make = |label: &'static str, format: TextureFormat| {
        device.create_texture(&TextureDescriptor {
            label: Some(label),
            size: Extent3d {
                width: size,
                height: size,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: TextureDimension::D2,
            format,
            usage: TextureUsages::RENDER_ATTACHMENT | TextureUsages::TEXTURE_BINDING | TextureUsages::COPY_SRC | TextureUsages::COPY_DST,
            view_formats: &[],
        })
    };
    [
        make(labels[0], POSITION_FORMAT),
        make(labels[1], NORMAL_FORMAT),
        make(labels[2], FLUX_FORMAT),
        make(labels[3], DEPTH_FORMAT),
    ]
}

impl RsmAtlas {
    fn allocate(device: &RenderDevice, size: u32, layers: u32, generation: u64) -> Self {
        let array_view = |t: &Texture| {
            t.create_view(&TextureViewDescriptor {
                dimension: Some(TextureViewDimension::D2Array),
                ..default()
            })
        };
        let [position, normal, flux, depth] = layer_textures(
            device,
            size,
            layers,
            ["diffuse_gi_rsm_position", "diffuse_gi_rsm_normal", "diffuse_gi_rsm_flux", "diffuse_gi_rsm_depth"],
        );
        Self {
            size,
            layers,
            generation,
            position_view: array_view(&position),
            normal_view: array_view(&normal),
            flux_view: array_view(&flux),
            position,
            normal,
            flux,
            depth,
            slots: Vec::new(),
            lights: StorageBuffer::default(),
            face_uniforms: DynamicUniformBuffer::default(),
            faces: StorageBuffer::default(),
            dirty_faces: Vec::new(),
            static_layers: None,
            version: 0,
            vertices: None,
            vertex_count: 0,
            geometry_generation: 0,
            scene_bounds: None,
        }
    }

    /// A view of one layer of `texture`, for rendering.
    pub fn layer_view(texture: &Texture, layer: u32) -> TextureView {
        texture.create_view(&TextureViewDescriptor {
            label: Some("diffuse_gi_rsm_layer"),
            dimension: Some(TextureViewDimension::D2),
            base_array_layer: layer,
            array_layer_count: Some(1),
            ..default()
        })
    }
}

/// The RSM rasterisation pipeline.
#[derive(Resource)]
pub struct RsmPipeline {
    pub layout: BindGroupLayoutDescriptor,
    pub pipeline: CachedRenderPipelineId,
}

/// Registers the RSM extraction, preparation and pipeline. Added by [`crate::DiffuseGiPlugin`].
pub struct RsmPlugin;

/// The RSM shader, kept alive by this resource.
#[derive(Resource, Clone)]
pub struct RsmShader(pub Handle<Shader>, pub Handle<Shader>);

impl Plugin for RsmPlugin {
    fn build(&self, app: &mut App) {
        let shader = crate::add_shader(app, "rsm/rsm.wgsl", include_str!("../../shaders/rsm/rsm.wgsl"));
        let types = crate::add_shader(app, "rsm/rsm_types.wgsl", include_str!("../../shaders/rsm/rsm_types.wgsl"));
        app.add_systems(PostUpdate, warn_emissive_only_lighting);
        let Some(render_app) = app.get_sub_app_mut(RenderApp) else {
            return;
        };
        render_app
            .insert_resource(RsmShader(shader, types))
            .init_resource::<ExtractedGiGeometry>()
            .init_resource::<ExtractedGiLights>()
            .init_resource::<RsmFocus>()
            .add_systems(RenderStartup, (init_rsm_pipeline, init_rsm_atlas))
            .add_systems(
                ExtractSchedule,
                (extract::extract_gi_geometry, extract::extract_gi_lights, extract_rsm_view_demand),
            )
            .add_systems(Render, prepare_rsm.in_set(RenderSystems::PrepareResources))
            .add_systems(RenderGraph, draw_rsm.in_set(RenderGraphSystems::Render).before(camera_driver));
    }
}

/// Frames the scene must stay lit by emissive surfaces alone before [`warn_emissive_only_lighting`] warns:
/// an app that adds its `GiLight`s a frame after the scene spawns (a glTF's lights once they exist) is
/// not warned.
const EMISSIVE_ONLY_FRAMES: u32 = 3;

/// Warns once per camera and method when a camera uses a method that gathers the GI lights' RSMs per pixel
/// ([`GiMethod::gathers_rsm_per_pixel`](crate::camera::GiMethod::gathers_rsm_per_pixel): the RSM gather,
/// DRM) in a scene whose only light is emissive: an RSM is rendered from a `GiLight`, so those methods
/// bounce nothing there, and the image has no GI without anything telling the user why.
pub(crate) fn warn_emissive_only_lighting(
    cameras: Query<(Entity, &Camera, &crate::camera::DiffuseGi)>,
    lights: Query<(), With<crate::light::GiLight>>,
    meshes: Query<&MeshMaterial3d<StandardMaterial>>,
    materials: Option<Res<Assets<StandardMaterial>>>,
    mut frames: Local<u32>,
    mut warned: Local<bevy::platform::collections::HashSet<(Entity, crate::camera::GiMethod)>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    // Cheap first: a camera that would be warned, and no GiLight; only then look for emissive meshes (the
    // snapshot, which samples the emitters, does not exist for these methods without a GiLight).
    let unwarned = cameras
        .iter()
        .any(|(entity, camera, gi)| camera.is_active && gi.enabled && gi.method.gathers_rsm_per_pixel() && !warned.contains(&(entity, gi.method)));
    let emissive = |m: &MeshMaterial3d<StandardMaterial>| {
        materials.as_ref().and_then(|a| a.get(&m.0)).is_some_and(|m| {
            let e = m.emissive;
            e.red.max(e.green).max(e.blue) > 0.0 && e.red.is_finite() && e.green.is_finite() && e.blue.is_finite()
        })
    };
    let emissive_only = unwarned && lights.is_empty() && meshes.iter().any(emissive);
    *frames = if emissive_only { frames.saturating_add(1) } else { 0 };
    if *frames < EMISSIVE_ONLY_FRAMES {
        return;
    }
    for (entity, camera, gi) in &cameras {
        if camera.is_active && gi.enabled && gi.method.gathers_rsm_per_pixel() && warned.insert((entity, gi.method)) {
            crate::gi_warning(
                &mut warnings,
                format!(
                    "bevy_diffuse_gi: camera {entity} uses GiMethod::{:?}, which bounces only the light of GiLights (it \
                     gathers their reflective shadow maps), but this scene is lit by emissive surfaces alone: it gets no \
                     bounced light. Use Vpl, RadianceHints, Radiosity or PhotonGrid, which bounce emissive light, or add \
                     a GiLight",
                    gi.method
                ),
            );
        }
    }
}

fn init_rsm_pipeline(mut commands: Commands, shader: Res<RsmShader>, pipeline_cache: Res<PipelineCache>) {
    let layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_rsm_bind_group_layout",
        &BindGroupLayoutEntries::single(
            ShaderStages::VERTEX_FRAGMENT,
            uniform_buffer::<RsmFaceUniform>(true),
        ),
    );
    let target = |format| Some(ColorTargetState { format, blend: None, write_mask: ColorWrites::ALL });
    let pipeline = pipeline_cache.queue_render_pipeline(RenderPipelineDescriptor {
        label: Some("diffuse_gi_rsm_pipeline".into()),
        layout: vec![layout.clone()],
        vertex: VertexState {
            shader: shader.0.clone(),
            entry_point: Some("vertex".into()),
            shader_defs: crate::shared_shader_defs(),
            buffers: vec![VertexBufferLayout {
                array_stride: std::mem::size_of::<RsmVertex>() as u64,
                step_mode: VertexStepMode::Vertex,
                attributes: vec![
                    VertexAttribute { format: VertexFormat::Float32x3, offset: 0, shader_location: 0 },
                    VertexAttribute { format: VertexFormat::Float32x3, offset: 12, shader_location: 1 },
                    VertexAttribute { format: VertexFormat::Float32x3, offset: 24, shader_location: 2 },
                ],
            }],
        },
        fragment: Some(FragmentState {
            shader: shader.0.clone(),
            entry_point: Some("fragment".into()),
            shader_defs: crate::shared_shader_defs(),
            targets: vec![target(POSITION_FORMAT), target(NORMAL_FORMAT), target(FLUX_FORMAT)],
        }),
        primitive: PrimitiveState {
            // Two-sided: a wall lights a room whichever way its triangles wind.
            cull_mode: None,
            ..default()
        },
        depth_stencil: Some(DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(CompareFunction::Less),
            stencil: default(),
            bias: default(),
        }),
        ..default()
    });
    commands.insert_resource(RsmPipeline { layout, pipeline });
}

fn init_rsm_atlas(mut commands: Commands, device: Res<RenderDevice>) {
    // A 1×1 placeholder keeps every bind group valid before the first GI light appears.
    commands.insert_resource(RsmAtlas::allocate(&device, 1, 1, 0));
}

/// Uploads changed geometry, assigns layers, fits the faces and marks the ones to redraw.
pub(crate) fn prepare_rsm(
    mut atlas: ResMut<RsmAtlas>,
    mut geometry: ResMut<ExtractedGiGeometry>,
    lights: Res<ExtractedGiLights>,
    focus: Res<RsmFocus>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    // Geometry: a full upload after a layout change, otherwise the changed instances' ranges in place.
    let mut geometry_dirty: Option<Option<Vec<(Vec3, Vec3)>>> = None;
    if let Some(vertices) = geometry.pending.take() {
        atlas.vertex_count = vertices.len() as u32;
        atlas.vertices = (!vertices.is_empty()).then(|| {
            device.create_buffer_with_data(&BufferInitDescriptor {
                label: Some("diffuse_gi_rsm_vertices"),
                contents: bytemuck::cast_slice(&vertices),
                usage: BufferUsages::VERTEX | BufferUsages::COPY_DST,
            })
        });
        geometry_dirty = Some(None);
    }
    let ranges = std::mem::take(&mut geometry.pending_ranges);
    if !ranges.is_empty()
        && let Some(buffer) = atlas.vertices.as_ref()
    {
        for (first, vertices) in &ranges {
            let end = *first as u64 + vertices.len() as u64;
            if end <= atlas.vertex_count as u64 && !vertices.is_empty() {
                queue.write_buffer(buffer, *first as u64 * std::mem::size_of::<RsmVertex>() as u64, bytemuck::cast_slice(vertices));
            }
        }
    }
    if geometry_dirty.is_none() && geometry.generation != atlas.geometry_generation {
        geometry_dirty = Some(geometry.dirty.take());
    }
    geometry.dirty = Some(Vec::new());
    atlas.geometry_generation = geometry.generation;
    atlas.scene_bounds = geometry.bounds;
    let scene_bounds = atlas.scene_bounds.unwrap_or((Vec3::splat(-1.0), Vec3::ONE));

    // Lay the lights out, dropping those beyond the device's array-layer limit.
    let max_layers = device.limits().max_texture_array_layers;
    let max_size = device.limits().max_texture_dimension_2d;
    let mut layouts = Vec::new();
    let mut layers = 0u32;
    let mut size = 1u32;
    for light in &lights.lights {
        let resolution = light.resolution.min(max_size);
        let light_faces = light_faces(&light.light, resolution, scene_bounds, focus.bounds);
        let faces = light_faces.faces.len() as u32;
        if layers + faces > max_layers {
            bevy::log::warn_once!(
                "bevy_diffuse_gi: too many GI light faces for max_texture_array_layers = {max_layers}; \
                 the extra GI lights are ignored"
            );
            break;
        }
        layouts.push((light.entity, layers, faces, resolution, light_faces));
        layers += faces;
        size = size.max(resolution);
    }
    let layers = layers.max(1);
    if size != atlas.size || layers != atlas.layers {
        let generation = atlas.generation + 1;
        let mut fresh = RsmAtlas::allocate(&device, size, layers, generation);
        fresh.vertices = atlas.vertices.take();
        fresh.vertex_count = atlas.vertex_count;
        fresh.geometry_generation = atlas.geometry_generation;
        fresh.scene_bounds = atlas.scene_bounds;
        fresh.version = atlas.version + 1;
        *atlas = fresh;
    }

    // Keep what each light was last rendered from, matched by entity.
    let previous: Vec<RsmSlot> = std::mem::take(&mut atlas.slots);
    let total_power: f32 = layouts.iter().map(|l| l.4.power).sum::<f32>().max(1e-12);
    atlas.face_uniforms.clear();
    atlas.dirty_faces.clear();
    let mut gpu_lights = Vec::new();
    let mut all_faces = Vec::new();
    for (entity, first_layer, faces, resolution, light_faces) in layouts {
        all_faces.extend_from_slice(&light_faces.faces);
        let kept = previous
            .iter()
            .find(|s| s.entity == entity && s.first_layer == first_layer && s.resolution == resolution);
        let drawn = kept.and_then(|s| s.drawn.clone());
        let mut stale_faces = kept.map_or(0, |s| s.stale_faces);
        let current = (atlas.generation, light_faces.faces.clone(), light_faces.flux_scale.to_bits());
        let dirty = drawn.as_ref() != Some(&current);
        for (i, face) in light_faces.faces.iter().enumerate() {
            // Geometry changed where this face looks (or everywhere).
            let sees_change = match &geometry_dirty {
                Some(None) => true,
                Some(Some(boxes)) => boxes.iter().any(|&(lo, hi)| frustum_overlaps(face.clip_from_world, lo, hi)),
                None => false,
            };
            if sees_change {
                stale_faces |= 1 << i;
            }
            let offset = atlas.face_uniforms.push(face);
            if !dirty && stale_faces & (1 << i) == 0 {
                continue;
            }
            let layer = first_layer + i as u32;
            // Only moving geometry changed here since the face was drawn (a full upload clears the
            // moving set): redraw it from its static layer.
            let mode = if dirty || geometry.moving.is_empty() {
                FaceMode::Full
            } else {
                let key: StaticKey = (atlas.generation, *face, light_faces.flux_scale.to_bits(), geometry.moving_generation);
                let cached = atlas.static_layers.as_ref().and_then(|s| s.keys.get(layer as usize)).and_then(Option::as_ref);
                FaceMode::Composite { rebuild: (cached != Some(&key)).then(|| Box::new(key)) }
            };
            atlas.dirty_faces.push(FaceDraw { layer, offset, resolution, mode });
        }
        gpu_lights.push(GpuGiLight {
            clip_from_world: light_faces.faces[0].clip_from_world,
            flux_scale: light_faces.flux_scale,
            sample_fraction: light_faces.power / total_power,
            first_layer,
            faces,
            resolution,
            kind: light_faces.kind,
        });
        atlas.slots.push(RsmSlot {
            entity,
            first_layer,
            faces,
            resolution,
            light_faces,
            current,
            drawn,
            stale_faces,
        });
    }
    let composite = atlas.dirty_faces.iter().any(|f| f.mode != FaceMode::Full);
    if composite && atlas.static_layers.is_none() {
        let [position, normal, flux, depth] = layer_textures(
            &device,
            atlas.size,
            atlas.layers,
            ["diffuse_gi_rsm_static_position", "diffuse_gi_rsm_static_normal", "diffuse_gi_rsm_static_flux", "diffuse_gi_rsm_static_depth"],
        );
        // (No face had a valid static layer before: each one here rebuilds its own.)
        atlas.static_layers = Some(StaticLayers { position, normal, flux, depth, keys: vec![None; atlas.layers as usize] });
    }
    // A light that went away changes the light set without anything to draw.
    let set_changed = previous.len() != atlas.slots.len()
        || previous.iter().zip(&atlas.slots).any(|(a, b)| a.entity != b.entity);
    if set_changed {
        atlas.version += 1;
    }
    atlas.face_uniforms.write_buffer(&device, &queue);
    if gpu_lights.is_empty() {
        // Storage buffers may not be empty.
        gpu_lights.push(GpuGiLight::default());
    }
    *atlas.lights.get_mut() = gpu_lights;
    atlas.lights.write_buffer(&device, &queue);
    if all_faces.is_empty() {
        all_faces.push(RsmFaceUniform::default());
    }
    if *atlas.faces.get() != all_faces {
        *atlas.faces.get_mut() = all_faces;
        atlas.faces.write_buffer(&device, &queue);
    } else if atlas.faces.buffer().is_none() {
        atlas.faces.write_buffer(&device, &queue);
    }
}

/// Whether the box `lo..hi` may be visible through the clip volume of `clip_from_world` (wgpu depth
/// `0..1`): false when all eight corners lie outside one clip plane. Conservative, correct for corners
/// behind a perspective eye.
pub fn frustum_overlaps(clip_from_world: Mat4, lo: Vec3, hi: Vec3) -> bool {
    let corners: [Vec4; 8] = std::array::from_fn(|i| {
        let p = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        clip_from_world * p.extend(1.0)
    });
    let planes: [fn(Vec4) -> f32; 6] = [
        |c| c.w + c.x,
        |c| c.w - c.x,
        |c| c.w + c.y,
        |c| c.w - c.y,
        |c| c.z,
        |c| c.w - c.z,
    ];
    !planes.iter().any(|plane| corners.iter().all(|&c| plane(c) < 0.0))
}

/// Draws the RSM faces that changed, once per frame and before any camera renders (the `RenderGraph`
/// schedule), and only while a method reads RSMs ([`RsmFocus::needed`]); until then the changed
/// faces stay pending.
pub(crate) fn draw_rsm(
    mut atlas: ResMut<RsmAtlas>,
    rsm_pipeline: Res<RsmPipeline>,
    pipeline_cache: Res<PipelineCache>,
    focus: Res<RsmFocus>,
    geometry: Res<ExtractedGiGeometry>,
    mut ctx: RenderContext,
) {
    if !focus.needed() || atlas.dirty_faces.is_empty() {
        return;
    }
    let (Some(pipeline), Some(uniforms)) =
        (pipeline_cache.get_render_pipeline(rsm_pipeline.pipeline), atlas.face_uniforms.binding())
    else {
        return;
    };
    let bind_group = ctx.render_device().create_bind_group(
        "diffuse_gi_rsm_bind_group",
        &pipeline_cache.get_bind_group_layout(&rsm_pipeline.layout),
        &BindGroupEntries::single(uniforms),
    );
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let span = diagnostics.time_span(ctx.command_encoder(), "diffuse_gi/rsm");
    draw_dirty_faces(&mut atlas, &geometry.moving, pipeline, &bind_group, ctx.command_encoder());
    span.end(ctx.command_encoder());
}

/// Renders the faces `prepare_rsm` marked dirty and records what they now show; the composites draw
/// the `moving` instances over their static layers. Returns whether anything was drawn.
pub(crate) fn draw_dirty_faces(
    atlas: &mut RsmAtlas,
    moving: &[extract::MovingRange],
    pipeline: &RenderPipeline,
    bind_group: &BindGroup,
    encoder: &mut CommandEncoder,
) -> bool {
    let dirty = std::mem::take(&mut atlas.dirty_faces);
    if dirty.is_empty() {
        return false;
    }
    for slot in &mut atlas.slots {
        slot.drawn = Some(slot.current.clone());
        slot.stale_faces = 0;
    }
    atlas.version += 1;
    let Some(vertices) = atlas.vertices.as_ref() else {
        // No geometry: the faces are cleared.
        for face in &dirty {
            let targets = [&atlas.position, &atlas.normal, &atlas.flux, &atlas.depth].map(|t| RsmAtlas::layer_view(t, face.layer));
            draw_face(encoder, &targets, Pass::Atlas, pipeline, bind_group, face, None, &[]);
        }
        return true;
    };
    let everything = [(0, atlas.vertex_count)];
    let moving: Vec<(u32, u32)> = moving.iter().map(|m| (m.first, m.count)).collect();
    let still = still_ranges(&moving, atlas.vertex_count);
    for face in &dirty {
        let targets = [&atlas.position, &atlas.normal, &atlas.flux, &atlas.depth].map(|t| RsmAtlas::layer_view(t, face.layer));
        let FaceMode::Composite { rebuild } = &face.mode else {
            draw_face(encoder, &targets, Pass::Atlas, pipeline, bind_group, face, Some(vertices), &everything);
            continue;
        };
        let Some(layers) = atlas.static_layers.as_mut() else {
            draw_face(encoder, &targets, Pass::Atlas, pipeline, bind_group, face, Some(vertices), &everything);
            continue;
        };
        let textures = [&layers.position, &layers.normal, &layers.flux, &layers.depth];
        if let Some(key) = rebuild {
            let static_targets = textures.map(|t| RsmAtlas::layer_view(t, face.layer));
            draw_face(encoder, &static_targets, Pass::Static, pipeline, bind_group, face, Some(vertices), &still);
            layers.keys[face.layer as usize] = Some(**key);
        }
        // The static layer (every texel, so that the depth copy covers whole subresources), then the
        // moving instances over it.
        let atlas_textures = [&atlas.position, &atlas.normal, &atlas.flux, &atlas.depth];
        for (from, to) in textures.into_iter().zip(atlas_textures) {
            let origin = Origin3d { x: 0, y: 0, z: face.layer };
            encoder.copy_texture_to_texture(
                TexelCopyTextureInfo { texture: from, mip_level: 0, origin, aspect: TextureAspect::All },
                TexelCopyTextureInfo { texture: to, mip_level: 0, origin, aspect: TextureAspect::All },
                Extent3d { width: atlas.size, height: atlas.size, depth_or_array_layers: 1 },
            );
        }
        draw_face(encoder, &targets, Pass::Over, pipeline, bind_group, face, Some(vertices), &moving);
    }
    true
}

/// The vertex ranges `(first, count)` of `0..count` outside `moving` (sorted, disjoint).
fn still_ranges(moving: &[(u32, u32)], count: u32) -> Vec<(u32, u32)> {
    let mut still = Vec::with_capacity(moving.len() + 1);
    let mut at = 0;
    for &(first, n) in moving {
        let first = first.min(count);
        if first > at {
            still.push((at, first - at));
        }
        at = at.max(first.saturating_add(n).min(count));
    }
    if count > at {
        still.push((at, count - at));
    }
    still
}

/// How [`draw_face`] treats what its targets held.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Pass {
    /// Clear the atlas's layer first (its depth is not kept).
    Atlas,
    /// Clear a static layer first and keep its depth for the composites that copy it.
    Static,
    /// Draw over the atlas's layer and the depth copied into it.
    Over,
}

/// One render pass into one face's layer of `targets` (position, normal, flux, depth), drawing
/// `ranges` of `vertices`.
#[allow(clippy::too_many_arguments)]
fn draw_face(
    encoder: &mut CommandEncoder,
    targets: &[TextureView; 4],
    pass_kind: Pass,
    pipeline: &RenderPipeline,
    bind_group: &BindGroup,
    face: &FaceDraw,
    vertices: Option<&Buffer>,
    ranges: &[(u32, u32)],
) {
    let colour = |view| {
        Some(RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: Operations {
                load: if pass_kind == Pass::Over { LoadOp::Load } else { LoadOp::Clear(default()) },
                store: StoreOp::Store,
            },
        })
    };
    let mut pass = encoder.begin_render_pass(&RenderPassDescriptor {
        label: Some("diffuse_gi_rsm"),
        color_attachments: &[colour(&targets[0]), colour(&targets[1]), colour(&targets[2])],
        depth_stencil_attachment: Some(RenderPassDepthStencilAttachment {
            view: &targets[3],
            depth_ops: Some(Operations {
                load: if pass_kind == Pass::Over { LoadOp::Load } else { LoadOp::Clear(1.0) },
                store: if pass_kind == Pass::Static { StoreOp::Store } else { StoreOp::Discard },
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    let Some(vertices) = vertices else {
        return;
    };
    pass.set_viewport(0.0, 0.0, face.resolution as f32, face.resolution as f32, 0.0, 1.0);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind_group, &[face.offset]);
    pass.set_vertex_buffer(0, *vertices.slice(..));
    for &(first, count) in ranges.iter().filter(|r| r.1 > 0) {
        pass.draw(first..first + count, 0..1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bounds() -> (Vec3, Vec3) {
        (Vec3::splat(-1.0), Vec3::splat(1.0))
    }

    #[test]
    fn the_still_ranges_are_every_vertex_outside_the_moving_ones() {
        assert_eq!(still_ranges(&[], 30), vec![(0, 30)]);
        assert_eq!(still_ranges(&[(0, 30)], 30), vec![]);
        assert_eq!(still_ranges(&[(3, 6), (12, 3)], 30), vec![(0, 3), (9, 3), (15, 15)]);
        assert_eq!(still_ranges(&[(0, 6), (24, 6)], 30), vec![(6, 18)]);
        // Ranges past the buffer (a stale set) are cut to it.
        assert_eq!(still_ranges(&[(27, 9)], 30), vec![(0, 27)]);
        assert_eq!(still_ranges(&[(40, 3)], 30), vec![(0, 30)]);
        // Together with the moving ranges they cover every vertex once.
        let moving = [(3, 6), (9, 3), (21, 3)];
        let mut covered = vec![0; 30];
        for (first, count) in moving.iter().chain(&still_ranges(&moving, 30)) {
            for v in *first..first + count {
                covered[v as usize] += 1;
            }
        }
        assert!(covered.iter().all(|&c| c == 1), "{covered:?}");
    }

    #[test]
    fn spot_face_sees_its_cone_and_stores_texel_solid_angle() {
        let (scale, offset) = SnapshotLight::spot_scale_offset(0.5, 0.5);
        let light = SnapshotLight::Spot {
            position: Vec3::new(0.0, 0.98, 0.0),
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(100.0),
            inverse_range_squared: 0.0,
            spot_scale: scale,
            spot_offset: offset,
        };
        let f = light_faces(&light, 256, bounds(), None);
        assert_eq!(f.faces.len(), 1);
        // The floor point straight below projects to the centre of the face.
        let clip = f.faces[0].clip_from_world * Vec4::new(0.0, -1.0, 0.0, 1.0);
        let ndc = clip.truncate() / clip.w;
        assert!(ndc.x.abs() < 1e-4 && ndc.y.abs() < 1e-4 && (0.0..1.0).contains(&ndc.z), "{ndc}");
        // Texel solid angle at the centre: (2 tan 0.5 / 256)².
        let omega = (2.0 * 0.5f32.tan() / 256.0).powi(2);
        assert!((f.faces[0].params.w - omega).abs() < 1e-9);
        assert!((f.flux_scale - 100.0 * omega).abs() < 1e-6);
    }

    #[test]
    fn an_intensity_change_alone_changes_the_flux_scale_the_faces_are_keyed_by() {
        let (scale, offset) = SnapshotLight::spot_scale_offset(0.5, 0.5);
        let spot = |candela: f32| SnapshotLight::Spot {
            position: Vec3::new(0.0, 0.98, 0.0),
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(candela),
            inverse_range_squared: 0.0,
            spot_scale: scale,
            spot_offset: offset,
        };
        let (a, b) = (light_faces(&spot(100.0), 256, bounds(), None), light_faces(&spot(200.0), 256, bounds(), None));
        // The faces store the colour normalised by its largest channel: identical for both…
        assert_eq!(a.faces, b.faces);
        // …so the slot key must carry the flux scale, which doubles (prepare_rsm keys faces by its bits).
        assert!((b.flux_scale / a.flux_scale - 2.0).abs() < 1e-6);
        assert_ne!(a.flux_scale.to_bits(), b.flux_scale.to_bits());
    }

    #[test]
    fn point_lights_and_wide_spots_use_six_faces() {
        let point = SnapshotLight::Point {
            position: Vec3::ZERO,
            intensity: Vec3::ONE,
            inverse_range_squared: 0.0,
        };
        assert_eq!(light_faces(&point, 64, bounds(), None).faces.len(), 6);
        let (scale, offset) = SnapshotLight::spot_scale_offset(1.2, 1.4);
        let wide = SnapshotLight::Spot {
            position: Vec3::ZERO,
            direction: Vec3::X,
            intensity: Vec3::ONE,
            inverse_range_squared: 0.0,
            spot_scale: scale,
            spot_offset: offset,
        };
        assert_eq!(light_faces(&wide, 64, bounds(), None).faces.len(), 6);
    }

    #[test]
    fn directional_face_covers_the_focus_and_keeps_occluders() {
        let light = SnapshotLight::Directional {
            direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            illuminance: Vec3::new(1000.0, 900.0, 800.0),
        };
        let scene = (Vec3::new(-10.0, -1.0, -10.0), Vec3::new(10.0, 20.0, 10.0));
        let focus = (Vec3::splat(-2.0), Vec3::splat(2.0));
        let f = light_faces(&light, 128, scene, Some(focus));
        let m = f.faces[0].clip_from_world;
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { -2.0 } else { 2.0 },
                if i & 2 == 0 { -2.0 } else { 2.0 },
                if i & 4 == 0 { -2.0 } else { 2.0 },
            );
            let p = m.project_point3(c);
            assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0 && (0.0..=1.0).contains(&p.z), "{c} -> {p}");
        }
        // The top of the scene, above the focus, is still in front of the near plane.
        let p = m.project_point3(Vec3::new(0.0, 20.0, 0.0));
        assert!(p.z >= 0.0, "{p}");
        assert!((f.faces[0].color.x - 1.0).abs() < 1e-6 && (f.faces[0].color.z - 0.8).abs() < 1e-6);
    }
}
