//! `score` kernel: the visual-alignment score (eq. 3-5) fused with rendering
//! and reduced on the GPU to one [`ScoreRecord`] per hypothesis.
//!
//! The CPU twin renders with [`raster_ids`](super::raster::raster_ids) and
//! scores with [`score_image`]: the definition, written out plainly.

use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use rayon::prelude::*;

use super::raster::{raster_params, render_ids, resolve, RasterBuffers, WaveLayout};
use super::{GpuPose, RenderMesh};
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::observation::ScoreTarget;
use super::plane_contacts::{plane_stage, PlaneContactOutput, PlaneParams, PlaneStage};
use super::ContactRecord;
use crate::pose::Pose;

/// Alignment tolerances of eq. 4-5.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScoreParams {
    /// Depth tolerance τ in metres (authors' code: 0.02).
    pub tau: f32,
    /// Normal tolerance α on `1 - n·n̂` (authors' code: 0.7).
    pub alpha: f32,
}

impl Default for ScoreParams {
    fn default() -> Self {
        ScoreParams { tau: 0.02, alpha: 0.7 }
    }
}

/// Per-hypothesis result, as written by the GPU (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ScoreRecord {
    /// ½ (mean a_d + mean a_n) over V; 0 when V is empty.
    pub score: f32,
    pub mean_ad: f32,
    pub mean_an: f32,
    /// |V|: pixels valid in the observation or the rendering.
    pub valid: u32,
    /// Pixels where the hypothesis renders.
    pub rendered: u32,
    /// Pixels with observed (masked) depth.
    pub observed: u32,
    /// Rendered more than τ in front of the observation.
    pub front: u32,
    /// Rendered more than τ behind the observation.
    pub behind: u32,
}
const _: () = assert!(std::mem::size_of::<ScoreRecord>() == 32);

/// Accumulates eq. 3-5 over one hypothesis' pixels.
#[derive(Default)]
struct Acc {
    ad: f64,
    an: f64,
    rec: ScoreRecord,
}

impl Acc {
    #[inline]
    fn pixel(&mut self, obs_d: f32, obs_n: Vec3, ren: Option<(f32, Vec3)>, p: &ScoreParams) {
        let has_obs = obs_d > 0.0;
        if !has_obs && ren.is_none() {
            return;
        }
        self.rec.valid += 1;
        self.rec.observed += has_obs as u32;
        let Some((d, n)) = ren else { return };
        self.rec.rendered += 1;
        if !has_obs {
            return; // valid in one image only: a_d = a_n = 0
        }
        let diff = d - obs_d;
        self.ad += (1.0 - (diff.abs() / p.tau).min(1.0)) as f64;
        if obs_n != Vec3::ZERO {
            let c = obs_n.dot(n).clamp(0.0, 1.0);
            self.an += (1.0 - ((1.0 - c) / p.alpha).min(1.0)) as f64;
        }
        if diff < -p.tau {
            self.rec.front += 1;
        } else if diff > p.tau {
            self.rec.behind += 1;
        }
    }

    fn finish(mut self) -> ScoreRecord {
        if self.rec.valid > 0 {
            let inv = 1.0 / self.rec.valid as f64;
            self.rec.mean_ad = (self.ad * inv) as f32;
            self.rec.mean_an = (self.an * inv) as f32;
            self.rec.score = (0.5 * (self.ad + self.an) * inv) as f32;
        }
        self.rec
    }
}

/// Scores one rendered depth/normal image against the target (the
/// definition of eq. 3-5, pixel by pixel).
pub fn score_image(target: &ScoreTarget, depth: &[f32], normals: &[Vec3], p: &ScoreParams) -> ScoreRecord {
    let mut acc = Acc::default();
    for i in 0..target.depth.len() {
        let ren = (depth[i] > 0.0 && !target.hidden(i, depth[i])).then(|| (depth[i], normals[i]));
        acc.pixel(target.depth[i], target.normals[i], ren, p);
    }
    acc.finish()
}

/// The record of a hypothesis that draws nothing in the region: every
/// observed pixel is in V and scores 0.
pub fn unseen_record(n_obs: u32) -> ScoreRecord {
    let mut acc = Acc::default();
    acc.rec.valid = n_obs;
    acc.rec.observed = n_obs;
    acc.finish()
}

/// CPU twin of the fused `score` kernel for a batch: renders each pose into
/// a per-thread z-buffer and scores it, in parallel over hypotheses.
///
/// Like the kernel, it visits only the hypothesis' screen rectangle: outside
/// it nothing is rendered, so those pixels are in V exactly when observed
/// and score 0 there; they enter through the region's observed-pixel count.
pub fn score_cpu(mesh: &RenderMesh, target: &ScoreTarget, poses: &[Pose], p: &ScoreParams) -> Vec<ScoreRecord> {
    let k = &target.intrinsics;
    let n = k.pixels();
    let w = k.width as usize;
    let n_obs = target.observed_pixels() as u32;
    poses
        .par_iter()
        .map_init(
            || (vec![0.0f32; n], vec![0u32; n]),
            |(zbuf, ids), pose| {
                let gp = GpuPose::from(pose);
                let du = gp.dual();
                let mut acc = Acc::default();
                if let Some([x0, y0, x1, y1]) = render_ids(mesh, &gp, k, zbuf, ids) {
                    for y in y0..=y1 {
                        for x in x0..=x1 {
                            let i = y * w + x;
                            if ids[i] == u32::MAX {
                                continue;
                            }
                            let ren = resolve(&mesh.triangles[ids[i] as usize], &gp, &du, mesh.radius, k, x as f32, y as f32);
                            if target.hidden(i, ren.0) {
                                continue; // behind another object of the scene
                            }
                            acc.pixel(target.depth[i], target.normals[i], Some(ren), p);
                        }
                    }
                }
                // Observed pixels that are not rendered: in V, scoring 0.
                let rendered_observed = acc.rec.observed;
                acc.rec.valid += n_obs - rendered_observed;
                acc.rec.observed = n_obs;
                acc.finish()
            },
        )
        .collect()
}

