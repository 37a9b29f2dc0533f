// Compute-shader rasterizer shared by the visual kernels (render, score).
//
// One workgroup owns one hypothesis and a private "slot" of the visibility
// buffer (one u32 per pixel); a dispatch runs one wave of hypotheses, one
// per slot (a workgroup never loops over hypotheses: lavapipe caps the total
// loop iterations of an invocation, see BIG_PIXELS). Its invocations take
// the mesh's meshlets (up to 64 neighbouring triangles with a bounding
// sphere and normal cone) in rounds: a meshlet facing away from the camera
// or outside the region is skipped whole, before any of its triangles is
// set up; otherwise each invocation sets up one of its triangles. Each
// covered pixel gets atomicMax of the key
// (quantized inverse depth << id_bits) | triangle id, so the nearest triangle
// wins and 0 means "nothing drawn". Inverse depth is quantized over the
// hypothesis' own depth range [t.z - radius, t.z + radius], so 32 - id_bits
// bits give sub-micrometre steps for typical meshes; the exact depth is
// recomputed from the winning triangle's plane (resolve), so quantization
// only decides ties closer than one step.
//
// No clearing pass: buffers start zeroed, and the consumer of a slot reads
// every pixel the rasterizer may have touched with atomicExchange(.., 0),
// which hands over the key and leaves the slot empty for the next
// hypothesis. The rasterizer reports the tight rectangle of the triangles it
// drew, so consumers visit only that.
//
// CPU twin: src/kernels/raster.rs (raster_ids, resolve).

struct RasterParams {
    fx: f32, fy: f32, cx: f32, cy: f32,
    width: u32, height: u32, n_hyp: u32, n_meshlets: u32,
    id_bits: u32, cull: u32, radius: f32, tau: f32,
    alpha: f32, near: f32, n_obs: u32, first: u32,
    draw_budget: u32, slots: u32, pad1: u32, pad2: u32,
}

struct GpuTriangle { v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, plane: vec4<f32> }

// Triangles first..first+count (model space): bounding sphere (centre,
// radius) and normal cone (axis, cutoff; a cutoff above 1 never culls).
// first_vertex and vertex_count serve the CPU twin only.
struct GpuMeshlet { sphere: vec4<f32>, cone: vec4<f32>, first: u32, count: u32, first_vertex: u32, vertex_count: u32 }

// Rows of [R | t], model -> camera, metres.
struct GpuPose { r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32> }

@group(0) @binding(0) var<uniform> params: RasterParams;
// The triangles as texels (GpuTriangle's four vec4s side by side,
// TRI_ROW triangles per row): on lavapipe a texel fetch is a vector
// gather, while a storage-buffer load runs lane by lane.
@group(0) @binding(1) var tris: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> poses: array<GpuPose>;
@group(0) @binding(3) var<storage, read_write> vis: array<atomic<u32>>;
// The meshlet table as texels (GpuMeshlet's three 16-byte words side by
// side, MESHLET_ROW meshlets per row; floats bit-cast).
@group(0) @binding(10) var meshlets: texture_2d<u32>;

// Invocations per workgroup: 64 measured fastest on lavapipe (fewer
// reduction steps per hypothesis) and is a full warp/wavefront on GPUs.
const WG: u32 = 64u;
const EMPTY: u32 = 0u;
const BIG: i32 = 0x7fffffff;
// Triangles per row of the triangle texture (kernels/raster.rs TRI_ROW).
const TRI_ROW: u32 = 1024u;

// Meshlets per row of the meshlet texture (kernels/raster.rs MESHLET_ROW).
const MESHLET_ROW: u32 = 1024u;

// Word k (0: sphere, 1: cone, 2: first, count, first_vertex,
// vertex_count) of meshlet m.
fn meshlet_texel(m: u32, k: u32) -> vec4<u32> {
    return textureLoad(meshlets, vec2<u32>((m % MESHLET_ROW) * 3u + k, m / MESHLET_ROW), 0);
}

fn meshlet(m: u32) -> GpuMeshlet {
    let s = meshlet_texel(m, 2u);
    return GpuMeshlet(bitcast<vec4<f32>>(meshlet_texel(m, 0u)), bitcast<vec4<f32>>(meshlet_texel(m, 1u)), s.x, s.y, s.z, s.w);
}

// Texel k (0-2: vertices v0-v2, 3: plane) of triangle t.
fn tri_texel(t: u32, k: u32) -> vec4<f32> {
    return textureLoad(tris, vec2<u32>((t % TRI_ROW) * 4u + k, t / TRI_ROW), 0);
}

