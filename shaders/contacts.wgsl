// contacts: signed distance of every surface sample of every hypothesis to
// the scene (analytic planes and signed-distance grids sampled
// trilinearly), classified per eq. 6, 7 and 13 and reduced per hypothesis.
// CPU twin: src/physical/contacts.rs (Environment::grid_distance is this
// arithmetic in f64; the twin also refines near ±ε exactly).
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
// Specialised per pipeline (the dispatch code sets them), so the loops over
// the scene unroll and unused paths disappear.
override N_PLANES: u32 = 1u;
override N_GRIDS: u32 = 0u;
override WRITE_DELTAS: bool = false;
// A grid contact whose normal has n·ĝ above this (more than ~8° from
// straight up) is refined exactly.
const REFINE_COS: f32 = -0.99;

struct Grid {
    // World -> grid-model rows [Rᵀ | −Rᵀt] (row i of Rᵀ is column i of R).
    inv: array<vec4<f32>, 3>,
    // Node (0,0,0) (xyz) and the inverse node spacing 1/h (w).
    origin: vec4<f32>,
    // Last node (xyz) and the margin around the mesh (w).
    upper: vec4<f32>,
    // Nodes along x, y, z and the offset of node (0,0,0) in `nodes`.
    dims: vec4<u32>,
}

struct Params {
    n_hyp: u32, n_samples: u32, n_planes: u32, n_grids: u32,
    eps: f32, support_cos: f32, write_deltas: u32, words: u32,
    // Unit gravity direction (xyz), largest grid error bound (w).
    gravity: vec4<f32>,
    // Up to 4 planes: unit normal (xyz), offset (w): δ = n·x − w.
    planes: array<vec4<f32>, 4>,
    // Up to 16 placed grids (in the uniform block: read for every sample,
    // and uniform loads are the cheapest kind on every adapter).
    grids: array<Grid, 16>,
}

// Model -> world rows [R | t].
struct Pose { rows: array<vec4<f32>, 3> }


struct Record { intersecting: u32, contact: u32, supported: u32, min_delta: f32 }

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> samples: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> poses: array<Pose>;
// Per node: signed distance (the normals stay on the CPU; the GPU takes
// them from the interpolant's gradient).
@group(0) @binding(4) var<storage, read> dist: array<f32>;
@group(0) @binding(5) var<storage, read_write> records: array<Record>;
@group(0) @binding(6) var<storage, read_write> support_bits: array<u32>;
@group(0) @binding(7) var<storage, read_write> deltas: array<f32>;

fn apply(r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32>, x: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(r0.xyz, x) + r0.w, dot(r1.xyz, x) + r1.w, dot(r2.xyz, x) + r2.w);
}

// Grid k at model-frame point q: the gradient of the trilinear interpolant
// (xyz, model frame, not unit: the closest-surface normal direction) and
// the trilinear δ (w), from the same eight loads. Outside the grid box: the
// lower bound |to box| + margin and no gradient.
fn grid_query(k: u32, q: vec3<f32>) -> vec4<f32> {
    // Branch-free: look up at the point clamped into the box (SIMD lanes
    // stay together), then take the lower bound for points outside.
    let o = params.grids[k].origin;
    let up = params.grids[k].upper;
    let qc = clamp(q, o.xyz, up.xyz);
    let out = q - qc;
    let dims = params.grids[k].dims;
    let dimf = vec3<f32>(dims.xyz);
    // Cell coordinates (o.w is 1/h); index arithmetic in f32 (exact below
    // 2^24 nodes, checked on the CPU) avoids slow vector integer multiplies.
    let u = (qc - o.xyz) * o.w;
    let cell = min(floor(u), dimf - vec3<f32>(2.0));
    let f = u - cell;
    let sy = dimf.x;
    let sz = dimf.x * dimf.y;
    let b = u32(dot(cell, vec3<f32>(1.0, sy, sz))) + dims.w;
    let iy = dims.x;
    let iz = dims.x * dims.y;
    let c000 = dist[b];
    let c100 = dist[b + 1u];
    let c010 = dist[b + iy];
    let c110 = dist[b + iy + 1u];
    let c001 = dist[b + iz];
    let c101 = dist[b + iz + 1u];
    let c011 = dist[b + iz + iy];
    let c111 = dist[b + iz + iy + 1u];
    let gx = mix(mix(c100 - c000, c110 - c010, f.y), mix(c101 - c001, c111 - c011, f.y), f.z);
    let gy = mix(mix(c010 - c000, c110 - c100, f.x), mix(c011 - c001, c111 - c101, f.x), f.z);
    let gz = mix(mix(c001 - c000, c101 - c100, f.x), mix(c011 - c010, c111 - c110, f.x), f.y);
    let d = mix(mix(mix(c000, c100, f.x), mix(c010, c110, f.x), f.y), mix(mix(c001, c101, f.x), mix(c011, c111, f.x), f.y), f.z);
    let outside = any(out != vec3<f32>(0.0));
    return select(vec4<f32>(gx, gy, gz, d), vec4<f32>(0.0, 0.0, 0.0, length(out) + up.w), outside);
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
        var pm: array<vec4<f32>, 4>;
        for (var k = 0u; k < N_PLANES; k += 1u) {
            let pl = params.planes[k];
            let t = vec3<f32>(p.rows[0].w, p.rows[1].w, p.rows[2].w);
            pm[k] = vec4<f32>(pl.x * p.rows[0].xyz + pl.y * p.rows[1].xyz + pl.z * p.rows[2].xyz, pl.w - dot(pl.xyz, t));
        }
        var gm: array<array<vec4<f32>, 3>, 16>;
        for (var k = 0u; k < N_GRIDS; k += 1u) {
            let t = vec3<f32>(p.rows[0].w, p.rows[1].w, p.rows[2].w);
            for (var i = 0u; i < 3u; i += 1u) {
                let gi = params.grids[k].inv[i];
                gm[k][i] = vec4<f32>(gi.x * p.rows[0].xyz + gi.y * p.rows[1].xyz + gi.z * p.rows[2].xyz, dot(gi.xyz, t) + gi.w);
            }
        }
        var cnt = vec3<u32>(0u);
        var mn = 3.0e38;
        for (var w = 0u; w < params.words; w += 1u) {
            var bits = 0u;
            var rbits = 0u;
            let j0 = w * 32u;
            let j1 = min(j0 + 32u, params.n_samples);
            for (var j = j0; j < j1; j += 1u) {
                let sm = samples[j].xyz;
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
                    let r = grid_query(k, q);
                    let c = r.w;
                    if (abs(c) < eps + bound) {
                        // Only candidates in the contact band need a normal.
                        let nk = grid_normal(k, r.xyz);
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
        records[h] = Record(cnt.x, cnt.y, cnt.z, mn);
    }
}
