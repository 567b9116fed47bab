//! `dynamic`: a 6 × 3 × 5 m room with ten objects moving through it and a point light orbiting under the
//! ceiling, all on fixed paths parameterised by a frame number ([`dynamic_pose`]), so that the tracer can
//! render the ground truth of any frame's pose. Tests what motion costs and how the bounced light keeps up.
//!
//! Interior: x ∈ [−3, 3], y ∈ [0, 3], z ∈ [−2.5, 2.5] metres, 20 cm walls; the wall at x = −3 is red, the
//! one at z = −2.5 green. Object 0 is a 1 280-triangle sphere, objects 1–9 are boxes. With
//! [`DynamicScene::extra_triangles`], static spheres along the back wall bring the scene to that many
//! triangles (the "one moving mesh in a big scene" case).
//!
//! Animation: [`DynamicScene`] holds the clock; [`animate_dynamic_scene`] (in `Update`, added by
//! [`super::StandardScenesPlugin`]) poses the objects and the light from it every frame, and advances it
//! while `animate_light` or `moving_meshes` ask for motion.

use bevy::camera::Exposure;
use bevy::prelude::*;

use super::SceneCamera;
use crate::light::GiLight;

pub const WALL: Vec3 = Vec3::new(0.72, 0.72, 0.7);
pub const FLOOR: Vec3 = Vec3::new(0.5, 0.46, 0.42);
pub const RED: Vec3 = Vec3::new(0.7, 0.12, 0.1);
pub const GREEN: Vec3 = Vec3::new(0.12, 0.6, 0.15);
pub const OBJECT_COLORS: [Vec3; 3] = [Vec3::new(0.75, 0.7, 0.2), Vec3::new(0.2, 0.35, 0.75), Vec3::new(0.8, 0.8, 0.8)];
/// Exposure of the scene.
pub const DYNAMIC_EV100: f32 = 4.0;
/// Point light luminous intensity, candela.
pub const LIGHT_CANDELA: f32 = 250.0;
/// Moving objects.
pub const OBJECTS: usize = 10;
pub const CAMERA_POSITION: Vec3 = Vec3::new(2.7, 1.8, 2.2);
pub const CAMERA_TARGET: Vec3 = Vec3::new(-1.0, 0.7, -1.0);
/// Frames of one orbit of the light.
pub const LIGHT_PERIOD: f32 = 240.0;
/// Frames of one lap of object 0 (the others are a little slower).
pub const OBJECT_PERIOD: f32 = 300.0;

const T: f32 = 0.2;

/// Where everything is at frame `frame`.
#[derive(Clone, Debug, PartialEq)]
pub struct DynamicPose {
    pub light: Vec3,
    /// Centre of each moving object.
    pub objects: [Vec3; OBJECTS],
}

/// The pose at `frame` of the light (a 1.8 m circle 2.5 m up) and the objects (ellipses over the floor,
/// each with its own radius, phase and speed, bobbing a little).
pub fn dynamic_pose(frame: f32) -> DynamicPose {
    let a = frame / LIGHT_PERIOD * std::f32::consts::TAU;
    let light = Vec3::new(1.8 * a.cos(), 2.5, 1.4 * a.sin());
    let objects = std::array::from_fn(|i| {
        let k = i as f32;
        let speed = 1.0 / (1.0 + 0.08 * k);
        let phase = k / OBJECTS as f32 * std::f32::consts::TAU;
        let b = frame / OBJECT_PERIOD * std::f32::consts::TAU * speed + phase;
        let r = 0.55 + 0.045 * k;
        Vec3::new(2.3 * r * b.cos(), 0.35 + 0.25 * (0.5 + 0.5 * (2.0 * b).sin()) * (k % 3.0) / 2.0, 1.8 * r * b.sin())
    });
    DynamicPose { light, objects }
}

/// The animation clock and what moves.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct DynamicScene {
    /// The pose frame now.
    pub frame: f32,
    /// Orbit the light.
    pub animate_light: bool,
    /// How many objects move (0–10, from object 0).
    pub moving_meshes: usize,
    /// Stop the clock at this frame (the motion stops; the scene stays in that pose).
    pub stop_at: Option<f32>,
    /// Static triangles added along the back wall.
    pub extra_triangles: u32,
    /// Hold the clock (the pose stays).
    pub paused: bool,
}

/// Triangles of `Sphere::mesh().ico(level)`: `20 (level + 1)²` (each face split `level + 1` times per edge).
pub fn ico_triangles(level: u32) -> u32 {
    20 * (level + 1) * (level + 1)
}

/// Triangles of the room, its objects and about `extra` static ones, as [`spawn_dynamic`] builds them.
pub fn dynamic_triangles(extra: u32) -> u32 {
    let room = dynamic_room().len() as u32 * 12 + ico_triangles(7) + (OBJECTS as u32 - 1) * 12;
    if extra == 0 {
        return room;
    }
    let per = ico_triangles(if extra < 20_480 { 6 } else { 31 });
    room + (extra as f32 / per as f32).round().max(1.0) as u32 * per
}

/// Marks a moving object of the dynamic scene.
#[derive(Component, Clone, Copy, Debug)]
pub struct DynamicObject(pub usize);

/// Marks the orbiting light.
#[derive(Component, Clone, Copy, Debug)]
pub struct DynamicLight;

