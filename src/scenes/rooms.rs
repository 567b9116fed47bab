//! `room_SEED`: a seeded family of rooms that no constant of this crate was tuned on.
//!
//! The standard scenes are few and the methods' defaults were measured on them; a game's rooms are not
//! those. [`GeneratedRoom::new`] builds, from a seed, what a level designer might block out:
//!
//! * one to three rooms in a row along x, each 2–20 m long (at most 20 m in all), 2–12 m deep, with
//!   ceilings of 2.4–6 m; every wall, floor and ceiling is a box 5–30 cm thick;
//! * a door in every dividing wall, and at random windows in the outer walls and openings in the roof
//!   (to the black outside: light escapes through them);
//! * furniture: cabinets, tables on thin legs, and floor-to-ceiling columns;
//! * albedos from dark (0.05) to white (0.85), neutral or saturated, per room; a dividing wall is two half
//!   walls, each coloured like the room it faces, so a method that leaks light or colour through it shows;
//! * one light: a spot aimed at a wall or the floor, a point lamp under the ceiling, the sun through a roof
//!   opening, or a glowing ceiling panel (an emissive `StandardMaterial`, no analytic light);
//! * the camera in the lit room or, in most multi-room seeds, in a room next to it, looking at the door.
//!
//! The exposure is estimated from the light's flux and the surfaces it reaches, so that images of every
//! seed are in a similar range (the error metrics are relative: the exposure does not change them).
//! [`ROOM_TUNING_SEEDS`] are the seeds the methods may be looked at on; [`ROOM_HELD_OUT_SEEDS`] are kept out
//! of all tuning and reported separately (`docs/unseen_rooms.md`, `examples/unseen_rooms.rs`).

use std::f32::consts::PI;
use std::ops::Range;

use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg32;

use super::SceneCamera;
use crate::light::GiLight;

/// Seeds the methods may be inspected and tuned on.
pub const ROOM_TUNING_SEEDS: Range<u64> = 0..16;
/// Seeds kept out of every tuning decision: their numbers are reported apart from the tuning seeds'.
pub const ROOM_HELD_OUT_SEEDS: Range<u64> = 16..24;

/// An axis-aligned box: min corner, max corner, index into [`GeneratedRoom::palette`].
pub type RoomBox = (Vec3, Vec3, usize);

/// The light of a generated room.
#[derive(Clone, Debug, PartialEq)]
pub enum RoomLight {
    /// A shadowed spot light.
    Spot {
        position: Vec3,
        target: Vec3,
        /// Luminous intensity on the axis, candela.
        candela: f32,
        /// Outer cone half-angle, radians (the inner one is 0.7 of it).
        outer_angle: f32,
    },
    /// A shadowed point light.
    Point {
        position: Vec3,
        /// Luminous flux, lumens.
        lumens: f32,
    },
    /// The sun, through a roof opening.
    Sun {
        /// The direction the light travels (downwards).
        direction: Vec3,
        /// Illuminance on a surface facing the sun, lux.
        lux: f32,
    },
    /// A glowing box under the ceiling (black base colour, emissive radiance in cd/m²).
    Emissive { lo: Vec3, hi: Vec3, radiance: Vec3 },
}

impl RoomLight {
    /// A short name for reports.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Spot { .. } => "spot",
            Self::Point { .. } => "point",
            Self::Sun { .. } => "sun",
            Self::Emissive { .. } => "emissive",
        }
    }
}

/// An opening in the dividing wall at `x` (its middle plane), over `z0..z1` and up to `top`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Door {
    pub x: f32,
    pub z0: f32,
    pub z1: f32,
    pub top: f32,
}

