// contacts: signed distance of every surface sample of every hypothesis to
// the scene (analytic planes and signed-distance grids sampled
// trilinearly), classified per eq. 6, 7 and 13 and reduced per hypothesis.
// CPU twin: contacts_cpu in src/kernels/contacts.rs (this arithmetic in
// f32); the exact f64 evaluation the verdicts are checked against is
// src/physical/contacts.rs, which also refines the flagged samples.
//
// One invocation per hypothesis (grid-stride): the invocations of a
// workgroup walk the same samples in lockstep, so sample loads and loop
// control are uniform and nothing needs a barrier or a workgroup reduction
// (on lavapipe, where a workgroup is a loop over SIMD lanes, this is several
// times faster than one workgroup per hypothesis). The supported set leaves
// the GPU as one bit per sample (the support polygon is finished on the CPU
// from those bits). Per hypothesis: |I|, |C|, |S| and min δ in a 16-byte
// record.
//
// Samples whose class the trilinear values cannot decide are flagged for
// exact refinement (a second bit set) and left out of the record: a grid
// value within the error bound of ±ε, or a grid contact whose interpolated
// normal is not clearly facing up (near edges the interpolated normal blends
// faces, so whether the point is supported is refined exactly).

const WG: u32 = 64u;
// Texels per row of the sample and node textures (kernels/contacts.rs).
const SAMPLE_ROW: u32 = 1024u;
const NODE_ROW: u32 = 4096u;

fn sample_at(j: u32) -> vec3<f32> {
    return textureLoad(samples, vec2<u32>(j % SAMPLE_ROW, j / SAMPLE_ROW), 0).xyz;
}

// Grid node values i and i + 1 (all grids' nodes one after another; each
// texel holds a node and its +x neighbour, so a cell is four fetches).
fn node_pair(i: u32) -> vec2<f32> {
    return textureLoad(dist, vec2<u32>(i % NODE_ROW, i / NODE_ROW), 0).xy;
}

// Specialised per pipeline (the dispatch code sets them), so the loops over
// the scene unroll and unused paths disappear.
override N_PLANES: u32 = 1u;
override N_GRIDS: u32 = 0u;
override WRITE_DELTAS: bool = false;
// Sizes of the per-hypothesis scene copies in private memory. Private arrays
// cannot be sized by override constants, so the dispatch code rewrites these
// two lines to the scene's counts (at least 1) before compiling: a 768-byte
// array for 16 grids would otherwise sit in every invocation's registers or
// spill to local memory on GPUs.
const PLANE_SLOTS: u32 = 4u;
const GRID_SLOTS: u32 = 16u;
// A grid contact whose normal has n·ĝ above this (more than ~8° from
// straight up) is refined exactly.
const REFINE_COS: f32 = -0.99;

struct GpuGrid {
    // World -> grid-model rows [Rᵀ | −Rᵀt] (row i of Rᵀ is column i of R).
    inv: array<vec4<f32>, 3>,
    // Node (0,0,0) (xyz) and the inverse node spacing 1/h (w).
    origin: vec4<f32>,
    // Last node (xyz) and the margin around the mesh (w).
    upper: vec4<f32>,
    // Nodes along x, y, z and the offset of node (0,0,0) in `nodes`.
    dims: vec4<u32>,
}

struct ContactParams {
    n_hyp: u32, n_samples: u32, n_planes: u32, n_grids: u32,
    eps: f32, support_cos: f32, write_deltas: u32, words: u32,
    // This dispatch classifies sample words [word_begin, word_end) and
    // continues the records of the previous one unless word_begin is 0
    // (lavapipe ends all loops of an invocation after 65,535 iterations, so
    // large sample counts against many grids take several dispatches).
    word_begin: u32, word_end: u32, pad0: u32, pad1: u32,
    // Unit gravity direction (xyz), largest grid error bound (w).
    gravity: vec4<f32>,
    // Up to 4 planes: unit normal (xyz), offset (w): δ = n·x − w.
    planes: array<vec4<f32>, 4>,
    // Up to 16 placed grids (in the uniform block: read for every sample,
    // and uniform loads are the cheapest kind on every adapter).
    grids: array<GpuGrid, 16>,
}

// Model -> world rows [R | t].
struct GpuPose { rows: array<vec4<f32>, 3> }


