//! `depth` kernel: z-depth of many poses of one mesh, each over its own
//! pixel tile (the projection of the bounding sphere, clipped to the
//! image), for evaluation: VSD renders every estimate and ground-truth pose
//! of a dataset, and visible fractions need the ground truth alone.
//!
//! Full images would be mostly background (an LM-O object covers ~2 % of a
//! 640×480 frame), so each pose writes only its tile, packed one after
//! another: reading back 2,900 renders of a test set costs a few hundred MB,
//! not 3.5 GB. The rasterization is the visual kernels' (`raster.wgsl`):
//! same coverage rule, pixel centres at integer coordinates, exact depth
//! from the winning triangle's plane.
//!
//! The CPU twin [`depth_tile_cpu`] is the same z-buffer as
//! [`raster::render_cpu`](super::raster::render_cpu), cut to the tile.

use bytemuck::{Pod, Zeroable};

use super::raster::{raster_params, render_ids, resolve, screen_rect, RasterBuffers};
use super::{GpuPose, RenderMesh, MAX_GPU_MESHLETS, RASTER_WGSL};
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::pose::Pose;

/// The WGSL of the depth kernel as the pipeline compiles it.
pub fn depth_wgsl() -> String {
    format!("{RASTER_WGSL}\n{}", include_str!("../../shaders/depth.wgsl"))
}

/// Largest tile the GPU kernel takes (pixels). lavapipe ends every loop of
/// an invocation after 65,535 iterations in total; with 64 invocations per
/// tile this keeps the kernel's own pixel loops under 10,000 iterations,
/// leaving the rest of the budget to rasterization. Larger tiles (an object
/// filling a big image) are rendered by the CPU twin, which gives the same
/// image.
pub const MAX_GPU_TILE_PIXELS: usize = 300_000;

/// Most tile pixels one dispatch batch writes (64 MB of f32).
const BATCH_PIXELS: usize = 16 << 20;

/// A pixel tile of `[x0, x1] × [y0, y1]` (inclusive) and where it starts in
/// the packed output (must match `Tile` in `shaders/depth.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq, Eq)]
pub struct Tile {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
    pub offset: u32,
    pub pad0: u32,
    pub pad1: u32,
    pub pad2: u32,
}
const _: () = assert!(std::mem::size_of::<Tile>() == 32);

/// The z-depth (metres, 0 = background) of one pose over its tile.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthTile {
    /// Inclusive pixel rectangle `[x0, y0, x1, y1]`.
    pub rect: [usize; 4],
    /// Row-major depths of the rectangle.
    pub depth: Vec<f32>,
}

impl DepthTile {
    pub fn width(&self) -> usize {
        self.rect[2] - self.rect[0] + 1
    }

    pub fn height(&self) -> usize {
        self.rect[3] - self.rect[1] + 1
    }

    /// Depth at image pixel `(x, y)`; 0 outside the tile.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        let [x0, y0, x1, y1] = self.rect;
        if x < x0 || x > x1 || y < y0 || y > y1 {
            return 0.0;
        }
        self.depth[(y - y0) * self.width() + (x - x0)]
    }

    /// Pixels with depth.
    pub fn covered(&self) -> usize {
        self.depth.iter().filter(|&&d| d > 0.0).count()
    }
}

/// The tile a pose is rendered over: the projection of the mesh's bounding
/// sphere clipped to the image (`None` when it misses the image).
pub fn tile_rect(mesh: &RenderMesh, pose: &Pose, k: &Intrinsics) -> Option<[usize; 4]> {
    screen_rect(&GpuPose::from(pose), mesh.radius, k)
}

/// Pixels of an inclusive rectangle `[x0, y0, x1, y1]`.
fn rect_pixels(r: &[usize; 4]) -> usize {
    (r[2] - r[0] + 1) * (r[3] - r[1] + 1)
}

