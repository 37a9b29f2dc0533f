//! The GPU ray caster (`shaders/raycast.wgsl`) and its CPU twin
//! [`cast_ids`]: one ray per pixel through the mesh's CWBVH in obvhs's
//! node layout ([`GpuBvh`], built by [`bvh::RayCaster`](super::bvh::RayCaster)),
//! for meshes with many triangles per pixel, where setting every triangle
//! up (the rasterizer) costs more than tracing the pixels.
//!
//! The twin walks the tree exactly as the kernel does, in plain Rust:
//! near-first depth first (children in the slot order obvhs lays out per
//! ray octant), the same quantized child boxes with the same slack, the
//! same triangle test as the CPU ray caster, and the same node budget
//! and stack size, so a ray the kernel would give up on is given up on
//! here too ([`Cast::overflow`]). Its hits are the nearest hits, so they
//! equal obvhs's own traversal's (tested) and the kernel's up to f32
//! rounding at triangle edges.

use glam::Vec3;

use super::{GpuPose, GpuTriangle, RenderMesh};
use crate::camera::Intrinsics;

/// The WGSL of the ray-casting kernel as compiled: the rasterizer's shared
/// part (bindings, poses, screen rectangle), then the ray caster.
pub const RAYCAST_WGSL: &str = concat!(include_str!("../../shaders/raster.wgsl"), "\n", include_str!("../../shaders/raycast.wgsl"));

/// u32 words per CWBVH node (obvhs's `CwBvhNode`, 80 bytes).
pub const NODE_WORDS: usize = 20;
/// Nodes per row of the node texture (`NODE_ROW` in raycast.wgsl): five
/// RGBA32Uint texels each.
pub const NODE_ROW: usize = 1024;
/// Nodes one ray may visit (`MAX_NODES` in raycast.wgsl): each costs a
/// SIMD vector of lavapipe at most 41 loop iterations, and 1,400 * 41 stays
/// under its 65,535 per vector.
pub const MAX_NODES: u32 = 1_400;
/// Pending nodes per ray (`STACK` in raycast.wgsl).
pub const STACK: usize = 176;
/// Relative slack on a child box's exit distance (`BOX_SLACK`).
const BOX_SLACK: f32 = 1.0001;

/// Side of the pixel tiles `raycast_main` takes per workgroup (`TILE`).
pub const TILE: u32 = 8;

/// The ray caster's workgroup grid for region `k`: (tiles along x, rows of
/// them along z) so that neither passes `max_workgroups` per dimension, or
/// `None` when the region has more tiles than the adapter can dispatch.
pub fn tile_grid(k: &Intrinsics, max_workgroups: u32) -> Option<(u32, u32)> {
    let tiles = k.width.div_ceil(TILE) * k.height.div_ceil(TILE);
    let per_row = tiles.min(max_workgroups.max(1));
    let rows = tiles.div_ceil(per_row);
    (rows <= max_workgroups).then_some((per_row, rows))
}

/// A mesh's CWBVH as the kernel reads it.
#[derive(Clone, Debug, Default)]
pub struct GpuBvh {
    /// The nodes' words, [`NODE_WORDS`] per node, root first.
    pub nodes: Vec<u32>,
    /// The render mesh's triangle id of each BVH primitive.
    pub prims: Vec<u32>,
}

/// What one hypothesis' rays gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cast {
    /// Tight rectangle of the pixels hit.
    pub drawn: Option<[usize; 4]>,
    /// A ray ran out of budget or stack: the image is incomplete, and the
    /// kernel would have asked for the rasterizer.
    pub overflow: bool,
}

/// Byte `b` of the words from `w` of a node.
fn byte(node: &[u32], w: usize, b: usize) -> u32 {
    (node[w + b / 4] >> ((b % 4) * 8)) & 0xff
}

/// obvhs's safe reciprocal (`safe_inverse` in raycast.wgsl).
fn safe_inverse(x: f32) -> f32 {
    if x.abs() <= f32::EPSILON {
        x.signum() / f32::EPSILON
    } else {
        1.0 / x
    }
}

/// Distance of the ray's hit with `tri` beyond `near` and before `best`,
/// else `best` (`hit_triangle` in raycast.wgsl).
fn hit_triangle(tri: &GpuTriangle, o: Vec3, d: Vec3, near: f32, best: f32, cull: bool) -> f32 {
    let v0 = Vec3::from_slice(&tri.v0[..3]);
    let e1 = v0 - Vec3::from_slice(&tri.v1[..3]);
    let e2 = Vec3::from_slice(&tri.v2[..3]) - v0;
    let ng = e1.cross(e2);
    let c = v0 - o;
    let r = d.cross(c);
    let det = ng.dot(d);
    if det == 0.0 || (cull && det < 0.0) {
        return best;
    }
    let inv = 1.0 / det;
    let (u, v) = (r.dot(e2) * inv, r.dot(e1) * inv);
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return best;
    }
    let dist = ng.dot(c) * inv;
    if dist >= near && dist < best { dist } else { best }
}

