//! The second CPU renderer: one ray per pixel through a compressed wide BVH
//! (CWBVH, built and traversed by obvhs, the project's BVH crate), for
//! meshes so large that setting up every triangle costs more than tracing
//! the pixels. It has no shader: it is an alternative to the rasterizer's
//! CPU twin ([`raster_ids`](super::raster::raster_ids)) with the same
//! output (triangle id per pixel of the hypothesis' rectangle, the tight
//! rectangle of what was hit), so depth and normals still come from
//! [`resolve`](super::raster::resolve) and every consumer is unchanged.
//!
//! Rays are cast in model space (the camera centre `-Rᵀt` and `Rᵀ` times
//! the pixel's camera ray), so one BVH serves every pose. With the camera
//! ray's z set to 1, the hit distance is the pixel's depth. Like the
//! rasterizer, closed meshes see front faces only, and nothing nearer than
//! [`NEAR_M`] is drawn (the ray caster keeps the part of a triangle beyond
//! the near plane, as the rasterizer twin clips it there).

use glam::Vec3A;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;

use super::raster::screen_rect;
use super::{GpuPose, GpuTriangle, RenderMesh, NEAR_M};
use crate::camera::Intrinsics;

/// Deepest tree the traversal may walk: obvhs's traversal stack holds 32
/// node groups and overwrites its last one when full, which would lose
/// hits silently. Deeper trees (degenerate geometry) fall back to the
/// rasterizer.
const MAX_DEPTH: usize = 24;

/// A mesh's CWBVH and its triangles in the BVH's primitive order.
#[derive(Clone)]
pub struct RayCaster {
    bvh: CwBvh,
    /// Triangles for intersection, indexed like `bvh.primitive_indices`.
    tris: Vec<RtTriangle>,
    /// The render mesh's triangle id of each BVH primitive.
    ids: Vec<u32>,
    cull_back_faces: bool,
}

impl std::fmt::Debug for RayCaster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RayCaster({} triangles, {} nodes)", self.tris.len(), self.bvh.nodes.len())
    }
}

impl RayCaster {
    /// Builds the BVH of `mesh` (obvhs's fast preset: PLOC with a little
    /// reinsertion), or `None` when the tree is too deep to traverse
    /// safely.
    pub fn new(mesh: &RenderMesh) -> Option<RayCaster> {
        let started = std::time::Instant::now();
        let corner = |v: [f32; 4]| Vec3A::new(v[0], v[1], v[2]);
        let source: Vec<Triangle> =
            mesh.triangles.iter().map(|t: &GpuTriangle| Triangle { v0: corner(t.v0), v1: corner(t.v1), v2: corner(t.v2) }).collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(&source, obvhs::BvhBuildParams::fast_build(), &mut Default::default());
        if depth(&bvh) > MAX_DEPTH {
            tracing::debug!("the mesh's BVH is deeper than {MAX_DEPTH} levels: rasterizing instead");
            return None;
        }
        let tris = bvh.primitive_indices.iter().map(|&i| RtTriangle::from(&source[i as usize])).collect();
        let ids = bvh.primitive_indices.clone();
        tracing::info!("BVH of {} triangles built in {:.2} s ({} nodes)", source.len(), started.elapsed().as_secs_f64(), bvh.nodes.len());
        Some(RayCaster { bvh, tris, ids, cull_back_faces: mesh.cull_back_faces })
    }

    /// Casts one ray through each pixel centre of the hypothesis' rectangle
    /// and writes the nearest triangle's id and inverse depth (`u32::MAX`
    /// and 0 where nothing is hit), as `raster_ids` does. Returns the tight
    /// rectangle of the hit pixels.
    pub fn cast_ids(&self, mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
        let w = k.width as usize;
        let rect = screen_rect(pose, mesh.radius, k)?;
        // The camera ray in model space: from -A⁻¹t along A⁻¹ (dx, dy, 1)
        // (A⁻¹ = Aᵀ for a rotation).
        let du = pose.dual();
        let origin = Vec3A::from(du.camera(pose.translation()));
        let rows = du.q.map(Vec3A::from);
        let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
        let mut drawn: Option<[usize; 4]> = None;
        for y in rect[1]..=rect[3] {
            let dy = (y as f32 - cy) / fy;
            for x in rect[0]..=rect[2] {
                let dx = (x as f32 - cx) / fx;
                let dir = rows[0] * dx + rows[1] * dy + rows[2];
                let i = y * w + x;
                match self.nearest(origin, dir) {
                    Some((t, id)) => {
                        zbuf[i] = 1.0 / t;
                        ids[i] = id;
                        drawn = Some(match drawn {
                            None => [x, y, x, y],
                            Some(d) => [d[0].min(x), d[1].min(y), d[2].max(x), d[3].max(y)],
                        });
                    }
                    None => {
                        zbuf[i] = 0.0;
                        ids[i] = u32::MAX;
                    }
                }
            }
        }
        drawn
    }

    /// The tree and primitive order as the GPU ray caster reads them
    /// (`shaders/raycast.wgsl`): obvhs's nodes word by word.
    pub fn gpu_layout(&self) -> super::raycast::GpuBvh {
        const _: () = assert!(std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>() == 4 * super::raycast::NODE_WORDS);
        super::raycast::GpuBvh { nodes: bytemuck::cast_slice(&self.bvh.nodes).to_vec(), prims: self.ids.clone() }
    }

    /// The nearest hit beyond the near plane: (depth, triangle id).
    fn nearest(&self, origin: Vec3A, dir: Vec3A) -> Option<(f32, u32)> {
        let ray = Ray::new(origin, dir, NEAR_M, f32::INFINITY);
        let mut hit = RayHit::none();
        let cull = self.cull_back_faces;
        self.bvh.ray_traverse(ray, &mut hit, |r, p| intersect(&self.tris[p], r, cull)).then(|| (hit.t, self.ids[hit.primitive_id as usize]))
    }
}

/// Möller–Trumbore in the edge layout of [`RtTriangle`] (`e1 = v0 - v1`,
/// `e2 = v2 - v0`, `ng = e1 × e2`, which points against the face's
/// counter-clockwise normal): the ray parameter of the hit, or infinity.
/// Pixel centres on an edge count as inside, as in the rasterizer; with
/// `cull`, faces seen from behind are skipped.
#[inline(always)]
fn intersect(tri: &RtTriangle, ray: &Ray, cull: bool) -> f32 {
    let c = tri.v0 - ray.origin;
    let r = ray.direction.cross(c);
    let det = tri.ng.dot(ray.direction);
    // Front faces (normal against the ray) have det > 0 in this layout.
    if det == 0.0 || (cull && det < 0.0) {
        return f32::INFINITY;
    }
    let inv = 1.0 / det;
    let u = r.dot(tri.e2) * inv;
    let v = r.dot(tri.e1) * inv;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return f32::INFINITY;
    }
    let t = tri.ng.dot(c) * inv;
    if t >= ray.tmin && t <= ray.tmax {
        t
    } else {
        f32::INFINITY
    }
}

/// Depth of a CWBVH (root = 1), walked with an explicit stack.
fn depth(bvh: &CwBvh) -> usize {
    if bvh.nodes.is_empty() {
        return 0;
    }
    let mut deepest = 0;
    let mut stack = vec![(0u32, 1usize)];
    while let Some((n, d)) = stack.pop() {
        deepest = deepest.max(d);
        let node = &bvh.nodes[n as usize];
        for ch in 0..8 {
            if !node.is_child_empty(ch) && !node.is_leaf(ch) {
                stack.push((node.child_node_index(ch), d + 1));
            }
        }
    }
    deepest
}