struct ContactRecord { intersecting: u32, contact: u32, supported: u32, min_delta: f32 }

@group(0) @binding(0) var<uniform> params: ContactParams;
// Model-frame surface samples (xyz), SAMPLE_ROW per row. Read-only tables
// are textures: on lavapipe a texel fetch is a vector gather, a
// storage-buffer load a loop over lanes (kernels/contacts.rs).
@group(0) @binding(1) var samples: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> poses: array<GpuPose>;
// Per node: signed distance (the normals stay on the CPU; the GPU takes
// them from the interpolant's gradient).
@group(0) @binding(4) var dist: texture_2d<f32>;
@group(0) @binding(5) var<storage, read_write> records: array<ContactRecord>;
@group(0) @binding(6) var<storage, read_write> support_bits: array<u32>;
@group(0) @binding(7) var<storage, read_write> deltas: array<f32>;

fn apply(r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32>, x: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(r0.xyz, x) + r0.w, dot(r1.xyz, x) + r1.w, dot(r2.xyz, x) + r2.w);
}

// The eight node values around a model-frame point of grid k (z = 0
// corners in `lo`, z = 1 corners in `hi`, each ordered 000, 100, 010, 110
// in x and y), the point's fraction in that cell, and its offset from the
// grid box (zero inside).
struct Cell { lo: vec4<f32>, hi: vec4<f32>, f: vec3<f32>, out: vec3<f32> }

fn grid_cell(k: u32, q: vec3<f32>) -> Cell {
    // Branch-free: look up at the point clamped into the box (SIMD lanes
    // stay together); callers take the lower bound for points outside.
    let o = params.grids[k].origin;
    let up = params.grids[k].upper;
    let qc = clamp(q, o.xyz, up.xyz);
    let dims = params.grids[k].dims;
    let dimf = vec3<f32>(dims.xyz);
    // Cell coordinates (o.w is 1/h); index arithmetic in f32 (exact below
    // 2^24 nodes, checked on the CPU) avoids slow vector integer multiplies.
    let u = (qc - o.xyz) * o.w;
    let cell = min(floor(u), dimf - vec3<f32>(2.0));
    let b = u32(dot(cell, vec3<f32>(1.0, dimf.x, dimf.x * dimf.y))) + dims.w;
    let iy = dims.x;
    let iz = dims.x * dims.y;
    let lo = vec4<f32>(node_pair(b), node_pair(b + iy));
    let hi = vec4<f32>(node_pair(b + iz), node_pair(b + iz + iy));
    return Cell(lo, hi, u - cell, q - qc);
}

// The trilinear δ of a cell; outside the grid box the lower bound
// |to box| + margin.
fn cell_distance(k: u32, c: Cell) -> f32 {
    let z = mix(c.lo, c.hi, c.f.z);
    let d = mix(mix(z.x, z.y, c.f.x), mix(z.z, z.w, c.f.x), c.f.y);
    return select(d, length(c.out) + params.grids[k].upper.w, any(c.out != vec3<f32>(0.0)));
}

// The gradient of the trilinear interpolant (model frame, not unit: the
// closest-surface normal direction); zero outside the grid box. Only
// samples in the contact band need it.
fn cell_gradient(c: Cell) -> vec3<f32> {
    let f = c.f;
    let dx = vec4<f32>(c.lo.y - c.lo.x, c.lo.w - c.lo.z, c.hi.y - c.hi.x, c.hi.w - c.hi.z);
    let dy = vec4<f32>(c.lo.z - c.lo.x, c.lo.w - c.lo.y, c.hi.z - c.hi.x, c.hi.w - c.hi.y);
    let dz = c.hi - c.lo;
    let gx = mix(mix(dx.x, dx.y, f.y), mix(dx.z, dx.w, f.y), f.z);
    let gy = mix(mix(dy.x, dy.y, f.x), mix(dy.z, dy.w, f.x), f.z);
    let gz = mix(mix(dz.x, dz.y, f.x), mix(dz.z, dz.w, f.x), f.y);
    return select(vec3<f32>(gx, gy, gz), vec3<f32>(0.0), any(c.out != vec3<f32>(0.0)));
}

