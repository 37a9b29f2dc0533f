//! The compute rasterizer shared by the visual kernels (`shaders/raster.wgsl`)
//! and its CPU twin: [`raster_ids`] culls the same meshlets
//! ([`meshlet_visible`]), sets triangles up the same way and keeps the same
//! coverage rule (pixel centres inside or on the edge) and interpolated
//! inverse depth for the visibility test; [`resolve`] gives the same exact
//! plane-based depth and normal per pixel. [`render_ids`] is what CPU
//! consumers call: the twin, or the BVH ray caster ([`super::bvh`]) for a
//! hypothesis with many triangles per pixel. Also the buffers and wave
//! dispatch every visual kernel uses.

use glam::{Vec2, Vec3, Vec3A, Vec4};

use super::{Dual, GpuMeshlet, GpuPose, GpuTriangle, RasterParams, RenderMesh, NEAR_M};
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::gpu::Context;


/// Projection `[xlo, ylo, xhi, yhi]`, in pixels, of the box around a
/// sphere at `c` (camera frame) of radius `r` lying wholly beyond the near
/// plane (the twin of `sphere_bounds` in raster.wgsl).
#[inline]
fn sphere_bounds(c: Vec3, r: f32, k: &Intrinsics) -> [f32; 4] {
    let (zn, zf) = (c.z - r, c.z + r);
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    [
        ((c.x - r) / zn).min((c.x - r) / zf) * fx + cx,
        ((c.y - r) / zn).min((c.y - r) / zf) * fy + cy,
        ((c.x + r) / zn).max((c.x + r) / zf) * fx + cx,
        ((c.y + r) / zn).max((c.y + r) / zf) * fy + cy,
    ]
}

/// Inclusive pixel rectangle `[x0, x1] x [y0, y1]` that can hold the
/// hypothesis: the projection of the box around its bounding sphere,
/// clipped to the image (`None` when it misses the image). Nothing outside
/// it is drawn or scored (the twin of `screen_rect` in raster.wgsl).
pub fn screen_rect(pose: &GpuPose, radius: f32, k: &Intrinsics) -> Option<[usize; 4]> {
    // `radius` is the mesh's about its origin; the pose may stretch it.
    let radius = radius * pose.dual().stretch;
    let c = pose.translation();
    let (w, h) = (k.width as i64, k.height as i64);
    if c.z - radius <= NEAR_M {
        return Some([0, 0, w as usize - 1, h as usize - 1]);
    }
    let [xlo, ylo, xhi, yhi] = sphere_bounds(c, radius, k);
    let x0 = (xlo.ceil().max(-1.0) as i64).max(0);
    let y0 = (ylo.ceil().max(-1.0) as i64).max(0);
    let x1 = (xhi.floor().min(w as f32) as i64).min(w - 1);
    let y1 = (yhi.floor().min(h as f32) as i64).min(h - 1);
    (x0 <= x1 && y0 <= y1).then_some([x0 as usize, y0 as usize, x1 as usize, y1 as usize])
}

/// Whether meshlet `m` may draw into the pixel rectangle `[first, last]`
/// (the twin of `meshlet_visible` in raster.wgsl): false when the whole
/// meshlet faces away from the camera (`cam`, the camera centre in model
/// coordinates, only for meshes whose back faces may be culled), lies
/// behind the near plane, or projects outside the rectangle (its bounding
/// sphere's box, with half a pixel to spare). Every triangle of a rejected
/// meshlet would have been rejected on its own.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn meshlet_visible(m: &GpuMeshlet, pose: &GpuPose, cam: Vec3, stretch: f32, cull: bool, k: &Intrinsics, first: (f32, f32), last: (f32, f32)) -> bool {
    let centre = Vec3::from_slice(&m.sphere[..3]);
    // The cone test in model space with the model's radius (facing does
    // not change under any invertible A); the camera-space tests below
    // take the stretched one.
    if cull {
        let v = centre - cam;
        if v.dot(Vec3::from_slice(&m.cone[..3])) >= m.cone[3] * v.length() + m.sphere[3] {
            return false;
        }
    }
    let r = m.sphere[3] * stretch;
    let c = pose.transform(centre);
    if c.z + r < NEAR_M {
        return false;
    }
    if c.z - r <= NEAR_M {
        return true;
    }
    let [xlo, ylo, xhi, yhi] = sphere_bounds(c, r, k);
    xhi >= first.0 - 0.5 && yhi >= first.1 - 0.5 && xlo <= last.0 + 0.5 && ylo <= last.1 + 0.5
}

/// `floor` and `ceil` for the triangles' pixel bounds, as the compiled
/// variant of [`raster_ids`] does them best.
trait Rounding {
    fn floor(x: f32) -> f32;
    fn ceil(x: f32) -> f32;
}