/// The WGSL of the score kernel as compiled: the rasterizer, then the score.
pub const SCORE_WGSL: &str = concat!(include_str!("../../shaders/raster.wgsl"), "\n", include_str!("../../shaders/score.wgsl"));

/// Wall-clock time per stage of a GPU scoring run.
#[derive(Clone, Copy, Debug, Default)]
pub struct StageTimes {
    /// Writing poses (and parameters) to the GPU.
    pub upload: Duration,
    /// The fused render + score + reduce dispatch.
    pub compute: Duration,
    /// Copying the records back.
    pub readback: Duration,
    /// GPU time of the compute pass from timestamp queries, when the
    /// adapter has them and they were asked for ([`GpuScorer::set_timestamps`]).
    pub gpu_compute: Option<Duration>,
}

impl std::ops::AddAssign for StageTimes {
    fn add_assign(&mut self, o: Self) {
        self.upload += o.upload;
        self.compute += o.compute;
        self.readback += o.readback;
        self.gpu_compute = match (self.gpu_compute, o.gpu_compute) {
            (Some(a), Some(b)) => Some(a + b),
            (a, b) => a.or(b),
        };
    }
}

/// The GPU scorer for one mesh and one observation; reuse it for many
/// batches of poses.
pub struct GpuScorer {
    ctx: Context,
    mesh: RenderMesh,
    target_intrinsics: crate::camera::Intrinsics,
    /// The observation, for hypotheses the rasterizer hands back over its
    /// loop budget (scored by the twin).
    target: ScoreTarget,
    n_obs: u32,
    params: ScoreParams,
    bufs: RasterBuffers,
    records: wgpu::Buffer,
    staging: wgpu::Buffer,
    /// The observation as a texture (`observed` in score.wgsl) and its view.
    observed: (wgpu::Texture, wgpu::TextureView),
    /// Timestamp query set and its resolve buffer, when enabled.
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    /// The fused physical stage against a support plane, when asked for.
    plane: Option<PlaneStage>,
    /// The ray-casting path, when the mesh is scored by ray casting.
    traced: Option<TracedStage>,
    /// The one-invocation-per-hypothesis kernel, when in use
    /// ([`ScoreKernel`]).
    lanes: Option<LaneStage>,
}

/// Which kernel rasterizes and scores ([`GpuScorer::set_kernel`]); the
/// records are the same either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScoreKernel {
    /// `Lanes` on a software adapter where it can run (subgroups of one
    /// fixed size of at least 8 lanes, no plane stage, a rasterized mesh),
    /// else `Workgroups`.
    #[default]
    Auto,
    /// `score_main` (`shaders/score.wgsl`): a workgroup per hypothesis,
    /// pixels drawn with atomics; the kernel for hardware GPUs.
    Workgroups,
    /// `score_lanes_main` (`shaders/score_lanes.wgsl`): an invocation per
    /// hypothesis, pixels drawn with plain texel loads and stores; faster
    /// on lavapipe (Mesa 22.3), whose atomics and storage-buffer accesses
    /// run lane by lane. Runs on any adapter with subgroups of one fixed
    /// size of at least 8 lanes (an error elsewhere).
    Lanes,
}

/// Whether the lanes kernel should draw most hypotheses of `mesh` over a
/// region of `pixels` within its vector's loop budget
/// ([`LANES_LOOP_BUDGET`](super::raster::LANES_LOOP_BUDGET)); `Auto` keeps
/// the workgroup kernel otherwise, as hypotheses past the budget are drawn
/// twice. A vector spends a quarter of the region's pixels emptying its
/// slots, one iteration per meshlet and, per group of four triangles that
/// faces some lane, two plus the busiest lane's pixels of their four
/// bounds over four: about 3 per triangle is a safe estimate for small
/// triangles (the duck: 16,800 estimated at 128x128 and none of the
/// demo's 4,096 poses over budget).
fn lanes_fit(mesh: &RenderMesh, pixels: usize) -> bool {
    pixels / 4 + mesh.meshlets.len() + 3 * mesh.triangles.len() <= super::raster::LANES_LOOP_BUDGET as usize / 2
}

/// `score_lanes.wgsl`'s pipelines, its keys texture (one slot of
/// `width x height` texels per hypothesis of a wave) and the counters its
/// workgroups take the vectors of each wave from (`handed`, one per wave
/// of a chunk, emptied before each chunk).
struct LaneStage {
    lanes: u32,
    keys: wgpu::TextureView,
    handed: wgpu::Buffer,
}

/// The lanes kernel's module: the rasterizer and score helpers, then its
/// entry points (compiled apart from [`SCORE_WGSL`]: it needs subgroup
/// operations, which hardware adapters may lack).
pub const SCORE_LANES_WGSL: &str = concat!(
    include_str!("../../shaders/raster.wgsl"),
    "\n",
    include_str!("../../shaders/score.wgsl"),
    "\n",
    include_str!("../../shaders/score_lanes.wgsl")
);

