//! GPU dispatch of the `contacts` kernel (`shaders/contacts.wgsl`): N poses
//! of one body × its M samples × the environment (planes and grids), one
//! 16-byte record and M bits per pose read back. The support polygon is
//! finished on the CPU from the supported-sample bits (a hull of a few
//! hundred 2D points per pose, in parallel): exact for the GPU's
//! classification, and cheaper than shipping the points back.
//!
//! The GPU uses the trilinear grid values, so δ of a sample near another
//! object differs from the exact value by at most the grid's error bound
//! ([`super::sdf::SdfGrid::error_bound`]); plane distances agree to f32
//! rounding. Samples whose class those values cannot decide (a grid value
//! within the bound of ±ε, or a grid contact near an edge of the other
//! object, where interpolated normals blend faces) are flagged by the kernel
//! and refined exactly on the CPU in [`GpuContacts::finish`], so the
//! verdicts match the CPU twin's.

use std::sync::Arc;
use std::time::{Duration, Instant};

use bytemuck::Zeroable;
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::contacts::{classify, finish, Body, Environment, Evaluation, Tally, SUPPORT_COS};
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::kernels::GpuPose;
use crate::pose::Pose;

pub use crate::kernels::contacts::{contacts_source, words_per_dispatch, ContactParams, GpuGrid, CONTACTS_WGSL, MAX_GRIDS, MAX_PLANES};
pub use crate::kernels::ContactRecord;
use crate::kernels::contacts::WG;

/// What one run returns.
#[derive(Clone, Debug, Default)]
pub struct ContactOutput {
    pub records: Vec<ContactRecord>,
    /// `2 · words` u32 per pose: first the supported bits (bit `j % 32` of
    /// word `j / 32` = sample j supported), then the refine bits (sample j
    /// left to the CPU: not counted in the record).
    pub bits: Vec<u32>,
    /// δ per pose and sample (pose-major), when asked for.
    pub deltas: Vec<f32>,
    /// Wall time of upload + dispatch until the GPU finished.
    pub compute: Duration,
    /// Wall time of the readback.
    pub readback: Duration,
}

/// The contacts kernel for one body against one environment; reuse it for
/// many batches of poses.
pub struct GpuContacts {
    ctx: Context,
    body: Body,
    env: Environment,
    params: ContactParams,
    pipeline: Arc<wgpu::ComputePipeline>,
    samples: wgpu::Buffer,
    nodes: wgpu::Buffer,
    params_buf: wgpu::Buffer,
    poses: wgpu::Buffer,
    records: wgpu::Buffer,
    bits: wgpu::Buffer,
    deltas: wgpu::Buffer,
    chunk: usize,
    with_deltas: bool,
}

fn storage(ctx: &Context, label: &str, size: u64, extra: wgpu::BufferUsages) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage: wgpu::BufferUsages::STORAGE | extra,
        mapped_at_creation: false,
    })
}

impl GpuContacts {
    /// Uploads the body's samples and the environment. At most `max_chunk`
    /// poses go in one dispatch (fewer where the adapter's limits say so);
    /// `with_deltas` also returns δ of every sample (for tests: N·M floats).
    pub fn new(ctx: &Context, body: &Body, env: &Environment, max_chunk: usize, with_deltas: bool) -> Result<Self> {
        check_scene(body, env)?;
        let m = body.samples.len();
        let words = m.div_ceil(32);
        let g = env.gravity.normalize();
        let planes = plane_rows(env);
        let (node_data, descs) = grid_block(ctx, env)?;
        let chunk = chunk_size_for(ctx, m, words, with_deltas, max_chunk)?;
        let mut grid_block = [GpuGrid::zeroed(); MAX_GRIDS];
        grid_block[..descs.len()].copy_from_slice(&descs);
        let params = ContactParams {
            grids: grid_block,
            n_hyp: 0,
            n_samples: m as u32,
            n_planes: env.planes.len() as u32,
            n_grids: descs.len() as u32,
            eps: body.epsilon as f32,
            support_cos: SUPPORT_COS as f32,
            write_deltas: with_deltas as u32,
            words: words as u32,
            word_begin: 0,
            word_end: words as u32,
            pad: [0; 2],
            gravity: [g.x as f32, g.y as f32, g.z as f32, env.error_bound() as f32],
            planes,
        };
        let b = ContactBuffers::new(ctx, body, &node_data, chunk, words, with_deltas);
        let pipeline = contacts_pipeline(ctx, env.planes.len(), descs.len(), with_deltas);
        Ok(GpuContacts {
            ctx: ctx.clone(),
            body: body.clone(),
            env: env.clone(),
            params,
            pipeline,
            samples: b.samples,
            nodes: b.nodes,
            params_buf: b.params,
            poses: b.poses,
            records: b.records,
            bits: b.bits,
            deltas: b.deltas,
            chunk,
            with_deltas,
        })
    }