/// The static boxes: (min, max corner, material index 0 wall, 1 floor, 2 red, 3 green).
pub fn dynamic_room() -> Vec<(Vec3, Vec3, usize)> {
    vec![
        (Vec3::new(-3.0 - T, -T, -2.5 - T), Vec3::new(3.0 + T, 0.0, 2.5 + T), 1),
        (Vec3::new(-3.0 - T, 3.0, -2.5 - T), Vec3::new(3.0 + T, 3.0 + T, 2.5 + T), 0),
        (Vec3::new(-3.0 - T, 0.0, -2.5 - T), Vec3::new(-3.0, 3.0, 2.5 + T), 2),
        (Vec3::new(3.0, 0.0, -2.5 - T), Vec3::new(3.0 + T, 3.0, 2.5 + T), 0),
        (Vec3::new(-3.0, 0.0, -2.5 - T), Vec3::new(3.0, 3.0, -2.5), 3),
        (Vec3::new(-3.0, 0.0, 2.5), Vec3::new(3.0, 3.0, 2.5 + T), 0),
    ]
}

/// Spawns the room, the objects, the light and the [`SceneCamera`]. The clock is the [`DynamicScene`]
/// resource if the app inserted one (its `extra_triangles` are spawned too), a still default otherwise.
pub fn spawn_dynamic(commands: &mut Commands, meshes: &mut Assets<Mesh>, materials: &mut Assets<StandardMaterial>, ev100: f32) {
    super::spawn_boxes(commands, meshes, materials, &dynamic_room(), &[WALL, FLOOR, RED, GREEN], "dynamic");
    let pose = dynamic_pose(0.0);
    let colors: Vec<_> = OBJECT_COLORS.iter().map(|c| materials.add(super::cornell::diffuse_material(*c))).collect();
    let sphere = meshes.add(Sphere::new(0.3).mesh().ico(7).expect("ico sphere"));
    let cube = meshes.add(Cuboid::new(0.35, 0.35, 0.35));
    for (i, centre) in pose.objects.iter().enumerate() {
        commands.spawn((
            Mesh3d(if i == 0 { sphere.clone() } else { cube.clone() }),
            MeshMaterial3d(colors[i % colors.len()].clone()),
            Transform::from_translation(*centre),
            DynamicObject(i),
            Name::new(format!("dynamic object {i}")),
        ));
    }
    commands.queue(|world: &mut World| {
        let scene = world.get_resource_or_insert_with(DynamicScene::default).clone();
        // Static spheres along the back wall, of 980 triangles (ico 6) or 20 480 (ico 31) each.
        if scene.extra_triangles == 0 {
            return;
        }
        let level = if scene.extra_triangles < 20_480 { 6 } else { 31 };
        let per = ico_triangles(level);
        let count = (scene.extra_triangles as f32 / per as f32).round().max(1.0) as u32;
        let mesh = world.resource_mut::<Assets<Mesh>>().add(Sphere::new(0.1).mesh().ico(level).expect("ico sphere"));
        let grey = world.resource_mut::<Assets<StandardMaterial>>().add(super::cornell::diffuse_material(Vec3::splat(0.6)));
        for k in 0..count {
            let (column, row) = (k % 24, k / 24);
            world.spawn((
                Mesh3d(mesh.clone()),
                MeshMaterial3d(grey.clone()),
                Transform::from_xyz(-2.76 + column as f32 * 0.24, 0.1 + row as f32 * 0.22, -2.35),
                Name::new(format!("dynamic static sphere {k}")),
            ));
        }
    });
    commands.spawn((
        PointLight {
            color: Color::WHITE,
            intensity: 4.0 * std::f32::consts::PI * LIGHT_CANDELA,
            shadow_maps_enabled: true,
            range: 20.0,
            radius: 0.0,
            ..default()
        },
        Transform::from_translation(pose.light),
        GiLight::default(),
        DynamicLight,
        Name::new("dynamic light"),
    ));
    commands.spawn((
        Camera3d::default(),
        Projection::Perspective(PerspectiveProjection { fov: 75f32.to_radians(), ..default() }),
        Transform::from_translation(CAMERA_POSITION).looking_at(CAMERA_TARGET, Vec3::Y),
        Exposure { ev100 },
        SceneCamera,
        Name::new("dynamic camera"),
    ));
}

/// Poses the dynamic scene from its clock, then advances the clock while something moves.
pub fn animate_dynamic_scene(
    mut scene: ResMut<DynamicScene>,
    mut objects: Query<(&DynamicObject, &mut Transform), Without<DynamicLight>>,
    mut lights: Query<&mut Transform, With<DynamicLight>>,
) {
    let moving = !scene.paused && (scene.animate_light || scene.moving_meshes > 0);
    if moving && scene.stop_at.is_none_or(|stop| scene.frame < stop) {
        scene.frame += 1.0;
    } else if !scene.is_changed() {
        return;
    }
    let pose = dynamic_pose(scene.frame);
    let still = dynamic_pose(0.0);
    for (object, mut transform) in &mut objects {
        let at = if object.0 < scene.moving_meshes { pose.objects[object.0] } else { still.objects[object.0] };
        if transform.translation != at {
            transform.translation = at;
        }
    }
    let at = if scene.animate_light { pose.light } else { still.light };
    for mut transform in &mut lights {
        if transform.translation != at {
            transform.translation = at;
        }
    }
}