/// One generated scene (see the module docs).
#[derive(Clone, Debug)]
pub struct GeneratedRoom {
    pub seed: u64,
    /// Walls, floor, ceiling and furniture.
    pub boxes: Vec<RoomBox>,
    /// Linear diffuse reflectances of the boxes.
    pub palette: Vec<Vec3>,
    pub light: RoomLight,
    /// The interiors (min, max corner) of the rooms, in order along x.
    pub rooms: Vec<(Vec3, Vec3)>,
    /// The furniture: kind (`cabinet`, `table`, `column`) and bounds.
    pub furniture: Vec<(&'static str, Vec3, Vec3)>,
    /// The doors, `doors[i]` between rooms `i` and `i + 1`.
    pub doors: Vec<Door>,
    /// The room the light is in, and the room the camera is in.
    pub lit_room: usize,
    pub camera_room: usize,
    pub wall_thickness: f32,
    pub camera_position: Vec3,
    pub camera_target: Vec3,
    pub fov_degrees: f32,
    pub ev100: f32,
}

/// `boxes` minus the axis-aligned `hole`: up to six boxes around it per box it cuts.
fn subtract(boxes: Vec<RoomBox>, hole: (Vec3, Vec3)) -> Vec<RoomBox> {
    let mut out = Vec::with_capacity(boxes.len() + 4);
    for (mut lo, mut hi, material) in boxes {
        let (cut_lo, cut_hi) = (lo.max(hole.0), hi.min(hole.1));
        if cut_lo.cmpge(cut_hi).any() {
            out.push((lo, hi, material));
            continue;
        }
        for axis in 0..3 {
            if lo[axis] < cut_lo[axis] {
                let mut top = hi;
                top[axis] = cut_lo[axis];
                out.push((lo, top, material));
                lo[axis] = cut_lo[axis];
            }
            if hi[axis] > cut_hi[axis] {
                let mut bottom = lo;
                bottom[axis] = cut_hi[axis];
                out.push((bottom, hi, material));
                hi[axis] = cut_hi[axis];
            }
        }
    }
    out
}

/// Uniform in `a..b`, or their midpoint when the range is empty (small rooms).
fn between(rng: &mut Pcg32, a: f32, b: f32) -> f32 {
    if b > a { rng.random_range(a..b) } else { 0.5 * (a + b) }
}

/// A random reflectance: neutral from dark to white, or saturated.
fn albedo(rng: &mut Pcg32) -> Vec3 {
    if rng.random_range(0.0..1.0) < 0.35 {
        let hue = rng.random_range(0.0..6.0f32);
        let saturation = rng.random_range(0.6..0.9f32);
        let value = rng.random_range(0.3..0.8f32);
        let channel = |k: f32| {
            let h = (hue + k) % 6.0;
            let ramp = (h - 3.0).abs() - 1.0;
            value * (1.0 - saturation * (1.0 - ramp.clamp(0.0, 1.0)))
        };
        Vec3::new(channel(5.0), channel(3.0), channel(1.0))
    } else {
        let grey = rng.random_range(0.05..0.85f32);
        let tint = Vec3::new(rng.random_range(0.95..1.05), 1.0, rng.random_range(0.92..1.05));
        (grey * tint).min(Vec3::splat(0.9))
    }
}

impl GeneratedRoom {
    /// The room of `seed` (the same on every machine: a PCG32 stream).
    pub fn new(seed: u64) -> Self {
        let mut rng = Pcg32::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x005E_ED0F_2032);
        let count = rng.random_range(1..=3usize);
        let height = rng.random_range(2.4..6.0f32);
        let depth = rng.random_range(2.0..12.0f32);
        let t = rng.random_range(0.05..0.30f32);
        let longest = 20.0 / count as f32;
        let widths: Vec<f32> = (0..count).map(|_| rng.random_range(2.0..longest.max(2.5))).collect();

        // Interiors along x, a wall of thickness t between neighbours; z ∈ [0, depth], y ∈ [0, height].
        let mut rooms = Vec::new();
        let mut x = 0.0;
        for w in &widths {
            rooms.push((Vec3::new(x, 0.0, 0.0), Vec3::new(x + w, height, depth)));
            x += w + t;
        }
        let x_end = x - t;

        // Materials: 0 floor, 1 ceiling, then per room its wall colour and an accent wall colour.
        let mut palette = vec![albedo(&mut rng), albedo(&mut rng)];
        let mut boxes = vec![
            (Vec3::new(-t, -t, -t), Vec3::new(x_end + t, 0.0, depth + t), 0),
            (Vec3::new(-t, height, -t), Vec3::new(x_end + t, height + t, depth + t), 1),
        ];
        for (i, &(lo, hi)) in rooms.iter().enumerate() {
            let wall = palette.len();
            palette.push(albedo(&mut rng));
            let accent = if rng.random_range(0.0..1.0) < 0.4 { palette.len() } else { wall };
            if accent != wall {
                palette.push(albedo(&mut rng));
            }
            // The room's share of the walls around it: half of a dividing wall, all of an outer one.
            let left = if i == 0 { t } else { t * 0.5 };
            let right = if i + 1 == count { t } else { t * 0.5 };
            let (x0, x1) = (lo.x - left, hi.x + right);
            boxes.push((Vec3::new(x0, 0.0, -t), Vec3::new(x1, height, 0.0), wall));
            boxes.push((Vec3::new(x0, 0.0, depth), Vec3::new(x1, height, depth + t), accent));
            boxes.push((Vec3::new(x0, 0.0, 0.0), Vec3::new(lo.x, height, depth), wall));
            boxes.push((Vec3::new(hi.x, 0.0, 0.0), Vec3::new(x1, height, depth), wall));
        }