    /// Poses per dispatch.
    pub fn chunk_size(&self) -> usize {
        self.chunk
    }

    /// Classifies every sample of every pose; returns the raw records, bits
    /// (and δ when enabled).
    pub fn run(&self, poses: &[Pose]) -> Result<ContactOutput> {
        let mut out = ContactOutput::default();
        for chunk in poses.chunks(self.chunk) {
            self.run_chunk(chunk, &mut out)?;
        }
        Ok(out)
    }

    fn run_chunk(&self, chunk: &[Pose], out: &mut ContactOutput) -> Result<()> {
        let ctx = &self.ctx;
        let t0 = Instant::now();
        let n = chunk.len();
        let mut params = self.params;
        params.n_hyp = n as u32;
        let gp: Vec<GpuPose> = chunk.iter().map(GpuPose::from).collect();
        ctx.queue
            .write_buffer(&self.poses, 0, bytemuck::cast_slice(&gp));
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("contacts"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.params_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.samples.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.poses.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: self.nodes.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: self.records.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: self.bits.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: self.deltas.as_entire_binding(),
                },
            ],
        });
        // One dispatch per range of sample words (usually one), each
        // continuing the records of the one before: see words_per_dispatch.
        let step = words_per_dispatch(self.env.planes.len(), self.env.obstacles.len());
        let words = self.params.words as usize;
        for begin in (0..words).step_by(step) {
            params.word_begin = begin as u32;
            params.word_end = (begin + step).min(words) as u32;
            // Queue writes land before the next submit, in order.
            ctx.queue
                .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&params));
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("contacts"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(
                    (n as u32).div_ceil(WG).min(self.ctx.limits.max_workgroups),
                    1,
                    1,
                );
            }
            ctx.queue.submit([enc.finish()]);
        }
        ctx.wait()?;
        out.compute += t0.elapsed();
        let t1 = Instant::now();
        let words = self.params.words as usize;
        let rec = ctx.read_buffer(&self.records, (n * 16) as u64)?;
        out.records.extend_from_slice(bytemuck::cast_slice(&rec));
        let bits = ctx.read_buffer(&self.bits, (n * words * 8) as u64)?;
        out.bits.extend_from_slice(bytemuck::cast_slice(&bits));
        if self.with_deltas {
            let d = ctx.read_buffer(&self.deltas, (n * self.body.samples.len() * 4) as u64)?;
            out.deltas.extend_from_slice(bytemuck::cast_slice(&d));
        }
        out.readback += t1.elapsed();
        Ok(())
    }

    /// Evaluations of `poses`: the GPU's classification, the support
    /// polygon finished on the CPU.
    pub fn evaluate(&self, poses: &[Pose]) -> Result<Vec<Evaluation>> {
        let out = self.run(poses)?;
        Ok(self.finish(poses, &out))
    }

    /// Completes evaluations from a run's output: refines the flagged
    /// samples exactly and builds the support polygons.
    pub fn finish(&self, poses: &[Pose], out: &ContactOutput) -> Vec<Evaluation> {
        finish_from_bits(&self.body, &self.env, poses, &out.records, &out.bits, self.params.words as usize, true)
    }

    /// Samples flagged for refinement in a run's output (for statistics).
    pub fn refined_count(&self, out: &ContactOutput) -> usize {
        let words = self.params.words as usize;
        out.bits
            .chunks(2 * words)
            .map(|c| {
                c[words..]
                    .iter()
                    .map(|w| w.count_ones() as usize)
                    .sum::<usize>()
            })
            .sum()
    }
}

