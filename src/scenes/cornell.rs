//! `cornell`: the Cornell box with a spot light, exactly as `shared/SCENES.md` specifies it.

use bevy::camera::Exposure;
use bevy::prelude::*;

use super::SceneCamera;
use crate::light::GiLight;

/// Linear diffuse reflectance of the white surfaces (floor, ceiling, back wall, both boxes).
pub const WHITE: Vec3 = Vec3::new(0.885809, 0.698859, 0.666422);
/// Linear diffuse reflectance of the left wall (x = −1).
pub const RED: Vec3 = Vec3::new(0.570068, 0.0430135, 0.0443706);
/// Linear diffuse reflectance of the right wall (x = +1).
pub const GREEN: Vec3 = Vec3::new(0.105421, 0.37798, 0.076425);
/// Camera exposure: `Exposure { ev100: 0.0 }`, a multiplier of 1/1.2.
pub const CORNELL_EV100: f32 = 0.0;
/// Vertical field of view in degrees.
pub const FOV_Y_DEGREES: f32 = 39.3077;
/// Camera position; it looks at the origin with +Y up.
pub const CAMERA_POSITION: Vec3 = Vec3::new(0.0, 0.0, 3.9);
/// Spot light position; it points straight down.
pub const LIGHT_POSITION: Vec3 = Vec3::new(0.0, 0.98, 0.0);
/// Spot light luminous intensity in candela (Bevy intensity = 4π × this, in lumens).
pub const LIGHT_CANDELA: f32 = 100.0;
/// Spot cone half-angle in degrees (inner = outer: a hard edge).
pub const LIGHT_CONE_DEGREES: f32 = 30.0;

/// The two boxes as 3×4 affine matrices (rows; last column = translation) applied to the cube [-1, 1]³.
pub const SMALL_BOX: [[f32; 4]; 3] = [
    [0.286891, 0.0, -0.0877115, 0.335],
    [0.0, 0.3, 0.0, -0.7],
    [0.0877115, 0.0, 0.286891, 0.38],
];
/// See [`SMALL_BOX`].
pub const LARGE_BOX: [[f32; 4]; 3] = [
    [0.28491, 0.0, 0.0939491, -0.33],
    [0.0, 0.61, 0.0, -0.4],
    [-0.0939491, 0.0, 0.28491, -0.28],
];

/// A `Transform` from a 3×4 row-major affine matrix.
pub fn transform_from_rows(rows: [[f32; 4]; 3]) -> Transform {
    let m = Mat4::from_cols(
        Vec4::new(rows[0][0], rows[1][0], rows[2][0], 0.0),
        Vec4::new(rows[0][1], rows[1][1], rows[2][1], 0.0),
        Vec4::new(rows[0][2], rows[1][2], rows[2][2], 0.0),
        Vec4::new(rows[0][3], rows[1][3], rows[2][3], 1.0),
    );
    Transform::from_matrix(m)
}

/// A purely diffuse material: roughness 1, no metal, no specular reflectance.
pub fn diffuse_material(rgb: Vec3) -> StandardMaterial {
    StandardMaterial {
        base_color: Color::linear_rgb(rgb.x, rgb.y, rgb.z),
        perceptual_roughness: 1.0,
        metallic: 0.0,
        reflectance: 0.0,
        ..default()
    }
}

/// Spawns the box, the two blocks, the spot light (with a [`GiLight`]) and the [`SceneCamera`].
pub fn spawn_cornell(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    ev100: f32,
) {
    spawn_cornell_geometry(commands, meshes, materials);
    commands.spawn((cornell_spot_light(), GiLight::default(), Name::new("spot light")));
    commands.spawn((cornell_camera(ev100), SceneCamera, Name::new("cornell camera")));
}

/// The spot light of `cornell` (without a [`GiLight`]): 100 cd at (0, 0.98, 0), pointing down, 30° hard cone.
pub fn cornell_spot_light() -> (SpotLight, Transform) {
    let cone = LIGHT_CONE_DEGREES.to_radians();
    (
        SpotLight {
            color: Color::WHITE,
            intensity: 4.0 * std::f32::consts::PI * LIGHT_CANDELA,
            shadow_maps_enabled: true,
            inner_angle: cone,
            outer_angle: cone,
            ..default()
        },
        Transform::from_translation(LIGHT_POSITION).looking_to(Vec3::NEG_Y, Vec3::Z),
    )
}

/// The camera of `cornell` (a plain `Camera3d` with its projection, transform and exposure).
pub fn cornell_camera(ev100: f32) -> impl Bundle {
    (
        Camera3d::default(),
        Projection::Perspective(PerspectiveProjection {
            fov: FOV_Y_DEGREES.to_radians(),
            ..default()
        }),
        Transform::from_translation(CAMERA_POSITION).looking_at(Vec3::ZERO, Vec3::Y),
        Exposure { ev100 },
    )
}