// A model-frame gradient of grid k as a world-frame unit normal (or zero).
fn grid_normal(k: u32, gm: vec3<f32>) -> vec3<f32> {
    let len = length(gm);
    if (len <= 0.0) {
        return vec3<f32>(0.0);
    }
    let m = gm / len;
    return m.x * params.grids[k].inv[0].xyz + m.y * params.grids[k].inv[1].xyz + m.z * params.grids[k].inv[2].xyz;
}

@compute @workgroup_size(WG)
fn contacts_main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let g = params.gravity.xyz;
    let eps = params.eps;
    let bound = params.gravity.w;
    for (var h = gid.x; h < params.n_hyp; h += nwg.x * WG) {
        let p = poses[h];
        // The scene in this hypothesis' model frame, once per hypothesis, so
        // a sample needs no world position: planes as (Rᵀn, w − n·t), grids
        // as the composite model -> grid-model rows.
        var pm: array<vec4<f32>, PLANE_SLOTS>;
        for (var k = 0u; k < N_PLANES; k += 1u) {
            let pl = params.planes[k];
            let t = vec3<f32>(p.rows[0].w, p.rows[1].w, p.rows[2].w);
            pm[k] = vec4<f32>(pl.x * p.rows[0].xyz + pl.y * p.rows[1].xyz + pl.z * p.rows[2].xyz, pl.w - dot(pl.xyz, t));
        }
        var gm: array<array<vec4<f32>, 3>, GRID_SLOTS>;
        for (var k = 0u; k < N_GRIDS; k += 1u) {
            let t = vec3<f32>(p.rows[0].w, p.rows[1].w, p.rows[2].w);
            for (var i = 0u; i < 3u; i += 1u) {
                let gi = params.grids[k].inv[i];
                gm[k][i] = vec4<f32>(gi.x * p.rows[0].xyz + gi.y * p.rows[1].xyz + gi.z * p.rows[2].xyz, dot(gi.xyz, t) + gi.w);
            }
        }
        var cnt = vec3<u32>(0u);
        var mn = 3.0e38;
        if (params.word_begin > 0u) {
            let r = records[h];
            cnt = vec3<u32>(r.intersecting, r.contact, r.supported);
            mn = r.min_delta;
        }
        for (var w = params.word_begin; w < params.word_end; w += 1u) {
            var bits = 0u;
            var rbits = 0u;
            let j0 = w * 32u;
            let j1 = min(j0 + 32u, params.n_samples);
            for (var j = j0; j < j1; j += 1u) {
                let sm = sample_at(j);
                // Closest component: its δ and world unit normal (grids:
                // computed only for candidates in the contact band).
                var d = 3.0e38;
                var n = vec3<f32>(0.0);
                var refine = false;
                for (var k = 0u; k < N_PLANES; k += 1u) {
                    let dk = dot(pm[k].xyz, sm) - pm[k].w;
                    if (dk < d) {
                        d = dk;
                        n = params.planes[k].xyz;
                    }
                }
                for (var k = 0u; k < N_GRIDS; k += 1u) {
                    let q = apply(gm[k][0], gm[k][1], gm[k][2], sm);
                    let cl = grid_cell(k, q);
                    let c = cell_distance(k, cl);
                    if (abs(c) < eps + bound) {
                        // Only candidates in the contact band need a normal.
                        let nk = grid_normal(k, cell_gradient(cl));
                        if (abs(abs(c) - eps) <= bound || dot(nk, g) > REFINE_COS) {
                            refine = true;
                        }
                        if (c < d) {
                            d = c;
                            n = nk;
                        }
                    } else if (c < d) {
                        d = c;
                        n = vec3<f32>(0.0);
                    }
                }
                if (WRITE_DELTAS) {
                    deltas[h * params.n_samples + j] = d;
                }
                if (refine) {
                    rbits |= 1u << (j - j0);
                    continue;
                }
                mn = min(mn, d);
                if (d < -eps) {
                    cnt.x += 1u;
                } else if (abs(d) < eps) {
                    cnt.y += 1u;
                    if (dot(n, g) < -params.support_cos) {
                        cnt.z += 1u;
                        bits |= 1u << (j - j0);
                    }
                }
            }
            support_bits[2u * h * params.words + w] = bits;
            support_bits[(2u * h + 1u) * params.words + w] = rbits;
        }
        records[h] = ContactRecord(cnt.x, cnt.y, cnt.z, mn);
    }
}