/// CPU twin: the depth of `pose` over its tile, with caller-owned z-buffer
/// and id scratch of `k.pixels()` items each (reused across poses).
pub fn depth_tile_cpu(mesh: &RenderMesh, pose: &Pose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<DepthTile> {
    let gp = GpuPose::from(pose);
    let rect = screen_rect(&gp, mesh.radius, k)?;
    let drawn = render_ids(mesh, &gp, k, zbuf, ids);
    let du = gp.dual();
    let w = k.width as usize;
    let mut depth = Vec::with_capacity((rect[2] - rect[0] + 1) * (rect[3] - rect[1] + 1));
    for y in rect[1]..=rect[3] {
        for x in rect[0]..=rect[2] {
            let inside = drawn.is_some_and(|d| x >= d[0] && x <= d[2] && y >= d[1] && y <= d[3]);
            let id = if inside { ids[y * w + x] } else { u32::MAX };
            depth.push(if id == u32::MAX { 0.0 } else { resolve(&mesh.triangles[id as usize], &gp, &du, mesh.radius, k, x as f32, y as f32).0 });
        }
    }
    Some(DepthTile { rect, depth })
}

/// CPU twin over many poses, in parallel (rayon), in input order.
pub fn depth_tiles_cpu(mesh: &RenderMesh, poses: &[Pose], k: &Intrinsics) -> Vec<Option<DepthTile>> {
    use rayon::prelude::*;
    let n = k.pixels();
    poses
        .par_iter()
        .map_init(|| (vec![f32::INFINITY; n], vec![u32::MAX; n]), |(zbuf, ids), pose| depth_tile_cpu(mesh, pose, k, zbuf, ids))
        .collect()
}

/// The depth kernel for one mesh and camera: pipeline and buffers are made
/// once and reused for every batch of poses.
pub struct GpuDepth<'a> {
    ctx: &'a Context,
    mesh: &'a RenderMesh,
    k: Intrinsics,
    bufs: RasterBuffers,
    pipeline: std::sync::Arc<wgpu::ComputePipeline>,
    tiles: wgpu::Buffer,
    out: wgpu::Buffer,
    out_pixels: usize,
}

impl<'a> GpuDepth<'a> {
    /// Prepares the kernel for poses of `mesh` seen with `k`, with buffers
    /// for batches of up to 4,096 poses.
    pub fn new(ctx: &'a Context, mesh: &'a RenderMesh, k: &Intrinsics) -> Result<Self> {
        Self::sized(ctx, mesh, k, 4096, BATCH_PIXELS)
    }

    /// Like [`new`](Self::new), with buffers sized for rendering `poses`
    /// (any poses still render, in more dispatches). The visibility buffer
    /// holds a whole camera image per pose of a wave, up to 256 MB, and the
    /// output 64 MB: allocating those for a few dozen poses cost an H200
    /// 13 ms per object and camera in `eval`, more than the renders.
    pub fn for_poses(ctx: &'a Context, mesh: &'a RenderMesh, k: &Intrinsics, poses: &[Pose]) -> Result<Self> {
        let pixels: usize = poses.iter().filter_map(|p| tile_rect(mesh, p, k)).map(|r| rect_pixels(&r)).sum();
        Self::sized(ctx, mesh, k, poses.len(), pixels.clamp(MAX_GPU_TILE_PIXELS, BATCH_PIXELS))
    }

