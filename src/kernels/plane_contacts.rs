//! The fused plane stage of the score kernel (`shaders/plane_contacts.wgsl`,
//! composed after `score.wgsl`): after its visual reduction each workgroup
//! moves the support plane into the hypothesis' model frame, classifies the
//! surface samples with one dot product each and writes a record and one
//! bit per supported sample. This module owns the stage's layouts (named as
//! in the WGSL) and buffers; it takes the plane and samples as plain data.
//! Its CPU twin is the exact classifier of `physical::contacts`, and
//! `physical::batch::PlanePhysics` prepares the inputs and finishes the
//! support polygons.

use bytemuck::{Pod, Zeroable};

use super::ContactRecord;
use crate::error::{Error, Result};
use crate::gpu::Context;

/// Uniform block of the plane stage of the fused score kernel
/// (`PlaneParams` in `shaders/plane_contacts.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PlaneParams {
    /// Unit normal (towards the camera) and offset `w` of the support plane
    /// in the camera frame: δ = n·x − w.
    pub plane: [f32; 4],
    pub n_samples: u32,
    /// u32 words of supported bits per hypothesis (`n_samples / 32`, rounded up).
    pub words: u32,
    pub eps: f32,
    pub pad: u32,
}
const _: () = assert!(std::mem::size_of::<PlaneParams>() == 32);

/// The WGSL of the score kernel with the fused plane stage
/// (`shaders/plane_contacts.wgsl`).
pub const SCORE_PHYSICS_WGSL: &str = concat!(
    include_str!("../../shaders/raster.wgsl"),
    "\n",
    include_str!("../../shaders/score.wgsl"),
    "\n",
    include_str!("../../shaders/plane_contacts.wgsl")
);

/// The physical terms the fused kernel returns for a batch: one record and
/// `words` supported-sample words per hypothesis, input order (finish them
/// with `physical::batch::PlanePhysics::finish_fused`).
#[derive(Clone, Debug, Default)]
pub struct PlaneContactOutput {
    pub records: Vec<ContactRecord>,
    pub bits: Vec<u32>,
}

/// Buffers and pipeline of the fused plane stage.
pub(crate) struct PlaneStage {
    pub words: usize,
    pub params: wgpu::Buffer,
    /// The samples as a texture (`samples` in plane_contacts.wgsl),
    /// `contacts::SAMPLE_ROW` per row.
    pub samples: wgpu::TextureView,
    pub records: wgpu::Buffer,
    pub bits: wgpu::Buffer,
    pub pipeline: std::sync::Arc<wgpu::ComputePipeline>,
}

/// Uploads the plane stage's parameters and samples and sizes its outputs
/// for `chunk` hypotheses per dispatch.
pub(crate) fn plane_stage(ctx: &Context, params: &PlaneParams, samples: &[[f32; 4]], chunk: usize) -> Result<PlaneStage> {
    use wgpu::util::DeviceExt;
    if samples.is_empty() {
        return Err(Error::InvalidInput("the body has no surface samples".into()));
    }
    // raster (poses, vis) + score (records) + this stage (records, bits);
    // the triangles, meshlets, observation and samples are textures.
    let needed = 5;
    let have = ctx.device.limits().max_storage_buffers_per_shader_stage;
    if have < needed {
        return Err(Error::Gpu(format!(
            "the physical terms on this adapter need {needed} storage buffers per shader stage, it offers {have}; use the CPU twin (device `cpu`)"
        )));
    }
    let words = params.words as usize;
    let bits_bytes = (chunk * words * 4) as u64;
    if bits_bytes > ctx.limits.max_items(1) || !super::raster::table_fits(ctx, samples.len(), super::contacts::SAMPLE_ROW) {
        return Err(Error::Gpu(format!(
            "{} surface samples do not fit this adapter's storage bindings and textures; use fewer samples",
            samples.len()
        )));
    }
    let init = |label: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
        ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: bytes, usage })
    };
    let output = |label: &str, size: u64| {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    };
    Ok(PlaneStage {
        words,
        params: init("plane params", bytemuck::bytes_of(params), wgpu::BufferUsages::UNIFORM),
        samples: super::raster::texel_table(ctx, "surface sample", samples, super::contacts::SAMPLE_ROW, wgpu::TextureFormat::Rgba32Float)?,
        records: output("plane records", (chunk * std::mem::size_of::<ContactRecord>()) as u64),
        bits: output("plane bits", bits_bytes),
        pipeline: ctx.pipeline(super::score::PLANE_SCORE, SCORE_PHYSICS_WGSL, "score_physics_main"),
    })
}
