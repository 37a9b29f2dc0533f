// contacts: signed distance of every surface sample of every hypothesis to
// the scene (analytic planes and signed-distance grids sampled
// trilinearly), classified per eq. 6, 7 and 13 and reduced per hypothesis.
// CPU twin: src/physical/contacts.rs (Environment::grid_distance is this
// arithmetic in f64; the twin also refines near ±ε exactly).
//
// One workgroup per hypothesis (grid-stride over hypotheses); each
// invocation takes 32 consecutive samples, so the supported set leaves the
// GPU as one bit per sample (the support polygon is finished on the CPU from
// those bits). Per hypothesis: |I|, |C|, |S| and min δ in a 16-byte record.
//
// Samples whose class the trilinear values cannot decide are flagged for
// exact refinement (a second bit set) and left out of the record: a grid
// value within the error bound of ±ε, or a grid contact whose interpolated
// normal is not clearly facing up (near edges the interpolated normal blends
// faces, so whether the point is supported is refined exactly).

const WG: u32 = 32u;
// A grid contact whose normal has n·ĝ above this (more than ~8° from
// straight up) is refined exactly.
const REFINE_COS: f32 = -0.99;

struct Params {
    n_hyp: u32, n_samples: u32, n_planes: u32, n_grids: u32,
    eps: f32, support_cos: f32, write_deltas: u32, words: u32,
    // Unit gravity direction (xyz), largest grid error bound (w).
    gravity: vec4<f32>,
    // Up to 4 planes: unit normal (xyz), offset (w): δ = n·x − w.
    planes: array<vec4<f32>, 4>,
}

// Model -> world rows [R | t].
struct Pose { rows: array<vec4<f32>, 3> }

struct Grid {
    // World -> grid-model rows [Rᵀ | −Rᵀt] (row i of Rᵀ is column i of R).
    inv: array<vec4<f32>, 3>,
    // Node (0,0,0) (xyz) and node spacing h (w).
    origin: vec4<f32>,
    // Last node (xyz) and the margin around the mesh (w).
    upper: vec4<f32>,
    // Nodes along x, y, z and the offset of node (0,0,0) in `nodes`.
    dims: vec4<u32>,
}

struct Record { intersecting: u32, contact: u32, supported: u32, min_delta: f32 }

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> samples: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> poses: array<Pose>;
@group(0) @binding(3) var<storage, read> grids: array<Grid>;
// Per node: closest-surface normal (xyz), signed distance (w).
@group(0) @binding(4) var<storage, read> nodes: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> records: array<Record>;
@group(0) @binding(6) var<storage, read_write> support_bits: array<u32>;
@group(0) @binding(7) var<storage, read_write> deltas: array<f32>;

var<workgroup> s_cnt: array<vec4<u32>, WG>;
var<workgroup> s_min: array<f32, WG>;

fn apply(r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32>, x: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(r0.xyz, x) + r0.w, dot(r1.xyz, x) + r1.w, dot(r2.xyz, x) + r2.w);
}

// Normal (xyz, world, unit or zero) and δ (w) of grid k at world point x.
// Outside the grid box: the lower bound |to box| + margin, no normal.
fn grid_query(k: u32, x: vec3<f32>) -> vec4<f32> {
    let g = grids[k];
    let q = apply(g.inv[0], g.inv[1], g.inv[2], x);
    let out = max(max(g.origin.xyz - q, q - g.upper.xyz), vec3<f32>(0.0));
    if (any(out > vec3<f32>(0.0))) {
        return vec4<f32>(0.0, 0.0, 0.0, length(out) + g.upper.w);
    }
    let u = (q - g.origin.xyz) / g.origin.w;
    let i0 = min(vec3<u32>(floor(u)), g.dims.xyz - vec3<u32>(2u));
    let f = u - vec3<f32>(i0);
    let sy = g.dims.x;
    let sz = g.dims.x * g.dims.y;
    let b = g.dims.w + i0.x + sy * i0.y + sz * i0.z;
    let c00 = mix(nodes[b], nodes[b + 1u], f.x);
    let c10 = mix(nodes[b + sy], nodes[b + sy + 1u], f.x);
    let c01 = mix(nodes[b + sz], nodes[b + sz + 1u], f.x);
    let c11 = mix(nodes[b + sz + sy], nodes[b + sz + sy + 1u], f.x);
    let v = mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
    var nw = vec3<f32>(0.0);
    let len = length(v.xyz);
    if (len > 0.0) {
        let n = v.xyz / len;
        nw = n.x * g.inv[0].xyz + n.y * g.inv[1].xyz + n.z * g.inv[2].xyz;
    }
    return vec4<f32>(nw, v.w);
}

@compute @workgroup_size(WG)
fn contacts_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let g = params.gravity.xyz;
    let eps = params.eps;
    let bound = params.gravity.w;
    for (var h = wid.x; h < params.n_hyp; h += nwg.x) {
        let p = poses[h];
        var cnt = vec4<u32>(0u);
        var mn = 3.0e38;
        for (var w = lid; w < params.words; w += WG) {
            var bits = 0u;
            var rbits = 0u;
            let j0 = w * 32u;
            let j1 = min(j0 + 32u, params.n_samples);
            for (var j = j0; j < j1; j += 1u) {
                let x = apply(p.rows[0], p.rows[1], p.rows[2], samples[j].xyz);
                var best = vec4<f32>(0.0, 0.0, 0.0, 3.0e38);
                var refine = false;
                for (var k = 0u; k < params.n_planes; k += 1u) {
                    let pl = params.planes[k];
                    let d = dot(pl.xyz, x) - pl.w;
                    if (d < best.w) {
                        best = vec4<f32>(pl.xyz, d);
                    }
                }
                for (var k = 0u; k < params.n_grids; k += 1u) {
                    let c = grid_query(k, x);
                    if (abs(c.w) < eps + bound && (abs(abs(c.w) - eps) <= bound || dot(c.xyz, g) > REFINE_COS)) {
                        refine = true;
                    }
                    if (c.w < best.w) {
                        best = c;
                    }
                }
                let d = best.w;
                if (params.write_deltas != 0u) {
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
                    if (dot(best.xyz, g) < -params.support_cos) {
                        cnt.z += 1u;
                        bits |= 1u << (j - j0);
                    }
                }
            }
            support_bits[2u * h * params.words + w] = bits;
            support_bits[(2u * h + 1u) * params.words + w] = rbits;
        }
        s_cnt[lid] = cnt;
        s_min[lid] = mn;
        workgroupBarrier();
        for (var s = WG / 2u; s > 0u; s >>= 1u) {
            if (lid < s) {
                s_cnt[lid] += s_cnt[lid + s];
                s_min[lid] = min(s_min[lid], s_min[lid + s]);
            }
            workgroupBarrier();
        }
        if (lid == 0u) {
            records[h] = Record(s_cnt[0].x, s_cnt[0].y, s_cnt[0].z, s_min[0]);
        }
        workgroupBarrier();
    }
}
