//! Render world: the gather's uniform and sample patterns, its layouts and pipelines.

use bevy::math::Vec4;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only, storage_buffer_read_only_sized, texture_2d_array, uniform_buffer,
};
use bevy::render::render_resource::*;
use bevy::render::renderer::{RenderDevice, RenderQueue};
use bevy::shader::Shader;

use super::RsmSampleWeights;
use super::extract::ExtractedRsmGatherSettings;
use crate::camera::GiMethod;
use crate::composite::{ExtractedDiffuseGi, GiViewPass};
use crate::rsm::{GpuGiLight, RsmAtlas, RsmFaceUniform};

/// The method's shaders.
#[derive(Resource, Clone)]
pub struct RsmGatherShaders {
    pub gather: Handle<Shader>,
}

/// The gather's uniform (`RsmGatherUniform` in `shaders/rsm_gather/gather.wgsl`), one per camera.
#[derive(ShaderType, Clone, Copy, Debug, Default)]
pub struct RsmGatherUniform {
    pub samples: u32,
    pub light_count: u32,
    pub intensity: f32,
}

/// One sample of the disk pattern (`RsmGatherSample` in the shader).
#[derive(ShaderType, Clone, Copy, Debug, Default, PartialEq)]
pub struct RsmGatherSample {
    /// xy: offset from the disk's centre in units of the map's side; z: the sample's weight as a
    /// fraction of the map's area (× resolution² = texels it stands for); w: unused.
    pub offset_weight: Vec4,
}

/// The paper's disk pattern (§3.3): `samples` offsets `r_max ξ₁ (sin 2πξ₂, cos 2πξ₂)` with ξ₁
/// stratified and ξ₂ the base-2 radical inverse, weighted by `ξ₁^k` (k from `weights`) and normalised so
/// that the weights sum to the disk's area `π r_max²` (in units of the map's area).
pub fn sample_pattern(samples: u32, radius: f32, weights: RsmSampleWeights) -> Vec<RsmGatherSample> {
    let n = samples.max(1);
    let power = weights.power_of_xi1();
    let xi1: Vec<f32> = (0..n).map(|i| (i as f32 + 0.5) / n as f32).collect();
    let total: f32 = xi1.iter().map(|x| x.powf(power)).sum();
    let area = std::f32::consts::PI * radius * radius;
    (0..n)
        .map(|i| {
            let xi2 = (i.reverse_bits() as f64 / 4_294_967_296.0) as f32;
            let phi = std::f32::consts::TAU * xi2;
            let x = xi1[i as usize];
            RsmGatherSample {
                offset_weight: Vec4::new(radius * x * phi.sin(), radius * x * phi.cos(), area * x.powf(power) / total, 0.0),
            }
        })
        .collect()
}

/// Layouts and pipelines of the gather.
#[derive(Resource)]
pub struct RsmGatherPipelines {
    pub(super) pass: GiViewPass,
    pub(super) gather_layout: BindGroupLayoutDescriptor,
    shader: Handle<Shader>,
}

impl SpecializedRenderPipeline for RsmGatherPipelines {
    /// Half resolution.
    type Key = bool;

    fn specialize(&self, half_resolution: bool) -> RenderPipelineDescriptor {
        let layouts = [&self.gather_layout];
        self.pass.pipeline("diffuse_gi_rsm_gather_pipeline", &self.shader, "gather", half_resolution, &layouts, vec![], None)
    }
}

pub(super) fn init_rsm_gather_pipelines(world: &mut World) {
    let unfilterable = TextureSampleType::Float { filterable: false };
    let gather_layout = BindGroupLayoutDescriptor::new(
        "diffuse_gi_rsm_gather_layout",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::FRAGMENT,
            (
                uniform_buffer::<RsmGatherUniform>(true),
                storage_buffer_read_only_sized(false, None),
                texture_2d_array(unfilterable),
                texture_2d_array(unfilterable),
                texture_2d_array(unfilterable),
                storage_buffer_read_only::<GpuGiLight>(false),
                storage_buffer_read_only::<RsmFaceUniform>(false),
            ),
        ),
    );
    world.insert_resource(RsmGatherPipelines {
        pass: GiViewPass::from_world(world),
        gather_layout,
        shader: world.resource::<RsmGatherShaders>().gather.clone(),
    });
}