        // A door in every dividing wall.
        let mut doors = Vec::new();
        for i in 1..count {
            let wall_x = rooms[i].0.x - t * 0.5;
            let width = rng.random_range(0.8..1.4f32).min(depth - 0.4);
            let z0 = between(&mut rng, 0.2, depth - 0.2 - width);
            let top = rng.random_range(2.0..2.3f32).min(height - 0.2);
            doors.push(Door { x: wall_x, z0, z1: z0 + width, top });
            boxes = subtract(boxes, (Vec3::new(wall_x - t, 0.0, z0), Vec3::new(wall_x + t, top, z0 + width)));
        }

        let lit_room = rng.random_range(0..count);
        // 0–2 spot, 3–5 point, 6–8 sun, 9 emissive panel. The path tracer finds emitters only by sampling
        // the BSDF: next door to a panel it would need hours, so the camera stays in a panel's room.
        let kind = rng.random_range(0..10u32);
        let camera_room = if count > 1 && kind < 9 && rng.random_range(0.0..1.0) < 0.65 {
            if lit_room == 0 {
                1
            } else if lit_room + 1 == count || rng.random_range(0.0..1.0) < 0.5 {
                lit_room - 1
            } else {
                lit_room + 1
            }
        } else {
            lit_room
        };

        // Windows in the outer long walls (to the dark outside).
        for &(lo, hi) in &rooms {
            if rng.random_range(0.0..1.0) < 0.3 && hi.x - lo.x > 1.6 {
                let width = between(&mut rng, 0.6, (hi.x - lo.x - 0.6).min(3.0));
                let x0 = between(&mut rng, lo.x + 0.3, hi.x - 0.3 - width);
                let y0 = between(&mut rng, 0.8, height - 1.2);
                let y1 = (y0 + rng.random_range(0.6..1.6f32)).min(height - 0.2);
                let (z_lo, z_hi) = if rng.random_range(0.0..1.0) < 0.5 { (-2.0 * t, 0.01) } else { (depth - 0.01, depth + 2.0 * t) };
                boxes = subtract(boxes, (Vec3::new(x0, y0, z_lo), Vec3::new(x0 + width, y1, z_hi)));
            }
        }

