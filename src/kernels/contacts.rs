//! The `contacts` kernel (`shaders/contacts.wgsl`): its source, specialised
//! for the scene's size, the uniform block and the placed-grid struct (named
//! and laid out as in the WGSL, checked field by field by a test), its loop
//! budget, the dispatch ([`ContactsKernel`]) and its CPU twin
//! ([`contacts_cpu`], the same f32 arithmetic in plain Rust).
//!
//! The kernel takes plain data ([`ContactScene`]: samples, plane rows, grid
//! nodes and placements): `physical::gpu` builds that from the physical
//! scene and finishes the verdicts, and `physical::contacts` is the exact f64
//! evaluation both are checked against.

use std::sync::Arc;
use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};

use super::raster::{table_fits, texel_table};
use super::{ContactRecord, GpuPose};
use crate::error::{Error, Result};
use crate::gpu::Context;

/// The WGSL source of the kernel.
pub const CONTACTS_WGSL: &str = include_str!("../../shaders/contacts.wgsl");

/// The kernel's source with its private scene arrays sized for `planes`
/// planes and `grids` grids (WGSL cannot size private arrays by override
/// constants).
pub fn contacts_source(planes: usize, grids: usize) -> String {
    let src = CONTACTS_WGSL
        .replace("const PLANE_SLOTS: u32 = 4u;", &format!("const PLANE_SLOTS: u32 = {}u;", planes.max(1)))
        .replace("const GRID_SLOTS: u32 = 16u;", &format!("const GRID_SLOTS: u32 = {}u;", grids.max(1)));
    debug_assert!(src.contains(&format!("GRID_SLOTS: u32 = {}u;", grids.max(1))));
    src
}

/// Most planes the kernel takes (they live in the uniform block).
pub const MAX_PLANES: usize = 4;
/// Most placed grids (other objects) the kernel takes (uniform block too).
pub const MAX_GRIDS: usize = 16;

/// Invocations per workgroup (`WG` in the shader; checked by a test).
pub const WG: u32 = 64;

/// Uniform parameters (`ContactParams` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ContactParams {
    pub n_hyp: u32,
    pub n_samples: u32,
    pub n_planes: u32,
    pub n_grids: u32,
    pub eps: f32,
    pub support_cos: f32,
    pub write_deltas: u32,
    pub words: u32,
    /// The sample words `[word_begin, word_end)` this dispatch classifies
    /// (a dispatch continues the records of the one before it unless
    /// `word_begin` is 0): see [`words_per_dispatch`].
    pub word_begin: u32,
    pub word_end: u32,
    pub pad: [u32; 2],
    pub gravity: [f32; 4],
    pub planes: [[f32; 4]; MAX_PLANES],
    pub grids: [GpuGrid; MAX_GRIDS],
}
const _: () = assert!(std::mem::size_of::<ContactParams>() == 128 + 96 * MAX_GRIDS);

/// Loop iterations one invocation may run on lavapipe, with a margin below
/// llvmpipe's silent cap of 65,535 (all loops of an invocation together;
/// past it every loop ends early and the results are wrong, not an error).
pub const LOOP_BUDGET: usize = 60_000;

/// Sample words (32 samples each) one dispatch may classify so that an
/// invocation stays within [`LOOP_BUDGET`]: each sample runs its own
/// iteration plus one per plane and one per grid (the scene loops are not
/// always unrolled), each word one more, plus the per-hypothesis setup.
pub fn words_per_dispatch(planes: usize, grids: usize) -> usize {
    let per_word = 32 * (1 + planes + grids) + 1;
    let setup = planes + 4 * grids + 1;
    ((LOOP_BUDGET - setup) / per_word).max(1)
}

/// One placed grid (`GpuGrid` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuGrid {
    pub inv: [[f32; 4]; 3],
    pub origin: [f32; 4],
    pub upper: [f32; 4],
    pub dims: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuGrid>() == 96);


/// A grid contact whose normal has n·ĝ above this is left to exact
/// refinement (`REFINE_COS` in the shader).
pub const REFINE_COS: f32 = -0.99;