type PatternKey = (u32, u32, RsmSampleWeights);

/// The gather's per-frame state: the uniforms, the sample patterns in use and each camera's offset,
/// pattern and pipeline.
#[derive(Resource, Default)]
pub struct RsmGatherGpu {
    pub(super) uniforms: DynamicUniformBuffer<RsmGatherUniform>,
    /// Patterns by (samples, radius bits, weights), kept while a camera uses them.
    pub(super) patterns: HashMap<PatternKey, Buffer>,
    pub(super) views: HashMap<Entity, (u32, PatternKey, CachedRenderPipelineId)>,
}

#[expect(clippy::too_many_arguments, reason = "per-view preparation")]
pub(super) fn prepare_rsm_gather(
    mut gpu: ResMut<RsmGatherGpu>,
    views: Query<(Entity, &ExtractedDiffuseGi, &ExtractedRsmGatherSettings)>,
    atlas: Res<RsmAtlas>,
    pipelines: Res<RsmGatherPipelines>,
    mut specialized: ResMut<SpecializedRenderPipelines<RsmGatherPipelines>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
) {
    let gpu = &mut *gpu;
    gpu.uniforms.clear();
    gpu.views.clear();
    let mut used = Vec::new();
    for (entity, gi, settings) in &views {
        if gi.0.method != GiMethod::RsmGather {
            continue;
        }
        let s = &settings.0;
        let key = (s.samples, s.radius.to_bits(), s.weights);
        used.push(key);
        gpu.patterns.entry(key).or_insert_with(|| {
            let mut buffer = StorageBuffer::from(sample_pattern(s.samples, s.radius, s.weights));
            buffer.set_label(Some("diffuse_gi_rsm_gather_pattern"));
            buffer.write_buffer(&device, &queue);
            buffer.buffer().expect("written above").clone()
        });
        let offset = gpu.uniforms.push(&RsmGatherUniform {
            samples: s.samples,
            light_count: atlas.slots.len() as u32,
            intensity: s.intensity,
        });
        let pipeline = specialized.specialize(&pipeline_cache, &pipelines, gi.0.half_resolution);
        gpu.views.insert(entity, (offset, key, pipeline));
    }
    gpu.patterns.retain(|key, _| used.contains(key));
    gpu.uniforms.write_buffer(&device, &queue);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_lies_in_the_disk_and_weighs_its_area() {
        for weights in [RsmSampleWeights::Paper, RsmSampleWeights::Density] {
            for (n, r) in [(1, 0.5), (64, 0.3), (400, 1.0)] {
                let pattern = sample_pattern(n, r, weights);
                assert_eq!(pattern.len(), n as usize);
                let total: f32 = pattern.iter().map(|s| s.offset_weight.z).sum();
                let area = std::f32::consts::PI * r * r;
                assert!((total - area).abs() < 1e-4 * area, "{total} vs {area}");
                for s in &pattern {
                    assert!(s.offset_weight.truncate().truncate().length() <= r + 1e-6);
                }
            }
        }
        // Denser near the centre, so outer samples weigh more: ξ₁² for the paper, ξ₁ for the density.
        let paper = sample_pattern(100, 1.0, RsmSampleWeights::Paper);
        assert!((paper[99].offset_weight.z / paper[0].offset_weight.z - (199.0f32 / 1.0).powi(2)).abs() < 1.0);
        let density = sample_pattern(100, 1.0, RsmSampleWeights::Density);
        assert!((density[99].offset_weight.z / density[0].offset_weight.z - 199.0).abs() < 1e-2);
    }

    #[test]
    fn density_weights_integrate_a_falloff_without_bias() {
        // Σ w f(r) over the pattern against ∫∫ f over the unit disk, for f = 1 − r (far texels count less).
        let exact = std::f32::consts::PI / 3.0;
        let estimate = |weights| -> f32 {
            sample_pattern(4096, 1.0, weights)
                .iter()
                .map(|s| s.offset_weight.z * (1.0 - s.offset_weight.truncate().truncate().length()))
                .sum()
        };
        assert!((estimate(RsmSampleWeights::Density) / exact - 1.0).abs() < 0.01);
        // The paper's ξ₁² over-weights the rim, where this f is small: it underestimates by a third.
        assert!((estimate(RsmSampleWeights::Paper) / exact - 0.75).abs() < 0.01);
    }
}
