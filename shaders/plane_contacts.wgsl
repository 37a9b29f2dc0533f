// plane_contacts: the physical terms of one hypothesis against a support
// plane (eq. 6, 7, 13), fused into the score kernel so that the visual score
// and the physical terms of every hypothesis come out of one dispatch.
// Prefixed with raster.wgsl and score.wgsl.
//
// The plane is given in the camera frame (unit normal n towards the camera,
// offset w: δ = n·x − w) and moved into the model frame once per
// hypothesis: δ(s) = (Rᵀn)·s − (w − n·t), one dot product per surface sample
// s. A support plane's normal opposes gravity by construction, so every
// contact sample is supported. The supported set leaves the GPU as one bit
// per sample (the support polygon and the stability margin are finished on
// the CPU from those bits, as for the contacts kernel).
//
// CPU twin: src/physical/contacts.rs (evaluate_batch against one plane,
// in f64); src/physical/batch.rs drives both.

struct PlaneParams {
    // Unit normal (xyz) and offset (w) of the plane, camera frame, metres.
    plane: vec4<f32>,
    n_samples: u32, words: u32, eps: f32, pad: u32,
}

struct ContactRecord { intersecting: u32, contact: u32, supported: u32, min_delta: f32 }

@group(0) @binding(6) var<uniform> plane_params: PlaneParams;
// Model-frame surface samples (xyz), PLANE_SAMPLE_ROW per row (a texture:
// a vector gather on lavapipe, see raster.wgsl's tables).
@group(0) @binding(7) var samples: texture_2d<f32>;
const PLANE_SAMPLE_ROW: u32 = 1024u;
@group(0) @binding(8) var<storage, read_write> contact_records: array<ContactRecord>;
// `words` u32 per hypothesis: bit j % 32 of word j / 32 = sample j supported.
@group(0) @binding(9) var<storage, read_write> support_bits: array<u32>;

var<workgroup> s_pcnt: array<vec2<u32>, WG>;
var<workgroup> s_pmin: array<f32, WG>;

// Visual score and physical terms of hypothesis h in one pass.
@compute @workgroup_size(WG)
fn score_physics_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    score_hypothesis(h, wid.x, lid);
    plane_contacts(h, lid);
}

fn plane_contacts(h: u32, lid: u32) {
    let p = poses[h];
    let n = plane_params.plane.xyz;
    let eps = plane_params.eps;
    // The plane in the model frame.
    let nm = n.x * p.r0.xyz + n.y * p.r1.xyz + n.z * p.r2.xyz;
    let wm = plane_params.plane.w - dot(n, vec3<f32>(p.r0.w, p.r1.w, p.r2.w));
    // Each invocation owns whole 32-sample words, so it writes its bits
    // without atomics.
    var cnt = vec2<u32>(0u); // intersecting, contact
    var mn = 3.0e38;
    for (var w = lid; w < plane_params.words; w += WG) {
        let j0 = w * 32u;
        let j1 = min(j0 + 32u, plane_params.n_samples);
        var bits = 0u;
        for (var j = j0; j < j1; j += 1u) {
            let d = dot(nm, textureLoad(samples, vec2<u32>(j % PLANE_SAMPLE_ROW, j / PLANE_SAMPLE_ROW), 0).xyz) - wm;
            mn = min(mn, d);
            if (d < -eps) {
                cnt.x += 1u;
            } else if (abs(d) < eps) {
                cnt.y += 1u;
                bits |= 1u << (j - j0);
            }
        }
        support_bits[h * plane_params.words + w] = bits;
    }
    s_pcnt[lid] = cnt;
    s_pmin[lid] = mn;
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            s_pcnt[lid] += s_pcnt[lid + s];
            s_pmin[lid] = min(s_pmin[lid], s_pmin[lid + s]);
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        let c = s_pcnt[0];
        contact_records[h] = ContactRecord(c.x, c.y, c.y, s_pmin[0]);
    }
}