/// What the kernel reads, as plain data: one body's surface samples (model
/// frame), the planes and the placed signed-distance grids of the scene
/// (world frame), and the classification constants.
#[derive(Clone, Debug, Default)]
pub struct ContactScene {
    /// Surface samples, model frame (xyz, w unused).
    pub samples: Vec<[f32; 4]>,
    /// Planes as unit normal (xyz) and offset (w): δ = n·x − w.
    pub planes: Vec<[f32; 4]>,
    /// One placement per other object.
    pub grids: Vec<GpuGrid>,
    /// Node distances of every distinct grid, addressed by `dims[3]`.
    pub nodes: Vec<f32>,
    /// Unit gravity direction.
    pub gravity: [f32; 3],
    /// Largest grid error bound (m): grid values this close to ±ε are left
    /// to exact refinement.
    pub error_bound: f32,
    /// Contact band half-width ε (m).
    pub eps: f32,
    /// cos of the largest support-normal angle from straight up.
    pub support_cos: f32,
}

impl ContactScene {
    /// Refuses scenes the kernel cannot take.
    pub fn check(&self) -> Result<()> {
        if self.planes.len() > MAX_PLANES {
            return Err(Error::InvalidInput(format!(
                "the GPU contacts kernel takes at most {MAX_PLANES} planes, the scene has {}",
                self.planes.len()
            )));
        }
        if self.grids.len() > MAX_GRIDS {
            return Err(Error::InvalidInput(format!(
                "the GPU contacts kernel takes at most {MAX_GRIDS} other objects, the scene has {}",
                self.grids.len()
            )));
        }
        if self.samples.is_empty() {
            return Err(Error::InvalidInput("the body has no surface samples".into()));
        }
        // Node indices are computed in f32 on the GPU: exact below 2^24.
        if self.nodes.len() >= 1 << 24 {
            return Err(Error::InvalidInput(format!(
                "the signed-distance grids have {} nodes; the GPU kernel takes fewer than 2^24 (lower the SDF resolution)",
                self.nodes.len()
            )));
        }
        Ok(())
    }

    /// 32-sample words per pose.
    pub fn words(&self) -> usize {
        self.samples.len().div_ceil(32)
    }

    /// The uniform block for a dispatch of `n_hyp` poses over all words.
    fn params(&self, with_deltas: bool) -> ContactParams {
        let mut grids = [GpuGrid::zeroed(); MAX_GRIDS];
        grids[..self.grids.len()].copy_from_slice(&self.grids);
        let mut planes = [[0.0f32; 4]; MAX_PLANES];
        planes[..self.planes.len()].copy_from_slice(&self.planes);
        let g = self.gravity;
        ContactParams {
            n_hyp: 0,
            n_samples: self.samples.len() as u32,
            n_planes: self.planes.len() as u32,
            n_grids: self.grids.len() as u32,
            eps: self.eps,
            support_cos: self.support_cos,
            write_deltas: with_deltas as u32,
            words: self.words() as u32,
            word_begin: 0,
            word_end: self.words() as u32,
            pad: [0; 2],
            gravity: [g[0], g[1], g[2], self.error_bound],
            planes,
            grids,
        }
    }
}

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

impl ContactOutput {
    /// Samples flagged for exact refinement (for statistics).
    pub fn refined_count(&self, words: usize) -> usize {
        self.bits
            .chunks(2 * words.max(1))
            .map(|c| c[words..].iter().map(|w| w.count_ones() as usize).sum::<usize>())
            .sum()
    }
}

/// The contacts kernel for one scene, its pipeline and buffers alive: reuse
/// it for many batches of poses.
pub struct ContactsKernel {
    ctx: Context,
    params: ContactParams,
    pipeline: Arc<wgpu::ComputePipeline>,
    buffers: ContactBuffers,
    chunk: usize,
    with_deltas: bool,
}

impl ContactsKernel {
    /// Uploads the scene. At most `max_chunk` poses go in one dispatch
    /// (fewer where the adapter's limits say so); `with_deltas` also returns
    /// δ of every sample (for tests: N·M floats).
    pub fn new(ctx: &Context, scene: &ContactScene, max_chunk: usize, with_deltas: bool) -> Result<Self> {
        scene.check()?;
        if !table_fits(ctx, scene.nodes.len(), NODE_ROW) || !table_fits(ctx, scene.samples.len(), SAMPLE_ROW) {
            return Err(Error::Gpu(format!(
                "the signed-distance grids ({} MiB) or the {} surface samples are more than this adapter's textures hold; lower the SDF resolution or the samples",
                (scene.nodes.len() * 4) >> 20,
                scene.samples.len()
            )));
        }
        let chunk = chunk_size_for(ctx, scene.samples.len(), scene.words(), with_deltas, max_chunk)?;
        Ok(ContactsKernel {
            ctx: ctx.clone(),
            params: scene.params(with_deltas),
            pipeline: contacts_pipeline(ctx, scene.planes.len(), scene.grids.len(), with_deltas),
            buffers: ContactBuffers::new(ctx, scene, chunk, with_deltas)?,
            chunk,
            with_deltas,
        })
    }