impl LaneStage {
    /// The stage for `slots` slots of a `k`-sized region and chunks of up
    /// to `waves` waves, or why it cannot run on this adapter.
    fn new(ctx: &Context, k: &crate::camera::Intrinsics, slots: u32, waves: usize) -> std::result::Result<Self, String> {
        let lanes = lane_count(ctx)?;
        // Whole vectors: the last vector of a wave that ends mid-vector has
        // lanes past `slots`, which draw nothing but still load and store
        // their slot's corner, so it must lie inside the texture (out of
        // bounds, a store may land on any texel, another slot's included).
        let slots = slots.next_multiple_of(lanes);
        let max = ctx.max_texture_dim;
        // A slot's block: the region in 4x4 tiles of 16 texels, four tile
        // rows to a texture row (`slot_size` in score_lanes.wgsl).
        let (slot_w, slot_h) = (4 * k.width.div_ceil(4) * 4, k.height.div_ceil(4));
        let cols = (max / slot_w.max(1)).min(slots).max(1);
        let rows = slots.div_ceil(cols);
        if slot_w > max || rows as u64 * slot_h as u64 > max as u64 {
            return Err(format!("{slots} slots of {}x{} pixels do not fit a {max}-texel texture", k.width, k.height));
        }
        let keys = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("lane keys"),
            size: wgpu::Extent3d { width: cols * slot_w, height: rows * slot_h, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Uint,
            usage: wgpu::TextureUsages::STORAGE_BINDING,
            view_formats: &[],
        });
        let handed = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lane vectors handed out"),
            size: 4 * waves.max(1) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(LaneStage { lanes, keys: keys.create_view(&Default::default()), handed })
    }

    /// The scoring pipeline, or with `raster_only` the one that only draws
    /// (for `bench`), compiled on first use: lavapipe compiles a pipeline
    /// in tens of milliseconds, a visible part of scoring a few thousand
    /// hypotheses.
    fn pipeline(&self, ctx: &Context, raster_only: bool) -> std::sync::Arc<wgpu::ComputePipeline> {
        let (key, entry, constants) = lanes_pipeline(self.lanes, raster_only);
        ctx.pipeline_with(key, SCORE_LANES_WGSL, entry, &constants)
    }
}

/// A lanes pipeline of `SCORE_LANES_WGSL`: its cache key, entry point and
/// override constants, in one place for the stage and
/// [`GpuScorer::precompile`], since the cache goes by the key alone (which
/// need not name LANES: it is fixed per context).
fn lanes_pipeline(lanes: u32, raster_only: bool) -> (&'static str, &'static str, [(&'static str, f64); 1]) {
    let constants = [("LANES", lanes as f64)];
    match raster_only {
        true => ("score/lanes raster", "raster_lanes_main", constants),
        false => ("score/lanes", "score_lanes_main", constants),
    }
}

/// The workgroup kernel's scoring pipeline without a plane stage.
const WORKGROUP_SCORE: (&str, &str) = ("score", "score_main");

/// The cache keys of the ray caster's scoring pipeline and of the
/// workgroup kernel fused with the plane stage.
const TRACED_SCORE: &str = "score/traced";
pub(crate) const PLANE_SCORE: &str = "score+plane";

/// Fewest lanes the lanes kernel runs with: its subgroup fetches two
/// triangles' four texels, or eight triangles' planes, in one go
/// (`lane_texel` in score_lanes.wgsl).
const LANES_MIN: u32 = 8;

/// Invocations of the lanes kernel's workgroup: the adapter's one fixed
/// subgroup size, or why it has none.
fn lane_count(ctx: &Context) -> std::result::Result<u32, String> {
    match ctx.subgroup_lanes {
        Some(l) if (LANES_MIN..=256).contains(&l) => Ok(l),
        _ => Err(format!("the adapter has no subgroups of one fixed size of {LANES_MIN} to 256 lanes")),
    }
}

/// The GPU ray caster's buffers and pipelines: `raycast_main`
/// (`shaders/raycast.wgsl`) fills the visibility slots, then
/// `score_traced_main` scores them.
struct TracedStage {
    /// Workgroups of a wave's ray-casting dispatch (`raycast::tile_grid`).
    grid: (u32, u32),
    /// The BVH's nodes as a texture (`nodes` in raycast.wgsl).
    nodes: wgpu::TextureView,
    prims: wgpu::Buffer,
    /// One word, set by a ray that ran out of budget or stack.
    overflow: wgpu::Buffer,
    raycast: std::sync::Arc<wgpu::ComputePipeline>,
    reduce: std::sync::Arc<wgpu::ComputePipeline>,
}

impl TracedStage {
    fn new(ctx: &Context, bvh: &super::raycast::GpuBvh, k: &crate::camera::Intrinsics) -> Result<Self> {
        let grid = super::raycast::tile_grid(k, ctx.limits.max_workgroups)
            .ok_or_else(|| Error::Gpu(format!("the adapter dispatches too few workgroups for a {}x{} region in tiles of 8x8 pixels", k.width, k.height)))?;
        use wgpu::util::DeviceExt;
        let limit = ctx.limits.max_storage_binding.min(ctx.limits.max_buffer);
        if (bvh.prims.len() * 4) as u64 > limit {
            return Err(Error::Gpu(format!("the mesh's BVH has {} primitives; the adapter binds at most {}", bvh.prims.len(), limit / 4)));
        }
        let init = |label, words: &[u32], usage| {
            ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: bytemuck::cast_slice(words), usage })
        };
        let read = wgpu::BufferUsages::STORAGE;
        Ok(TracedStage {
            grid,
            nodes: super::raster::texel_table::<[u32; 20]>(ctx, "BVH node", bytemuck::cast_slice(&bvh.nodes), super::raycast::NODE_ROW, wgpu::TextureFormat::Rgba32Uint)?,
            prims: init("bvh primitives", &bvh.prims, read),
            overflow: init("ray overflow", &[0], read | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC),
            raycast: ctx.pipeline("raycast", super::raycast::RAYCAST_WGSL, "raycast_main"),
            reduce: ctx.pipeline(TRACED_SCORE, SCORE_WGSL, "score_traced_main"),
        })
    }
}

/// `valid` of a record the rasterizer could not draw within its loop budget
/// (`OVER_BUDGET` in score.wgsl).
const OVER_BUDGET: u32 = u32::MAX;

/// What one chunk gives: the score records, the plane stage's output when
/// the scorer has one, and the stage times.
type ChunkOut = (Vec<ScoreRecord>, Option<PlaneContactOutput>, StageTimes);

