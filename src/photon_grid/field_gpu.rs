//! The SH field (§3.4) built on the GPU from the background preparation: the paper builds it on the
//! GPU, and it is most of the preparation's CPU time (`cornell`: 77 % at the default preset, `docs/photon_grid.md`).
//!
//! The preparation's background task uploads the V-grid (occupancy bits, a rank per 32-bit word and
//! each boundary V-cell's normal sum and area), the R-grid's levels and the `N_sh` directions (with the
//! environment's radiance along each and their SH basis values), dispatches
//! `shaders/photon_grid/field.wgsl` over the probes in chunks of about 2¹⁸ rays, waiting for each, so
//! that the frame's own submissions run between them, and reads the coefficients back. Everything
//! after (dropping probes inside solid geometry, the blend) is the CPU path's, so the field is the
//! one [`ShField::build`] makes, up to the order of floating-point sums (the GPU test compares them).
//! The pipeline is made by the render world's [`PipelineCache`] (which catches a shader that fails to
//! compile) when a preparation first asks for it ([`make_field_pipeline`]), and handed to the task.
//! A device that lacks a limit the pass needs, or a pipeline that fails, gives an error and the CPU
//! builds the field instead (one warning).

use std::sync::{Arc, Mutex};

use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{storage_buffer, storage_buffer_read_only, uniform_buffer};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::shader::{Shader, ShaderCacheError, ShaderDefVal};

use super::grid::{self, FieldParams, RGrid, ShField, VGrid};
use crate::method::{GpuCapabilities, Shortfall};
use crate::scene::environment::Environment;

/// `FieldParams` in `field.wgsl`.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
struct FieldParamsGpu {
    origin: Vec3,
    cell: f32,
    dims: UVec3,
    v_cell: f32,
    v_dims: UVec3,
    directions: u32,
    max_distance: f32,
    filter_levels: u32,
    levels: u32,
    first_probe: u32,
    probe_count: u32,
    weight: f32,
    inside_limit: u32,
}

/// `RLevel` in `field.wgsl`: one R-grid level.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
struct RLevelGpu {
    dims: UVec3,
    /// Index of the level's first face in the faces buffer.
    offset: u32,
    cell: f32,
}

/// `FieldDirection` in `field.wgsl`: one of the `N_sh` directions.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
struct FieldDirectionGpu {
    direction: Vec3,
    environment: Vec3,
    basis: [Vec4; 3],
}

/// Threads per workgroup (the crate's, `WORKGROUP_SIZE` in `field.wgsl`), and probes per workgroup
/// (`FIELD_PROBES`); each probe's directions are split over `THREADS / PROBES_PER_GROUP` threads.
const THREADS: u32 = crate::WORKGROUP_SIZE;
const PROBES_PER_GROUP: u32 = 8;
/// Output `vec4`s per probe: nine coefficients and the back-face count.
const OUTPUT_PER_PROBE: usize = 10;
/// Probe rays per submission: the frame's own work runs between them.
const RAYS_PER_SUBMISSION: u32 = 1 << 18;
/// Storage buffers the pass binds (`field.wgsl`, group 0).
const STORAGE_BUFFERS: u64 = 8;
/// Workgroup memory the pass uses, bytes: nine `vec4`s per thread and a counter per probe.
const WORKGROUP_BYTES: u32 = THREADS * 9 * 16 + PROBES_PER_GROUP * 4;

/// Where the field's compute pipeline stands. The pipeline is made by the render world's
/// [`PipelineCache`] (which catches a shader that fails to compile), when a preparation first asks
/// for it, and handed to the main world's background task through [`FieldPipeline`].
#[derive(Default)]
enum FieldPipelineState {
    /// Not asked for (nothing is compiled for a scene that never builds its field on the GPU).
    #[default]
    Unrequested,
    Requested,
    Ready(ComputePipeline, BindGroupLayout),
    Failed(String),
}

