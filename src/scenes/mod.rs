//! The standard scenes of `shared/SCENES.md`, built the same way for the examples, the tests, the headless
//! renderer and the ground-truth tracer.
//!
//! * [`StandardScene::Cornell`]: the Cornell box with a spot light (`cornell.rs`).
//! * [`StandardScene::Cellar`]: two rooms and a door, lit from one, seen from the other (`cellar.rs`).
//! * [`StandardScene::SponzaLike`]: a 12 m atrium with columns, sunlit through a roof opening
//!   (`sponza_like.rs`).
//! * [`StandardScene::EmissivePanel`]: the Cornell box lit only by a glowing ceiling panel
//!   (`emissive_panel.rs`).
//! * [`StandardScene::OpenField`]: a 60 m sunlit field with a few buildings (`open_field.rs`).
//! * [`StandardScene::SkyRoom`]: an 8 m room lit only by an environment map, through a roof opening
//!   and a door (`sky_room.rs`).
//! * [`StandardScene::NearLight`]: `cornell` with a block hung just below the light (`near_light.rs`).
//! * [`StandardScene::Dynamic`]: a room with ten moving objects and an orbiting light (`dynamic.rs`).
//! * [`StandardScene::Room`]: `room_SEED`, one of a seeded family of generated rooms no method was tuned
//!   on (`rooms.rs`).
//! * [`StandardScene::Gltf`]: any glTF 2.0 file, loaded through Bevy's glTF loader (meshes,
//!   `StandardMaterial`s, `KHR_lights_punctual` lights, the first camera). Bevy spawns glTF lights without
//!   shadows; here they get shadows on and a [`GiLight`], so that a wall blocks light in the game as it
//!   does in the tracer. Lights keep Bevy's glTF conversion: candela × 4π lumens for point and spot lights,
//!   lux for directional lights, and a 20 m range where the file gives none.
//!
//! Add [`StandardScenesPlugin`], call [`spawn_standard_scene`], and wait for [`SceneStatus::Ready`]. The
//! camera to render through carries [`SceneCamera`]; apps add their render target to it.

pub mod cellar;
pub mod cornell;
pub mod dynamic;
pub mod emissive_panel;
pub mod near_light;
pub mod open_field;
pub mod rooms;
pub mod sky_room;
pub mod sponza_like;

use std::path::{Path, PathBuf};

use bevy::asset::{LoadState, RecursiveDependencyLoadState};
use bevy::camera::Exposure;
use bevy::gltf::Gltf;
use bevy::light::GlobalAmbientLight;
use bevy::prelude::*;
use bevy::world_serialization::{WorldAssetRoot, WorldInstanceReady};

use crate::light::GiLight;

pub use cellar::{CELLAR_EV100, cellar_snapshot, spawn_cellar};
pub use cornell::{CORNELL_EV100, cornell_snapshot, spawn_cornell};
pub use dynamic::{DYNAMIC_EV100, DynamicScene, dynamic_pose, spawn_dynamic};
pub use emissive_panel::{EMISSIVE_PANEL_EV100, spawn_emissive_panel};
pub use near_light::{NEAR_LIGHT_EV100, spawn_near_light};
pub use open_field::{OPEN_FIELD_EV100, open_field_snapshot, spawn_open_field};
pub use rooms::{GeneratedRoom, ROOM_HELD_OUT_SEEDS, ROOM_TUNING_SEEDS, RoomLight};
pub use sky_room::{SKY_ROOM_EV100, sky_room_snapshot, spawn_sky_room};
pub use sponza_like::{SPONZA_EV100, spawn_sponza_like, sponza_like_snapshot};