/// Completes the evaluations of `poses` (world frame) from a kernel's
/// per-pose records and sample bits: `words` u32 of supported bits per pose,
/// followed, when `with_refine`, by `words` u32 of samples left to the CPU,
/// which are classified here exactly. The support polygons are built from
/// the supported samples, in parallel over poses.
pub(crate) fn finish_from_bits(
    body: &Body,
    env: &Environment,
    poses: &[Pose],
    records: &[ContactRecord],
    bits: &[u32],
    words: usize,
    with_refine: bool,
) -> Vec<Evaluation> {
    let stride = words * if with_refine { 2 } else { 1 };
    let g = env.gravity.normalize();
    let eps = body.epsilon;
    poses
        .par_iter()
        .enumerate()
        .map(|(i, pose)| {
            let r = records[i];
            let supported = &bits[i * stride..i * stride + words];
            let refine = with_refine.then(|| &bits[i * stride + words..(i + 1) * stride]);
            let mut tally = Tally { intersecting: r.intersecting, contact: r.contact, supported: Vec::new() };
            let mut min = r.min_delta as f64;
            for (j, s) in body.samples.iter().enumerate() {
                let (w, b) = (j / 32, j % 32);
                if supported[w] >> b & 1 == 1 {
                    tally.supported.push(pose.transform_point(*s));
                } else if refine.is_some_and(|r| r[w] >> b & 1 == 1) {
                    let x = pose.transform_point(*s);
                    let d = env.refined_distance(x, eps);
                    min = min.min(d.delta);
                    tally.add(classify(d.delta, d.normal, eps, g), x);
                }
            }
            finish(tally.intersecting, tally.contact, min, &tally.supported, pose.transform_point(body.com), env.gravity).0
        })
        .collect()
}

/// Refuses scenes the kernel cannot take: too many planes or objects, an
/// ε the grids cannot resolve, a body without samples.
fn check_scene(body: &Body, env: &Environment) -> Result<()> {
    if env.planes.len() > MAX_PLANES {
        return Err(Error::InvalidInput(format!(
            "the GPU contacts kernel takes at most {MAX_PLANES} planes, the scene has {}",
            env.planes.len()
        )));
    }
    if env.obstacles.len() > MAX_GRIDS {
        return Err(Error::InvalidInput(format!(
            "the GPU contacts kernel takes at most {MAX_GRIDS} other objects, the scene has {}",
            env.obstacles.len()
        )));
    }
    env.check_epsilon(body.epsilon)?;
    if body.samples.is_empty() {
        return Err(Error::InvalidInput(
            "the body has no surface samples".into(),
        ));
    }
    Ok(())
}

/// The planes as the uniform block holds them: unit normal and offset.
fn plane_rows(env: &Environment) -> [[f32; 4]; MAX_PLANES] {
    let mut planes = [[0.0f32; 4]; MAX_PLANES];
    for (i, p) in env.planes.iter().enumerate() {
        planes[i] = [
            p.normal.x as f32,
            p.normal.y as f32,
            p.normal.z as f32,
            p.normal.dot(p.point) as f32,
        ];
    }
    planes
}

/// Each distinct grid's nodes once, and one descriptor per placed
/// obstacle; checked against the kernel's and the adapter's limits.
fn grid_block(ctx: &Context, env: &Environment) -> Result<(Vec<f32>, Vec<GpuGrid>)> {
    // Grids: each distinct grid's nodes once, one descriptor per placement.
    let mut node_data: Vec<f32> = Vec::new();
    let mut offsets: Vec<(*const super::sdf::SdfGrid, u32)> = Vec::new();
    let mut descs = Vec::new();
    for o in &env.obstacles {
        let key = Arc::as_ptr(&o.sdf);
        let offset = match offsets.iter().find(|(k, _)| *k == key) {
            Some((_, off)) => *off,
            None => {
                let off = node_data.len() as u32;
                node_data.extend(o.sdf.nodes.iter().map(|n| n[3]));
                offsets.push((key, off));
                off
            }
        };
        let inv = o.pose.inverse();
        let gp = GpuPose::from(&inv);
        let s = &o.sdf;
        let up = s.upper();
        descs.push(GpuGrid {
            inv: gp.rows,
            origin: [
                s.origin.x as f32,
                s.origin.y as f32,
                s.origin.z as f32,
                (1.0 / s.h) as f32,
            ],
            upper: [up.x as f32, up.y as f32, up.z as f32, s.margin as f32],
            dims: [s.dims[0] as u32, s.dims[1] as u32, s.dims[2] as u32, offset],
        });
    }
    // Node indices are computed in f32 on the GPU: exact below 2^24.
    if node_data.len() >= 1 << 24 {
        return Err(Error::InvalidInput(format!(
            "the signed-distance grids have {} nodes; the GPU kernel takes fewer than 2^24 (lower the SDF resolution)",
            node_data.len()
        )));
    }
    if (node_data.len() as u64) * 4 > ctx.limits.max_items(1) {
        return Err(Error::Gpu(format!(
            "the signed-distance grids need {} MiB, more than one storage binding holds on this adapter; lower the SDF resolution",
            (node_data.len() * 4) >> 20
        )));
    }
    Ok((node_data, descs))
}