// Tight rectangle of what was drawn: (min x, min y, max x, max y).
var<workgroup> drawn: array<atomic<i32>, 4>;

fn rotate(p: GpuPose, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(p.r0.xyz, v), dot(p.r1.xyz, v), dot(p.r2.xyz, v));
}

fn transform(p: GpuPose, v: vec3<f32>) -> vec3<f32> {
    return rotate(p, v) + vec3<f32>(p.r0.w, p.r1.w, p.r2.w);
}

// The pose's linear part A is a rotation wherever the library makes poses,
// but a results file under evaluation may hold a slightly sheared or scaled
// one, which the BOP toolkit renders as given. Vertices then move by A,
// planes (normals) by A⁻ᵀ and camera rays into the model by A⁻¹, and the
// bounding sphere grows by A's largest stretch. q0..q2 are the rows of A⁻ᵀ
// (the columns of A⁻¹); for a rotation they are A's rows and the stretch
// is 1, exactly (CPU twin: kernels/mod.rs GpuPose::dual).
struct Dual { q0: vec3<f32>, q1: vec3<f32>, q2: vec3<f32>, stretch: f32, rigid: bool }

// Largest |A Aᵀ - I| entry still taken for a rotation (f32 rows of an f64
// rotation are off by about 1e-7).
const RIGID_TOL: f32 = 1e-5;

fn dual(p: GpuPose) -> Dual {
    let a = p.r0.xyz;
    let b = p.r1.xyz;
    let c = p.r2.xyz;
    // Rows of the Gram matrix A Aᵀ.
    let g0 = vec3<f32>(dot(a, a), dot(a, b), dot(a, c));
    let g1 = vec3<f32>(g0.y, dot(b, b), dot(b, c));
    let g2 = vec3<f32>(g0.z, g1.z, dot(c, c));
    let off = max(max(abs(g0 - vec3<f32>(1.0, 0.0, 0.0)), abs(g1 - vec3<f32>(0.0, 1.0, 0.0))), abs(g2 - vec3<f32>(0.0, 0.0, 1.0)));
    if (max(off.x, max(off.y, off.z)) <= RIGID_TOL) {
        return Dual(a, b, c, 1.0, true);
    }
    let det = dot(a, cross(b, c));
    // Gershgorin: A Aᵀ's largest eigenvalue is at most its largest absolute row sum.
    let rows = vec3<f32>(dot(abs(g0), vec3<f32>(1.0)), dot(abs(g1), vec3<f32>(1.0)), dot(abs(g2), vec3<f32>(1.0)));
    return Dual(cross(b, c) / det, cross(c, a) / det, cross(a, b) / det, sqrt(max(rows.x, max(rows.y, rows.z))), false);
}

// Camera centre in model coordinates, -A⁻¹t.
fn camera_in_model(p: GpuPose, d: Dual) -> vec3<f32> {
    return -(d.q0 * p.r0.w + d.q1 * p.r1.w + d.q2 * p.r2.w);
}

// Radius of the hypothesis' bounding sphere (about the model origin), du
// = dual(p).
fn pose_radius(du: Dual) -> f32 {
    return params.radius * du.stretch;
}

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

fn project(v: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(params.fx * v.x / v.z + params.cx, params.fy * v.y / v.z + params.cy);
}

// Depth range of the hypothesis: its bounding sphere, clipped at near.
fn depth_range(p: GpuPose, du: Dual) -> vec2<f32> {
    let r = pose_radius(du);
    return vec2<f32>(max(p.r2.w - r, params.near), p.r2.w + r);
}

// Projection (xlo, ylo, xhi, yhi), in pixels, of the box around a sphere at
// c (camera frame) of radius r lying wholly beyond the near plane.
fn sphere_bounds(c: vec3<f32>, r: f32) -> vec4<f32> {
    let zn = c.z - r;
    let zf = c.z + r;
    let xlo = min((c.x - r) / zn, (c.x - r) / zf) * params.fx + params.cx;
    let xhi = max((c.x + r) / zn, (c.x + r) / zf) * params.fx + params.cx;
    let ylo = min((c.y - r) / zn, (c.y - r) / zf) * params.fy + params.cy;
    let yhi = max((c.y + r) / zn, (c.y + r) / zf) * params.fy + params.cy;
    return vec4<f32>(xlo, ylo, xhi, yhi);
}