/// The CPU's rounding instructions (SSE4.1's `roundss`, which AVX2
/// implies, or any non-x86 CPU's).
struct Native;

impl Rounding for Native {
    #[inline(always)]
    fn floor(x: f32) -> f32 {
        x.floor()
    }
    #[inline(always)]
    fn ceil(x: f32) -> f32 {
        x.ceil()
    }
}

/// Baseline x86-64 (SSE2) has no rounding instruction, so `floor`/`ceil`
/// are library calls, a tenth of the rasterizer's time on meshes of
/// sub-pixel triangles: inlined here. Exact for |x| < 2^31; beyond, the
/// bounds are clamped to the image anyway.
#[cfg(target_arch = "x86_64")]
struct Sse2;

#[cfg(target_arch = "x86_64")]
impl Rounding for Sse2 {
    #[inline(always)]
    fn floor(x: f32) -> f32 {
        let i = x as i32 as f32;
        if i > x { i - 1.0 } else { i }
    }
    #[inline(always)]
    fn ceil(x: f32) -> f32 {
        let i = x as i32 as f32;
        if i < x { i + 1.0 } else { i }
    }
}

/// Rasterizes `mesh` at `pose` into a buffer of triangle ids (`u32::MAX`
/// for background), with `zbuf` as the depth test's scratch (inverse depth,
/// larger = nearer, as in the kernel; exact depth comes from [`resolve`]).
/// `zbuf` and `ids` must hold `w * h` items. Returns the tight rectangle
/// `[x0, y0, x1, y1]` of the drawn triangles' pixel bounds (`None` if
/// nothing was drawn); only inside it are the buffers valid (the GPU kernel
/// visits the same rectangle). Meshlets are culled first, as the kernel
/// culls them, and each triangle is set up as the kernel sets it up:
/// barycentric weights affine in the pixel position (start value and
/// steps), inverse depth interpolated with them.
pub fn raster_ids(mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
    #[cfg(target_arch = "x86_64")]
    {
        if avx2::available() {
            // SAFETY: the CPU has every feature the function is compiled for.
            return unsafe { avx2::raster_ids(mesh, pose, k, zbuf, ids) };
        }
        raster_ids_body::<Sse2>(mesh, pose, k, zbuf, ids)
    }
    #[cfg(not(target_arch = "x86_64"))]
    raster_ids_body::<Native>(mesh, pose, k, zbuf, ids)
}

/// [`raster_ids`] compiled for x86-64 CPUs with AVX2 and FMA (nearly every
/// x86 server since 2013), chosen at run time: the build targets baseline
/// x86-64 (SSE2), without rounding instructions (`floor`/`ceil` of the
/// bounds of sub-pixel triangles) and with an extra register copy for every
/// vector operation. Together about 20 % on LM-O's can at `--lod off`. Rust
/// never fuses a multiply and an add on its own, so the results are bit for
/// bit the same.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::*;

    /// Whether this CPU has them (the standard library caches the answer).
    pub fn available() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn raster_ids(mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
        raster_ids_body::<Native>(mesh, pose, k, zbuf, ids)
    }
}