/// Why a ray-cast chunk is drawn another way.
const RAY_OVERFLOW: &str = "a ray through the mesh's BVH visited more nodes than the GPU allows (surfaces overlapping many times over)";

/// Target of the GPU-time events in a `--trace` (see [`trace_gpu_time`]).
pub const GPU_TIME_TARGET: &str = "plausible::gpu";

/// Two timestamp queries (start and end of a compute pass) and the buffer
/// they resolve into.
fn timestamp_queries(ctx: &Context) -> (wgpu::QuerySet, wgpu::Buffer) {
    let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
        label: Some("compute timestamps"),
        ty: wgpu::QueryType::Timestamp,
        count: 2,
    });
    let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("timestamps"),
        size: 16,
        usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    (set, buf)
}

/// Puts the GPU time of one score pass into the trace, inside its
/// `dispatch` span. A software adapter (lavapipe) stamps on the CPU as it
/// emulates the pass, so its times are marked not reliable.
fn trace_gpu_time(ctx: &Context, gpu: Duration, hypotheses: usize) {
    tracing::trace!(
        target: GPU_TIME_TARGET,
        gpu_ms = gpu.as_secs_f64() * 1e3,
        hypotheses,
        reliable = !ctx.is_software(),
        adapter = %ctx.info.name,
        "gpu pass"
    );
}

/// The observation as an RGBA32F texture of the region's size (normal,
/// depth; `ScoreTarget::packed`).
fn observed_texture(ctx: &Context, target: &ScoreTarget) -> Result<(wgpu::Texture, wgpu::TextureView)> {
    let k = target.intrinsics;
    if k.width.max(k.height) > ctx.max_texture_dim {
        return Err(Error::Gpu(format!("a {}x{} region is too large for this adapter's textures (at most {} a side)", k.width, k.height, ctx.max_texture_dim)));
    }
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("observed"),
        size: wgpu::Extent3d { width: k.width, height: k.height, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    write_observed(ctx, &texture, target);
    let view = texture.create_view(&Default::default());
    Ok((texture, view))
}

fn write_observed(ctx: &Context, texture: &wgpu::Texture, target: &ScoreTarget) {
    let k = target.intrinsics;
    ctx.queue.write_texture(
        texture.as_image_copy(),
        bytemuck::cast_slice(&target.packed()),
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(k.width * 16), rows_per_image: Some(k.height) },
        wgpu::Extent3d { width: k.width, height: k.height, depth_or_array_layers: 1 },
    );
}

/// Default most hypotheses per dispatch: keeps each submission short (the
/// OS watchdog on desktop GPUs) and memory bounded for any N.
pub const DEFAULT_MAX_CHUNK: usize = 4096;

impl GpuScorer {
    /// Uploads the mesh and the observation. `n_hint` sizes the buffers
    /// (batches larger than what fits are split automatically).
    pub fn new(ctx: &Context, mesh: &RenderMesh, target: &ScoreTarget, params: ScoreParams, n_hint: usize) -> Result<Self> {
        Self::with_max_chunk(ctx, mesh, target, params, n_hint, DEFAULT_MAX_CHUNK)
    }

    pub fn with_max_chunk(
        ctx: &Context,
        mesh: &RenderMesh,
        target: &ScoreTarget,
        params: ScoreParams,
        n_hint: usize,
        max_chunk: usize,
    ) -> Result<Self> {
        Self::build(ctx, mesh, target, params, n_hint, max_chunk, None)
    }

    /// A scorer whose kernel also computes the physical terms of every
    /// hypothesis against `physics`' support plane in the same dispatch
    /// (`shaders/plane_contacts.wgsl`); run it with
    /// [`score_with_physics`](Self::score_with_physics).
    pub fn with_plane_stage(
        ctx: &Context,
        mesh: &RenderMesh,
        target: &ScoreTarget,
        params: ScoreParams,
        n_hint: usize,
        plane: &PlaneParams,
        samples: &[[f32; 4]],
    ) -> Result<Self> {
        Self::build(ctx, mesh, target, params, n_hint, DEFAULT_MAX_CHUNK, Some((plane, samples)))
    }

    /// Starts compiling, on a thread of its own, the score pipeline that
    /// [`ScoreKernel::Auto`] would pick on `ctx` for a rasterized mesh
    /// without a plane stage (the lanes kernel on a software adapter with
    /// subgroups of one fixed size of 8 lanes or more, else the workgroup
    /// kernel), and returns
    /// at once. Called before the mesh and observation are prepared, the
    /// compile (30-50 ms on lavapipe) overlaps that work; a scorer made
    /// meanwhile waits for it, and one that uses another kernel compiles
    /// its own as usual. Dropping the handle waits for the compile.
    pub fn precompile(ctx: &Context) -> crate::gpu::Compiling {
        match lane_count(ctx) {
            Ok(lanes) if ctx.is_software() => {
                let (key, entry, constants) = lanes_pipeline(lanes, false);
                ctx.compile_in_background(key, SCORE_LANES_WGSL, entry, constants.to_vec())
            }
            _ => ctx.compile_in_background(WORKGROUP_SCORE.0, SCORE_WGSL, WORKGROUP_SCORE.1, Vec::new()),
        }
    }