    /// Poses per dispatch.
    pub fn chunk_size(&self) -> usize {
        self.chunk
    }

    /// 32-sample words per pose.
    pub fn words(&self) -> usize {
        self.params.words as usize
    }

    /// Classifies every sample of every pose (model → world); returns the
    /// raw records, bits (and δ when enabled).
    pub fn run(&self, poses: &[GpuPose]) -> Result<ContactOutput> {
        let mut out = ContactOutput::default();
        for chunk in poses.chunks(self.chunk) {
            self.run_chunk(chunk, &mut out)?;
        }
        Ok(out)
    }

    fn run_chunk(&self, chunk: &[GpuPose], out: &mut ContactOutput) -> Result<()> {
        let (ctx, b) = (&self.ctx, &self.buffers);
        let t0 = Instant::now();
        let n = chunk.len();
        let mut params = self.params;
        params.n_hyp = n as u32;
        ctx.queue.write_buffer(&b.poses, 0, bytemuck::cast_slice(chunk));
        let mut entries: Vec<wgpu::BindGroupEntry> = [(0, &b.params), (2, &b.poses), (5, &b.records), (6, &b.bits), (7, &b.deltas)]
            .into_iter()
            .map(|(binding, buf)| wgpu::BindGroupEntry { binding, resource: buf.as_entire_binding() })
            .collect();
        entries.push(wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&b.samples) });
        entries.push(wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(&b.nodes) });
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("contacts"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        // One dispatch per range of sample words (usually one), each
        // continuing the records of the one before: see words_per_dispatch.
        let step = words_per_dispatch(params.n_planes as usize, params.n_grids as usize);
        let words = self.words();
        let mut last = None;
        for begin in (0..words).step_by(step) {
            params.word_begin = begin as u32;
            params.word_end = (begin + step).min(words) as u32;
            // Queue writes land before the next submit, in order.
            ctx.queue.write_buffer(&b.params, 0, bytemuck::bytes_of(&params));
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("contacts"), timestamp_writes: None });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups((n as u32).div_ceil(WG).min(ctx.limits.max_workgroups), 1, 1);
            }
            last = Some(ctx.queue.submit([enc.finish()]));
        }
        if let Some(index) = last {
            ctx.wait_for(index)?;
        }
        out.compute += t0.elapsed();
        let t1 = Instant::now();
        let rec = ctx.read_buffer(&b.records, (n * 16) as u64)?;
        out.records.extend_from_slice(bytemuck::cast_slice(&rec));
        let bits = ctx.read_buffer(&b.bits, (n * words * 8) as u64)?;
        out.bits.extend_from_slice(bytemuck::cast_slice(&bits));
        if self.with_deltas {
            let d = ctx.read_buffer(&b.deltas, (n * params.n_samples as usize * 4) as u64)?;
            out.deltas.extend_from_slice(bytemuck::cast_slice(&d));
        }
        out.readback += t1.elapsed();
        Ok(())
    }
}

/// Poses per dispatch within the adapter's binding and workgroup limits.
fn chunk_size_for(ctx: &Context, m: usize, words: usize, with_deltas: bool, max_chunk: usize) -> Result<usize> {
    let per_pose = if with_deltas { (m * 4) as u64 } else { (words * 8) as u64 };
    let chunk = (ctx.limits.max_items(per_pose).min(ctx.limits.max_items(48)) as usize)
        .min(max_chunk.max(1))
        .min(ctx.limits.max_workgroups as usize * WG as usize);
    if chunk == 0 {
        return Err(Error::Gpu("one pose's output does not fit a storage binding".into()));
    }
    Ok(chunk)
}

/// Samples per row of the sample texture and grid nodes per row of the
/// node texture (`SAMPLE_ROW`, `NODE_ROW` in contacts.wgsl).
pub const SAMPLE_ROW: usize = 1024;
pub const NODE_ROW: usize = 4096;