/// The body of [`raster_ids`], inlined into each compiled variant.
#[inline(always)]
fn raster_ids_body<R: Rounding>(mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
    let w = k.width as usize;
    let rect = screen_rect(pose, mesh.radius, k)?;
    for y in rect[1]..=rect[3] {
        zbuf[y * w + rect[0]..=y * w + rect[2]].fill(0.0);
        ids[y * w + rect[0]..=y * w + rect[2]].fill(u32::MAX);
    }
    let mut drawn: Option<[usize; 4]> = None;
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let (first, last) = ((rect[0] as f32, rect[1] as f32), (rect[2] as f32, rect[3] as f32));
    // Camera centre in model coordinates: a face is a back face when the
    // camera lies on the inner side of its plane.
    let du = pose.dual();
    let cam = du.camera(pose.translation());
    let mut proj = [(Vec3::ZERO, Vec2::ZERO); 256];
    // Per meshlet vertex, its pixel coordinates rounded both ways as
    // (ceil x, ceil y, -floor x, -floor y): rounding is monotonic, so a
    // triangle's clipped bounds (lo = ceil of the corners' minimum, hi =
    // floor of their maximum) are two 4-wide minimums of its corners' and
    // one maximum with the rectangle, the same values as rounding each
    // triangle's extremes.
    let mut snap = [Vec4::ZERO; 256];
    let clip = Vec4::new(first.0, first.1, -last.0, -last.1);
    let project = |p: Vec3| Vec2::new(fx * p.x / p.z + cx, fy * p.y / p.z + cy);
    let rounded = |s: Vec2| Vec4::new(R::ceil(s.x), R::ceil(s.y), -R::floor(s.x), -R::floor(s.y));
    // A triangle's pixel bounds (lo, hi) from its corners' rounded minimum.
    let bounds = |corners: Vec4| {
        let b = corners.max(clip);
        (Vec2::new(b.x, b.y), Vec2::new(-b.z, -b.w))
    };
    let frustum = near_frustum(k, first, last);
    for m in &mesh.meshlets {
        if !meshlet_visible(m, pose, cam, du.stretch, mesh.cull_back_faces, k, first, last) {
            continue;
        }
        // The meshlet's vertices transformed and projected once (the same
        // f32 operations the kernel does per corner, so the values are
        // identical).
        let verts = &mesh.meshlet_vertices[m.first_vertex as usize..][..m.vertex_count as usize];
        for ((slot, snapped), &v) in proj.iter_mut().zip(snap.iter_mut()).zip(verts) {
            let p = pose.transform(mesh.vertices[v as usize]);
            let s = project(p);
            *slot = (p, s);
            *snapped = rounded(s);
        }
        // Only where its bounding sphere reaches the near plane can a
        // triangle cross it; its corners' projections are then no bounds.
        let crosses = pose.transform(Vec3::from_slice(&m.sphere[..3])).z - m.sphere[3] * du.stretch <= NEAR_M;
        for t in m.first as usize..(m.first + m.count) as usize {
            let tri = &mesh.triangles[t];
            if mesh.cull_back_faces && Vec3::from_slice(&tri.plane[..3]).dot(cam) <= tri.plane[3] {
                continue;
            }
            let [ia, ib, ic] = mesh.corners[t].map(|i| i as usize);
            let ((a, sa), (b, sb), (c, sc)) = (proj[ia], proj[ib], proj[ic]);
            if crosses && a.z.min(b.z).min(c.z) < NEAR_M {
                for part in clipped([a, b, c], &frustum) {
                    let [pa, pb, pc] = part.map(|p| (p, project(p)));
                    let (lo, hi) = bounds(rounded(pa.1).min(rounded(pb.1)).min(rounded(pc.1)));
                    if lo.x <= hi.x && lo.y <= hi.y {
                        drawn = union(drawn, fill_triangle([pa, pb, pc], lo, hi, t as u32, w, zbuf, ids));
                    }
                }
                continue;
            }
            // Empty bounds first (most triangles of a full-size model).
            let (lo, hi) = bounds(snap[ia].min(snap[ib]).min(snap[ic]));
            if lo.x > hi.x || lo.y > hi.y {
                continue;
            }
            if a.z.min(b.z).min(c.z) < NEAR_M {
                continue; // only by rounding, outside a meshlet that crosses
            }
            drawn = union(drawn, fill_triangle([(a, sa), (b, sb), (c, sc)], lo, hi, t as u32, w, zbuf, ids));
        }
    }
    drawn
}

/// The union of two drawn rectangles `[x0, y0, x1, y1]`.
#[inline(always)]
fn union(a: Option<[usize; 4]>, b: Option<[usize; 4]>) -> Option<[usize; 4]> {
    match (a, b) {
        (Some(a), Some(b)) => Some([a[0].min(b[0]), a[1].min(b[1]), a[2].max(b[2]), a[3].max(b[3])]),
        (a, b) => a.or(b),
    }
}

/// Sets up triangle `t` (corners in the camera frame with their pixel
/// positions, pixel bounds `lo..=hi` within the rectangle) and draws it
/// into the buffers (row width `w`) as the kernel's setup_vertices and
/// shade do. Returns its bounds, `None` for a degenerate triangle.
#[inline(always)]
fn fill_triangle(corners: [(Vec3, Vec2); 3], lo: Vec2, hi: Vec2, t: u32, w: usize, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
    let [(a, sa), (b, sb), (c, sc)] = corners;
    let area = (sb - sa).perp_dot(sc - sa);
    if area.abs() < 1e-12 {
        return None;
    }
    let (bx0, by0, bx1, by1) = (lo.x as usize, lo.y as usize, hi.x as usize, hi.y as usize);
    // The start pixel's edge functions; their signs (with the area's) say
    // whether it is covered.
    let edges = Vec3A::new((sc - sb).perp_dot(lo - sb), (sa - sc).perp_dot(lo - sc), (sb - sa).perp_dot(lo - sa));
    if bx0 == bx1 && by0 == by1 && (edges * area.signum()).min_element() < -1e-30 * area.abs() {
        // The only pixel of the bounds (most triangles of a full-size
        // model at 128x128) lies outside: no setup. Its weight edges / area
        // is then below -1e-30, a normal f32 that stays negative, so
        // fill_row would reject it too.
        return Some([bx0, by0, bx1, by1]);
    }
    // The kernel's setup (setup_triangle in raster.wgsl).
    let inv = 1.0 / area;
    let iz = Vec3A::new(1.0 / a.z, 1.0 / b.z, 1.0 / c.z);
    let dw_dx = Vec3A::new(sb.y - sc.y, sc.y - sa.y, sa.y - sb.y) * inv;
    let dw_dy = Vec3A::new(sc.x - sb.x, sa.x - sc.x, sb.x - sa.x) * inv;
    let w0 = edges * inv;
    for (j, y) in (by0..=by1).enumerate() {
        let row = y * w + bx0;
        fill_row(w0 + dw_dy * j as f32, dw_dx, iz, &mut zbuf[row..=row + bx1 - bx0], &mut ids[row..=row + bx1 - bx0], t);
    }
    Some([bx0, by0, bx1, by1])
}