// Pixel rectangle (x0, y0, x1, y1), inclusive, that can hold the
// hypothesis: the projection of the box around its bounding sphere, clipped
// to the image. x0 > x1 when it misses the image.
fn screen_rect(p: GpuPose, du: Dual) -> vec4<i32> {
    let c = vec3<f32>(p.r0.w, p.r1.w, p.r2.w);
    let r = pose_radius(du);
    let full = vec4<i32>(0, 0, i32(params.width) - 1, i32(params.height) - 1);
    if (c.z - r <= params.near) {
        return full;
    }
    let b = sphere_bounds(c, r);
    let lo = max(ceil(b.xy), vec2<f32>(-1.0));
    let hi = min(floor(b.zw), vec2<f32>(f32(params.width), f32(params.height)));
    return vec4<i32>(max(vec2<i32>(lo), full.xy), min(vec2<i32>(hi), full.zw));
}

fn rect_pixels(rect: vec4<i32>) -> u32 {
    if (rect.x > rect.z || rect.y > rect.w) {
        return 0u;
    }
    return u32(rect.z - rect.x + 1) * u32(rect.w - rect.y + 1);
}

// Invocation lid's walk over a non-empty rectangle's pixels in row-major
// order: pixels lid, lid + WG, ... (j), at image column x and row y. Each
// step moves on WG pixels without a division: lavapipe divides lane by
// lane (a division per pixel cost the fused score kernel 3 % on the duck
// and 5 % on a 64-triangle sphere, whose big triangles walk this way).
struct RectWalk { j: u32, x: u32, y: u32, rw: u32, sx: u32, sy: u32 }

fn rect_walk(rect: vec4<i32>, lid: u32) -> RectWalk {
    let rw = u32(max(rect.z - rect.x + 1, 1));
    return RectWalk(lid, u32(rect.x) + lid % rw, u32(rect.y) + lid / rw, rw, WG % rw, WG / rw);
}

fn walk_step(w: ptr<function, RectWalk>, rect: vec4<i32>) {
    (*w).j += WG;
    (*w).x += (*w).sx;
    (*w).y += (*w).sy;
    if ((*w).x > u32(rect.z)) {
        (*w).x -= (*w).rw;
        (*w).y += 1u;
    }
}

// Whether meshlet m may draw into [first, last] (CPU twin:
// kernels/raster.rs meshlet_visible): not when it faces away from the camera
// as a whole (meshoptimizer's cone test with the bounding sphere, cam = the
// camera centre in model coordinates), lies behind the near plane, or
// projects outside the rectangle (with half a pixel to spare). Every
// triangle of a rejected meshlet would be rejected on its own.
fn meshlet_visible(m: GpuMeshlet, p: GpuPose, cam: vec3<f32>, stretch: f32, first: vec2<f32>, last: vec2<f32>) -> bool {
    let centre = m.sphere.xyz;
    // The cone test is in model space (which side of a face the camera
    // lies on does not change under any invertible A), with the model's
    // radius; the camera-space tests below take the stretched one.
    if (params.cull != 0u) {
        let v = centre - cam;
        if (dot(v, m.cone.xyz) >= m.cone.w * length(v) + m.sphere.w) {
            return false;
        }
    }
    let r = m.sphere.w * stretch;
    let c = transform(p, centre);
    if (c.z + r < params.near) {
        return false;
    }
    if (c.z - r <= params.near) {
        return true;
    }
    let b = sphere_bounds(c, r);
    return all(b.zw >= first - 0.5) && all(b.xy <= last + 0.5);
}

// Takes the key of a pixel and leaves the slot empty (EMPTY = nothing drawn).
// Called only after raster_slot's closing barrier, by the one invocation
// that visits the pixel, so a load and a store where something was drawn
// do what an exchange would (3-5 % faster on lavapipe, which runs atomic
// read-modify-writes one lane at a time).
fn take_key(at: u32) -> u32 {
    let key = atomicLoad(&vis[at]);
    if (key != EMPTY) {
        atomicStore(&vis[at], 0u);
    }
    return key;
}

// A triangle set up for rasterization: its clipped pixel bounds and the
// barycentric weights' start value and steps (weights are affine in the
// pixel position, and so is inverse depth). `cut`: not set up because a
// corner lies nearer than the near plane; the kernels then report the
// hypothesis as over budget, and the host draws it with the CPU twin,
// which clips the triangle at the plane (raster.rs `clipped`) where
// skipping it would leave a wrong image (an object reaching behind the
// camera drew none of its crossing triangles).
struct Setup {
    ok: bool,
    cut: bool,
    lo: vec2<f32>,
    hi: vec2<f32>,
    w0: vec3<f32>,
    dw_dx: vec3<f32>,
    dw_dy: vec3<f32>,
    iz: vec3<f32>,
}

