//! What each Radiance Hints volume did in the last rendered frame, published to the main world for the
//! tuning panel, tests and tools: whether it updated or reused its field, and how many extra bounces its
//! last full update ran before the stop threshold ([`RadianceHintsVolume::bounce_threshold`]) ended them.
//!
//! The bounce count is decided on the GPU (`decide.wgsl` writes it); it is copied to a small staging
//! buffer after an update and mapped without waiting, so it arrives one or two frames late and never
//! stalls the frame.
//!
//! [`RadianceHintsVolume::bounce_threshold`]: super::RadianceHintsVolume::bounce_threshold

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

use bevy::math::UVec3;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::{Buffer, MapMode};

use super::prepare::RhVolumesGpu;

/// What one volume did in the last rendered frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RhVolumeActivity {
    /// The volume ran its update (injection, bounces, blend) in the last frame; `false`: it reused the
    /// field it already had, and only the per-pixel reconstruction ran.
    pub updating: bool,
    /// The last update was an amortised one (its inputs change every frame: injection plus one bounce
    /// gathered from the displayed field, so bounces accumulate over frames).
    pub amortised: bool,
    /// Updates still to run before the temporal blend and the refinement have converged (0: settled).
    pub updates_left: u32,
    /// Frames in a row that reused the field (0 while it updates).
    pub frames_reused: u32,
    /// Extra bounces (after the injection, which is the first bounce) that the last full update ran before
    /// the stop threshold ended them; `None` until the GPU's count has been read back.
    pub extra_bounces_run: Option<u32>,
    /// The extra bounces the settings allow.
    pub extra_bounces_max: u32,
    /// Hints along x, y and z of the grid in use.
    pub resolution: UVec3,
}

/// Every active volume's [`RhVolumeActivity`], by volume entity. Empty while no camera uses Radiance
/// Hints (the volumes then run nothing). Shared between the main and render worlds; cheap to clone.
#[derive(Resource, Clone, Default)]
pub struct RadianceHintsActivity(Arc<Mutex<HashMap<Entity, RhVolumeActivity>>>);

impl RadianceHintsActivity {
    /// The activity of the volume `entity`, if it ran in the last rendered frame.
    pub fn get(&self, entity: Entity) -> Option<RhVolumeActivity> {
        self.0.lock().ok()?.get(&entity).cloned()
    }

    /// Every active volume's activity.
    pub fn all(&self) -> Vec<(Entity, RhVolumeActivity)> {
        self.0.lock().map(|m| m.iter().map(|(e, a)| (*e, a.clone())).collect()).unwrap_or_default()
    }

    pub(crate) fn publish(&self, activity: HashMap<Entity, RhVolumeActivity>) {
        if let Ok(mut map) = self.0.lock() {
            *map = activity;
        }
    }
}

/// The staging side of a volume's bounce count: a 4-byte mappable buffer and where its copy stands.
pub struct BounceReadback {
    pub buffer: Buffer,
    /// [`IDLE`], [`COPIED`] (a copy is encoded this frame) or [`MAPPING`].
    pub state: Arc<AtomicU32>,
    /// The last count read, `u32::MAX` before the first.
    pub extra_bounces: Arc<AtomicU32>,
}

pub const IDLE: u32 = 0;
pub const COPIED: u32 = 1;
pub const MAPPING: u32 = 2;

impl BounceReadback {
    pub fn new(buffer: Buffer) -> Self {
        Self { buffer, state: Arc::new(AtomicU32::new(IDLE)), extra_bounces: Arc::new(AtomicU32::new(u32::MAX)) }
    }

    /// The last count read back, if any.
    pub fn last(&self) -> Option<u32> {
        Some(self.extra_bounces.load(Ordering::Acquire)).filter(|&n| n != u32::MAX)
    }
}

/// After the frame's commands are submitted (`RenderSystems::Cleanup`): maps the staging buffers that an
/// update copied its count into. The callback reads the count and unmaps; nothing waits for it.
pub(crate) fn map_bounce_counts(state: Res<RhVolumesGpu>) {
    for v in &state.volumes {
        let readback = &v.bounce_readback;
        if readback.state.compare_exchange(COPIED, MAPPING, Ordering::AcqRel, Ordering::Acquire).is_err() {
            continue;
        }
        let buffer = readback.buffer.clone();
        let (status, count) = (readback.state.clone(), readback.extra_bounces.clone());
        readback.buffer.slice(..).map_async(MapMode::Read, move |result| {
            if result.is_ok() {
                let value = {
                    let data = buffer.slice(..).get_mapped_range();
                    u32::from_le_bytes([data[0], data[1], data[2], data[3]])
                };
                buffer.unmap();
                count.store(value, Ordering::Release);
            }
            status.store(IDLE, Ordering::Release);
        });
    }
}