/// The kernel's buffers for one scene; the read-only samples and grid
/// nodes are textures (a vector gather on lavapipe, where a storage-buffer
/// load runs lane by lane).
struct ContactBuffers {
    samples: wgpu::TextureView,
    nodes: wgpu::TextureView,
    params: wgpu::Buffer,
    poses: wgpu::Buffer,
    records: wgpu::Buffer,
    bits: wgpu::Buffer,
    deltas: wgpu::Buffer,
}

impl ContactBuffers {
    fn new(ctx: &Context, scene: &ContactScene, chunk: usize, with_deltas: bool) -> Result<ContactBuffers> {
        let storage = |label: &str, size: usize, extra: wgpu::BufferUsages| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: (size as u64).max(16),
                usage: wgpu::BufferUsages::STORAGE | extra,
                mapped_at_creation: false,
            })
        };
        let dummy_node = [0.0f32; 4];
        let nodes: &[f32] = if scene.nodes.is_empty() { &dummy_node } else { &scene.nodes };
        let words = scene.words();
        let deltas = if with_deltas { chunk * scene.samples.len() * 4 } else { 16 };
        Ok(ContactBuffers {
            samples: texel_table(ctx, "surface sample", &scene.samples, SAMPLE_ROW, wgpu::TextureFormat::Rgba32Float)?,
            nodes: texel_table(ctx, "grid node", &node_pairs(nodes), NODE_ROW, wgpu::TextureFormat::Rg32Float)?,
            params: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("contacts params"),
                size: std::mem::size_of::<ContactParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            poses: storage("contacts poses", chunk * 48, wgpu::BufferUsages::COPY_DST),
            records: storage("contacts records", chunk * 16, wgpu::BufferUsages::COPY_SRC),
            bits: storage("contacts bits", chunk * words * 8, wgpu::BufferUsages::COPY_SRC),
            deltas: storage("contacts deltas", deltas, wgpu::BufferUsages::COPY_SRC),
        })
    }
}

/// Each grid node with its +x neighbour (`node_pair` in contacts.wgsl):
/// a trilinear cell is then four texel fetches instead of eight, for
/// twice the memory (`bench physics` on lavapipe, plane + mesh grid: 71M
/// → 101M queries/s over single nodes with AVX-512, 80M → 96M with AVX2).
fn node_pairs(nodes: &[f32]) -> Vec<[f32; 2]> {
    (0..nodes.len()).map(|i| [nodes[i], nodes.get(i + 1).copied().unwrap_or(0.0)]).collect()
}

/// The kernel's own pipeline (not the context's cache): the scene's shape
/// is baked in through override constants and the private array sizes.
fn contacts_pipeline(ctx: &Context, n_planes: usize, n_grids: usize, with_deltas: bool) -> Arc<wgpu::ComputePipeline> {
    let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("contacts"),
        source: wgpu::ShaderSource::Wgsl(contacts_source(n_planes, n_grids).into()),
    });
    let constants = [("N_PLANES", n_planes as f64), ("N_GRIDS", n_grids as f64), ("WRITE_DELTAS", if with_deltas { 1.0 } else { 0.0 })];
    Arc::new(ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("contacts"),
        layout: None,
        module: &module,
        entry_point: Some("contacts_main"),
        compilation_options: wgpu::PipelineCompilationOptions { constants: &constants, zero_initialize_workgroup_memory: false },
        cache: None,
    }))
}

// ---------------------------------------------------------------------------
// CPU twin: the shader's arithmetic in f32, one function per WGSL function.

fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn xyz(v: [f32; 4]) -> [f32; 3] {
    [v[0], v[1], v[2]]
}

fn mix(a: f32, b: f32, t: f32) -> f32 {
    a * (1.0 - t) + b * t
}

/// `Cell` in the shader: the eight node values around a point (z = 0
/// corners in `lo`, z = 1 in `hi`, each 000, 100, 010, 110), the point's
/// fraction in the cell and its offset from the grid box.
struct Cell {
    lo: [f32; 4],
    hi: [f32; 4],
    f: [f32; 3],
    out: [f32; 3],
}

impl Cell {
    fn outside(&self) -> bool {
        self.out != [0.0; 3]
    }
}