    fn build(
        ctx: &Context,
        mesh: &RenderMesh,
        target: &ScoreTarget,
        params: ScoreParams,
        n_hint: usize,
        max_chunk: usize,
        physics: Option<(&PlaneParams, &[[f32; 4]])>,
    ) -> Result<Self> {
        let _span = tracing::trace_span!("gpu_setup").entered();
        let k = target.intrinsics;
        let traced = match physics {
            None if mesh.gpu_renderer() == super::CpuRenderer::RayCast => {
                let caster = mesh.ray_caster().expect("chosen only when built");
                super::check_pixel_budget(k.pixels())?;
                let stage = TracedStage::new(ctx, &caster.gpu_layout(), &k)?;
                tracing::info!("GPU renderer: the BVH ray caster ({} triangles)", mesh.triangles.len());
                Some(stage)
            }
            _ => {
                super::check_loop_budget(mesh, k.pixels())?;
                None
            }
        };
        let words = physics.map_or(0, |(p, _)| p.words as usize);
        let per_hyp = (std::mem::size_of::<ScoreRecord>() as u64).max(words as u64 * 4);
        let bufs = RasterBuffers::new(ctx, mesh, &k, n_hint, per_hyp, max_chunk)?;
        let observed = observed_texture(ctx, target)?;
        let rec_bytes = (bufs.chunk * std::mem::size_of::<ScoreRecord>()) as u64;
        let records = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("records"),
            size: rec_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("records staging"),
            size: rec_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let plane = physics.map(|(p, samples)| plane_stage(ctx, p, samples, bufs.chunk)).transpose()?;
        GpuScorer {
            ctx: ctx.clone(),
            mesh: mesh.clone(),
            target_intrinsics: k,
            target: target.clone(),
            n_obs: target.observed_pixels() as u32,
            params,
            bufs,
            records,
            staging,
            observed,
            timestamps: None,
            plane,
            traced,
            lanes: None,
        }
        .with_kernel(ScoreKernel::Auto)
    }

    /// The kernel `kernel` asks for; `Lanes` where it cannot run is an
    /// error, `Auto` falls back to `Workgroups`.
    pub fn set_kernel(&mut self, kernel: ScoreKernel) -> Result<()> {
        // A lanes stage already built is kept (its texture and pipelines).
        if kernel == ScoreKernel::Lanes && self.lanes.is_some() {
            return Ok(());
        }
        self.lanes = None;
        if kernel == ScoreKernel::Workgroups {
            return Ok(());
        }
        let stage = if self.plane.is_some() || self.traced.is_some() {
            Err("this scorer fuses the plane stage or ray-casts, which only the workgroup kernels do".to_string())
        } else if kernel == ScoreKernel::Auto && !self.ctx.is_software() {
            Err("hardware adapters draw faster with atomics".to_string())
        } else if kernel == ScoreKernel::Auto && !lanes_fit(&self.mesh, self.target_intrinsics.pixels()) {
            Err("the mesh and region would often exceed its loop budget".to_string())
        } else {
            LaneStage::new(&self.ctx, &self.target_intrinsics, self.bufs.slots, self.bufs.chunk.div_ceil(self.bufs.slots as usize))
        };
        match (stage, kernel) {
            (Ok(stage), _) => self.lanes = Some(stage),
            (Err(why), ScoreKernel::Lanes) => return Err(Error::Gpu(format!("the lanes score kernel cannot run here: {why}"))),
            (Err(_), _) => {}
        }
        Ok(())
    }

    fn with_kernel(mut self, kernel: ScoreKernel) -> Result<Self> {
        self.set_kernel(kernel)?;
        Ok(self)
    }

    /// The kernel in use: `Lanes` or `Workgroups`.
    pub fn kernel(&self) -> ScoreKernel {
        if self.lanes.is_some() {
            ScoreKernel::Lanes
        } else {
            ScoreKernel::Workgroups
        }
    }

    /// Compiles the score pipeline this scorer dispatches, or waits for a
    /// [`precompile`](Self::precompile) of it, so that the first scores
    /// wait for no compile and a caller timing its scoring times the
    /// kernel. The ray caster's and the plane stage's pipelines were
    /// compiled with their stages.
    ///
    /// On a software adapter it then scores one hypothesis, the first time
    /// the device runs this pipeline with textures of these sizes
    /// (`Context::first_dispatch`): lavapipe makes the machine code on
    /// that first dispatch. Where Mesa's shader cache does not hold it (a
    /// fresh machine, a read-only home), that took 0.26 s of the first
    /// scoring call for the lanes kernel on the duck, as long as scoring
    /// the demo's 4,096 poses on two threads. The dispatch also has wgpu
    /// clear the new textures (done on their first use): with the cache
    /// warm, `score` on the demo scored 4-18 % faster (README, "Where
    /// lavapipe's time goes").
    pub fn compile(&self) -> Result<()> {
        if let (Some(l), None) = (&self.lanes, &self.traced) {
            l.pipeline(&self.ctx, false);
        } else if self.traced.is_none() && self.plane.is_none() {
            self.ctx.pipeline(WORKGROUP_SCORE.0, SCORE_WGSL, WORKGROUP_SCORE.1);
        }
        if self.ctx.is_software() && self.ctx.first_dispatch(self.pipeline_key(), self.texture_sizes()) {
            let _span = tracing::trace_span!("first_dispatch").entered();
            self.run_chunk(&[self.centred_pose()], false, None)?;
        }
        Ok(())
    }