/// A scene the crate knows how to build.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub enum StandardScene {
    /// The Cornell box with a spot light (`shared/SCENES.md`).
    Cornell,
    /// Two rooms joined by a door, a flashlight in one, the camera in the other: light leaking through
    /// walls.
    Cellar,
    /// A 12 m atrium with columns, lit only by the sun through a roof opening: mostly light that bounced
    /// twice or more.
    SponzaLike,
    /// A room with moving objects and an orbiting light, posed by a frame clock ([`DynamicScene`]).
    Dynamic,
    /// The Cornell box lit only by a glowing ceiling panel (an emissive material, no analytic light).
    EmissivePanel,
    /// A 60 m sunlit field with a few buildings: a large, sparse, open volume.
    OpenField,
    /// `cornell` with a white block hung just below the spot light: most of the light's map shows a
    /// small, brightly lit surface (Fig. 7 of the Direct Radiance Mapping paper).
    NearLight,
    /// An 8 × 6 × 3 m room lit only by the sky (an `EnvironmentMapLight`) through a roof opening and a
    /// door.
    SkyRoom,
    /// A generated room of the unseen-rooms family ([`GeneratedRoom`]), by seed: `room_7` or `room:7`.
    Room(u64),
    /// A glTF 2.0 file (`.glb` or `.gltf`).
    Gltf(PathBuf),
}

impl StandardScene {
    /// Names accepted by [`StandardScene::parse`] besides file paths.
    pub const NAMES: &'static [&'static str] =
        &["cornell", "cellar", "sponza_like", "dynamic", "emissive_panel", "open_field", "near_light", "sky_room"];

    /// A scene name, or a path to a `.glb`/`.gltf` file (which must exist).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "cornell" => Ok(Self::Cornell),
            "cellar" => Ok(Self::Cellar),
            "sponza_like" => Ok(Self::SponzaLike),
            "dynamic" => Ok(Self::Dynamic),
            "emissive_panel" => Ok(Self::EmissivePanel),
            "open_field" => Ok(Self::OpenField),
            "near_light" => Ok(Self::NearLight),
            "sky_room" => Ok(Self::SkyRoom),
            room if room.starts_with("room_") || room.starts_with("room:") => room[5..]
                .parse::<u64>()
                .map(Self::Room)
                .map_err(|_| format!("`{room}`: a generated room is `room_SEED` with SEED a whole number")),
            path if path.ends_with(".glb") || path.ends_with(".gltf") => {
                let p = Path::new(path);
                if !p.is_file() {
                    return Err(format!("scene file {path} does not exist"));
                }
                Ok(Self::Gltf(p.to_path_buf()))
            }
            other => Err(format!(
                "unknown scene `{other}`: expected one of {}, room_SEED or a path to a .glb/.gltf file",
                Self::NAMES.join(", ")
            )),
        }
    }

    /// A short name for reports.
    pub fn name(&self) -> String {
        match self {
            Self::Cornell => "cornell".into(),
            Self::Cellar => "cellar".into(),
            Self::SponzaLike => "sponza_like".into(),
            Self::Dynamic => "dynamic".into(),
            Self::EmissivePanel => "emissive_panel".into(),
            Self::OpenField => "open_field".into(),
            Self::NearLight => "near_light".into(),
            Self::SkyRoom => "sky_room".into(),
            Self::Room(seed) => format!("room_{seed}"),
            Self::Gltf(path) => path.display().to_string(),
        }
    }
}

/// Spawns `boxes` (min corner, max corner, index into `palette`) as cuboid meshes with diffuse
/// `StandardMaterial`s of the palette's linear reflectances, named `"{name} box {i}"`.
pub(crate) fn spawn_boxes(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    boxes: &[(Vec3, Vec3, usize)],
    palette: &[Vec3],
    name: &str,
) {
    let palette: Vec<_> = palette.iter().map(|c| materials.add(cornell::diffuse_material(*c))).collect();
    for (i, &(lo, hi, material)) in boxes.iter().enumerate() {
        commands.spawn((
            Mesh3d(meshes.add(Cuboid::from_corners(lo, hi))),
            MeshMaterial3d(palette[material].clone()),
            // `Cuboid` is centred on the origin: place it.
            Transform::from_translation((lo + hi) * 0.5),
            Name::new(format!("{name} box {i}")),
        ));
    }
}

