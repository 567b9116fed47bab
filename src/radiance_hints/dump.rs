//! Reading a volume back to the CPU, for measurements and debugging: with the [`RhVolumeDump`]
//! resource present, the render world writes the first volume's displayed field to a JSON file after every
//! frame (a blocking GPU readback: not for shipping builds).

use std::path::PathBuf;

use bevy::prelude::*;
use bevy::render::extract_resource::ExtractResource;
use bevy::render::render_resource::{Buffer, BufferDescriptor, BufferUsages, CommandEncoderDescriptor, MapMode, PollType};
use bevy::render::renderer::{RenderDevice, RenderQueue};
use serde_json::json;

use super::prepare::RhVolumesGpu;
use super::{field_floats, field_terms};

/// Write the first Radiance Hints volume to `path` (JSON: resolution, SH order, `world_from_local`, per
/// hint the SH coefficients, distances and albedo/validity, the reconstruction's visibility masks (four
/// voxels per word) and how they were last updated) after every rendered frame.
#[derive(Resource, Clone, Debug, ExtractResource)]
pub struct RhVolumeDump {
    pub path: PathBuf,
}

fn read_buffer<T: bytemuck::Pod>(device: &RenderDevice, queue: &RenderQueue, source: &Buffer) -> Vec<T> {
    let size = source.size();
    let staging = device.create_buffer(&BufferDescriptor {
        label: Some("diffuse_gi_rh_dump_staging"),
        size,
        usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&CommandEncoderDescriptor { label: Some("diffuse_gi_rh_dump") });
    encoder.copy_buffer_to_buffer(source, 0, &staging, 0, size);
    queue.submit([encoder.finish()]);
    let slice = staging.slice(..);
    slice.map_async(MapMode::Read, |_| {});
    let _ = device.wgpu_device().poll(PollType::wait_indefinitely());
    let data = slice.get_mapped_range();
    bytemuck::cast_slice::<u8, T>(&data).to_vec()
}

pub(crate) fn dump_volume(
    dump: Option<Res<RhVolumeDump>>,
    volumes: Res<RhVolumesGpu>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    mut frames_without: Local<u32>,
) {
    let Some(dump) = dump else {
        return;
    };
    let Some(v) = volumes.volumes.first() else {
        // Say so once, rather than leave the file unwritten without a word (the first frames of a run
        // have no volume yet).
        *frames_without = frames_without.saturating_add(1);
        if *frames_without == 60 {
            warn!("bevy_diffuse_gi: RhVolumeDump asks for {}, but no Radiance Hints volume has been prepared in 60 frames", dump.path.display());
        }
        return;
    };
    let floats = field_floats(v.settings.sh_order);
    let hints = v.hints as usize;
    let result = read_buffer::<f32>(&device, &queue, &v.result);
    let distances = read_buffer::<f32>(&device, &queue, &v.distances);
    let albedo = read_buffer::<f32>(&device, &queue, &v.albedo);
    let visibility = read_buffer::<u32>(&device, &queue, &v.visibility);
    let text = json!({
        "resolution": v.settings.resolution.to_array(),
        "sh_coefficients": v.settings.sh_order.coefficients(),
        // RGB terms per hint in "sh": the SH coefficients, then the irradiance facing up and facing down.
        "field_terms": field_terms(v.settings.sh_order),
        "world_from_local": v.world_from_local.to_cols_array(),
        "updates_left": v.updates_left,
        "sh": result[..hints * floats].to_vec(),
        "distances": distances[..hints * 4].to_vec(),
        "albedo_validity": albedo[..hints * 4].to_vec(),
        "occupancy_resolution": v.occupancy_resolution.to_array(),
        "visibility": visibility,
        "last_visibility_update": format!("{:?}", v.last_visibility_update),
    });
    if let Err(e) = std::fs::write(&dump.path, text.to_string()) {
        warn_once!("bevy_diffuse_gi: cannot write the volume dump {}: {e}", dump.path.display());
    }
}