    /// The cache key of the pipeline that scores (the ray caster's reduce
    /// for a scorer that ray-casts).
    fn pipeline_key(&self) -> &'static str {
        match (&self.traced, &self.plane, &self.lanes) {
            (Some(_), _, _) => TRACED_SCORE,
            (None, Some(_), _) => PLANE_SCORE,
            (None, None, Some(l)) => lanes_pipeline(l.lanes, false).0,
            (None, None, None) => WORKGROUP_SCORE.0,
        }
    }

    /// The sizes of the textures the scoring dispatches bind.
    fn texture_sizes(&self) -> Vec<[u32; 2]> {
        let views = [Some(&self.bufs.tris), Some(&self.bufs.meshlets), Some(&self.observed.1)];
        let extra = [self.lanes.as_ref().map(|l| &l.keys), self.traced.as_ref().map(|t| &t.nodes), self.plane.as_ref().map(|p| &p.samples)];
        views.into_iter().chain(extra).flatten().map(|v| [v.texture().width(), v.texture().height()]).collect()
    }

    /// A pose that shows the mesh whole in the middle of the region, half
    /// as wide as the region (for [`compile`](Self::compile)'s first
    /// dispatch: any pose would do, one that draws runs all of the code).
    fn centred_pose(&self) -> Pose {
        let k = &self.target_intrinsics;
        let r = f64::from(self.mesh.radius).max(1e-6);
        let across = (f64::from(k.width.min(k.height)) / 2.0).max(1.0);
        let z = (k.fx.max(k.fy) * 2.0 * r / across).max(4.0 * r);
        let x = (f64::from(k.width) / 2.0 - k.cx) / k.fx * z;
        let y = (f64::from(k.height) / 2.0 - k.cy) / k.fy * z;
        Pose { r: glam::DMat3::IDENTITY, t: glam::DVec3::new(x, y, z) }
    }

    /// Records GPU timestamps around each compute pass (when the adapter
    /// supports them; returns whether they are on). Costs one extra small
    /// readback per chunk, so it is off by default.
    pub fn set_timestamps(&mut self, on: bool) -> bool {
        self.timestamps = (on && self.ctx.timestamps).then(|| timestamp_queries(&self.ctx));
        self.timestamps.is_some()
    }

    /// Timestamp queries for one scoring call when a trace is being
    /// recorded (`plausible --trace`: the GPU time of each pass goes into
    /// it) and they are not on already. Without a trace this is one
    /// disabled-callsite check, and the passes run without queries.
    fn traced_timestamps(&self) -> Option<(wgpu::QuerySet, wgpu::Buffer)> {
        let wanted = self.timestamps.is_none() && self.ctx.timestamps && tracing::enabled!(target: GPU_TIME_TARGET, tracing::Level::TRACE);
        wanted.then(|| timestamp_queries(&self.ctx))
    }

    /// Replaces the observation with `target`'s, which must be the same
    /// region with the same observed pixels and may differ only in the
    /// other objects' depth ([`ScoreTarget::set_occluders`]): one texture
    /// write, the mesh and pipeline stay.
    pub fn set_observation(&mut self, target: &ScoreTarget) -> Result<()> {
        if target.intrinsics != self.target_intrinsics || target.observed_pixels() as u32 != self.n_obs {
            return Err(Error::InvalidInput("a scorer's observation can only change its occluders, not its region or observed pixels".into()));
        }
        write_observed(&self.ctx, &self.observed.0, target);
        self.target = target.clone();
        Ok(())
    }

    /// Hypotheses per dispatch.
    pub fn chunk_size(&self) -> usize {
        self.bufs.chunk
    }

    /// Scores `poses` (any number; split into chunks), returning records in
    /// input order and the time spent per stage.
    pub fn score(&self, poses: &[Pose]) -> Result<(Vec<ScoreRecord>, StageTimes)> {
        self.score_with_progress(poses, |_| {})
    }

    /// Like [`score`](Self::score), calling `done(n)` after each chunk with
    /// the number of hypotheses scored so far.
    ///
    /// Hypotheses whose bounding sphere misses the region are not
    /// dispatched: nothing of them can be drawn, so their record is known
    /// (every observed pixel in V, scoring 0), exactly as the CPU twin
    /// computes it. 100,000 poses off the image cost a moment, not a minute
    /// of GPU time.
    pub fn score_with_progress(&self, poses: &[Pose], mut done: impl FnMut(usize)) -> Result<(Vec<ScoreRecord>, StageTimes)> {
        let cull = tracing::trace_span!("cull", hypotheses = poses.len()).entered();
        let seen = self.dispatch_order(poses);
        drop(cull);
        let mut out = vec![unseen_record(self.n_obs); poses.len()];
        let mut times = StageTimes::default();
        let mut finished = poses.len() - seen.len();
        let traced = self.traced_timestamps();
        let ts = self.timestamps.as_ref().or(traced.as_ref());
        for ids in seen.chunks(self.bufs.chunk) {
            let chunk: Vec<Pose> = ids.iter().map(|&i| poses[i]).collect();
            let (r, _, t) = self.run_chunk(&chunk, false, ts)?;
            for (&i, rec) in ids.iter().zip(r) {
                out[i] = rec;
            }
            times += t;
            finished += ids.len();
            done(finished);
        }
        if seen.is_empty() {
            done(poses.len());
        }
        Ok((out, times))
    }

    /// Scores `poses` and computes their physical terms against the support
    /// plane in the same dispatch (a scorer made by
    /// [`with_plane_stage`](Self::with_plane_stage)); `done(n)` is
    /// called after each chunk.
    pub fn score_with_physics(
        &self,
        poses: &[Pose],
        mut done: impl FnMut(usize),
    ) -> Result<(Vec<ScoreRecord>, PlaneContactOutput, StageTimes)> {
        if self.plane.is_none() {
            return Err(Error::InvalidInput(
                "this scorer has no support plane: make it with GpuScorer::with_plane_stage".into(),
            ));
        }
        let mut out = Vec::with_capacity(poses.len());
        let mut phys = PlaneContactOutput::default();
        let mut times = StageTimes::default();
        let traced = self.traced_timestamps();
        let ts = self.timestamps.as_ref().or(traced.as_ref());
        for chunk in poses.chunks(self.bufs.chunk) {
            let (r, p, t) = self.run_chunk(chunk, false, ts)?;
            out.extend(r);
            let p = p.expect("plane stage output");
            phys.records.extend(p.records);
            phys.bits.extend(p.bits);
            times += t;
            done(out.len());
        }
        Ok((out, phys, times))
    }

    /// Whether this scorer renders by ray casting through the mesh's BVH
    /// (else it rasterizes).
    pub fn ray_casts(&self) -> bool {
        self.traced.is_some()
    }

    /// Runs rasterization alone over `poses` and returns its wall time (for
    /// the benchmark's render/reduce split; `None` for a scorer that ray
    /// casts, whose render and reduce are separate dispatches).
    pub fn raster_only(&self, poses: &[Pose]) -> Result<Option<Duration>> {
        if self.traced.is_some() {
            return Ok(None);
        }
        let mut total = Duration::ZERO;
        for chunk in self.dispatch_order(poses).chunks(self.bufs.chunk) {
            let chunk: Vec<Pose> = chunk.iter().map(|&i| poses[i]).collect();
            total += self.run_chunk(&chunk, true, self.timestamps.as_ref())?.2.compute;
        }
        Ok(Some(total))
    }

    /// The hypotheses to dispatch, in the order to dispatch them: those
    /// whose bounding sphere meets the region, in input order, or for the
    /// lanes kernel, which draws the hypotheses of a SIMD vector together,
    /// ordered by the side they see the mesh from ([`view_order`]):
    /// neighbours then skip the same meshlets and draw triangles of
    /// similar sizes (duck, `bench score`'s poses: 14 % faster).
    fn dispatch_order(&self, poses: &[Pose]) -> Vec<usize> {
        let k = &self.target_intrinsics;
        let mut seen: Vec<usize> =
            (0..poses.len()).filter(|&i| super::raster::screen_rect(&GpuPose::from(&poses[i]), self.mesh.radius, k).is_some()).collect();
        if self.lanes.is_some() {
            seen.sort_by_cached_key(|&i| view_order(&poses[i]));
        }
        seen
    }

    /// One chunk ([`ChunkOut`]); with `timestamps` the GPU time of the
    /// pass too. What the GPU could not draw within lavapipe's loop cap is
    /// drawn another way: a chunk in which a ray visited too many nodes is
    /// rasterized where the mesh allows, else scored by the twin, and
    /// hypotheses the rasterizer marked over its budget by the twin.
    fn run_chunk(&self, chunk: &[Pose], raster_only: bool, timestamps: Option<&(wgpu::QuerySet, wgpu::Buffer)>) -> Result<ChunkOut> {
        let mut out = match self.run_chunk_with(chunk, raster_only, (self.traced.as_ref(), self.lanes.as_ref()), timestamps)? {
            Some(out) => out,
            None if super::check_loop_budget(&self.mesh, self.target_intrinsics.pixels()).is_ok() => {
                tracing::warn!("{RAY_OVERFLOW}: rasterizing these {} hypotheses instead", chunk.len());
                self.run_chunk_with(chunk, raster_only, (None, None), timestamps)?.expect("only the ray caster overflows")
            }
            None => {
                tracing::warn!("{RAY_OVERFLOW}: scoring these {} hypotheses on the CPU", chunk.len());
                let t = Instant::now();
                let records = score_cpu(&self.mesh, &self.target, chunk, &self.params);
                (records, None, StageTimes { compute: t.elapsed(), ..Default::default() })
            }
        };
        // Hypotheses the rasterizer marked over its loop budget (triangles
        // overlapping many times over): those of the lanes kernel, whose
        // vector shares one budget, go to the workgroup kernel first, the
        // rest to the twin.
        let mut over: Vec<usize> = (0..out.0.len()).filter(|&i| out.0[i].valid == OVER_BUDGET).collect();
        if !over.is_empty() && self.lanes.is_some() && self.traced.is_none() {
            tracing::debug!("{} hypotheses past the lanes kernel's loop budget or crossing the near plane: drawn by the workgroup kernel", over.len());
            let poses: Vec<Pose> = over.iter().map(|&i| chunk[i]).collect();
            let (records, _, t) = self.run_chunk_with(&poses, raster_only, (None, None), timestamps)?.expect("only the ray caster overflows");
            for (&i, rec) in over.iter().zip(records) {
                out.0[i] = rec;
            }
            out.2 += t;
            over.retain(|&i| out.0[i].valid == OVER_BUDGET);
        }
        if !over.is_empty() {
            tracing::warn!("{} {}: scored on the CPU", super::hypotheses(over.len()), super::NOT_DRAWN_ON_GPU);
            let poses: Vec<Pose> = over.iter().map(|&i| chunk[i]).collect();
            for (i, rec) in over.into_iter().zip(score_cpu(&self.mesh, &self.target, &poses, &self.params)) {
                out.0[i] = rec;
            }
        }
        Ok(out)
    }

    /// One chunk through the ray caster (`traced`) or the rasterizer;
    /// `None` when a ray ran out of nodes (its pixels were left empty).
    fn run_chunk_with(
        &self,
        chunk: &[Pose],
        raster_only: bool,
        (traced, lanes): (Option<&TracedStage>, Option<&LaneStage>),
        timestamps: Option<&(wgpu::QuerySet, wgpu::Buffer)>,
    ) -> Result<Option<ChunkOut>> {
        let ctx = &self.ctx;
        let mut times = StageTimes::default();
        let upload = tracing::trace_span!("upload", hypotheses = chunk.len()).entered();
        let t0 = Instant::now();
        let gp: Vec<GpuPose> = chunk.iter().map(GpuPose::from).collect();
        let params = raster_params(
            &self.mesh,
            &self.target_intrinsics,
            chunk.len() as u32,
            self.params.tau,
            self.params.alpha,
            self.n_obs,
        );
        ctx.queue.write_buffer(&self.bufs.poses, 0, bytemuck::cast_slice(&gp));
        ctx.wait_for(ctx.queue.submit([]))?;
        times.upload = t0.elapsed();
        drop(upload);

        let dispatch = tracing::trace_span!("dispatch", hypotheses = chunk.len()).entered();
        let t1 = Instant::now();
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let timestamp_writes = timestamps.map(|(set, _)| wgpu::ComputePassTimestampWrites {
            query_set: set,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        });
        let scored = [
            wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(&self.observed.1) },
            wgpu::BindGroupEntry { binding: 5, resource: self.records.as_entire_binding() },
        ];
        let lane_keys = lanes.map(|l| {
            (
                l,
                [
                    wgpu::BindGroupEntry { binding: 14, resource: wgpu::BindingResource::TextureView(&l.keys) },
                    wgpu::BindGroupEntry { binding: 15, resource: l.handed.as_entire_binding() },
                ],
            )
        });
        if let (Some((l, keys)), None) = (&lane_keys, traced) {
            // Both entry points bind the observation and records (the
            // raster one only empties its slots, but shares the code).
            let pipeline = l.pipeline(ctx, raster_only);
            enc.clear_buffer(&l.handed, 0, None);
            let extra: Vec<wgpu::BindGroupEntry> = scored.iter().chain(keys).cloned().collect();
            self.bufs.dispatch_waves(ctx, &mut enc, (&pipeline, WaveLayout::Lanes(l.lanes)), &extra, params, chunk.len(), timestamp_writes);
        } else if raster_only {
            let pipeline = ctx.pipeline("score/raster", SCORE_WGSL, "raster_main");
            self.bufs.dispatch_waves(ctx, &mut enc, (&pipeline, WaveLayout::Workgroups), &[], params, chunk.len(), timestamp_writes);
        } else if let Some(st) = traced {
            ctx.queue.write_buffer(&st.overflow, 0, bytemuck::bytes_of(&0u32));
            let traced_entries = [
                wgpu::BindGroupEntry { binding: 11, resource: wgpu::BindingResource::TextureView(&st.nodes) },
                wgpu::BindGroupEntry { binding: 12, resource: st.prims.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 13, resource: st.overflow.as_entire_binding() },
            ];
            self.bufs.dispatch_traced_waves(
                ctx,
                &mut enc,
                (&st.raycast, &traced_entries),
                (&st.reduce, &scored),
                params,
                chunk.len(),
                st.grid,
                timestamp_writes,
            );
        } else {
            let mut extra = scored.to_vec();
            let pipeline = match &self.plane {
                Some(st) => {
                    extra.extend([
                        wgpu::BindGroupEntry { binding: 6, resource: st.params.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 7, resource: wgpu::BindingResource::TextureView(&st.samples) },
                        wgpu::BindGroupEntry { binding: 8, resource: st.records.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 9, resource: st.bits.as_entire_binding() },
                    ]);
                    st.pipeline.clone()
                }
                // Compiled on first use (or by `compile`/`precompile`), as the lanes kernel's.
                None => ctx.pipeline(WORKGROUP_SCORE.0, SCORE_WGSL, WORKGROUP_SCORE.1),
            };
            self.bufs.dispatch_waves(ctx, &mut enc, (&pipeline, WaveLayout::Workgroups), &extra, params, chunk.len(), timestamp_writes);
        }
        if let Some((set, buf)) = timestamps {
            enc.resolve_query_set(set, 0..2, buf, 0);
        }
        ctx.wait_for(ctx.queue.submit([enc.finish()]))?;
        times.compute = t1.elapsed();
        if let Some((_, buf)) = timestamps {
            let raw = ctx.read_buffer(buf, 16)?;
            let ticks: &[u64] = bytemuck::cast_slice(&raw);
            let ns = ticks[1].saturating_sub(ticks[0]) as f64 * ctx.queue.get_timestamp_period() as f64;
            let gpu = Duration::from_nanos(ns as u64);
            times.gpu_compute = Some(gpu);
            trace_gpu_time(&self.ctx, gpu, chunk.len());
        }
        drop(dispatch);
        if raster_only {
            return Ok(Some((Vec::new(), None, times)));
        }

        let _readback = tracing::trace_span!("readback", hypotheses = chunk.len()).entered();
        let t2 = Instant::now();
        if let Some(st) = traced {
            let flag = ctx.read_buffer(&st.overflow, 4)?;
            if bytemuck::cast_slice::<u8, u32>(&flag)[0] != 0 {
                return Ok(None);
            }
        }
        let size = (chunk.len() * std::mem::size_of::<ScoreRecord>()) as u64;
        let bytes = ctx.read_through(&self.records, &self.staging, size)?;
        let recs: Vec<ScoreRecord> = bytemuck::cast_slice(&bytes).to_vec();
        let plane = match &self.plane {
            Some(st) => {
                let n = chunk.len();
                let rec = ctx.read_buffer(&st.records, (n * std::mem::size_of::<ContactRecord>()) as u64)?;
                let bits = ctx.read_buffer(&st.bits, (n * st.words * 4) as u64)?;
                Some(PlaneContactOutput {
                    records: bytemuck::cast_slice(&rec).to_vec(),
                    bits: bytemuck::cast_slice(&bits).to_vec(),
                })
            }
            None => None,
        };
        times.readback = t2.elapsed();
        Ok(Some((recs, plane, times)))
    }
}

/// Where the camera lies as seen from the model (its direction, on the
/// octahedron, quantized and interleaved into a Morton code): hypotheses
/// near in this order see the same faces of the mesh. Only an order: for a
/// sheared pose Aᵀ stands in for A⁻¹.
fn view_order(p: &Pose) -> u64 {
    let d = (-(p.r.transpose() * p.t)).normalize_or_zero();
    let l1 = d.x.abs() + d.y.abs() + d.z.abs();
    let (mut u, mut v) = if l1 > 0.0 { (d.x / l1, d.y / l1) } else { (0.0, 0.0) };
    if d.z < 0.0 {
        (u, v) = ((1.0 - v.abs()) * u.signum(), (1.0 - u.abs()) * v.signum());
    }
    let q = |x: f64| (((x + 1.0) * 0.5).clamp(0.0, 1.0) * 65535.0) as u64;
    let (a, b) = (q(u), q(v));
    (0..16).fold(0, |key, bit| key | ((a >> bit) & 1) << (2 * bit) | ((b >> bit) & 1) << (2 * bit + 1))
}
