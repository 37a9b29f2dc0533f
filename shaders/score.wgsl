// score: the visual-alignment score (eq. 3-5) of each hypothesis, fused with
// rendering so no image leaves the workgroup. Prefixed with raster.wgsl.
//
// Over V = {observed depth > 0} ∪ {rendered depth > 0}:
// (scene-level scoring: observed.w < 0 carries another object's depth -w
// where this object is not observed; a rendered pixel behind it is hidden,
// neither rendered nor in V)
// (only the rectangle of drawn triangles is visited: outside it nothing is
// rendered, so those pixels are in V exactly when observed, scoring 0; their
// count comes from params.n_obs, the observed pixels of the whole region)
//   a_d = 1 - min(1, |d - d̂| / tau)       (0 where only one image is valid)
//   a_n = 1 - min(1, (1 - clamp(n·n̂, 0, 1)) / alpha)   (0 where a normal is missing)
//   score = (mean a_d + mean a_n) / 2, 0 when V is empty.
// Partial sums are reduced in workgroup memory; one 32-byte record per
// hypothesis is written. CPU twin: src/kernels/score.rs (score_cpu).
//
// The a_d and a_n sums are 64-bit fixed point (each pixel's term rounded to
// a multiple of 2^-24): integer sums do not depend on the order they are
// added in, so the lanes kernel (one invocation adds every pixel of its
// hypothesis) and the workgroup kernel (a tree of partial sums) give the
// same record, and a mean over many pixels stays within 2^-25 of the
// twin's f64 sum of the same terms. An f32 running sum drifted by up to
// 2e-3 over a 350x350 region in the lanes kernel.

struct ScoreRecord {
    score: f32, mean_ad: f32, mean_an: f32, valid: u32,
    rendered: u32, observed: u32, front: u32, behind: u32,
}

// Observed normal (xyz, zero if unknown) and depth (w, zero if invalid),
// one texel per region pixel (a texel fetch is a vector gather on
// lavapipe, a storage-buffer load a loop over lanes).
@group(0) @binding(4) var observed: texture_2d<f32>;
@group(0) @binding(5) var<storage, read_write> records: array<ScoreRecord>;

// `valid` of a hypothesis the rasterizer could not draw within its budget.
const OVER_BUDGET: u32 = 0xffffffffu;

var<workgroup> s_sum: array<vec4<u32>, WG>;
var<workgroup> s_cnt: array<vec4<u32>, WG>;
var<workgroup> s_behind: array<u32, WG>;

@compute @workgroup_size(WG)
fn score_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    // One hypothesis per workgroup and slot; a dispatch is one wave of
    // hypotheses starting at params.first.
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    score_hypothesis(h, wid.x, lid);
}

// Renders hypothesis h into visibility slot `slot` and writes its record
// (the whole workgroup calls it, in uniform control flow).
fn score_hypothesis(h: u32, slot: u32, lid: u32) {
    let base = slot * params.width * params.height;
    let p = poses[h];
    let drawn = raster_slot(p, base, lid);
    reduce_slot(h, p, base, drawn.rect, drawn.over, lid);
}

// The score of a visibility slot already filled by raycast.wgsl (one
// workgroup per hypothesis of the wave, after the ray-casting dispatch):
// every pixel of the hypothesis' screen rectangle is visited.
@compute @workgroup_size(WG)
fn score_traced_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    let p = poses[h];
    reduce_slot(h, p, wid.x * params.width * params.height, screen_rect(p, dual(p)), false, lid);
}

// What the pixels of one hypothesis (or one invocation's share of them)
// add up to: depth and normal agreement sums (eq. 4, 5), pixels rendered
// where nothing is observed, pixels rendered, -, in front of the
// observation, and behind it.
struct PixelSums { ad: vec2<u32>, an: vec2<u32>, cnt: vec4<u32>, behind: u32 }

fn pixel_sums() -> PixelSums {
    return PixelSums(vec2<u32>(0u), vec2<u32>(0u), vec4<u32>(0u), 0u);
}

// Fixed-point sums (see the header): (x) the part below 1 in units of
// 2^-24, which fixed_add lets grow past 1 until fixed_carry moves the whole
// units to (y); an invocation carries at least every 255 terms.
const FIXED_ONE: f32 = 16777216.0;

// Adds term v (in [0, 1]) to the fixed-point sum s, without carrying.
// Converted through i32 (the value is at most 2^24): x86 has a vector
// conversion to signed integers only, which gallivm uses as it is, where
// one to u32 takes several more instructions.
fn fixed_add(s: vec2<u32>, v: f32) -> vec2<u32> {
    return vec2<u32>(s.x + u32(i32(v * FIXED_ONE + 0.5)), s.y);
}

// Moves the whole units of s.x to s.y.
fn fixed_carry(s: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(s.x & 0xffffffu, s.y + (s.x >> 24u));
}