        // The light.
        let (llo, lhi) = rooms[lit_room];
        let in_room = |rng: &mut Pcg32, lo: Vec3, hi: Vec3, margin: f32| {
            Vec3::new(between(rng, lo.x + margin, hi.x - margin), 0.0, between(rng, lo.z + margin, hi.z - margin))
        };
        let mut roof_opening = None;
        let light = match kind {
            0..=2 => {
                let p = in_room(&mut rng, llo, lhi, 0.4);
                let position = Vec3::new(p.x, height * rng.random_range(0.6..0.9), p.z);
                // Aim at a wall of the lit room or at the floor.
                let target = match rng.random_range(0..5u32) {
                    0 => Vec3::new(llo.x, rng.random_range(0.3..height * 0.7), between(&mut rng, llo.z + 0.2, lhi.z - 0.2)),
                    1 => Vec3::new(lhi.x, rng.random_range(0.3..height * 0.7), between(&mut rng, llo.z + 0.2, lhi.z - 0.2)),
                    2 => Vec3::new(between(&mut rng, llo.x + 0.2, lhi.x - 0.2), rng.random_range(0.3..height * 0.7), llo.z),
                    3 => Vec3::new(between(&mut rng, llo.x + 0.2, lhi.x - 0.2), rng.random_range(0.3..height * 0.7), lhi.z),
                    _ => in_room(&mut rng, llo, lhi, 0.3),
                };
                let target = if (target - position).length() < 0.5 { Vec3::new(p.x, 0.0, p.z) } else { target };
                RoomLight::Spot {
                    position,
                    target,
                    candela: rng.random_range(200.0..3000.0),
                    outer_angle: rng.random_range(20.0..50.0f32).to_radians(),
                }
            }
            3..=5 => {
                let p = in_room(&mut rng, llo, lhi, 0.4);
                RoomLight::Point {
                    position: Vec3::new(p.x, height - rng.random_range(0.3..0.8f32).min(height * 0.3), p.z),
                    lumens: rng.random_range(2000.0..20000.0),
                }
            }
            6..=8 => {
                let size = Vec2::new(
                    rng.random_range(1.0..3.0f32).min(lhi.x - llo.x - 0.6),
                    rng.random_range(1.0..3.0f32).min(lhi.z - llo.z - 0.6),
                );
                let c = in_room(&mut rng, llo + Vec3::new(size.x, 0.0, size.y) * 0.5, lhi - Vec3::new(size.x, 0.0, size.y) * 0.5, 0.3);
                roof_opening = Some((Vec3::new(c.x - size.x * 0.5, height - 0.01, c.z - size.y * 0.5), Vec3::new(c.x + size.x * 0.5, height + 2.0 * t, c.z + size.y * 0.5)));
                // Through the opening's centre to a point of the lit room's floor, at least 35° high.
                let floor = in_room(&mut rng, llo, lhi, 0.3);
                let mut direction = (floor - Vec3::new(c.x, height, c.z)).normalize();
                let min_down = 35f32.to_radians().sin();
                if -direction.y < min_down {
                    let horizontal = Vec3::new(direction.x, 0.0, direction.z).normalize_or(Vec3::X) * min_down.acos().sin();
                    direction = (horizontal - Vec3::Y * min_down).normalize();
                }
                RoomLight::Sun { direction, lux: rng.random_range(20_000.0..100_000.0) }
            }
            _ => {
                // Large enough that the path tracer (which finds emitters only by sampling the BSDF)
                // converges in minutes.
                let half = Vec2::new(rng.random_range(0.5..1.0f32), rng.random_range(0.5..1.0f32))
                    .min(Vec2::new(lhi.x - llo.x, lhi.z - llo.z) * 0.3);
                let c = in_room(&mut rng, llo + Vec3::new(half.x, 0.0, half.y), lhi - Vec3::new(half.x, 0.0, half.y), 0.2);
                let warmth = rng.random_range(0.0..1.0f32);
                RoomLight::Emissive {
                    lo: Vec3::new(c.x - half.x, height - 0.03, c.z - half.y),
                    hi: Vec3::new(c.x + half.x, height, c.z + half.y),
                    radiance: Vec3::new(1.0, 0.9 - 0.15 * warmth, 0.8 - 0.3 * warmth) * rng.random_range(50.0..500.0),
                }
            }
        };
        if let Some(hole) = roof_opening.or_else(|| {
            // Sometimes an opening to the night sky where no sun comes in.
            (rng.random_range(0.0..1.0) < 0.15).then(|| {
                let (lo, hi) = rooms[rng.random_range(0..count)];
                let c = (lo + hi) * 0.5;
                let half = Vec3::new(((hi.x - lo.x) * 0.2).min(1.0), 0.0, ((hi.z - lo.z) * 0.2).min(1.0));
                (Vec3::new(c.x - half.x, height - 0.01, c.z - half.z), Vec3::new(c.x + half.x, height + 2.0 * t, c.z + half.z))
            })
        }) {
            boxes = subtract(boxes, hole);
        }

        // The camera: looking at the door to the lit room, or across its own room.
        let (clo, chi) = rooms[camera_room];
        let eye_y = rng.random_range(1.2..1.9f32).min(height - 0.3);
        let (camera_position, camera_target) = if camera_room != lit_room {
            let door = doors[camera_room.min(lit_room)];
            let door_centre = Vec3::new(door.x, rng.random_range(0.8..1.4), (door.z0 + door.z1) * 0.5);
            let back_x = if camera_room > lit_room { chi.x - 0.3 } else { clo.x + 0.3 };
            let along = rng.random_range(0.35..0.95f32);
            let x = door.x + (back_x - door.x) * along;
            let x = if camera_room > lit_room { x.max(door.x + 0.6) } else { x.min(door.x - 0.6) };
            let z = between(&mut rng, clo.z + 0.3, chi.z - 0.3);
            (Vec3::new(x, eye_y, z), door_centre)
        } else {
            let corner = Vec3::new(
                if rng.random_range(0.0..1.0) < 0.5 { clo.x + 0.3 } else { chi.x - 0.3 },
                eye_y,
                if rng.random_range(0.0..1.0) < 0.5 { clo.z + 0.3 } else { chi.z - 0.3 },
            );
            let centre = (clo + chi) * 0.5;
            let target = Vec3::new(centre.x, rng.random_range(0.6..1.2) * centre.y, centre.z)
                + Vec3::new(rng.random_range(-0.3..0.3), 0.0, rng.random_range(-0.3..0.3)) * (chi - clo);
            (corner, target)
        };
        let fov_degrees = rng.random_range(60.0..80.0);