/// The field's pipeline, shared by the main world (which asks for it and uses it from its background
/// task) and the render world (which makes it). Cheap to clone.
#[derive(Resource, Clone, Default)]
pub struct FieldPipeline(Arc<Mutex<FieldPipelineState>>);

/// The render world's side of [`FieldPipeline`]: the pipeline's layout and shader.
#[derive(Resource)]
pub(super) struct FieldPipelineSource {
    pub shader: Handle<Shader>,
    layout: BindGroupLayoutDescriptor,
    id: Option<CachedComputePipelineId>,
}

impl FieldPipelineSource {
    pub fn new(shader: Handle<Shader>) -> Self {
        let layout = BindGroupLayoutDescriptor::new(
            "diffuse_gi_photon_field_layout",
            &BindGroupLayoutEntries::sequential(
                ShaderStages::COMPUTE,
                (
                    uniform_buffer::<FieldParamsGpu>(false),
                    storage_buffer_read_only::<u32>(false),
                    storage_buffer_read_only::<Vec4>(false),
                    storage_buffer_read_only::<u32>(false),
                    storage_buffer_read_only::<Vec4>(false),
                    storage_buffer_read_only::<RLevelGpu>(false),
                    storage_buffer_read_only::<FieldDirectionGpu>(false),
                    storage_buffer_read_only::<u32>(false),
                    storage_buffer::<Vec4>(false),
                ),
            ),
        );
        Self { shader, layout, id: None }
    }
}

/// Render world: queues the field's pipeline once a preparation asked for it, and hands it (or why it
/// failed) to the main world.
pub(super) fn make_field_pipeline(shared: Res<FieldPipeline>, mut source: ResMut<FieldPipelineSource>, cache: Res<PipelineCache>) {
    let Ok(mut state) = shared.0.lock() else { return };
    if !matches!(*state, FieldPipelineState::Requested) {
        return;
    }
    let source = &mut *source;
    let id = *source.id.get_or_insert_with(|| {
        cache.queue_compute_pipeline(ComputePipelineDescriptor {
            label: Some("diffuse_gi_photon_field_pipeline".into()),
            layout: vec![source.layout.clone()],
            shader: source.shader.clone(),
            shader_defs: [
                crate::shared_shader_defs(),
                vec![ShaderDefVal::Int("V_PER_SH".into(), grid::V_PER_SH as i32), ShaderDefVal::UInt("FIELD_PROBES".into(), PROBES_PER_GROUP)],
            ]
            .concat(),
            entry_point: Some("field".into()),
            ..default()
        })
    });
    match cache.get_compute_pipeline_state(id) {
        CachedPipelineState::Ok(Pipeline::ComputePipeline(pipeline)) => {
            *state = FieldPipelineState::Ready(pipeline.clone(), cache.get_bind_group_layout(&source.layout));
        }
        CachedPipelineState::Err(ShaderCacheError::ShaderNotLoaded(_) | ShaderCacheError::ShaderImportNotYetAvailable) => {}
        CachedPipelineState::Err(error) => *state = FieldPipelineState::Failed(error.to_string()),
        _ => {}
    }
}

/// How long a preparation waits for the render world to make the pipeline before it builds the field
/// on the CPU.
const PIPELINE_WAIT: std::time::Duration = std::time::Duration::from_secs(60);

/// The device and queue the field is built with, what the device offers, and its pipeline. Cheap to
/// clone.
#[derive(Clone)]
pub struct FieldGpu {
    device: RenderDevice,
    queue: RenderQueue,
    capabilities: GpuCapabilities,
    pipeline: FieldPipeline,
}

impl std::fmt::Debug for FieldGpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FieldGpu").finish_non_exhaustive()
    }
}

impl FieldGpu {
    pub fn new(device: RenderDevice, queue: RenderQueue, capabilities: GpuCapabilities, pipeline: FieldPipeline) -> Self {
        Self { device, queue, capabilities, pipeline }
    }