/// The same boxes as [`spawn_boxes`], with `lights`, as a CPU [`SceneSnapshot`](crate::scene::SceneSnapshot).
pub(crate) fn boxes_snapshot(
    boxes: &[(Vec3, Vec3, usize)],
    palette: &[Vec3],
    lights: Vec<crate::scene::SnapshotLightEntry>,
) -> crate::scene::SceneSnapshot {
    use crate::scene::{SceneSnapshot, extract::material_from_standard, mesh_triangles};
    let materials = palette.iter().map(|c| material_from_standard(&cornell::diffuse_material(*c))).collect();
    let mut triangles = Vec::new();
    for &(lo, hi, material) in boxes {
        let mesh = Mesh::from(Cuboid::from_corners(lo, hi));
        let transform = GlobalTransform::from_translation((lo + hi) * 0.5);
        triangles.extend(mesh_triangles(&mesh, &transform, material as u32).expect("CPU mesh"));
    }
    SceneSnapshot::build(triangles, materials, vec![], lights)
}

/// The sun of [`spawn_sun`] as a [`SceneSnapshot`](crate::scene::SceneSnapshot) light, for the CPU
/// snapshots of the sunlit scenes.
pub(crate) fn sun_snapshot(direction: Vec3, lux: f32) -> crate::scene::SnapshotLightEntry {
    crate::scene::SnapshotLightEntry {
        entity: Entity::PLACEHOLDER,
        light: crate::scene::SnapshotLight::Directional {
            direction: GlobalTransform::from(sun_transform(direction)).forward().as_vec3(),
            illuminance: Vec3::splat(lux),
        },
        shadows_enabled: true,
    }
}

/// The transform of a directional light whose light travels along `direction` (any length).
pub(crate) fn sun_transform(direction: Vec3) -> Transform {
    Transform::IDENTITY.looking_to(direction.normalize(), Vec3::Z)
}

/// Spawns a shadowed sun of `lux` travelling along `direction`, with a [`GiLight`] and Bevy's shadow
/// cascades `cascades`, named "sun".
pub(crate) fn spawn_sun(commands: &mut Commands, direction: Vec3, lux: f32, cascades: bevy::light::CascadeShadowConfig) {
    commands.spawn((
        DirectionalLight {
            color: Color::WHITE,
            illuminance: lux,
            shadow_maps_enabled: true,
            ..default()
        },
        cascades,
        sun_transform(direction),
        GiLight::default(),
        Name::new("sun"),
    ));
}

/// Spawns the [`SceneCamera`] of a scene: a perspective camera at `position` looking at `target` (Y up)
/// with a vertical field of view of `fov_degrees` and exposure `ev100`.
pub(crate) fn spawn_scene_camera(commands: &mut Commands, position: Vec3, target: Vec3, fov_degrees: f32, ev100: f32, name: &str) {
    commands.spawn((
        Camera3d::default(),
        Projection::Perspective(PerspectiveProjection {
            fov: fov_degrees.to_radians(),
            ..default()
        }),
        Transform::from_translation(position).looking_at(target, Vec3::Y),
        Exposure { ev100 },
        SceneCamera,
        Name::new(name.to_string()),
    ));
}

/// The camera a standard scene is seen through. The scene gives it a transform, a projection and an
/// [`Exposure`]; the app adds its render target and settings.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct SceneCamera;

/// Where the scene set up by [`spawn_standard_scene`] stands.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub enum SceneStatus {
    /// No scene was asked for.
    #[default]
    None,
    /// Assets are loading.
    Loading,
    /// Everything is spawned and the [`SceneCamera`] exists.
    Ready,
    /// The scene cannot be built; the message names the problem.
    Failed(String),
}

/// A glTF file being loaded.
#[derive(Resource)]
struct PendingGltf {
    handle: Handle<Gltf>,
    path: PathBuf,
    spawned: bool,
    ev100: f32,
}

/// Finishes loading glTF scenes: picks the camera, turns shadows on and makes lights bounce.
pub struct StandardScenesPlugin;