        // Furniture, kept off the doors, the camera, the light and each other.
        let mut keep_out: Vec<(Vec2, f32)> = doors.iter().map(|d| (Vec2::new(d.x, (d.z0 + d.z1) * 0.5), 1.2)).collect();
        keep_out.push((camera_position.xz(), 0.7));
        match &light {
            RoomLight::Spot { position, .. } | RoomLight::Point { position, .. } => keep_out.push((position.xz(), 0.6)),
            _ => {}
        }
        let mut furniture: Vec<(&'static str, Vec3, Vec3)> = Vec::new();
        for &(lo, hi) in &rooms {
            for _ in 0..rng.random_range(0..=3u32) {
                let material = palette.len();
                palette.push(albedo(&mut rng));
                let kind = rng.random_range(0..3u32);
                let (size, top) = match kind {
                    0 => (Vec2::new(rng.random_range(0.4..1.5), rng.random_range(0.3..0.8)), rng.random_range(0.6..2.0f32).min(height - 0.3)),
                    1 => (Vec2::new(rng.random_range(0.8..1.8), rng.random_range(0.6..1.0)), rng.random_range(0.7..0.8)),
                    _ => (Vec2::splat(rng.random_range(0.2..0.5)), height),
                };
                for _attempt in 0..20 {
                    if hi.x - lo.x < size.x + 0.4 || hi.z - lo.z < size.y + 0.4 {
                        break;
                    }
                    let x0 = rng.random_range(lo.x + 0.1..hi.x - 0.1 - size.x);
                    let z0 = rng.random_range(lo.z + 0.1..hi.z - 0.1 - size.y);
                    let (a, b) = (Vec3::new(x0, 0.0, z0), Vec3::new(x0 + size.x, top, z0 + size.y));
                    let clear = keep_out.iter().all(|&(p, r)| {
                        let nearest = p.clamp(a.xz(), b.xz());
                        nearest.distance(p) > r
                    }) && furniture.iter().all(|(_, c, d)| a.xz().cmpgt(d.xz() + 0.1).any() || b.xz().cmplt(c.xz() - 0.1).any());
                    if !clear {
                        continue;
                    }
                    furniture.push((["cabinet", "table", "column"][kind as usize], a, b));
                    if kind == 1 {
                        // A table: a 4 cm top on four thin legs.
                        let leg = rng.random_range(0.03..0.06f32);
                        boxes.push((Vec3::new(a.x, top - 0.04, a.z), b, material));
                        for (lx, lz) in [(a.x, a.z), (b.x - leg, a.z), (a.x, b.z - leg), (b.x - leg, b.z - leg)] {
                            boxes.push((Vec3::new(lx, 0.0, lz), Vec3::new(lx + leg, top - 0.04, lz + leg), material));
                        }
                    } else {
                        boxes.push((a, b, material));
                    }
                    break;
                }
            }
        }

        let mut room = Self {
            seed,
            boxes,
            palette,
            light,
            rooms,
            doors,
            furniture,
            lit_room,
            camera_room,
            wall_thickness: t,
            camera_position,
            camera_target,
            fov_degrees,
            ev100: 0.0,
        };
        room.ev100 = room.estimated_ev100();
        room
    }

    /// Its scene name: `room_SEED`.
    pub fn name(&self) -> String {
        format!("room_{}", self.seed)
    }

    /// One line for reports: rooms, sizes, wall thickness, light, where the camera is.
    pub fn describe(&self) -> String {
        let sizes: Vec<String> = self.rooms.iter().map(|(lo, hi)| format!("{:.1}×{:.1}", hi.x - lo.x, hi.z - lo.z)).collect();
        format!(
            "{} room(s) {} m, {:.1} m high, {:.0} cm walls, {} light, camera {}{}",
            self.rooms.len(),
            sizes.join(" + "),
            self.rooms[0].1.y,
            self.wall_thickness * 100.0,
            self.light.kind(),
            if self.camera_room == self.lit_room { "in the lit room" } else { "next door" },
            if self.furniture.is_empty() {
                String::new()
            } else {
                format!(", {}", self.furniture.iter().map(|f| f.0).collect::<Vec<_>>().join(" "))
            }
        )
    }

    /// The interior (min, max) of the camera's room.
    pub fn camera_room_bounds(&self) -> (Vec3, Vec3) {
        self.rooms[self.camera_room]
    }