// Whether triangle t may face the camera at `cam` (model space): not a
// back face of a closed mesh (the twin's test, raster.rs: culled where the
// plane's side is <= 0, so a NaN is drawn, not culled).
fn faces_camera(t: u32, cam: vec3<f32>) -> bool {
    return plane_faces(tri_texel(t, 3u), cam);
}

// faces_camera for a triangle's plane texel already fetched.
fn plane_faces(plane: vec4<f32>, cam: vec3<f32>) -> bool {
    return params.cull == 0u || !(dot(plane.xyz, cam) <= plane.w);
}

fn setup_triangle(p: GpuPose, t: u32, cam: vec3<f32>, first: vec2<f32>, last: vec2<f32>) -> Setup {
    if (!faces_camera(t, cam)) {
        var s: Setup;
        s.ok = false;
        return s; // back face of a closed mesh
    }
    return setup_vertices(p, tri_texel(t, 0u), tri_texel(t, 1u), tri_texel(t, 2u), first, last);
}

// setup_triangle for a triangle that faces the camera, from its vertex
// texels (the lanes kernel fetches a group's texels together:
// score_lanes.wgsl).
fn setup_vertices(p: GpuPose, v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, first: vec2<f32>, last: vec2<f32>) -> Setup {
    var s: Setup;
    s.ok = false;
    let a = transform(p, v0.xyz);
    let b = transform(p, v1.xyz);
    let c = transform(p, v2.xyz);
    if (min(a.z, min(b.z, c.z)) < params.near) {
        s.cut = true;
        return s;
    }
    let sa = project(a);
    let sb = project(b);
    let sc = project(c);
    let area = cross2(sb - sa, sc - sa);
    if (abs(area) < 1e-12) {
        return s;
    }
    s.lo = max(ceil(min(sa, min(sb, sc))), first);
    s.hi = min(floor(max(sa, max(sb, sc))), last);
    if (s.lo.x > s.hi.x || s.lo.y > s.hi.y) {
        return s;
    }
    let inv = 1.0 / area;
    s.iz = vec3<f32>(1.0 / a.z, 1.0 / b.z, 1.0 / c.z);
    s.dw_dx = vec3<f32>(sb.y - sc.y, sc.y - sa.y, sa.y - sb.y) * inv;
    s.dw_dy = vec3<f32>(sc.x - sb.x, sa.x - sc.x, sb.x - sa.x) * inv;
    s.w0 = vec3<f32>(cross2(sc - sb, s.lo - sb), cross2(sa - sc, s.lo - sc), cross2(sb - sa, s.lo - sa)) * inv;
    s.ok = true;
    return s;
}

// How a hypothesis' keys quantize inverse depth (affine in screen space,
// no division per pixel; larger = nearer) over its depth range: the
// inverse depth of the far end, the scale to codes, the number of codes.
struct KeyScale { izfar: f32, izscale: f32, max_code: f32 }

fn key_scale(p: GpuPose, du: Dual) -> KeyScale {
    let zr = depth_range(p, du);
    let max_code = f32((1u << (32u - params.id_bits)) - 1u);
    let izfar = 1.0 / zr.y;
    return KeyScale(izfar, (max_code - 1.0) / max(1.0 / zr.x - izfar, 1e-9), max_code);
}

// The visibility key of triangle t at inverse depth iz (code 0 is reserved
// for "nothing drawn").
fn depth_key(ks: KeyScale, iz: f32, t: u32) -> u32 {
    let code = u32(clamp((iz - ks.izfar) * ks.izscale, 0.0, ks.max_code - 1.0)) + 1u;
    return (code << params.id_bits) | t;
}

// Depth test of image pixel (x, y) of the triangle's bounds.
// The weights are summed in the twin's order, the row's start first (w0 +
// dw_dy * j, then + dw_dx * i): in another order a pixel centre on an edge
// can fall on the other side of it (a few pixels of big triangles differed
// from the twin and the lanes kernel).
fn shade(s: Setup, t: u32, x: u32, y: u32, base: u32, ks: KeyScale) {
    let w = (s.w0 + s.dw_dy * (f32(y) - s.lo.y)) + s.dw_dx * (f32(x) - s.lo.x);
    if (min(w.x, min(w.y, w.z)) < 0.0) {
        return;
    }
    atomicMax(&vis[base + y * params.width + x], depth_key(ks, dot(w, s.iz), t));
}