impl Plugin for StandardScenesPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<SceneStatus>()
            .add_systems(Update, poll_gltf.run_if(resource_exists::<PendingGltf>))
            .add_systems(Update, dynamic::animate_dynamic_scene.run_if(resource_exists::<DynamicScene>))
            .add_observer(prepare_loaded_gltf);
    }
}

/// Spawns `scene`. `ev100` overrides the scene's exposure (cornell: [`CORNELL_EV100`]; glTF files, which
/// carry no exposure: 0). Sets the global ambient light to zero, as every measured scene does.
///
/// glTF paths are loaded through the asset server: relative paths are relative to the `AssetPlugin`'s
/// folder, so apps that load arbitrary files should give an absolute path (as the headless renderer does).
pub fn spawn_standard_scene(
    commands: &mut Commands,
    asset_server: &AssetServer,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    scene: &StandardScene,
    ev100: Option<f32>,
) {
    commands.insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    });
    match scene {
        StandardScene::Cornell => {
            spawn_cornell(commands, meshes, materials, ev100.unwrap_or(CORNELL_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::Cellar => {
            spawn_cellar(commands, meshes, materials, ev100.unwrap_or(CELLAR_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::SponzaLike => {
            spawn_sponza_like(commands, meshes, materials, ev100.unwrap_or(SPONZA_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::Dynamic => {
            spawn_dynamic(commands, meshes, materials, ev100.unwrap_or(DYNAMIC_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::EmissivePanel => {
            spawn_emissive_panel(commands, meshes, materials, ev100.unwrap_or(EMISSIVE_PANEL_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::OpenField => {
            spawn_open_field(commands, meshes, materials, ev100.unwrap_or(OPEN_FIELD_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::NearLight => {
            spawn_near_light(commands, meshes, materials, ev100.unwrap_or(NEAR_LIGHT_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::SkyRoom => {
            spawn_sky_room(commands, meshes, materials, ev100.unwrap_or(SKY_ROOM_EV100));
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::Room(seed) => {
            GeneratedRoom::new(*seed).spawn(commands, meshes, materials, ev100);
            commands.insert_resource(SceneStatus::Ready);
        }
        StandardScene::Gltf(path) => {
            let handle = asset_server.load::<Gltf>(path.clone());
            commands.insert_resource(PendingGltf {
                handle,
                path: path.clone(),
                spawned: false,
                ev100: ev100.unwrap_or(0.0),
            });
            commands.insert_resource(SceneStatus::Loading);
        }
    }
}

fn poll_gltf(
    mut commands: Commands,
    mut pending: ResMut<PendingGltf>,
    asset_server: Res<AssetServer>,
    gltfs: Res<Assets<Gltf>>,
) {
    if pending.spawned {
        return;
    }
    match asset_server.get_load_state(pending.handle.id()) {
        Some(LoadState::Failed(error)) => {
            commands.insert_resource(SceneStatus::Failed(format!(
                "cannot load glTF {}: {error}",
                pending.path.display()
            )));
            pending.spawned = true;
        }
        Some(LoadState::Loaded) => {
            // A texture or buffer that fails (a missing file, an image format this build cannot decode)
            // ends the wait at once, with the loader's message, which names the file.
            match asset_server.get_recursive_dependency_load_state(pending.handle.id()) {
                Some(RecursiveDependencyLoadState::Loaded) => {}
                Some(RecursiveDependencyLoadState::Failed(error)) => {
                    commands.insert_resource(SceneStatus::Failed(format!(
                        "cannot load glTF {}: a texture or buffer it uses failed: {error}",
                        pending.path.display()
                    )));
                    pending.spawned = true;
                    return;
                }
                _ => return,
            }
            let Some(gltf) = gltfs.get(pending.handle.id()) else {
                return;
            };
            let Some(scene) = gltf.default_scene.clone().or_else(|| gltf.scenes.first().cloned()) else {
                commands.insert_resource(SceneStatus::Failed(format!(
                    "glTF {} has no scene",
                    pending.path.display()
                )));
                pending.spawned = true;
                return;
            };
            commands.spawn((WorldAssetRoot(scene), GltfSceneRoot { ev100: pending.ev100 }));
            pending.spawned = true;
        }
        _ => {}
    }
}

/// The root entity of a loaded glTF scene.
#[derive(Component)]
struct GltfSceneRoot {
    ev100: f32,
}

type LightQuery<'a> = (
    Option<&'a mut DirectionalLight>,
    Option<&'a mut PointLight>,
    Option<&'a mut SpotLight>,
);

fn prepare_loaded_gltf(
    ready: On<WorldInstanceReady>,
    mut commands: Commands,
    roots: Query<&GltfSceneRoot>,
    children: Query<&Children>,
    mut cameras: Query<&mut Camera, With<Camera3d>>,
    mut lights: Query<LightQuery, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>>,
    aabbs: Query<(&bevy::camera::primitives::Aabb, &GlobalTransform)>,
) {
    let Ok(root) = roots.get(ready.entity) else {
        return;
    };
    let ev100 = root.ev100;
    let mut first_camera = None;
    for entity in children.iter_descendants_depth_first(ready.entity) {
        if let Ok(mut camera) = cameras.get_mut(entity) {
            if first_camera.is_none() {
                first_camera = Some(entity);
            } else {
                camera.is_active = false;
            }
        }
        if let Ok((directional, point, spot)) = lights.get_mut(entity) {
            if let Some(mut l) = directional {
                l.shadow_maps_enabled = true;
            }
            if let Some(mut l) = point {
                l.shadow_maps_enabled = true;
            }
            if let Some(mut l) = spot {
                l.shadow_maps_enabled = true;
            }
            commands.entity(entity).insert(GiLight::default());
        }
    }
    match first_camera {
        Some(camera) => {
            commands.entity(camera).insert((SceneCamera, Exposure { ev100 }));
        }
        None => {
            // No camera in the file: frame the scene's bounds from +Z.
            let mut lo = Vec3::splat(f32::INFINITY);
            let mut hi = Vec3::splat(f32::NEG_INFINITY);
            for entity in children.iter_descendants(ready.entity) {
                if let Ok((aabb, transform)) = aabbs.get(entity) {
                    for corner in [-1.0f32, 1.0] {
                        for c2 in [-1.0f32, 1.0] {
                            for c3 in [-1.0f32, 1.0] {
                                let local = Vec3::from(aabb.center)
                                    + Vec3::from(aabb.half_extents) * Vec3::new(corner, c2, c3);
                                let p = transform.transform_point(local);
                                lo = lo.min(p);
                                hi = hi.max(p);
                            }
                        }
                    }
                }
            }
            let (center, radius) = if lo.is_finite() && hi.is_finite() {
                ((lo + hi) * 0.5, ((hi - lo) * 0.5).length().max(0.1))
            } else {
                (Vec3::ZERO, 1.0)
            };
            let fov = 45f32.to_radians();
            let distance = radius / (0.5 * fov).sin();
            commands.spawn((
                Camera3d::default(),
                Projection::Perspective(PerspectiveProjection { fov, ..default() }),
                Transform::from_translation(center + Vec3::Z * distance).looking_at(center, Vec3::Y),
                Exposure { ev100 },
                SceneCamera,
            ));
        }
    }
    commands.insert_resource(SceneStatus::Ready);
}

/// World-space bounds of meshes from Bevy's `Aabb`s and transforms (e.g. to fit a GI volume to a scene).
pub fn mesh_bounds<'a>(
    meshes: impl IntoIterator<Item = (&'a bevy::camera::primitives::Aabb, &'a GlobalTransform)>,
) -> Option<(Vec3, Vec3)> {
    let mut bounds: Option<(Vec3, Vec3)> = None;
    for (aabb, transform) in meshes {
        for i in 0..8 {
            let sign = Vec3::new(
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { -1.0 } else { 1.0 },
            );
            let p = transform.transform_point(Vec3::from(aabb.center) + Vec3::from(aabb.half_extents) * sign);
            bounds = Some(bounds.map_or((p, p), |(lo, hi)| (lo.min(p), hi.max(p))));
        }
    }
    bounds
}