/// `grid_cell`: looks up at the point clamped into the box.
fn grid_cell(g: &GpuGrid, nodes: &[f32], q: [f32; 3]) -> Cell {
    let (o, up, dims) = (g.origin, g.upper, g.dims);
    let mut u = [0.0f32; 3];
    let mut f = [0.0f32; 3];
    let mut out = [0.0f32; 3];
    let mut b = 0.0f32;
    let strides = [1.0, dims[0] as f32, dims[0] as f32 * dims[1] as f32];
    for a in 0..3 {
        let qc = q[a].max(o[a]).min(up[a]);
        out[a] = q[a] - qc;
        u[a] = (qc - o[a]) * o[3];
        let cell = u[a].floor().min(dims[a] as f32 - 2.0);
        f[a] = u[a] - cell;
        b += cell * strides[a];
    }
    let b = b as usize + dims[3] as usize;
    let (iy, iz) = (dims[0] as usize, dims[0] as usize * dims[1] as usize);
    let at = |i: usize| nodes[i];
    Cell {
        lo: [at(b), at(b + 1), at(b + iy), at(b + iy + 1)],
        hi: [at(b + iz), at(b + iz + 1), at(b + iz + iy), at(b + iz + iy + 1)],
        f,
        out,
    }
}

/// `cell_distance`: trilinear δ, or |to box| + margin outside it.
fn cell_distance(g: &GpuGrid, c: &Cell) -> f32 {
    if c.outside() {
        return dot3(c.out, c.out).sqrt() + g.upper[3];
    }
    let z: Vec<f32> = (0..4).map(|i| mix(c.lo[i], c.hi[i], c.f[2])).collect();
    mix(mix(z[0], z[1], c.f[0]), mix(z[2], z[3], c.f[0]), c.f[1])
}

/// `cell_gradient`: the interpolant's gradient (model frame, not unit).
fn cell_gradient(c: &Cell) -> [f32; 3] {
    if c.outside() {
        return [0.0; 3];
    }
    let (lo, hi, f) = (c.lo, c.hi, c.f);
    let dx = [lo[1] - lo[0], lo[3] - lo[2], hi[1] - hi[0], hi[3] - hi[2]];
    let dy = [lo[2] - lo[0], lo[3] - lo[1], hi[2] - hi[0], hi[3] - hi[1]];
    let dz: Vec<f32> = (0..4).map(|i| hi[i] - lo[i]).collect();
    [
        mix(mix(dx[0], dx[1], f[1]), mix(dx[2], dx[3], f[1]), f[2]),
        mix(mix(dy[0], dy[1], f[0]), mix(dy[2], dy[3], f[0]), f[2]),
        mix(mix(dz[0], dz[1], f[0]), mix(dz[2], dz[3], f[0]), f[1]),
    ]
}

/// `grid_normal`: a model-frame gradient as a world unit normal (or zero).
fn grid_normal(g: &GpuGrid, gm: [f32; 3]) -> [f32; 3] {
    let len = dot3(gm, gm).sqrt();
    if len <= 0.0 {
        return [0.0; 3];
    }
    let m = gm.map(|x| x / len);
    std::array::from_fn(|a| m[0] * g.inv[0][a] + m[1] * g.inv[1][a] + m[2] * g.inv[2][a])
}

/// One hypothesis' scene in its model frame: planes as (Rᵀn, w − n·t),
/// grids as the composite model → grid-model rows.
fn scene_in_model(scene: &ContactScene, p: &GpuPose) -> (Vec<[f32; 4]>, Vec<[[f32; 4]; 3]>) {
    let t = [p.rows[0][3], p.rows[1][3], p.rows[2][3]];
    let back = |v: [f32; 4]| -> [f32; 3] { std::array::from_fn(|a| v[0] * p.rows[0][a] + v[1] * p.rows[1][a] + v[2] * p.rows[2][a]) };
    let planes = scene
        .planes
        .iter()
        .map(|pl| {
            let n = back(*pl);
            [n[0], n[1], n[2], pl[3] - dot3(xyz(*pl), t)]
        })
        .collect();
    let grids = scene
        .grids
        .iter()
        .map(|g| {
            std::array::from_fn(|i| {
                let r = back(g.inv[i]);
                [r[0], r[1], r[2], dot3(xyz(g.inv[i]), t) + g.inv[i][3]]
            })
        })
        .collect();
    (planes, grids)
}

