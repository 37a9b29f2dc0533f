// score_lanes: the score kernel for software adapters (lavapipe), one
// invocation per hypothesis. Prefixed with raster.wgsl and score.wgsl; the
// same visibility keys, the same set-up, depth test and per-pixel score
// (score_pixel), so the records are those of score_main. CPU twin:
// src/kernels/score.rs (score_cpu).
//
// Why a second kernel: Mesa 22.3's gallivm runs every storage-buffer and
// workgroup-memory access of a SIMD vector as a loop over its lanes, and
// every atomic as a locked read-modify-write per lane; score_main, where a
// workgroup's invocations share one hypothesis, draws each pixel with an
// atomicMax (about 40 cycles a pixel). Here the lanes of a vector are
// different hypotheses, each alone in its slot of the `keys` storage
// texture: a pixel is a texel load (a vector gather) and a plain store;
// the triangle set-up, shared by the lanes, is one vector computation for
// all of them. Measured on the duck at 128x128 (README, "Where lavapipe's
// time goes", and the design notes).
//
// lavapipe stops a vector's loops after 65,535 iterations in total. The
// subgroup here is the vector (LANES is the subgroup size, set by the
// host, which uses this kernel only where that size is fixed), so
// subgroupMax of the lanes' trip counts bounds each loop's iterations, and
// `spent` adds up those bounds, each loop's entry included: a vector that
// would exceed params.draw_budget stops drawing, still empties what it
// drew, and reports its hypotheses over budget (the host draws them with
// the workgroup kernel, then the CPU twin). Never a silently truncated
// image.

// Visibility keys, one texel per pixel: slot s (hypothesis first + s of the
// wave) is the params.width x params.height block at slot_corner(s).
@group(0) @binding(14) var keys: texture_storage_2d<r32uint, read_write>;

// Invocations per workgroup: the adapter's subgroup size (set by the host).
override LANES: u32 = 8u;

// Top-left texel of slot `slot`: slots side by side, as many per row of the
// texture as fit.
fn slot_corner(slot: u32) -> vec2<u32> {
    let cols = max(textureDimensions(keys).x / params.width, 1u);
    return vec2<u32>((slot % cols) * params.width, (slot / cols) * params.height);
}

// The depth test of the triangle's pixel i of the row starting at texel
// `row` (i may run past the bounds' nx columns on the row's last block).
fn lane_plot(s: Setup, ks: KeyScale, t: u32, w_row: vec3<f32>, row: vec2<u32>, i: u32, nx: u32) {
    // Stores unconditionally (what was there where the triangle is farther
    // or misses the pixel; past the row's end, the row's last pixel):
    // gallivm branches on each lane's mask around a store, and those
    // branches mispredict (measured 1.2x slower). The texel is in the
    // lane's own slot, which no other invocation touches.
    let w = w_row + s.dw_dx * f32(i);
    let inside = i < nx && min(w.x, min(w.y, w.z)) >= 0.0;
    let at = vec2<u32>(row.x + min(i, nx - 1u), row.y);
    let old = textureLoad(keys, at).x;
    let key = select(0u, depth_key(ks, dot(w, s.iz), t), inside);
    textureStore(keys, at, vec4<u32>(max(old, key), 0u, 0u, 0u));
}

// A triangle set up by one lane: its set-up and the pixel-loop
// iterations it needs (0 where the lane does not draw it).
struct LaneTri { s: Setup, t: u32, nx: u32, trips: u32 }

fn lane_setup(p: GpuPose, t: u32, cam: vec3<f32>, first: vec2<f32>, last: vec2<f32>, draws: bool) -> LaneTri {
    let s = setup_triangle(p, t, cam, first, last);
    if (!draws || !s.ok) {
        return LaneTri(s, t, 0u, 0u);
    }
    let nx = u32(s.hi.x - s.lo.x) + 1u;
    let ny = u32(s.hi.y - s.lo.y) + 1u;
    return LaneTri(s, t, nx, ((nx + 3u) / 4u) * ny);
}

// Draws a set-up triangle into the slot at `corner`, four pixels of a row
// per iteration.
fn lane_draw(tri: LaneTri, ks: KeyScale, corner: vec2<u32>) {
    let s = tri.s;
    let nb = (tri.nx + 3u) / 4u;
    var b = 0u;
    var j = 0u;
    var w_row = s.w0;
    var row = corner + vec2<u32>(s.lo);
    for (var q = 0u; q < tri.trips; q++) {
        let i = b * 4u;
        lane_plot(s, ks, tri.t, w_row, row, i, tri.nx);
        lane_plot(s, ks, tri.t, w_row, row, i + 1u, tri.nx);
        lane_plot(s, ks, tri.t, w_row, row, i + 2u, tri.nx);
        lane_plot(s, ks, tri.t, w_row, row, i + 3u, tri.nx);
        b += 1u;
        if (b == nb) {
            b = 0u;
            j += 1u;
            w_row = s.w0 + s.dw_dy * f32(j);
            row.y += 1u;
        }
    }
}

// What a lane drew: the tight rectangle of its drawn triangles, and
// whether the vector ran out of params.draw_budget.
struct LaneDrawn { rect: vec4<i32>, over: bool }

fn grow(lo: ptr<function, vec2<i32>>, hi: ptr<function, vec2<i32>>, tri: LaneTri) {
    if (tri.trips > 0u) {
        *lo = min(*lo, vec2<i32>(tri.s.lo));
        *hi = max(*hi, vec2<i32>(tri.s.hi));
    }
}