    /// What the pass needs that `gpu` lacks (the methods' own check, [`GpuCapabilities::require`]):
    /// compute shaders, eight storage buffers and its workgroup memory.
    pub fn missing_capabilities(gpu: &GpuCapabilities) -> Vec<Shortfall> {
        gpu.require()
            .compute()
            .storage_buffers(STORAGE_BUFFERS)
            .at_least("max_compute_workgroup_storage_size", WORKGROUP_BYTES.into(), gpu.limits.max_compute_workgroup_storage_size.into())
            .missing()
    }

    /// The pipeline, asking the render world for it and waiting (on this background thread) until it
    /// is made.
    fn pipeline(&self) -> Result<(ComputePipeline, BindGroupLayout), String> {
        let missing = Self::missing_capabilities(&self.capabilities);
        if !missing.is_empty() {
            let named: Vec<String> = missing.iter().map(|(name, required, found)| format!("{name}: needs {required}, has {found}")).collect();
            return Err(format!("the GPU lacks {}", named.join(", ")));
        }
        let start = std::time::Instant::now();
        loop {
            {
                let mut state = self.pipeline.0.lock().map_err(|_| "the field's pipeline state is poisoned".to_string())?;
                match &*state {
                    FieldPipelineState::Unrequested => *state = FieldPipelineState::Requested,
                    FieldPipelineState::Requested => {}
                    FieldPipelineState::Ready(pipeline, layout) => return Ok((pipeline.clone(), layout.clone())),
                    FieldPipelineState::Failed(error) => return Err(format!("the field's pipeline: {error}")),
                }
            }
            if start.elapsed() > PIPELINE_WAIT {
                return Err(format!("the field's pipeline was not made within {} s", PIPELINE_WAIT.as_secs()));
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    }

    /// The field [`ShField::build`] makes, built on this device. Blocks the calling (background)
    /// thread until the GPU is done. Errors name what failed; the caller builds on the CPU then.
    pub fn build(&self, vgrid: &VGrid, rgrid: &RGrid, env: Option<&Environment>, params: &FieldParams) -> Result<ShField, String> {
        let Some(layout) = vgrid.layout else { return Ok(ShField::default()) };
        let probes = grid::probe_cells(vgrid, &layout);
        let n = params.directions.max(1);
        if probes.is_empty() {
            return Ok(ShField::from_probes(layout, &probes, []));
        }
        let start = std::time::Instant::now();
        let (pipeline, bind_layout) = self.pipeline()?;
        let (pipeline, bind_layout) = (&pipeline, &bind_layout);
        let compiled = start.elapsed().as_secs_f32() * 1e3;

        // The inputs, laid out as `field.wgsl` reads them.
        let occupancy = vgrid.occupancy_words();
        let mut ranks = Vec::with_capacity(occupancy.len());
        let mut below = 0u32;
        for word in &occupancy {
            ranks.push(below);
            below += word.count_ones();
        }
        // Occupancy words, then their ranks.
        let occupancy_ranks: Vec<u32> = occupancy.iter().chain(&ranks).copied().collect();
        let v_cells: Vec<Vec4> = vgrid.boundary_data().iter().map(|(_, c)| c.normal_sum.extend(c.area)).collect();
        let mut sh_boundary = vec![0u32; layout.cell_count().div_ceil(32)];
        for (i, _) in vgrid.sh_boundary.iter().enumerate().filter(|(_, b)| **b) {
            sh_boundary[i / 32] |= 1 << (i % 32);
        }
        let mut faces = Vec::new();
        let mut levels = Vec::new();
        for (dims, cell, level) in &rgrid.levels {
            levels.push(RLevelGpu { dims: *dims, offset: faces.len() as u32, cell: *cell });
            faces.extend(level.iter().flat_map(|f| f.map(|face| face.extend(0.0))));
        }
        let directions: Vec<FieldDirectionGpu> = (0..n)
            .map(|i| {
                let d = crate::sampling::fibonacci_sphere(i, n);
                let y = crate::sh::basis(d);
                FieldDirectionGpu {
                    direction: d,
                    environment: env.map_or(Vec3::ZERO, |e| e.radiance(d)),
                    basis: [Vec4::new(y[0], y[1], y[2], y[3]), Vec4::new(y[4], y[5], y[6], y[7]), Vec4::new(y[8], 0.0, 0.0, 0.0)],
                }
            })
            .collect();
        let probe_list: Vec<u32> = probes.iter().map(|&i| i as u32).collect();
        let mut field_params = FieldParamsGpu {
            origin: layout.origin,
            cell: layout.cell,
            dims: layout.dims,
            v_cell: layout.v_cell(),
            v_dims: layout.v_dims(),
            directions: n,
            max_distance: params.max_distance,
            filter_levels: params.filter_levels,
            levels: levels.len() as u32,
            first_probe: 0,
            probe_count: probe_list.len() as u32,
            weight: 4.0 * std::f32::consts::PI / n as f32,
            inside_limit: grid::inside_limit(n),
        };

        let limits = &self.capabilities.limits;
        let max_binding = limits.max_storage_buffer_binding_size;
        let output_bytes = (probe_list.len() * OUTPUT_PER_PROBE * 16) as u64;
        let storage = |label: &str, bytes: &[u8]| -> Result<Buffer, String> {
            if bytes.len() as u64 > max_binding {
                return Err(format!("{label}: {} bytes over max_storage_buffer_binding_size {max_binding}", bytes.len()));
            }
            // An empty binding is not allowed: sixteen zero bytes instead.
            let contents: &[u8] = if bytes.is_empty() { &[0; 16] } else { bytes };
            Ok(self.device.create_buffer_with_data(&BufferInitDescriptor { label: Some(label), contents, usage: BufferUsages::STORAGE }))
        };
        let levels_bytes = storage_bytes(&levels);
        let directions_bytes = storage_bytes(&directions);
        if output_bytes > max_binding {
            return Err(format!("field output: {output_bytes} bytes over max_storage_buffer_binding_size {max_binding}"));
        }
        let uniform = self.device.create_buffer(&BufferDescriptor {
            label: Some("diffuse_gi_photon_field_params"),
            size: FieldParamsGpu::min_size().get(),
            usage: BufferUsages::UNIFORM | BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let buffers = [
            storage("diffuse_gi_photon_field_occupancy", bytemuck::cast_slice(&occupancy_ranks))?,
            storage("diffuse_gi_photon_field_v_cells", bytemuck::cast_slice(&v_cells))?,
            storage("diffuse_gi_photon_field_sh_boundary", bytemuck::cast_slice(&sh_boundary))?,
            storage("diffuse_gi_photon_field_rgrid", bytemuck::cast_slice(&faces))?,
            storage("diffuse_gi_photon_field_levels", &levels_bytes)?,
            storage("diffuse_gi_photon_field_directions", &directions_bytes)?,
            storage("diffuse_gi_photon_field_probes", bytemuck::cast_slice(&probe_list))?,
        ];
        let output = self.device.create_buffer(&BufferDescriptor {
            label: Some("diffuse_gi_photon_field_output"),
            size: output_bytes,
            usage: BufferUsages::STORAGE | BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = self.device.create_buffer(&BufferDescriptor {
            label: Some("diffuse_gi_photon_field_readback"),
            size: output_bytes,
            usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut entries = vec![BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }];
        entries.extend(buffers.iter().enumerate().map(|(k, b)| BindGroupEntry { binding: k as u32 + 1, resource: b.as_entire_binding() }));
        entries.push(BindGroupEntry { binding: 8, resource: output.as_entire_binding() });
        let bind_group = self.device.create_bind_group("diffuse_gi_photon_field_bind_group", bind_layout, &entries);

        // The probes in chunks, one submission each, waiting for each before the next.
        let chunk = (RAYS_PER_SUBMISSION / n).div_ceil(PROBES_PER_GROUP).clamp(1, limits.max_compute_workgroups_per_dimension);
        let total = probe_list.len() as u32;
        let mut first = 0;
        while first < total {
            field_params.first_probe = first;
            let mut bytes = encase::UniformBuffer::new(Vec::<u8>::new());
            bytes.write(&field_params).expect("the field's parameters");
            self.queue.write_buffer(&uniform, 0, &bytes.into_inner());
            let groups = chunk.min((total - first).div_ceil(PROBES_PER_GROUP));
            let mut encoder = self.device.create_command_encoder(&CommandEncoderDescriptor { label: Some("diffuse_gi_photon_field") });
            {
                let mut pass = encoder.begin_compute_pass(&ComputePassDescriptor { label: Some("diffuse_gi_photon_field"), timestamp_writes: None });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &*bind_group, &[]);
                pass.dispatch_workgroups(groups, 1, 1);
            }
            first += groups * PROBES_PER_GROUP;
            if first >= total {
                encoder.copy_buffer_to_buffer(&output, 0, &readback, 0, output_bytes);
            }
            let index = self.queue.submit([encoder.finish()]);
            self.device.poll(PollType::Wait { submission_index: Some(index), timeout: None }).map_err(|e| format!("waiting for the field: {e}"))?;
        }

        let dispatched = start.elapsed().as_secs_f32() * 1e3;
        // Read back.
        let (sender, receiver) = std::sync::mpsc::channel();
        readback.slice(..).map_async(MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.device.poll(PollType::wait_indefinitely()).map_err(|e| format!("reading the field back: {e}"))?;
        receiver.recv().map_err(|e| format!("reading the field back: {e}"))?.map_err(|e| format!("reading the field back: {e}"))?;
        let values: Vec<Vec4> = bytemuck::cast_slice::<u8, f32>(&readback.slice(..).get_mapped_range()).chunks_exact(4).map(Vec4::from_slice).collect();
        readback.unmap();
        let found: Vec<_> = values
            .chunks_exact(OUTPUT_PER_PROBE)
            .map(|p| {
                let mut coefficients = [Vec4::ZERO; 9];
                coefficients.copy_from_slice(&p[..9]);
                grid::kept_probe(coefficients, p[9].x as u32, n)
            })
            .collect();
        bevy::log::debug!(
            "photon grid: SH field on the GPU, {} probes × {n} rays: pipeline {compiled:.1} ms, upload and dispatches {:.1} ms, read back {:.1} ms",
            probe_list.len(),
            dispatched - compiled,
            start.elapsed().as_secs_f32() * 1e3 - dispatched
        );
        Ok(ShField::from_probes(layout, &probes, found))
    }
}

/// `value` laid out as a storage buffer holds it (`ShaderType`), as bytes to upload.
fn storage_bytes<T: ShaderType + encase::internal::WriteInto>(value: &T) -> Vec<u8> {
    let mut buffer = encase::StorageBuffer::new(Vec::<u8>::new());
    buffer.write(value).expect("a storage layout");
    buffer.into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn webgpu_default_limits_build_the_field_and_downlevel_ones_name_what_they_lack() {
        assert_eq!(FieldGpu::missing_capabilities(&GpuCapabilities::desktop()), vec![]);
        let downlevel = GpuCapabilities { limits: WgpuLimits::downlevel_defaults(), flags: DownlevelFlags::all() };
        assert_eq!(FieldGpu::missing_capabilities(&downlevel), vec![("max_storage_buffers_per_shader_stage", 8, 4)], "four storage buffers are too few");
        let webgl = FieldGpu::missing_capabilities(&GpuCapabilities::webgl2());
        let names: Vec<_> = webgl.iter().map(|m| m.0).collect();
        assert!(names.iter().any(|n| n.contains("COMPUTE_SHADERS")), "no compute on WebGL2: {names:?}");
        assert!(webgl.contains(&("max_compute_workgroup_storage_size", WORKGROUP_BYTES.into(), 0)), "{webgl:?}");
    }
}
