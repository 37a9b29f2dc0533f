// Compute-shader rasterizer shared by the visual kernels (render, score).
//
// One workgroup owns one hypothesis at a time and a private "slot" of the
// visibility buffer (one u32 per pixel). Its invocations stride over the
// triangles; each covered pixel gets atomicMin of a key packing
// (quantized depth << id_bits) | triangle id, so the nearest triangle wins.
// Depth is quantized over the hypothesis' own depth range
// [t.z - radius, t.z + radius], so 32 - id_bits bits give sub-micrometre
// steps for typical meshes; the exact depth is recomputed afterwards from the
// winning triangle's plane (resolve), so quantization only decides ties
// closer than one step.
//
// CPU twin: src/kernels/raster.rs (render_cpu).

struct Params {
    fx: f32, fy: f32, cx: f32, cy: f32,
    width: u32, height: u32, n_hyp: u32, n_tri: u32,
    id_bits: u32, cull: u32, radius: f32, tau: f32,
    alpha: f32, near: f32, pad0: u32, pad1: u32,
}

struct Tri { v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, plane: vec4<f32> }

// Rows of [R | t], model -> camera, metres.
struct Pose { r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32> }

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> tris: array<Tri>;
@group(0) @binding(2) var<storage, read> poses: array<Pose>;
@group(0) @binding(3) var<storage, read_write> vis: array<atomic<u32>>;

const WG: u32 = 256u;
const EMPTY: u32 = 0xffffffffu;

fn rotate(p: Pose, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(p.r0.xyz, v), dot(p.r1.xyz, v), dot(p.r2.xyz, v));
}

fn transform(p: Pose, v: vec3<f32>) -> vec3<f32> {
    return rotate(p, v) + vec3<f32>(p.r0.w, p.r1.w, p.r2.w);
}

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

fn project(v: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(params.fx * v.x / v.z + params.cx, params.fy * v.y / v.z + params.cy);
}

// Depth range of the hypothesis: its bounding sphere, clipped at near.
fn depth_range(p: Pose) -> vec2<f32> {
    return vec2<f32>(max(p.r2.w - params.radius, params.near), p.r2.w + params.radius);
}

fn clear_slot(base: u32, lid: u32) {
    let npix = params.width * params.height;
    for (var i = lid; i < npix; i += WG) {
        atomicStore(&vis[base + i], EMPTY);
    }
}

fn raster_slot(p: Pose, base: u32, lid: u32) {
    let zr = depth_range(p);
    let max_code = f32((1u << (32u - params.id_bits)) - 1u);
    let zscale = max_code / max(zr.y - zr.x, 1e-9);
    let last = vec2<f32>(f32(params.width - 1u), f32(params.height - 1u));
    for (var t = lid; t < params.n_tri; t += WG) {
        let tri = tris[t];
        let a = transform(p, tri.v0.xyz);
        let b = transform(p, tri.v1.xyz);
        let c = transform(p, tri.v2.xyz);
        if (min(a.z, min(b.z, c.z)) < params.near) {
            continue;
        }
        if (params.cull != 0u && dot(rotate(p, tri.plane.xyz), a) >= 0.0) {
            continue; // back face of a closed mesh
        }
        let sa = project(a);
        let sb = project(b);
        let sc = project(c);
        let area = cross2(sb - sa, sc - sa);
        if (abs(area) < 1e-12) {
            continue;
        }
        let lo = max(ceil(min(sa, min(sb, sc))), vec2<f32>(0.0));
        let hi = min(floor(max(sa, max(sb, sc))), last);
        if (lo.x > hi.x || lo.y > hi.y) {
            continue;
        }
        let inv = 1.0 / area;
        let iz = vec3<f32>(1.0 / a.z, 1.0 / b.z, 1.0 / c.z);
        // Barycentric weights are affine in the pixel position: step them.
        let dw_dx = vec3<f32>(sb.y - sc.y, sc.y - sa.y, sa.y - sb.y) * inv;
        let dw_dy = vec3<f32>(sc.x - sb.x, sa.x - sc.x, sb.x - sa.x) * inv;
        let q0 = lo;
        let w_row0 = vec3<f32>(cross2(sc - sb, q0 - sb), cross2(sa - sc, q0 - sc), cross2(sb - sa, q0 - sa)) * inv;
        let nx = u32(hi.x - lo.x) + 1u;
        let ny = u32(hi.y - lo.y) + 1u;
        let x0 = u32(lo.x);
        let y0 = u32(lo.y);
        for (var j = 0u; j < ny; j++) {
            let w_row = w_row0 + dw_dy * f32(j);
            let row = base + (y0 + j) * params.width + x0;
            for (var i = 0u; i < nx; i++) {
                let w = w_row + dw_dx * f32(i);
                if (min(w.x, min(w.y, w.z)) < 0.0) {
                    continue;
                }
                let z = 1.0 / dot(w, iz);
                let code = u32(clamp((z - zr.x) * zscale, 0.0, max_code));
                atomicMin(&vis[row + i], (code << params.id_bits) | t);
            }
        }
    }
}

// Exact depth and camera-facing unit normal at pixel (x, y) from the winning
// triangle's plane; vec4(0) where nothing was drawn.
fn resolve(p: Pose, key: u32, x: f32, y: f32) -> vec4<f32> {
    if (key == EMPTY) {
        return vec4<f32>(0.0);
    }
    let id_mask = (1u << params.id_bits) - 1u;
    let tri = tris[key & id_mask];
    let n = rotate(p, tri.plane.xyz);
    let d = tri.plane.w + dot(n, vec3<f32>(p.r0.w, p.r1.w, p.r2.w));
    let ray = vec3<f32>((x - params.cx) / params.fx, (y - params.cy) / params.fy, 1.0);
    let den = dot(n, ray);
    // Clamp to the triangle's own depth span (grazing planes are ill-conditioned).
    let za = dot(p.r2.xyz, tri.v0.xyz) + p.r2.w;
    let zb = dot(p.r2.xyz, tri.v1.xyz) + p.r2.w;
    let zc = dot(p.r2.xyz, tri.v2.xyz) + p.r2.w;
    let zlo = min(za, min(zb, zc));
    let zhi = max(za, max(zb, zc));
    var z = 0.5 * (zlo + zhi);
    if (abs(den) > 1e-12) {
        z = clamp(d / den, zlo, zhi);
    }
    var nn = n;
    if (den > 0.0) {
        nn = -n;
    }
    return vec4<f32>(nn, z);
}