    /// Pixels of a `width`×`height` image from the scene camera whose view ray passes through a door of
    /// the camera's room into another room: what the camera sees of the rest of the scene. Every other
    /// pixel sees the camera's own room (or the dark outside).
    #[cfg(feature = "reference")]
    pub fn through_doors(&self, width: u32, height: u32) -> Vec<bool> {
        let camera = self.reference_camera();
        // The doors of the camera's room.
        let doors: Vec<Door> = (0..self.doors.len()).filter(|&i| i == self.camera_room || i + 1 == self.camera_room).map(|i| self.doors[i]).collect();
        let mut out = vec![false; (width * height) as usize];
        for y in 0..height {
            for x in 0..width {
                let (_, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5, width, height);
                out[(y * width + x) as usize] = doors.iter().any(|door| {
                    let s = (door.x - self.camera_position.x) / d.x;
                    let p = self.camera_position + d * s;
                    s > 0.0 && p.y > 0.0 && p.y < door.top && p.z > door.z0 && p.z < door.z1
                });
            }
        }
        out
    }

    /// The scene camera as the path tracer sees it (position, orientation, field of view, exposure), for
    /// tools and tests that trace the room without Bevy.
    #[cfg(feature = "reference")]
    pub fn reference_camera(&self) -> crate::reference::ReferenceCamera {
        crate::reference::ReferenceCamera {
            position: self.camera_position,
            rotation: Transform::from_translation(self.camera_position).looking_at(self.camera_target, Vec3::Y).rotation,
            projection: crate::reference::CameraProjection::Perspective { fov_y: self.fov_degrees.to_radians() },
            exposure: bevy::camera::Exposure { ev100: self.ev100 }.exposure(),
        }
    }

    /// `Σ image / Σ truth` over the pixels that see the camera's own room (not [`Self::through_doors`])
    /// and geometry in both images: how much of its room's light a method gives the room the player is in.
    #[cfg(feature = "reference")]
    pub fn camera_room_energy(&self, image: &crate::hdr_image::HdrImage, truth: &crate::hdr_image::HdrImage) -> f64 {
        let Ok(mask) = crate::metrics::mask(image, truth) else { return f64::NAN };
        let doors = self.through_doors(truth.width, truth.height);
        let (mut a, mut r) = (0.0f64, 0.0f64);
        for (i, (&m, &door)) in mask.iter().zip(&doors).enumerate() {
            if m && !door {
                a += image.pixels[i][..3].iter().map(|&v| v as f64).sum::<f64>();
                r += truth.pixels[i][..3].iter().map(|&v| v as f64).sum::<f64>();
            }
        }
        if r > 0.0 { a / r } else { f64::NAN }
    }

    /// An exposure that puts the indirect light of the camera's room near 0.3: the light's flux spread
    /// over the surfaces of the rooms with a mean reflectance's geometric series of bounces, a tenth of it
    /// next door.
    fn estimated_ev100(&self) -> f32 {
        let flux = match &self.light {
            RoomLight::Spot { candela, outer_angle, .. } => candela * 2.0 * PI * (1.0 - outer_angle.cos()),
            RoomLight::Point { lumens, .. } => *lumens,
            RoomLight::Sun { direction, lux } => {
                // The opening is about as large as the rooms' openings; 2 m² is its mean.
                lux * 2.0 * (-direction.y)
            }
            RoomLight::Emissive { lo, hi, radiance } => {
                let area = (hi.x - lo.x) * (hi.z - lo.z);
                PI * radiance.max_element() * area
            }
        };
        let area: f32 = self.rooms.iter().map(|(lo, hi)| {
            let d = hi - lo;
            2.0 * (d.x * d.z + d.x * d.y + d.y * d.z)
        }).sum();
        let rho = self.palette.iter().map(|c| c.dot(Vec3::splat(1.0 / 3.0))).sum::<f32>() / self.palette.len() as f32;
        let irradiance = flux * rho / (area * (1.0 - rho));
        let next_door = if self.camera_room == self.lit_room { 1.0 } else { 0.1 };
        let luminance = rho * irradiance / PI * next_door;
        // Bevy: exposure = 1 / (1.2 · 2^ev100).
        (luminance / (0.3 * 1.2)).max(1e-6).log2().clamp(-16.0, 24.0)
    }