/// Spawns the box and the two blocks (no light, no camera).
pub fn spawn_cornell_geometry(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
) {
    let white = materials.add(diffuse_material(WHITE));
    let red = materials.add(diffuse_material(RED));
    let green = materials.add(diffuse_material(GREEN));

    // Five inward-facing 2×2 quads.
    let walls = [
        (Vec3::Y, Vec3::new(0.0, -1.0, 0.0), &white, "floor"),
        (Vec3::NEG_Y, Vec3::new(0.0, 1.0, 0.0), &white, "ceiling"),
        (Vec3::Z, Vec3::new(0.0, 0.0, -1.0), &white, "back wall"),
        (Vec3::X, Vec3::new(-1.0, 0.0, 0.0), &red, "left wall"),
        (Vec3::NEG_X, Vec3::new(1.0, 0.0, 0.0), &green, "right wall"),
    ];
    for (normal, position, material, name) in walls {
        let normal = Dir3::new(normal).expect("unit axis");
        commands.spawn((
            Mesh3d(meshes.add(Plane3d::new(*normal, Vec2::ONE))),
            MeshMaterial3d(material.clone()),
            Transform::from_translation(position),
            Name::new(name),
        ));
    }
    let cube = meshes.add(Cuboid::new(2.0, 2.0, 2.0));
    for (rows, name) in [(SMALL_BOX, "small box"), (LARGE_BOX, "large box")] {
        commands.spawn((
            Mesh3d(cube.clone()),
            MeshMaterial3d(white.clone()),
            transform_from_rows(rows),
            Name::new(name),
        ));
    }

}

/// The scene as a [`SceneSnapshot`](crate::scene::SceneSnapshot), built on the CPU from the same meshes,
/// materials and light as [`spawn_cornell`] (for tests and the CPU models of the GI methods).
pub fn cornell_snapshot() -> crate::scene::SceneSnapshot {
    use crate::scene::{SceneSnapshot, SnapshotLight, SnapshotLightEntry, SnapshotMaterial, extract::material_from_standard, mesh_triangles};
    let materials: Vec<SnapshotMaterial> =
        [WHITE, RED, GREEN].iter().map(|c| material_from_standard(&diffuse_material(*c))).collect();
    let mut triangles = Vec::new();
    let walls = [
        (Vec3::Y, Vec3::new(0.0, -1.0, 0.0), 0),
        (Vec3::NEG_Y, Vec3::new(0.0, 1.0, 0.0), 0),
        (Vec3::Z, Vec3::new(0.0, 0.0, -1.0), 0),
        (Vec3::X, Vec3::new(-1.0, 0.0, 0.0), 1),
        (Vec3::NEG_X, Vec3::new(1.0, 0.0, 0.0), 2),
    ];
    for (normal, position, material) in walls {
        let mesh = Mesh::from(Plane3d::new(normal, Vec2::ONE));
        let transform = GlobalTransform::from(Transform::from_translation(position));
        triangles.extend(mesh_triangles(&mesh, &transform, material).expect("CPU mesh"));
    }
    let cube = Mesh::from(Cuboid::new(2.0, 2.0, 2.0));
    for rows in [SMALL_BOX, LARGE_BOX] {
        let transform = GlobalTransform::from(transform_from_rows(rows));
        triangles.extend(mesh_triangles(&cube, &transform, 0).expect("CPU mesh"));
    }
    let cone = LIGHT_CONE_DEGREES.to_radians();
    let (spot_scale, spot_offset) = SnapshotLight::spot_scale_offset(cone, cone);
    let light = SnapshotLightEntry {
        entity: Entity::PLACEHOLDER,
        light: SnapshotLight::Spot {
            position: LIGHT_POSITION,
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(LIGHT_CANDELA),
            // Bevy's default spot range, 20 m.
            inverse_range_squared: 1.0 / 400.0,
            spot_scale,
            spot_offset,
        },
        shadows_enabled: true,
    };
    SceneSnapshot::build(triangles, materials, vec![], vec![light])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_snapshot_has_the_scene() {
        let s = cornell_snapshot();
        // Five quads and two boxes.
        assert_eq!(s.triangle_count(), 5 * 2 + 2 * 12);
        let (lo, hi) = s.bounds().unwrap();
        // The large box's base sits 1 cm below the floor (y = −0.4 − 0.61), as in the Mitsuba layout.
        assert!((lo - Vec3::new(-1.0, -1.01, -1.0)).abs().max_element() < 1e-5, "{lo}");
        assert!((hi - Vec3::ONE).abs().max_element() < 1e-5, "{hi}");
        assert_eq!(s.lights.len(), 1);
    }

    #[test]
    fn box_matrices_decompose_exactly() {
        for rows in [SMALL_BOX, LARGE_BOX] {
            let t = transform_from_rows(rows);
            let m = t.to_matrix();
            for r in 0..3 {
                for c in 0..4 {
                    assert!((m.col(c)[r] - rows[r][c]).abs() < 1e-5, "row {r} col {c}");
                }
            }
        }
    }
}
