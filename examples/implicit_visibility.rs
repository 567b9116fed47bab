//! Implicit-visibility radiosity (Dong et al. 2007) on the Cornell box with a deforming mesh: a white
//! banner waving under the spot light. Its vertices are rewritten every frame, so the radiosity solver
//! re-makes the banner's elements (only the banner's), rebuilds the links and relights: the light it
//! bounces onto the walls and the shadow it casts in bounced light follow it.
//!
//! `cargo run --release --features tools --example implicit_visibility [-- --scene NAME|PATH.glb]`
//!
//! Keys: G bounced light on/off, M or 1–6 the method, P the preset of every method, V the debug view, H
//! half resolution, L the lights' motion, B the banner's motion, C orbit ↔ fly camera, F1 the tuning panel
//! ("Diffuse GI": the radiosity settings and what each solve did, per stage).
//! Orbit: left drag turns, right drag pans, the wheel zooms; fly: W A S D Q E, right drag looks.
//!
//! Without a display (no `DISPLAY` or `WAYLAND_DISPLAY`) it renders one frame headless on whatever Vulkan
//! device exists and writes `out/implicit_visibility.png` instead.

#[path = "common/mod.rs"]
mod common;
#[path = "common/app.rs"]
mod app;

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;

/// Quads along each side of the banner.
const CELLS: usize = 16;
/// The banner's side, metres.
const SIZE: f32 = 0.9;

#[derive(Component)]
struct Banner;

/// Whether the banner waves (B toggles it) and its clock, seconds.
#[derive(Resource)]
struct Waving(bool, f32);

fn main() -> AppExit {
    app::run(
        app::ExampleSpec {
            tool: "implicit_visibility",
            title: "Implicit-visibility radiosity",
            scene: "cornell",
            method: GiMethod::Radiosity,
            light_motion: false,
            extra_help: &["B: the banner waves / stops"],
            ci: app::CiMode::OwnMethod,
        },
        |app| {
            app.insert_resource(Waving(true, 0.0)).add_systems(Startup, spawn_banner).add_systems(Update, wave);
        },
    )
}

/// The banner's vertex positions at time `t`: a vertical sheet at the box's centre, with a travelling
/// wave across it.
fn banner_positions(t: f32) -> Vec<[f32; 3]> {
    let mut positions = Vec::with_capacity((CELLS + 1) * (CELLS + 1));
    for j in 0..=CELLS {
        for i in 0..=CELLS {
            let (u, v) = (i as f32 / CELLS as f32, j as f32 / CELLS as f32);
            let x = (u - 0.5) * SIZE;
            let y = 0.35 - v * SIZE;
            let z = 0.15 * u * (u * 6.0 - t * 2.0).sin();
            positions.push([x, y, z]);
        }
    }
    positions
}

fn banner_mesh(t: f32) -> Mesh {
    let mut indices = Vec::new();
    let row = (CELLS + 1) as u32;
    for j in 0..CELLS as u32 {
        for i in 0..CELLS as u32 {
            let a = j * row + i;
            indices.extend_from_slice(&[a, a + row, a + 1, a + 1, a + row, a + row + 1]);
        }
    }
    let mut mesh = Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::default())
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, banner_positions(t))
        .with_inserted_indices(Indices::U32(indices));
    mesh.compute_smooth_normals();
    mesh
}

fn spawn_banner(mut commands: Commands, mut meshes: ResMut<Assets<Mesh>>, mut materials: ResMut<Assets<StandardMaterial>>) {
    commands.spawn((
        Mesh3d(meshes.add(banner_mesh(0.0))),
        MeshMaterial3d(materials.add(StandardMaterial {
            base_color: Color::linear_rgb(0.8, 0.75, 0.3),
            perceptual_roughness: 1.0,
            reflectance: 0.0,
            double_sided: true,
            cull_mode: None,
            ..default()
        })),
        Banner,
        Name::new("banner"),
    ));
}

fn wave(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    mut waving: ResMut<Waving>,
    banners: Query<&Mesh3d, With<Banner>>,
    mut meshes: ResMut<Assets<Mesh>>,
) {
    if keys.just_pressed(KeyCode::KeyB) {
        waving.0 = !waving.0;
    }
    if !waving.0 {
        return;
    }
    waving.1 += time.delta_secs();
    for handle in &banners {
        if let Some(mut mesh) = meshes.get_mut(&handle.0) {
            *mesh = banner_mesh(waving.1);
        }
    }
}