/// The nearest hit of the ray from `o` along `d` (distance, triangle id),
/// or `Err(())` when the walk exceeds the budget or the stack, as in
/// `raycast_main`.
fn trace(mesh: &RenderMesh, bvh: &GpuBvh, o: Vec3, d: Vec3, near: f32) -> Result<Option<(f32, u32)>, ()> {
    let inv = Vec3::new(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    let oct = (if d.x >= 0.0 { 4 } else { 0 }) | (if d.y >= 0.0 { 2 } else { 0 }) | (if d.z >= 0.0 { 1 } else { 0 });
    let mut stack = vec![0u32];
    let (mut best, mut best_id) = (3.4e38f32, u32::MAX);
    let mut visited = 0u32;
    while let Some(n) = stack.pop() {
        visited += 1;
        if visited > MAX_NODES {
            return Err(());
        }
        let node = &bvh.nodes[n as usize * NODE_WORDS..][..NODE_WORDS];
        let np = Vec3::new(f32::from_bits(node[0]), f32::from_bits(node[1]), f32::from_bits(node[2]));
        let scale = Vec3::new(f32::from_bits((node[3] & 0xff) << 23), f32::from_bits(((node[3] >> 8) & 0xff) << 23), f32::from_bits(((node[3] >> 16) & 0xff) << 23));
        let imask = node[3] >> 24;
        let mut enter = 0u32;
        for k in (0..8).rev() {
            let c = k ^ oct;
            let meta = byte(node, 6, c);
            if meta == 0 {
                continue;
            }
            let q = |w: usize| Vec3::new(byte(node, w, c) as f32, byte(node, w + 4, c) as f32, byte(node, w + 8, c) as f32);
            let t0 = (np + scale * q(8) - o) * inv;
            let t1 = (np + scale * q(10) - o) * inv;
            let t_in = t0.min(t1).max_element().max(near);
            let t_out = t0.max(t1).min_element().min(best) * BOX_SLACK;
            if t_in > t_out {
                continue;
            }
            if imask & (1 << c) != 0 {
                enter |= 1 << k;
                continue;
            }
            let first = node[5] + (meta & 31);
            for q in 0..(meta & 0xe0).count_ones() {
                let id = bvh.prims[(first + q) as usize];
                let hit = hit_triangle(&mesh.triangles[id as usize], o, d, near, best, mesh.cull_back_faces);
                if hit < best {
                    (best, best_id) = (hit, id);
                }
            }
        }
        while enter != 0 {
            let k = enter.trailing_zeros() as usize;
            enter &= enter - 1;
            if stack.len() == STACK {
                return Err(());
            }
            let c = k ^ oct;
            stack.push(node[4] + (imask & ((1 << c) - 1)).count_ones());
        }
    }
    Ok((best_id != u32::MAX).then_some((best, best_id)))
}

/// Casts one ray through each pixel centre of the hypothesis' rectangle
/// and writes the nearest triangle's id and inverse depth (`u32::MAX` and
/// 0 where nothing is hit), the contract of
/// [`raster_ids`](super::raster::raster_ids). The CPU twin of `raycast_main`.
pub fn cast_ids(mesh: &RenderMesh, bvh: &GpuBvh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Cast {
    let mut cast = Cast { drawn: None, overflow: false };
    let Some(rect) = super::raster::screen_rect(pose, mesh.radius, k) else {
        return cast;
    };
    let w = k.width as usize;
    // The camera ray in model space: from -A⁻¹t along A⁻¹ (dx, dy, 1)
    // (A⁻¹ = Aᵀ for a rotation).
    let du = pose.dual();
    let o = du.camera(pose.translation());
    let rows = du.q;
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    for y in rect[1]..=rect[3] {
        for x in rect[0]..=rect[2] {
            let (dx, dy) = ((x as f32 - cx) / fx, (y as f32 - cy) / fy);
            let d = rows[0] * dx + rows[1] * dy + rows[2];
            let i = y * w + x;
            (zbuf[i], ids[i]) = (0.0, u32::MAX);
            match trace(mesh, bvh, o, d, super::NEAR_M) {
                Err(()) => cast.overflow = true,
                Ok(None) => {}
                Ok(Some((t, id))) => {
                    (zbuf[i], ids[i]) = (1.0 / t, id);
                    cast.drawn = Some(match cast.drawn {
                        None => [x, y, x, y],
                        Some(r) => [r[0].min(x), r[1].min(y), r[2].max(x), r[3].max(y)],
                    });
                }
            }
        }
    }
    cast
}