// params.draw_budget: pixel-loop iterations (and queued big triangles) one
// invocation may spend drawing a hypothesis. Everything else an invocation
// loops over is bounded by the mesh and region caps (kernels/mod.rs: at
// most 8,192 meshlets and 1M region pixels), but drawing is not: a mesh
// whose triangles overlap many times over could need millions. A
// workgroup that would spend more stops drawing and reports the hypothesis
// as over budget (the host then renders it on the CPU). The host sets the
// budget (kernels/raster.rs draw_budget) so that a SIMD vector of a
// software adapter stays under lavapipe's 65,535 loop iterations; on
// hardware it is unlimited.
var<workgroup> over_budget: atomic<u32>;

// Triangles whose bounds exceed this many pixels are rasterized by the
// whole workgroup together. Besides balancing the work this keeps every
// invocation's loop trip count small: lavapipe (llvmpipe) stops a shader's
// loops after 65535 iterations in total, which a single invocation filling a
// large triangle would exceed.
const BIG_PIXELS: u32 = 256u;
// Meshlets per round (one per invocation for the culling test): rounds end
// with a barrier (to draw the queued big triangles), so fewer, larger
// rounds are cheaper. A round holds at most PER_ROUND * 64 triangles.
const PER_ROUND: u32 = 64u;
var<workgroup> big_count: atomic<u32>;
var<workgroup> big_list: array<u32, 64u * PER_ROUND>;
// Bit k: meshlet k of the round may draw.
var<workgroup> keep: array<atomic<u32>, 2>;

// What raster_slot drew: the tight rectangle of the drawn triangles, and
// whether the workgroup ran out of params.draw_budget (then the slot holds only
// part of the image: the consumer must still empty `rect`, and report the
// hypothesis as over budget instead of using it).
struct Drawn { rect: vec4<i32>, over: bool }