// Rasterizes pose p (screen rectangle `rect`) into the slot at `corner`
// (a lane that is not `live` draws nothing but takes part: the subgroup
// operations need every lane).
// `reserved` loop iterations are kept for the consumer.
//
// Triangles go four at a time: each of their pixel loops runs as long as
// its busiest lane, at most the group's largest trip count, one
// subgroupMax for the four (gallivm runs a subgroup operation as a loop
// over the lanes: one per triangle cost 12 %).
fn lane_raster(p: GpuPose, du: Dual, rect: vec4<i32>, live: bool, corner: vec2<u32>, reserved: u32) -> LaneDrawn {
    let ks = key_scale(p, du);
    let first = vec2<f32>(f32(rect.x), f32(rect.y));
    let last = vec2<f32>(f32(rect.z), f32(rect.w));
    let cam = camera_in_model(p, du);
    var lo_all = vec2<i32>(BIG);
    var hi_all = vec2<i32>(-1);
    // The meshlet loop, the consumer's and one for each loop's entry.
    var spent = params.n_meshlets + reserved + 2u;
    var over = false;
    for (var m = 0u; m < params.n_meshlets; m++) {
        let ml = meshlet(m);
        let visible = live && meshlet_visible(ml, p, cam, du.stretch, first, last);
        if (!subgroupAny(visible)) {
            continue;
        }
        let groups = (ml.count + 3u) / 4u;
        if (spent + groups + 1u > params.draw_budget) {
            over = true;
            break;
        }
        spent += groups + 1u;
        for (var g = 0u; g < groups; g++) {
            let t = ml.first + 4u * g;
            let left = ml.count - 4u * g;
            let a = lane_setup(p, t, cam, first, last, visible);
            let b = lane_setup(p, t + 1u, cam, first, last, visible && left > 1u);
            let c = lane_setup(p, t + 2u, cam, first, last, visible && left > 2u);
            let d = lane_setup(p, t + 3u, cam, first, last, visible && left > 3u);
            // Each pixel loop and its entry.
            let most = subgroupMax(max(max(a.trips, b.trips), max(c.trips, d.trips)));
            if (spent + 4u * (most + 1u) > params.draw_budget) {
                over = true;
                break;
            }
            spent += 4u * (most + 1u);
            grow(&lo_all, &hi_all, a);
            grow(&lo_all, &hi_all, b);
            grow(&lo_all, &hi_all, c);
            grow(&lo_all, &hi_all, d);
            lane_draw(a, ks, corner);
            lane_draw(b, ks, corner);
            lane_draw(c, ks, corner);
            lane_draw(d, ks, corner);
        }
        if (over) {
            break;
        }
    }
    return LaneDrawn(vec4<i32>(lo_all, hi_all), over);
}

// A lane's walk over its rectangle: the next pixel (x, y) and how many are
// left.
struct LaneWalk { x: u32, y: u32, left: u32 }

// Scores (when `score`) and empties the next pixel of the walk over `rect`
// in the slot at `corner`, if any is left.
fn lane_take(acc: ptr<function, PixelSums>, w: ptr<function, LaneWalk>, p: GpuPose, du: Dual, corner: vec2<u32>, rect: vec4<i32>, score: bool) {
    if ((*w).left == 0u) {
        return;
    }
    let x = (*w).x;
    let y = (*w).y;
    let at = corner + vec2<u32>(x, y);
    let key = textureLoad(keys, at).x;
    // Unconditionally, as in lane_plot.
    textureStore(keys, at, vec4<u32>(0u));
    if (score && key != EMPTY) {
        score_pixel(acc, p, du, key, textureLoad(observed, vec2<u32>(x, y), 0), f32(x), f32(y));
    }
    (*w).left -= 1u;
    (*w).x += 1u;
    if ((*w).x > u32(rect.z)) {
        (*w).x = u32(rect.x);
        (*w).y += 1u;
    }
}

// Pixels per iteration of lane_reduce's loop.
const TAKE: u32 = 4u;

// Scores (when `score`) and empties the keys of `rect` in the slot at
// `corner`, TAKE pixels per iteration, in `trips` iterations (the
// subgroup's most).
fn lane_reduce(p: GpuPose, du: Dual, corner: vec2<u32>, rect: vec4<i32>, trips: u32, score: bool) -> PixelSums {
    var acc = PixelSums(vec2<f32>(0.0), vec4<u32>(0u), 0u);
    var w = LaneWalk(u32(max(rect.x, 0)), u32(max(rect.y, 0)), rect_pixels(rect));
    for (var q = 0u; q < trips; q++) {
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
    }
    return acc;
}

// One hypothesis per invocation: draws it, then scores (or, for `bench`'s
// render timing, only empties) its slot.
fn lanes(slot: u32, score: bool) {
    let h = params.first + slot;
    let live = h < params.n_hyp && slot < params.slots;
    let p = poses[min(h, params.n_hyp - 1u)];
    let du = dual(p);
    let corner = slot_corner(slot);
    let rect = screen_rect(p, du);
    // The consumer visits at most the screen rectangle.
    var own = 0u;
    if (live) {
        own = (rect_pixels(rect) + TAKE - 1u) / TAKE;
    }
    let drawn = lane_raster(p, du, rect, live, corner, subgroupMax(own));
    var tight = drawn.rect;
    if (!live || tight.z < 0) {
        tight = vec4<i32>(0, 0, -1, -1);
    }
    let trips = subgroupMax((rect_pixels(tight) + TAKE - 1u) / TAKE);
    let acc = lane_reduce(p, du, corner, tight, trips, score);
    if (live && score) {
        records[h] = score_record(acc, drawn.over);
    }
}

@compute @workgroup_size(LANES)
fn score_lanes_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    lanes(gid.x, true);
}

// Rasterization alone (the slot is emptied again), so `bench` can split
// render from reduce.
@compute @workgroup_size(LANES)
fn raster_lanes_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    lanes(gid.x, false);
}