/// Where a triangle crossing the near plane is drawn: the camera-frame
/// half-spaces (`n·p ≥ d`) of the near plane and of the four planes through
/// the camera centre and the rectangle's sides, a pixel beyond them.
/// Clipped at the near plane alone, a corner 1 mm from the camera projects
/// a thousand times farther out than at 1 m (600,000 pixels for 1 m aside
/// at fx = 600), and the edge functions' f32 rounding grows with it: a 20 m
/// square 5 cm from the camera lost two pixels along its diagonal (a fuzz
/// found it; `gpu_meshes_crossing_the_near_plane_draw_their_part_beyond_it`
/// holds it). Clipped to the frustum every corner stays within a pixel of
/// the rectangle, and the pixels inside it are the same.
fn near_frustum(k: &Intrinsics, first: (f32, f32), last: (f32, f32)) -> [(Vec3, f32); 5] {
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let (x0, x1) = ((first.0 - 1.0 - cx) / fx, (last.0 + 1.0 - cx) / fx);
    let (y0, y1) = ((first.1 - 1.0 - cy) / fy, (last.1 + 1.0 - cy) / fy);
    [
        (Vec3::Z, NEAR_M),
        (Vec3::new(1.0, 0.0, -x0), 0.0),
        (Vec3::new(-1.0, 0.0, x1), 0.0),
        (Vec3::new(0.0, 1.0, -y0), 0.0),
        (Vec3::new(0.0, -1.0, y1), 0.0),
    ]
}

/// The part of triangle `corners` (camera frame) inside every half-space
/// of `planes` (Sutherland-Hodgman), as a fan of triangles of the same
/// winding. The GPU rasterizers hand a hypothesis with a triangle crossing
/// the near plane to this twin (`setup_vertices` in raster.wgsl marks it),
/// which draws the part beyond the plane ([`near_frustum`]) as the ray
/// casters do, where the triangle used to be left out.
fn clipped(corners: [Vec3; 3], planes: &[(Vec3, f32)]) -> impl Iterator<Item = [Vec3; 3]> {
    // Each plane adds at most one corner: 3 + 5.
    let mut poly = [Vec3::ZERO; 8];
    poly[..3].copy_from_slice(&corners);
    let mut n = 3;
    for &(normal, d) in planes {
        let mut out = [Vec3::ZERO; 8];
        let mut m = 0;
        for i in 0..n {
            let (p, q) = (poly[i], poly[(i + 1) % n]);
            let (dp, dq) = (normal.dot(p) - d, normal.dot(q) - d);
            if dp >= 0.0 && m < out.len() {
                out[m] = p;
                m += 1;
            }
            if (dp >= 0.0) != (dq >= 0.0) && m < out.len() {
                // From the inside corner, whichever way the edge runs: the
                // neighbour sharing the edge walks it the other way and gets
                // the same point, bit for bit.
                let ((i, di), (o, dout)) = if dp >= 0.0 { ((p, dp), (q, dq)) } else { ((q, dq), (p, dp)) };
                out[m] = i + (o - i) * (di / (di - dout));
                m += 1;
            }
        }
        (poly, n) = (out, m);
    }
    (1..n.saturating_sub(1)).map(move |i| [poly[0], poly[i], poly[i + 1]])
}

/// One row of a triangle's bounds: pixel `i` is covered when every
/// barycentric weight `w_row + dw_dx * i` is at least 0, and is drawn when
/// its interpolated inverse depth beats the buffer's. Four pixels are
/// tested at once (the same f32 operations per pixel as one at a time:
/// the kernel's `w_row + dw_dx * f32(i)`), then the covered ones are
/// depth-tested.
#[inline]
fn fill_row(w_row: Vec3A, dw_dx: Vec3A, iz: Vec3A, zbuf: &mut [f32], ids: &mut [u32], t: u32) {
    let lanes = Vec4::new(0.0, 1.0, 2.0, 3.0);
    let (r0, r1, r2) = (Vec4::splat(w_row.x), Vec4::splat(w_row.y), Vec4::splat(w_row.z));
    let (d0, d1, d2) = (Vec4::splat(dw_dx.x), Vec4::splat(dw_dx.y), Vec4::splat(dw_dx.z));
    let n = zbuf.len();
    for i in (0..n).step_by(4) {
        let fi = Vec4::splat(i as f32) + lanes;
        let (e0, e1, e2) = (r0 + d0 * fi, r1 + d1 * fi, r2 + d2 * fi);
        let covered = e0.cmpge(Vec4::ZERO) & e1.cmpge(Vec4::ZERO) & e2.cmpge(Vec4::ZERO);
        let mut mask = covered.bitmask() & (0b1111 >> 4usize.saturating_sub(n - i));
        if mask == 0 {
            continue;
        }
        let near = (e0 * iz.x + e1 * iz.y + e2 * iz.z).to_array();
        while mask != 0 {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if near[l] > zbuf[i + l] {
                zbuf[i + l] = near[l];
                ids[i + l] = t;
            }
        }
    }
}

