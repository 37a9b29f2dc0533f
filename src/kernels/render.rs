//! `render` kernel (`shaders/render.wgsl`): depth and flat face normal per
//! pixel for each hypothesis, for tests and pictures (scoring uses the fused
//! `score` kernel, evaluation the `depth` kernel). The CPU twin
//! [`render_cpu`] runs the rasterizer's twin ([`raster_ids`], [`resolve`]).

use glam::Vec3;

use super::raster::{raster_params, render_ids, resolve, RasterBuffers};
use super::{GpuPose, RenderMesh, RASTER_WGSL};
use crate::camera::Intrinsics;
use crate::error::Result;
use crate::gpu::Context;
use crate::pose::Pose;

/// The WGSL of the render kernel as the pipeline compiles it.
pub fn render_wgsl() -> String {
    format!("{RASTER_WGSL}\n{}", include_str!("../../shaders/render.wgsl"))
}

/// Depth (m, 0 = background) and unit camera-frame normal per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderImage {
    pub width: u32,
    pub height: u32,
    pub depth: Vec<f32>,
    pub normals: Vec<Vec3>,
}

/// CPU twin of the `render` kernel for one pose.
pub fn render_cpu(mesh: &RenderMesh, pose: &Pose, k: &Intrinsics) -> RenderImage {
    let n = k.pixels();
    let gp = GpuPose::from(pose);
    let mut zbuf = vec![f32::INFINITY; n];
    let mut ids = vec![u32::MAX; n];
    render_ids(mesh, &gp, k, &mut zbuf, &mut ids);
    let du = gp.dual();
    let mut depth = vec![0.0; n];
    let mut normals = vec![Vec3::ZERO; n];
    for i in 0..n {
        if ids[i] != u32::MAX {
            let x = (i % k.width as usize) as f32;
            let y = (i / k.width as usize) as f32;
            let (z, nn) = resolve(&mesh.triangles[ids[i] as usize], &gp, &du, mesh.radius, k, x, y);
            depth[i] = z;
            normals[i] = nn;
        }
    }
    RenderImage { width: k.width, height: k.height, depth, normals }
}

/// GPU `render` kernel: depth and normals of every pose (for tests and
/// pictures; scoring uses the fused `score` kernel instead).
pub fn render_gpu(ctx: &Context, mesh: &RenderMesh, poses: &[Pose], k: &Intrinsics) -> Result<Vec<RenderImage>> {
    super::check_loop_budget(mesh, k.pixels())?;
    let pix = k.pixels();
    let bufs = RasterBuffers::new(ctx, mesh, k, poses.len(), pix as u64 * 16, usize::MAX)?;
    let pipeline = ctx.pipeline("render", &render_wgsl(), "render_main");
    let images = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("images"),
        size: (bufs.chunk * pix * 16) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let mut out = Vec::with_capacity(poses.len());
    for chunk in poses.chunks(bufs.chunk) {
        let gp: Vec<GpuPose> = chunk.iter().map(GpuPose::from).collect();
        ctx.queue.write_buffer(&bufs.poses, 0, bytemuck::cast_slice(&gp));
        let params = raster_params(mesh, k, chunk.len() as u32, 0.0, 0.0, 0);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let extra = [wgpu::BindGroupEntry { binding: 4, resource: images.as_entire_binding() }];
        bufs.dispatch_waves(ctx, &mut enc, (&pipeline, super::raster::WaveLayout::Workgroups), &extra, params, chunk.len(), None);
        ctx.queue.submit([enc.finish()]);
        let bytes = ctx.read_buffer(&images, (chunk.len() * pix * 16) as u64)?;
        let px: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
        for h in 0..chunk.len() {
            let img = &px[h * pix..(h + 1) * pix];
            // Marked over the rasterizer's loop budget (raster.wgsl's
            // draw_budget) or cut by the near plane (Setup.cut): rendered
            // by the twin instead.
            if img[0][3] < 0.0 {
                tracing::warn!("1 hypothesis {}: rendered on the CPU", super::NOT_DRAWN_ON_GPU);
                out.push(render_cpu(mesh, &chunk[h], k));
                continue;
            }
            out.push(RenderImage {
                width: k.width,
                height: k.height,
                depth: img.iter().map(|p| p[3]).collect(),
                normals: img.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect(),
            });
        }
    }
    Ok(out)
}