// Carries the sums of `acc` (at least every 255 pixels).
fn carry_sums(acc: ptr<function, PixelSums>) {
    (*acc).ad = fixed_carry((*acc).ad);
    (*acc).an = fixed_carry((*acc).an);
}

// The sum of two carried fixed-point sums, carried.
fn fixed_sum(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return fixed_carry(a + b);
}

// A carried fixed-point sum as a number.
fn fixed_value(s: vec2<u32>) -> f32 {
    return f32(s.y) + f32(s.x) / FIXED_ONE;
}

// Adds rendered pixel (x, y) with visibility key `key` (not EMPTY) and
// observation `obs` to `acc`.
// The rendered depth and normal are resolved once, before any branch:
// gallivm (lavapipe) runs both sides of every branch, so a resolve in each
// branch cost the lanes kernel two (about 20 % of its time on the duck).
fn score_pixel(acc: ptr<function, PixelSums>, p: GpuPose, du: Dual, key: u32, obs: vec4<f32>, x: f32, y: f32) {
    let r = resolve(p, du, key, x, y);
    if (obs.w <= 0.0) {
        // Only where another object is: hidden behind it?
        if (obs.w < 0.0 && r.w > -obs.w) {
            return;
        }
        (*acc).cnt.y += 1u;
        (*acc).cnt.x += 1u;
        return;
    }
    (*acc).cnt.y += 1u;
    let diff = r.w - obs.w;
    (*acc).ad = fixed_add((*acc).ad, 1.0 - min(1.0, abs(diff) / params.tau));
    if (dot(obs.xyz, obs.xyz) > 0.0) {
        let c = clamp(dot(obs.xyz, r.xyz), 0.0, 1.0);
        (*acc).an = fixed_add((*acc).an, 1.0 - min(1.0, (1.0 - c) / params.alpha));
    }
    if (diff < -params.tau) {
        (*acc).cnt.w += 1u;
    } else if (diff > params.tau) {
        (*acc).behind += 1u;
    }
}

// The record of a hypothesis whose rendered pixels sum to `acc`; one
// drawn `over` budget is marked with valid = OVER_BUDGET for the host to
// score on the CPU.
fn score_record(acc: PixelSums, over: bool) -> ScoreRecord {
    var rec: ScoreRecord;
    rec.valid = params.n_obs + acc.cnt.x;
    rec.rendered = acc.cnt.y;
    rec.observed = params.n_obs;
    rec.front = acc.cnt.w;
    rec.behind = acc.behind;
    if (rec.valid > 0u) {
        let inv = 1.0 / f32(rec.valid);
        rec.mean_ad = fixed_value(acc.ad) * inv;
        rec.mean_an = fixed_value(acc.an) * inv;
        rec.score = 0.5 * (rec.mean_ad + rec.mean_an);
    } else {
        rec.mean_ad = 0.0;
        rec.mean_an = 0.0;
        rec.score = 0.0;
    }
    if (over) {
        rec.valid = OVER_BUDGET;
    }
    return rec;
}

// Scores hypothesis h from its slot at `base` (keys inside `rect` only),
// emptying the slot, and writes its record.
fn reduce_slot(h: u32, p: GpuPose, base: u32, rect: vec4<i32>, over: bool, lid: u32) {
    var acc = pixel_sums();
    let n = rect_pixels(rect);
    let du = dual(p);
    for (var w = rect_walk(rect, lid); w.j < n; walk_step(&w, rect)) {
        let key = take_key(base + w.y * params.width + w.x);
        if (key != EMPTY) {
            score_pixel(&acc, p, du, key, textureLoad(observed, vec2<u32>(w.x, w.y), 0), f32(w.x), f32(w.y));
            carry_sums(&acc);
        }
    }
    s_sum[lid] = vec4<u32>(acc.ad, acc.an);
    s_cnt[lid] = acc.cnt;
    s_behind[lid] = acc.behind;
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            let a = s_sum[lid];
            let b = s_sum[lid + s];
            s_sum[lid] = vec4<u32>(fixed_sum(a.xy, b.xy), fixed_sum(a.zw, b.zw));
            s_cnt[lid] += s_cnt[lid + s];
            s_behind[lid] += s_behind[lid + s];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        records[h] = score_record(PixelSums(s_sum[0].xy, s_sum[0].zw, s_cnt[0], s_behind[0]), over);
    }
}

// Rasterization alone (no scoring; the slot is emptied again), so `bench`
// can split render from reduce.
@compute @workgroup_size(WG)
fn raster_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    let base = wid.x * params.width * params.height;
    let rect = raster_slot(poses[h], base, lid).rect;
    let n = rect_pixels(rect);
    for (var w = rect_walk(rect, lid); w.j < n; walk_step(&w, rect)) {
        atomicStore(&vis[base + w.y * params.width + w.x], 0u);
    }
}