/// The CPU renderer `mesh` gets at `pose` (from the pixels of the
/// hypothesis' rectangle; `None` when it misses the image).
pub fn cpu_renderer_at(mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics) -> Option<super::CpuRenderer> {
    let r = screen_rect(pose, mesh.radius, k)?;
    Some(mesh.cpu_renderer((r[2] - r[0] + 1) * (r[3] - r[1] + 1)))
}

/// Triangle ids and depths of `mesh` at `pose` with its CPU renderer (the
/// rasterizer twin or the BVH ray caster, chosen per hypothesis by
/// [`RenderMesh::cpu_renderer`]); the same contract as [`raster_ids`].
pub fn render_ids(mesh: &RenderMesh, pose: &GpuPose, k: &Intrinsics, zbuf: &mut [f32], ids: &mut [u32]) -> Option<[usize; 4]> {
    match cpu_renderer_at(mesh, pose, k)? {
        super::CpuRenderer::RayCast => mesh.ray_caster().expect("chosen only when built").cast_ids(mesh, pose, k, zbuf, ids),
        super::CpuRenderer::Raster => raster_ids(mesh, pose, k, zbuf, ids),
    }
}

/// Exact depth and camera-facing normal at pixel `(x, y)` on triangle `tri`,
/// from the triangle's plane (the twin of `resolve` in raster.wgsl). The
/// pixel centre lies inside the triangle, so the plane gives its depth;
/// edge-on faces are clamped to the hypothesis' depth range.
#[inline]
pub fn resolve(tri: &GpuTriangle, pose: &GpuPose, du: &Dual, radius: f32, k: &Intrinsics, x: f32, y: f32) -> (f32, Vec3) {
    // The plane n·x = w moves to (A⁻ᵀn)·x = w + (A⁻ᵀn)·t (du = pose.dual(),
    // made once per pose by the caller).
    let m = Vec3::from_slice(&tri.plane[..3]);
    let n = Vec3::new(du.q[0].dot(m), du.q[1].dot(m), du.q[2].dot(m));
    let t = pose.translation();
    let d = tri.plane[3] + n.dot(t);
    let ray = Vec3::new((x - k.cx as f32) / k.fx as f32, (y - k.cy as f32) / k.fy as f32, 1.0);
    let den = n.dot(ray);
    let radius = radius * du.stretch;
    let (zlo, zhi) = ((t.z - radius).max(NEAR_M), t.z + radius);
    let z = if den.abs() > 1e-12 { (d / den).clamp(zlo, zhi) } else { zhi };
    let nn = if du.rigid { n } else { n.normalize() };
    (z, if den > 0.0 { -nn } else { nn })
}

pub(crate) fn raster_params(mesh: &RenderMesh, k: &Intrinsics, n_hyp: u32, tau: f32, alpha: f32, n_obs: u32) -> RasterParams {
    RasterParams {
        fx: k.fx as f32,
        fy: k.fy as f32,
        cx: k.cx as f32,
        cy: k.cy as f32,
        width: k.width,
        height: k.height,
        n_hyp,
        n_meshlets: mesh.meshlets.len() as u32,
        id_bits: mesh.id_bits(),
        cull: mesh.cull_back_faces as u32,
        radius: mesh.radius,
        tau,
        alpha,
        near: NEAR_M,
        n_obs,
        first: 0,
        draw_budget: u32::MAX,
        slots: 0,
        pad1: 0,
        pad2: 0,
    }
}

/// lavapipe (llvmpipe) ends every loop of a shader after this many
/// iterations in total, counted per SIMD vector of invocations: a loop
/// runs as long as any of the vector's lanes is in it.
pub const SOFTWARE_LOOP_CAP: u32 = 65_535;

/// How a kernel's dispatch lays hypotheses onto workgroups.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum WaveLayout {
    /// One workgroup per hypothesis and visibility slot (`raster.wgsl`'s
    /// kernels); the draw budget is per invocation ([`draw_budget`]).
    Workgroups,
    /// One invocation per hypothesis, this many to a workgroup
    /// (`score_lanes.wgsl`); the draw budget is the SIMD vector's loop
    /// iterations ([`LANES_LOOP_BUDGET`]).
    Lanes(u32),
}