// Rasterizes hypothesis p into the slot at `base`; returns (after a barrier,
// so every invocation sees it) what was drawn.
// Meshlets are taken in rounds of PER_ROUND: each invocation tests one, then
// the workgroup steps through the kept ones, one triangle per invocation
// (meshlets hold at most WG triangles). Small triangles are drawn by the
// invocation that set them up, big ones queued and drawn cooperatively.
fn raster_slot(p: GpuPose, base: u32, lid: u32) -> Drawn {
    if (lid == 0u) {
        atomicStore(&over_budget, 0u);
        atomicStore(&drawn[0], BIG);
        atomicStore(&drawn[1], BIG);
        atomicStore(&drawn[2], -1);
        atomicStore(&drawn[3], -1);
    }
    let du = dual(p);
    let rect = screen_rect(p, du);
    let ks = key_scale(p, du);
    let first = vec2<f32>(f32(rect.x), f32(rect.y));
    let last = vec2<f32>(f32(rect.z), f32(rect.w));
    var lo_all = vec2<i32>(BIG);
    var hi_all = vec2<i32>(-1);
    var spent = 0u;
    // Camera centre in model coordinates, -A⁻¹t: back faces are culled with
    // one dot product, before any vertex is transformed.
    let cam = camera_in_model(p, du);
    for (var round = 0u; round < params.n_meshlets; round += PER_ROUND) {
        if (lid == 0u) {
            atomicStore(&big_count, 0u);
            atomicStore(&keep[0], 0u);
            atomicStore(&keep[1], 0u);
        }
        workgroupBarrier();
        let mine = round + lid;
        if (lid < PER_ROUND && mine < params.n_meshlets && meshlet_visible(meshlet(mine), p, cam, du.stretch, first, last)) {
            atomicOr(&keep[lid / 32u], 1u << (lid % 32u));
        }
        workgroupBarrier();
        let kept = vec2<u32>(atomicLoad(&keep[0]), atomicLoad(&keep[1]));
        for (var k = 0u; k < PER_ROUND; k++) {
            let m = round + k;
            if (m >= params.n_meshlets) {
                break;
            }
            if ((kept[k / 32u] & (1u << (k % 32u))) == 0u) {
                continue;
            }
            let span = meshlet_texel(m, 2u).xy; // first, count
            if (lid >= span.y) {
                continue;
            }
            let t = span.x + lid;
            let s = setup_triangle(p, t, cam, first, last);
            if (!s.ok) {
                if (s.cut) {
                    atomicStore(&over_budget, 1u);
                }
                continue;
            }
            lo_all = min(lo_all, vec2<i32>(s.lo));
            hi_all = max(hi_all, vec2<i32>(s.hi));
            let nx = u32(s.hi.x - s.lo.x) + 1u;
            let ny = u32(s.hi.y - s.lo.y) + 1u;
            if (nx * ny > BIG_PIXELS) {
                big_list[atomicAdd(&big_count, 1u)] = t;
                continue;
            }
            if (spent + nx * ny > params.draw_budget) {
                atomicStore(&over_budget, 1u);
                continue;
            }
            spent += nx * ny;
            // One loop over the bounds' pixels, row by row, rather than
            // two nested ones: on a SIMD CPU (lavapipe) the invocations of
            // a vector then run max(nx * ny) iterations, not max(ny) *
            // max(nx) (render 6 % faster on the duck). Same weights as the
            // twin: w0 + dw_dy * j + dw_dx * i.
            var i = 0u;
            var j = 0u;
            var w_row = s.w0;
            var row = base + u32(s.lo.y) * params.width + u32(s.lo.x);
            for (var q = nx * ny; q > 0u; q--) {
                let w = w_row + s.dw_dx * f32(i);
                if (min(w.x, min(w.y, w.z)) >= 0.0) {
                    atomicMax(&vis[row + i], depth_key(ks, dot(w, s.iz), t));
                }
                i += 1u;
                if (i == nx) {
                    i = 0u;
                    j += 1u;
                    w_row = s.w0 + s.dw_dy * f32(j);
                    row += params.width;
                }
            }
        }
        let n_big = workgroupUniformLoad(&big_count);
        for (var k = 0u; k < n_big; k++) {
            let tb = big_list[k];
            let s = setup_triangle(p, tb, cam, first, last);
            let nx = u32(s.hi.x - s.lo.x) + 1u;
            let n = nx * (u32(s.hi.y - s.lo.y) + 1u);
            // This invocation's share of the pixels, and the queue entry.
            let cost = n / WG + 2u;
            if (spent + cost > params.draw_budget) {
                atomicStore(&over_budget, 1u);
                break;
            }
            spent += cost;
            let bounds = vec4<i32>(vec2<i32>(s.lo), vec2<i32>(s.hi));
            for (var w = rect_walk(bounds, lid); w.j < n; walk_step(&w, bounds)) {
                shade(s, tb, w.x, w.y, base, ks);
            }
        }
    }
    if (hi_all.x >= 0) {
        atomicMin(&drawn[0], lo_all.x);
        atomicMin(&drawn[1], lo_all.y);
        atomicMax(&drawn[2], hi_all.x);
        atomicMax(&drawn[3], hi_all.y);
    }
    storageBarrier();
    workgroupBarrier();
    let tight = vec4<i32>(atomicLoad(&drawn[0]), atomicLoad(&drawn[1]), atomicLoad(&drawn[2]), atomicLoad(&drawn[3]));
    return Drawn(tight, atomicLoad(&over_budget) != 0u);
}

// Exact depth and camera-facing unit normal at pixel (x, y) from the winning
// triangle's plane; vec4(0) where nothing was drawn. The pixel centre lies
// inside the triangle, so the plane gives its depth; edge-on faces are
// clamped to the hypothesis' depth range.
fn resolve(p: GpuPose, du: Dual, key: u32, x: f32, y: f32) -> vec4<f32> {
    if (key == EMPTY) {
        return vec4<f32>(0.0);
    }
    let id_mask = (1u << params.id_bits) - 1u;
    let plane = tri_texel(key & id_mask, 3u);
    // The plane n·x = w moves to (A⁻ᵀn)·x = w + (A⁻ᵀn)·t (du = dual(p),
    // made once per hypothesis by the caller).
    let n = vec3<f32>(dot(du.q0, plane.xyz), dot(du.q1, plane.xyz), dot(du.q2, plane.xyz));
    let d = plane.w + dot(n, vec3<f32>(p.r0.w, p.r1.w, p.r2.w));
    let ray = vec3<f32>((x - params.cx) / params.fx, (y - params.cy) / params.fy, 1.0);
    let den = dot(n, ray);
    let zr = depth_range(p, du);
    var z = zr.y;
    if (abs(den) > 1e-12) {
        z = clamp(d / den, zr.x, zr.y);
    }
    var nn = n;
    if (!du.rigid) {
        nn = normalize(n);
    }
    if (den > 0.0) {
        nn = -nn;
    }
    return vec4<f32>(nn, z);
}