/// The closest component of one model-frame sample: δ, world unit normal,
/// and whether the trilinear values cannot decide its class.
fn closest(scene: &ContactScene, planes: &[[f32; 4]], grids: &[[[f32; 4]; 3]], s: [f32; 3]) -> (f32, [f32; 3], bool) {
    let (mut d, mut n, mut refine) = (3.0e38f32, [0.0f32; 3], false);
    for (k, pm) in planes.iter().enumerate() {
        let dk = dot3(xyz(*pm), s) - pm[3];
        if dk < d {
            d = dk;
            n = xyz(scene.planes[k]);
        }
    }
    for (k, gm) in grids.iter().enumerate() {
        let g = &scene.grids[k];
        let q = std::array::from_fn(|i| dot3(xyz(gm[i]), s) + gm[i][3]);
        let cl = grid_cell(g, &scene.nodes, q);
        let c = cell_distance(g, &cl);
        if c.abs() < scene.eps + scene.error_bound {
            let nk = grid_normal(g, cell_gradient(&cl));
            if (c.abs() - scene.eps).abs() <= scene.error_bound || dot3(nk, scene.gravity) > REFINE_COS {
                refine = true;
            }
            if c < d {
                (d, n) = (c, nk);
            }
        } else if c < d {
            (d, n) = (c, [0.0; 3]);
        }
    }
    (d, n, refine)
}

/// The CPU twin of the kernel: the same records, bits and δ for the same
/// inputs, computed with the shader's f32 arithmetic (results may differ in
/// the last bits where the GPU fuses multiply-adds; the tests state the
/// tolerance).
pub fn contacts_cpu(scene: &ContactScene, poses: &[GpuPose], with_deltas: bool) -> ContactOutput {
    let words = scene.words();
    let m = scene.samples.len();
    let mut out = ContactOutput { bits: vec![0; poses.len() * 2 * words], ..Default::default() };
    for (h, p) in poses.iter().enumerate() {
        let (planes, grids) = scene_in_model(scene, p);
        let (mut cnt, mut mn) = ([0u32; 3], 3.0e38f32);
        for (j, s) in scene.samples.iter().enumerate() {
            let (d, n, refine) = closest(scene, &planes, &grids, xyz(*s));
            if with_deltas {
                out.deltas.push(d);
            }
            let (w, bit) = (j / 32, 1u32 << (j % 32));
            if refine {
                out.bits[(2 * h + 1) * words + w] |= bit;
                continue;
            }
            mn = mn.min(d);
            if d < -scene.eps {
                cnt[0] += 1;
            } else if d.abs() < scene.eps {
                cnt[1] += 1;
                if dot3(n, scene.gravity) < -scene.support_cos {
                    cnt[2] += 1;
                    out.bits[2 * h * words + w] |= bit;
                }
            }
        }
        debug_assert!(!with_deltas || out.deltas.len() == (h + 1) * m);
        out.records.push(ContactRecord { intersecting: cnt[0], contact: cnt[1], supported: cnt[2], min_delta: mn });
    }
    out
}


#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::{ContactRecord, GpuPose};

    /// The WGSL structs match the Rust ones field by field (naga's layouter).
    #[test]
    fn wgsl_structs_match_rust_field_by_field() {
        use crate::kernels::wgsl_layout::assert_layout;
        use std::mem::{offset_of, size_of};
        let src = CONTACTS_WGSL;
        macro_rules! same {
            ($t:ty, $($f:ident),+) => { &[$((stringify!($f), offset_of!($t, $f))),+] };
        }
        let pad = offset_of!(ContactParams, pad);
        let mut params: Vec<(&str, usize)> =
            same!(ContactParams, n_hyp, n_samples, n_planes, n_grids, eps, support_cos, write_deltas, words, word_begin, word_end, gravity, planes, grids).to_vec();
        params.extend([("pad0", pad), ("pad1", pad + 4)]);
        assert_layout(src, "ContactParams", size_of::<ContactParams>(), &params);
        assert_layout(src, "GpuGrid", size_of::<GpuGrid>(), same!(GpuGrid, inv, origin, upper, dims));
        assert_layout(src, "GpuPose", size_of::<GpuPose>(), same!(GpuPose, rows));
        assert_layout(src, "ContactRecord", size_of::<ContactRecord>(), same!(ContactRecord, intersecting, contact, supported, min_delta));
        assert!(CONTACTS_WGSL.contains(&format!("const WG: u32 = {WG}u;")));
        assert!(CONTACTS_WGSL.contains(&format!("const PLANE_SLOTS: u32 = {MAX_PLANES}u;")));
        assert!(CONTACTS_WGSL.contains(&format!("const GRID_SLOTS: u32 = {MAX_GRIDS}u;")));
    }

}