/// Loop iterations a vector of `score_lanes.wgsl` may spend in all: the
/// software cap less a margin (the kernel adds up a bound of its vector's
/// iterations, each loop's entry included).
pub const LANES_LOOP_BUDGET: u32 = SOFTWARE_LOOP_CAP - 1_000;

/// Pixel-loop iterations one invocation may spend drawing a hypothesis
/// (`params.draw_budget` in raster.wgsl). Unlimited on hardware GPUs. On a
/// software adapter, a vector of W lanes runs at most W times what its
/// busiest lane spends (each of its pixel loops runs as long as its
/// longest lane), on top of the loops every kernel has anyway (meshlet
/// rounds and steps, the consumer's passes over the region, at most two;
/// the fused plane stage's samples, at most 850 for 50,000 samples; a
/// margin of 1,000); so the budget is what the cap leaves of those, over
/// W. The duck at 128x128 spends about 200 per invocation against about
/// 7,800 allowed.
pub fn draw_budget(ctx: &Context, n_meshlets: u32, pixels: u32) -> u32 {
    if !ctx.is_software() {
        return u32::MAX;
    }
    let fixed = n_meshlets.div_ceil(64) * 65 + 2 * pixels.div_ceil(64) + 850 + 1_000 + 64;
    SOFTWARE_LOOP_CAP.saturating_sub(fixed) / ctx.simd_lanes()
}

/// Refuses a mesh whose triangle or meshlet table is larger than the
/// adapter's textures hold (`TRI_ROW` triangles per row: 16.7M triangles
/// on an adapter with 16,384-texel textures).
pub fn check_mesh_bindings(ctx: &Context, mesh: &RenderMesh) -> Result<()> {
    if !table_fits(ctx, mesh.triangles.len(), TRI_ROW) || !table_fits(ctx, mesh.meshlets.len(), MESHLET_ROW) {
        return Err(Error::Gpu(format!(
            "mesh has {} triangles but the adapter's textures hold at most {}: decimate it",
            mesh.triangles.len(),
            TRI_ROW * ctx.max_texture_dim as usize
        )));
    }
    Ok(())
}

/// GPU buffers and textures a visual kernel needs for one mesh and image
/// size.
pub(crate) struct RasterBuffers {
    pub params: wgpu::Buffer,
    pub tris: wgpu::TextureView,
    pub meshlets: wgpu::TextureView,
    pub poses: wgpu::Buffer,
    pub vis: wgpu::Buffer,
    /// Hypotheses per dispatch.
    pub chunk: usize,
    /// Workgroups (visibility slots) per dispatch.
    pub slots: u32,
}

/// Upper bound on the visibility buffer, so memory stays bounded whatever
/// the adapter allows.
const VIS_BUDGET_BYTES: u64 = 256 << 20;