    /// Spawns the light: a Bevy light with a [`GiLight`], or for the emissive panel a glowing mesh.
    fn spawn_light(&self, commands: &mut Commands, meshes: &mut Assets<Mesh>, materials: &mut Assets<StandardMaterial>) {
        let range = self.light_range();
        match self.light {
            RoomLight::Spot { position, target, candela, outer_angle } => {
                commands.spawn((
                    SpotLight {
                        color: Color::WHITE,
                        intensity: 4.0 * PI * candela,
                        shadow_maps_enabled: true,
                        inner_angle: outer_angle * 0.7,
                        outer_angle,
                        range,
                        ..default()
                    },
                    Transform::from_translation(position).looking_at(target, Vec3::Y),
                    GiLight::default(),
                    Name::new("room spot"),
                ));
            }
            RoomLight::Point { position, lumens } => {
                commands.spawn((
                    PointLight {
                        color: Color::WHITE,
                        intensity: lumens,
                        shadow_maps_enabled: true,
                        range,
                        ..default()
                    },
                    Transform::from_translation(position),
                    GiLight::default(),
                    Name::new("room lamp"),
                ));
            }
            RoomLight::Sun { direction, lux } => super::spawn_sun(
                commands,
                direction,
                lux,
                CascadeShadowConfigBuilder {
                    num_cascades: 2,
                    first_cascade_far_bound: range / 3.0,
                    maximum_distance: range * 4.0 / 3.0,
                    ..default()
                }
                .build(),
            ),
            RoomLight::Emissive { lo, hi, radiance } => {
                let glow = materials.add(StandardMaterial {
                    base_color: Color::BLACK,
                    emissive: LinearRgba::rgb(radiance.x, radiance.y, radiance.z),
                    perceptual_roughness: 1.0,
                    metallic: 0.0,
                    reflectance: 0.0,
                    ..default()
                });
                commands.spawn((
                    Mesh3d(meshes.add(Cuboid::from_corners(lo, hi))),
                    MeshMaterial3d(glow),
                    Transform::from_translation((lo + hi) * 0.5),
                    Name::new("glowing panel"),
                ));
            }
        }
    }

    /// The range of the point and spot lights: beyond every corner of the scene.
    fn light_range(&self) -> f32 {
        let (lo, hi) = (self.rooms[0].0, self.rooms[self.rooms.len() - 1].1);
        ((hi - lo).length() + 2.0) * 1.5
    }

    /// The scene as a CPU [`SceneSnapshot`](crate::scene::SceneSnapshot), built from the same boxes,
    /// materials and light as [`Self::spawn`] (for tools that trace it without Bevy, like
    /// `rh_volume_check`).
    pub fn snapshot(&self) -> crate::scene::SceneSnapshot {
        use crate::scene::{SnapshotLight, SnapshotLightEntry};
        let entry = |light| SnapshotLightEntry { entity: Entity::PLACEHOLDER, light, shadows_enabled: true };
        let inverse_range_squared = 1.0 / (self.light_range() * self.light_range());
        match self.light {
            RoomLight::Spot { position, target, candela, outer_angle } => {
                let (spot_scale, spot_offset) = SnapshotLight::spot_scale_offset(outer_angle * 0.7, outer_angle);
                let direction = GlobalTransform::from(Transform::from_translation(position).looking_at(target, Vec3::Y)).forward().as_vec3();
                let light = SnapshotLight::Spot { position, direction, intensity: Vec3::splat(candela), inverse_range_squared, spot_scale, spot_offset };
                super::boxes_snapshot(&self.boxes, &self.palette, vec![entry(light)])
            }
            RoomLight::Point { position, lumens } => {
                let light = SnapshotLight::Point { position, intensity: Vec3::splat(lumens / (4.0 * PI)), inverse_range_squared };
                super::boxes_snapshot(&self.boxes, &self.palette, vec![entry(light)])
            }
            RoomLight::Sun { direction, lux } => super::boxes_snapshot(&self.boxes, &self.palette, vec![super::sun_snapshot(direction, lux)]),
            RoomLight::Emissive { lo, hi, radiance } => {
                let mut boxes = self.boxes.clone();
                let mut palette = self.palette.clone();
                boxes.push((lo, hi, palette.len()));
                palette.push(Vec3::ZERO);
                let mut snapshot = super::boxes_snapshot(&boxes, &palette, vec![]);
                let glow = StandardMaterial {
                    base_color: Color::BLACK,
                    emissive: LinearRgba::rgb(radiance.x, radiance.y, radiance.z),
                    ..super::cornell::diffuse_material(Vec3::ZERO)
                };
                let last = snapshot.materials.len() - 1;
                snapshot.materials[last] = crate::scene::extract::material_from_standard(&glow);
                snapshot
            }
        }
    }