    /// Buffers for batches of `n` poses and `pixels` tile pixels.
    fn sized(ctx: &'a Context, mesh: &'a RenderMesh, k: &Intrinsics, n: usize, pixels: usize) -> Result<Self> {
        let bufs = RasterBuffers::new(ctx, mesh, k, n, std::mem::size_of::<Tile>() as u64, 4096)?;
        let pipeline = ctx.pipeline("depth", &depth_wgsl(), "depth_main");
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let tiles = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tiles"),
            size: (bufs.chunk * std::mem::size_of::<Tile>()) as u64,
            usage: storage,
            mapped_at_creation: false,
        });
        let out_pixels = (ctx.limits.max_items(4) as usize).min(pixels);
        if out_pixels < MAX_GPU_TILE_PIXELS {
            return Err(Error::Gpu(format!(
                "the adapter binds at most {} bytes of storage; the depth kernel needs {}",
                out_pixels * 4,
                MAX_GPU_TILE_PIXELS * 4
            )));
        }
        let out = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("depths"),
            size: (out_pixels * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Ok(GpuDepth { ctx, mesh, k: *k, bufs, pipeline, tiles, out, out_pixels })
    }

    /// Depth tiles of `poses`, in input order. Poses whose tile exceeds
    /// [`MAX_GPU_TILE_PIXELS`] are rendered by the CPU twin.
    pub fn render(&self, poses: &[Pose]) -> Result<Vec<Option<DepthTile>>> {
        if self.mesh.meshlets.len() > MAX_GPU_MESHLETS {
            tracing::warn!(
                "the mesh has {} triangles in {} meshlets, more than the depth kernel's {MAX_GPU_MESHLETS} (lavapipe's loop cap): rendering with the CPU twin",
                self.mesh.triangles.len(),
                self.mesh.meshlets.len()
            );
            return Ok(depth_tiles_cpu(self.mesh, poses, &self.k));
        }
        let rects: Vec<Option<[usize; 4]>> = poses.iter().map(|p| tile_rect(self.mesh, p, &self.k)).collect();
        let mut out: Vec<Option<DepthTile>> = vec![None; poses.len()];
        let mut batch: Vec<usize> = Vec::new();
        let mut pixels = 0usize;
        let mut cpu: Vec<usize> = Vec::new();
        for (i, r) in rects.iter().enumerate() {
            let Some(r) = r else { continue };
            let a = rect_pixels(r);
            if a > MAX_GPU_TILE_PIXELS {
                cpu.push(i);
                continue;
            }
            if pixels + a > self.out_pixels || batch.len() == self.bufs.chunk {
                self.render_batch(poses, &rects, &batch, &mut out)?;
                batch.clear();
                pixels = 0;
            }
            batch.push(i);
            pixels += a;
        }
        if !batch.is_empty() {
            self.render_batch(poses, &rects, &batch, &mut out)?;
        }
        if !cpu.is_empty() {
            tracing::debug!("{} poses fill more than {MAX_GPU_TILE_PIXELS} pixels: rendered by the CPU twin", cpu.len());
            let far: Vec<Pose> = cpu.iter().map(|&i| poses[i]).collect();
            for (i, t) in cpu.into_iter().zip(depth_tiles_cpu(self.mesh, &far, &self.k)) {
                out[i] = t;
            }
        }
        Ok(out)
    }

    /// One dispatch over the poses `batch` (indices into `poses`), whose
    /// tiles fit the output buffer together.
    fn render_batch(&self, poses: &[Pose], rects: &[Option<[usize; 4]>], batch: &[usize], out: &mut [Option<DepthTile>]) -> Result<()> {
        let ctx = self.ctx;
        let mut tiles = Vec::with_capacity(batch.len());
        let mut offset = 0u32;
        for &i in batch {
            let r = rects[i].expect("batched poses have tiles");
            let t = Tile { x0: r[0] as i32, y0: r[1] as i32, x1: r[2] as i32, y1: r[3] as i32, offset, pad0: 0, pad1: 0, pad2: 0 };
            offset += rect_pixels(&r) as u32;
            tiles.push(t);
        }
        let gp: Vec<GpuPose> = batch.iter().map(|&i| GpuPose::from(&poses[i])).collect();
        ctx.queue.write_buffer(&self.bufs.poses, 0, bytemuck::cast_slice(&gp));
        ctx.queue.write_buffer(&self.tiles, 0, bytemuck::cast_slice(&tiles));
        let params = raster_params(self.mesh, &self.k, batch.len() as u32, 0.0, 0.0, 0);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let extra = [
            wgpu::BindGroupEntry { binding: 4, resource: self.tiles.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 5, resource: self.out.as_entire_binding() },
        ];
        self.bufs.dispatch_waves(ctx, &mut enc, (&self.pipeline, super::raster::WaveLayout::Workgroups), &extra, params, batch.len(), None);
        ctx.queue.submit([enc.finish()]);
        let bytes = ctx.read_buffer(&self.out, offset.max(1) as u64 * 4)?;
        let depths: &[f32] = bytemuck::cast_slice(&bytes);
        let mut over = Vec::new();
        for (&i, t) in batch.iter().zip(&tiles) {
            let rect = [t.x0 as usize, t.y0 as usize, t.x1 as usize, t.y1 as usize];
            let n = rect_pixels(&rect);
            let at = t.offset as usize;
            // -1 first: the pose overdraws past the rasterizer's loop
            // budget (`raster::draw_budget`) or crosses the near plane;
            // the twin renders it.
            if depths[at] < 0.0 {
                over.push(i);
                continue;
            }
            out[i] = Some(DepthTile { rect, depth: depths[at..at + n].to_vec() });
        }
        if !over.is_empty() {
            tracing::warn!("{} {}: rendered on the CPU", super::hypotheses(over.len()), super::NOT_DRAWN_ON_GPU);
            let cpu: Vec<Pose> = over.iter().map(|&i| poses[i]).collect();
            for (i, t) in over.into_iter().zip(depth_tiles_cpu(self.mesh, &cpu, &self.k)) {
                out[i] = t;
            }
        }
        Ok(())
    }
}