impl RasterBuffers {
    /// Sizes the buffers so every binding fits the adapter's limits;
    /// `per_hyp_bytes` is what each hypothesis adds to the largest output.
    pub fn new(ctx: &Context, mesh: &RenderMesh, k: &Intrinsics, n: usize, per_hyp_bytes: u64, max_chunk: usize) -> Result<Self> {
        let lim = ctx.limits;
        let pix = k.pixels() as u64;
        check_mesh_bindings(ctx, mesh)?;
        if pix * 16 > lim.max_storage_binding.min(lim.max_buffer) {
            return Err(Error::Gpu(format!("a {}x{} region is too large for this adapter", k.width, k.height)));
        }
        let chunk = (n.max(1) as u64)
            .min(lim.max_items(std::mem::size_of::<GpuPose>() as u64))
            .min(lim.max_items(per_hyp_bytes.max(1)))
            .min(max_chunk.max(1) as u64)
            .max(1) as usize;
        // Hypotheses per wave (one workgroup and visibility slot each). A
        // software adapter runs one workgroup per CPU thread, so a few
        // hundred per wave keep it busy and its memory small; GPUs get as
        // many as the memory budget allows.
        let (max_slots, budget) = if ctx.is_software() { (256, 64 << 20) } else { (u64::MAX, VIS_BUDGET_BYTES) };
        let slots = (chunk as u64)
            .min(max_slots)
            .min(lim.max_workgroups as u64)
            .min((lim.max_storage_binding.min(lim.max_buffer).min(budget) / (pix * 4)).max(1))
            .max(1) as u32;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let tris = texel_table(ctx, "triangles", &mesh.triangles, TRI_ROW, wgpu::TextureFormat::Rgba32Float)?;
        let meshlets = texel_table(ctx, "meshlets", &mesh.meshlets, MESHLET_ROW, wgpu::TextureFormat::Rgba32Uint)?;
        // One parameter block per wave, each at a uniform-offset boundary.
        let waves = (chunk as u64).div_ceil(slots as u64);
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: waves * PARAMS_STRIDE,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let poses = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("poses"),
            size: (chunk * std::mem::size_of::<GpuPose>()) as u64,
            usage: storage,
            mapped_at_creation: false,
        });
        let vis = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visibility"),
            size: slots as u64 * pix * 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        Ok(RasterBuffers { params, tris, meshlets, poses, vis, chunk, slots })
    }

    /// Runs a kernel over `n` hypotheses (already uploaded to `poses`) in
    /// waves of `slots` workgroups, one hypothesis per workgroup: one
    /// parameter block per wave (`params.first` = the wave's first
    /// hypothesis) and one dispatch per wave in a single compute pass. wgpu
    /// orders the dispatches, since each writes the visibility buffer.
    #[allow(clippy::too_many_arguments)] // one call site per kernel; a struct would only rename them
    pub fn dispatch_waves(
        &self,
        ctx: &Context,
        enc: &mut wgpu::CommandEncoder,
        (pipeline, layout): (&wgpu::ComputePipeline, WaveLayout),
        extra: &[wgpu::BindGroupEntry<'_>],
        params: RasterParams,
        n: usize,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let waves = self.write_wave_params(ctx, params, n, layout);
        let vis = layout == WaveLayout::Workgroups;
        let groups: Vec<wgpu::BindGroup> = (0..waves).map(|w| self.wave_group(ctx, pipeline, w, extra, true, vis)).collect();
        let per_group = match layout {
            WaveLayout::Workgroups => 1,
            WaveLayout::Lanes(lanes) => lanes,
        };
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("waves"), timestamp_writes: timestamps });
        pass.set_pipeline(pipeline);
        for (w, group) in groups.iter().enumerate() {
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(self.wave_len(n, w).div_ceil(per_group), 1, 1);
        }
    }

    /// Like [`dispatch_waves`](Self::dispatch_waves) for the ray caster:
    /// per wave, `raycast` fills the slots (one workgroup per 8x8 tile of
    /// the region and hypothesis, laid out by `grid`, see
    /// [`tile_grid`](super::raycast::tile_grid)), then `reduce` consumes
    /// them (one workgroup per hypothesis); `traced` and `reduced` are each
    /// one's own bindings.
    #[allow(clippy::too_many_arguments)] // one call site; a struct would only rename them
    pub fn dispatch_traced_waves(
        &self,
        ctx: &Context,
        enc: &mut wgpu::CommandEncoder,
        (raycast, traced): (&wgpu::ComputePipeline, &[wgpu::BindGroupEntry<'_>]),
        (reduce, reduced): (&wgpu::ComputePipeline, &[wgpu::BindGroupEntry<'_>]),
        params: RasterParams,
        n: usize,
        (per_row, rows): (u32, u32),
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let waves = self.write_wave_params(ctx, params, n, WaveLayout::Workgroups);
        let groups: Vec<(wgpu::BindGroup, wgpu::BindGroup)> = (0..waves)
            .map(|w| (self.wave_group(ctx, raycast, w, traced, false, true), self.wave_group(ctx, reduce, w, reduced, false, true)))
            .collect();
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("traced waves"), timestamp_writes: timestamps });
        for (w, (trace, score)) in groups.iter().enumerate() {
            pass.set_pipeline(raycast);
            pass.set_bind_group(0, trace, &[]);
            pass.dispatch_workgroups(per_row, self.wave_len(n, w), rows);
            pass.set_pipeline(reduce);
            pass.set_bind_group(0, score, &[]);
            pass.dispatch_workgroups(self.wave_len(n, w), 1, 1);
        }
    }

    /// Hypotheses in wave `w` of `n`.
    fn wave_len(&self, n: usize, w: usize) -> u32 {
        (n - w * self.slots as usize).min(self.slots as usize) as u32
    }

    /// Writes one parameter block per wave of `n` hypotheses; returns the
    /// number of waves.
    fn write_wave_params(&self, ctx: &Context, params: RasterParams, n: usize, layout: WaveLayout) -> usize {
        let slots = self.slots as usize;
        let waves = n.div_ceil(slots);
        let mut blocks = vec![0u8; waves * PARAMS_STRIDE as usize];
        let budget = match layout {
            WaveLayout::Workgroups => draw_budget(ctx, params.n_meshlets, params.width * params.height),
            WaveLayout::Lanes(_) if ctx.is_software() => LANES_LOOP_BUDGET,
            WaveLayout::Lanes(_) => u32::MAX,
        };
        for w in 0..waves {
            let p = RasterParams { n_hyp: n as u32, first: (w * slots) as u32, draw_budget: budget, slots: self.slots, ..params };
            let at = w * PARAMS_STRIDE as usize;
            blocks[at..at + std::mem::size_of::<RasterParams>()].copy_from_slice(bytemuck::bytes_of(&p));
        }
        ctx.queue.write_buffer(&self.params, 0, &blocks);
        waves
    }

    /// The bind group of wave `w` for `pipeline`: the shared bindings 0-2,
    /// the visibility buffer (3) and the meshlet table when the kernel uses
    /// them, and `extra`.
    #[allow(clippy::too_many_arguments)] // flags of what the kernel binds
    fn wave_group(
        &self,
        ctx: &Context,
        pipeline: &wgpu::ComputePipeline,
        w: usize,
        extra: &[wgpu::BindGroupEntry<'_>],
        meshlets: bool,
        vis: bool,
    ) -> wgpu::BindGroup {
        let mut entries = vec![
            wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &self.params,
                    offset: w as u64 * PARAMS_STRIDE,
                    size: std::num::NonZeroU64::new(std::mem::size_of::<RasterParams>() as u64),
                }),
            },
            wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&self.tris) },
            wgpu::BindGroupEntry { binding: 2, resource: self.poses.as_entire_binding() },
        ];
        if vis {
            entries.push(wgpu::BindGroupEntry { binding: 3, resource: self.vis.as_entire_binding() });
        }
        if meshlets {
            entries.push(wgpu::BindGroupEntry { binding: MESHLETS_BINDING, resource: wgpu::BindingResource::TextureView(&self.meshlets) });
        }
        entries.extend(extra.iter().cloned());
        let layout = pipeline.get_bind_group_layout(0);
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some("wave"), layout: &layout, entries: &entries })
    }
}