    /// Spawns the boxes, the light and the [`SceneCamera`] (exposure `ev100`, or the estimated one).
    pub fn spawn(&self, commands: &mut Commands, meshes: &mut Assets<Mesh>, materials: &mut Assets<StandardMaterial>, ev100: Option<f32>) {
        let name = self.name();
        super::spawn_boxes(commands, meshes, materials, &self.boxes, &self.palette, &name);
        self.spawn_light(commands, meshes, materials);
        commands.spawn((
            Camera3d::default(),
            Projection::Perspective(PerspectiveProjection {
                fov: self.fov_degrees.to_radians(),
                ..default()
            }),
            Transform::from_translation(self.camera_position).looking_at(self.camera_target, Vec3::Y),
            bevy::camera::Exposure { ev100: ev100.unwrap_or(self.ev100) },
            SceneCamera,
            Name::new(format!("{name} camera")),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inside(p: Vec3, (lo, hi): (Vec3, Vec3)) -> bool {
        p.cmpgt(lo).all() && p.cmplt(hi).all()
    }

    #[test]
    fn seeds_are_reproducible_and_differ() {
        let a = GeneratedRoom::new(3);
        let b = GeneratedRoom::new(3);
        assert_eq!(a.boxes, b.boxes);
        assert_eq!(a.light, b.light);
        let c = GeneratedRoom::new(4);
        assert_ne!(a.boxes, c.boxes);
    }

    #[test]
    fn the_family_covers_what_the_issue_asks_for() {
        let rooms: Vec<GeneratedRoom> = (0..ROOM_HELD_OUT_SEEDS.end).map(GeneratedRoom::new).collect();
        for kind in ["spot", "point", "sun", "emissive"] {
            assert!(rooms.iter().any(|r| r.light.kind() == kind), "no {kind} light in 24 seeds");
        }
        assert!(rooms.iter().any(|r| r.rooms.len() == 1) && rooms.iter().any(|r| r.rooms.len() == 3));
        assert!(rooms.iter().filter(|r| r.camera_room != r.lit_room).count() >= 4);
        assert!(rooms.iter().any(|r| r.wall_thickness < 0.1) && rooms.iter().any(|r| r.wall_thickness > 0.2));
        for room in &rooms {
            let extent = room.rooms.last().unwrap().1.x - room.rooms[0].0.x;
            assert!(extent <= 20.0 + 2.0 * 0.3, "{}: {extent} m", room.name());
            assert!((2.4..6.0).contains(&room.rooms[0].1.y));
            assert!(room.ev100.is_finite());
        }
    }

    #[test]
    fn camera_and_light_are_inside_their_rooms_and_outside_every_box() {
        for seed in 0..64 {
            let room = GeneratedRoom::new(seed);
            assert!(inside(room.camera_position, room.camera_room_bounds()), "{}: camera outside its room", room.name());
            let light_position = match room.light {
                RoomLight::Spot { position, .. } | RoomLight::Point { position, .. } => Some(position),
                _ => None,
            };
            for (lo, hi, _) in &room.boxes {
                assert!(!inside(room.camera_position, (*lo - 0.05, *hi + 0.05)), "{}: camera in a box", room.name());
                if let Some(p) = light_position {
                    assert!(!inside(p, (*lo - 0.05, *hi + 0.05)), "{}: light in a box", room.name());
                }
            }
            if let Some(p) = light_position {
                assert!(inside(p, room.rooms[room.lit_room]), "{}: light outside the lit room", room.name());
            }
        }
    }

    #[test]
    fn subtracting_a_door_leaves_the_wall_around_it() {
        let wall = vec![(Vec3::new(-0.1, 0.0, 0.0), Vec3::new(0.1, 3.0, 4.0), 0)];
        let pieces = subtract(wall, (Vec3::new(-1.0, 0.0, 1.0), Vec3::new(1.0, 2.0, 2.0)));
        let volume: f32 = pieces.iter().map(|(lo, hi, _)| (*hi - *lo).x * (*hi - *lo).y * (*hi - *lo).z).sum();
        assert!((volume - 0.2 * (12.0 - 2.0)).abs() < 1e-4, "{volume}");
        for (lo, hi, _) in &pieces {
            assert!(!inside(Vec3::new(0.0, 1.0, 1.5), (*lo, *hi)));
        }
    }

    #[test]
    fn the_sun_reaches_the_lit_room_through_its_opening() {
        for seed in 0..64 {
            let room = GeneratedRoom::new(seed);
            let RoomLight::Sun { direction, .. } = room.light else { continue };
            let snapshot = super::super::boxes_snapshot(&room.boxes, &room.palette, vec![]);
            let (lo, hi) = room.rooms[room.lit_room];
            let lit = (0..400).filter(|k| {
                let p = Vec3::new(lo.x + (hi.x - lo.x) * ((k % 20) as f32 + 0.5) / 20.0, 0.001, lo.z + (hi.z - lo.z) * ((k / 20) as f32 + 0.5) / 20.0);
                let start = p - direction * 100.0;
                snapshot.intersect(start, direction, 0.0, f32::INFINITY).is_some_and(|hit| (start + direction * hit.t).y < 0.01)
            });
            assert!(lit.count() > 0, "{}: no sunlight on the lit room's floor", room.name());
        }
    }
}