/// Poses per dispatch within the adapter's binding and workgroup limits.
fn chunk_size_for(ctx: &Context, m: usize, words: usize, with_deltas: bool, max_chunk: usize) -> Result<usize> {
    // Chunk: poses per dispatch within the binding limits.
    let per_pose = if with_deltas {
        (m * 4) as u64
    } else {
        (words * 8) as u64
    };
    let chunk = (ctx.limits.max_items(per_pose).min(ctx.limits.max_items(48)) as usize)
        .min(max_chunk.max(1))
        .min(ctx.limits.max_workgroups as usize * WG as usize);
    if chunk == 0 {
        return Err(Error::Gpu(
            "one pose's output does not fit a storage binding".into(),
        ));
    }
    Ok(chunk)
}

/// The kernel's buffers for one body and scene.
struct ContactBuffers {
    samples: wgpu::Buffer,
    nodes: wgpu::Buffer,
    params: wgpu::Buffer,
    poses: wgpu::Buffer,
    records: wgpu::Buffer,
    bits: wgpu::Buffer,
    deltas: wgpu::Buffer,
}

impl ContactBuffers {
    fn new(ctx: &Context, body: &Body, node_data: &[f32], chunk: usize, words: usize, with_deltas: bool) -> ContactBuffers {
        let m = body.samples.len();
        let samples: Vec<[f32; 4]> = body
            .samples
            .iter()
            .map(|s| [s.x as f32, s.y as f32, s.z as f32, 0.0])
            .collect();
        let init = |label: &str, bytes: &[u8]| {
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: bytes,
                    usage: wgpu::BufferUsages::STORAGE,
                })
        };
        let dummy_node = [0.0f32; 4];
        let samples_buf = init("contacts samples", bytemuck::cast_slice(&samples));
        let nodes = init(
            "contacts nodes",
            bytemuck::cast_slice(if node_data.is_empty() {
                &dummy_node[..]
            } else {
                node_data
            }),
        );
        let params_buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("contacts params"),
            size: std::mem::size_of::<ContactParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let poses = storage(
            ctx,
            "contacts poses",
            (chunk * 48) as u64,
            wgpu::BufferUsages::COPY_DST,
        );
        let records = storage(
            ctx,
            "contacts records",
            (chunk * 16) as u64,
            wgpu::BufferUsages::COPY_SRC,
        );
        let bits = storage(
            ctx,
            "contacts bits",
            (chunk * words * 8) as u64,
            wgpu::BufferUsages::COPY_SRC,
        );
        let deltas = storage(
            ctx,
            "contacts deltas",
            if with_deltas {
                (chunk * m * 4) as u64
            } else {
                16
            },
            wgpu::BufferUsages::COPY_SRC,
        );
        ContactBuffers { samples: samples_buf, nodes, params: params_buf, poses, records, bits, deltas }
    }
}

/// The kernel's own pipeline (not the context's cache): the scene's shape
/// is baked in through override constants and the private array sizes.
fn contacts_pipeline(ctx: &Context, n_planes: usize, n_grids: usize, with_deltas: bool) -> Arc<wgpu::ComputePipeline> {
    let module = ctx
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("contacts"),
            source: wgpu::ShaderSource::Wgsl(contacts_source(n_planes, n_grids).into()),
        });
    let constants = [
        ("N_PLANES", n_planes as f64),
        ("N_GRIDS", n_grids as f64),
        ("WRITE_DELTAS", if with_deltas { 1.0 } else { 0.0 }),
    ];
    Arc::new(ctx.device.create_compute_pipeline(
        &wgpu::ComputePipelineDescriptor {
            label: Some("contacts"),
            layout: None,
            module: &module,
            entry_point: Some("contacts_main"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &constants,
                zero_initialize_workgroup_memory: false,
            },
            cache: None,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every specialised source still validates.
    #[test]
    fn specialised_sources_validate() {
        for (planes, grids) in [(0, 0), (1, 0), (1, 1), (4, 16)] {
            let src = contacts_source(planes, grids);
            assert!(src.contains(&format!("const GRID_SLOTS: u32 = {}u;", grids.max(1))));
            crate::kernels::wgsl_layout::module("contacts", &src);
        }
    }
}