/// Triangles per row of the triangle texture (`TRI_ROW` in raster.wgsl).
pub const TRI_ROW: usize = 1024;
/// Meshlets per row of the meshlet texture (`MESHLET_ROW` in raster.wgsl).
pub const MESHLET_ROW: usize = 1024;

/// Whether a table of `len` items, `per_row` a row, fits the adapter's
/// textures (see [`texel_table`]).
pub(crate) fn table_fits(ctx: &Context, len: usize, per_row: usize) -> bool {
    len.div_ceil(per_row) <= ctx.max_texture_dim as usize
}

/// A read-only table as a texture of `format`'s texels (4 to 16 bytes):
/// `per_row` items per row, each item's texels side by side, the last row
/// zero-padded (only that row is copied to pad it, so a large mesh is not
/// held twice); refused when it has more rows than the adapter's textures.
/// On lavapipe a texel fetch is a vector gather, where a storage-buffer
/// load runs lane by lane with a branch and a bounds check each.
pub(crate) fn texel_table<T: bytemuck::Pod>(ctx: &Context, label: &str, items: &[T], per_row: usize, format: wgpu::TextureFormat) -> Result<wgpu::TextureView> {
    if !table_fits(ctx, items.len(), per_row) {
        return Err(Error::Gpu(format!(
            "the {label} table ({} items, {per_row} a row) is taller than this adapter's textures ({} rows)",
            items.len(),
            ctx.max_texture_dim
        )));
    }
    let texel_bytes = format.block_copy_size(None).expect("an uncompressed colour format") as usize;
    let texels = std::mem::size_of::<T>() / texel_bytes;
    debug_assert_eq!(texels * texel_bytes, std::mem::size_of::<T>());
    let rows = items.len().div_ceil(per_row).max(1);
    let width = (per_row * texels) as u32;
    let row_bytes = width as usize * texel_bytes;
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width, height: rows as u32, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let write = |first_row: usize, data: &[u8]| {
        let n_rows = (data.len() / row_bytes) as u32;
        ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: 0, origin: wgpu::Origin3d { x: 0, y: first_row as u32, z: 0 }, aspect: wgpu::TextureAspect::All },
            data,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row_bytes as u32), rows_per_image: Some(n_rows) },
            wgpu::Extent3d { width, height: n_rows, depth_or_array_layers: 1 },
        );
    };
    let full = items.len() / per_row;
    if full > 0 {
        write(0, bytemuck::cast_slice(&items[..full * per_row]));
    }
    if full < rows {
        let mut last = items[full * per_row..].to_vec();
        last.resize(per_row, bytemuck::Zeroable::zeroed());
        write(full, bytemuck::cast_slice(&last));
    }
    Ok(texture.create_view(&Default::default()))
}

/// Binding of the meshlet table in raster.wgsl (after every kernel's own
/// bindings 4-9).
const MESHLETS_BINDING: u32 = 10;

/// Byte stride of the per-wave parameter blocks (the largest uniform-offset
/// alignment wgpu allows).
const PARAMS_STRIDE: u64 = 256;

pub use super::render::{render_cpu, render_gpu, RenderImage};
