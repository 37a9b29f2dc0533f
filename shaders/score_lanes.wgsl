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
// host, which uses this kernel only where that size is fixed and at
// least 8: lane_texel), so
// subgroupMax of the lanes' trip counts bounds each loop's iterations, and
// `spent` adds up those bounds, each loop's entry included, over every
// vector of hypotheses the workgroup draws (lanes_wave): a vector that
// would take the sum past params.draw_budget stops drawing, still empties
// what it drew, and reports its hypotheses over budget (the host draws
// them with the workgroup kernel, then the CPU twin). Never a silently
// truncated image.

// Visibility keys, one texel per pixel: slot s (hypothesis first + s of the
// wave) is the block at slot_corner(s), its pixels in tiles of 4x4
// (key_texel).
@group(0) @binding(14) var keys: texture_storage_2d<r32uint, read_write>;

// Vectors of each wave handed out so far (the host empties them before
// each chunk): workgroups take their vectors from here (lanes_wave).
@group(0) @binding(15) var<storage, read_write> handed: array<atomic<u32>>;

// Invocations per workgroup: the adapter's subgroup size (set by the host).
override LANES: u32 = 8u;

// A slot's block of texels: the region rounded up to whole 4x4 tiles, each
// tile one run of 16 texels (64 bytes, a cache line), so four tile rows
// make a texture row (the host sizes the texture the same way:
// LaneStage::new).
fn slot_size() -> vec2<u32> {
    return vec2<u32>(4u * ((params.width + 3u) & ~3u), (params.height + 3u) / 4u);
}

// Top-left texel of slot `slot`: slots side by side, as many per row of the
// texture as fit.
fn slot_corner(slot: u32) -> vec2<u32> {
    let size = slot_size();
    let cols = max(textureDimensions(keys).x / size.x, 1u);
    return vec2<u32>((slot % cols) * size.x, (slot / cols) * size.y);
}

// The texel of pixel `p` (region coordinates) in the slot at `corner`: tile
// (p.x / 4, p.y / 4) is texels 16 (p.x / 4) .. + 15 of texture row p.y / 4,
// row by row. A small triangle's pixels then share one or a few cache lines
// where rows of the region lie a texture row apart (measured +7 % on the
// duck: the texel gathers were the kernel's largest stall).
fn key_texel(corner: vec2<u32>, p: vec2<u32>) -> vec2<u32> {
    return corner + vec2<u32>(4u * (p.x & ~3u) + 4u * (p.y & 3u) + (p.x & 3u), p.y >> 2u);
}

// This invocation's lane in its subgroup (set by the entry points).
var<private> lane: u32;

// A triangle set up by one lane: its set-up, the size of its pixel bounds
// and the pixel-loop iterations it needs, four pixels each (0 where the
// lane does not draw it).
struct LaneTri { s: Setup, t: u32, nx: u32, ny: u32, trips: u32 }

// A triangle's four texels (tri_texel 0-3: vertices, plane).
struct TriTexels { v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, plane: vec4<f32> }

// Sets up triangle t from its texels where `draws` and it faces the
// camera.
fn lane_setup(p: GpuPose, t: u32, tri: TriTexels, cam: vec3<f32>, first: vec2<f32>, last: vec2<f32>, draws: bool) -> LaneTri {
    var s: Setup;
    s.ok = false;
    if (plane_faces(tri.plane, cam)) {
        s = setup_vertices(p, tri.v0, tri.v1, tri.v2, first, last);
    }
    // Cut by the near plane only where the lane draws the triangle.
    s.cut = s.cut && draws;
    if (!draws || !s.ok) {
        return LaneTri(s, t, 1u, 1u, 0u);
    }
    let nx = u32(s.hi.x - s.lo.x) + 1u;
    let ny = u32(s.hi.y - s.lo.y) + 1u;
    return LaneTri(s, t, nx, ny, (nx * ny + 3u) / 4u);
}

// Why the subgroup fetches triangle texels together: the lanes of a
// vector all set up the same triangle, but gallivm runs a texel fetch as
// one load per lane, also where every lane fetches the same texel. So
// lane j fetches texel `k(j)` of triangle `t(j)` (at most `end`) and
// subgroupBroadcast, a shuffle within the vector, hands each texel to
// every lane: one fetch for eight planes, two for a group of four
// triangles' sixteen texels, in place of a fetch per texel (measured on
// the duck, AVX2, one thread: render 155-167 -> 130-136 ms, README).
// Needs LANES >= 8 (the host: LANES_MIN).
fn lane_texel(t: u32, k: u32, end: u32) -> vec4<f32> {
    return tri_texel(min(t, end), k);
}

// The texels of the first (lanes 0-3) and second (lanes 4-7) triangle a
// lane_texel fetch of `f = lane_texel(t + lane / 4, lane % 4, end)` holds
// (subgroupBroadcast takes a constant lane).
fn first_texels(f: vec4<f32>) -> TriTexels {
    return TriTexels(subgroupBroadcast(f, 0u), subgroupBroadcast(f, 1u), subgroupBroadcast(f, 2u), subgroupBroadcast(f, 3u));
}

fn second_texels(f: vec4<f32>) -> TriTexels {
    return TriTexels(subgroupBroadcast(f, 4u), subgroupBroadcast(f, 5u), subgroupBroadcast(f, 6u), subgroupBroadcast(f, 7u));
}

// The groups of four triangles of meshlet `ml` (bit g: triangles 4g ..
// 4g + 3) that face the camera of some lane of the subgroup where `visible`.
// gallivm runs every instruction of both sides of a branch, so a lane
// cannot skip a back face; only the subgroup can, by leaving the group out
// of the drawing loop's trips. MESHLET_TRIANGLES <= 128 (host) keeps the
// bits in a u32. Eight triangles per iteration, their planes fetched
// together (lane_texel).
// `end` is the meshlet's last triangle.
fn lane_facing_groups(ml: GpuMeshlet, end: u32, cam: vec3<f32>, visible: bool) -> u32 {
    var bits = 0u;
    for (var c = 0u; c < ml.count; c += 8u) {
        let plane = lane_texel(ml.first + c + lane, 3u, end);
        var f = u32(plane_faces(subgroupBroadcast(plane, 0u), cam));
        f |= u32(plane_faces(subgroupBroadcast(plane, 1u), cam)) << 1u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 2u), cam)) << 2u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 3u), cam)) << 3u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 4u), cam)) << 4u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 5u), cam)) << 5u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 6u), cam)) << 6u;
        f |= u32(plane_faces(subgroupBroadcast(plane, 7u), cam)) << 7u;
        // Only the meshlet's own triangles.
        f &= (1u << min(ml.count - c, 8u)) - 1u;
        bits |= (u32((f & 0xfu) != 0u) | (u32(f > 0xfu) << 1u)) << (c / 4u);
    }
    return subgroupOr(select(0u, bits, visible));
}

// Triangle k (0-3) of a group of four.
fn lane_pick(a: LaneTri, b: LaneTri, c: LaneTri, d: LaneTri, k: u32) -> LaneTri {
    var r = d;
    if (k == 0u) {
        r = a;
    }
    if (k == 1u) {
        r = b;
    }
    if (k == 2u) {
        r = c;
    }
    return r;
}

// The depth test of pixel (x, y) of the triangle's bounds (`live`: the lane
// still has pixels to draw this iteration).
fn lane_plot(tri: LaneTri, ks: KeyScale, corner: vec2<u32>, x: u32, y: u32, live: bool) {
    // Summed in the twin's order (raster.rs, and shade in raster.wgsl).
    let s = tri.s;
    let w = (s.w0 + s.dw_dy * f32(y)) + s.dw_dx * f32(x);
    let inside = live && y < tri.ny && min(w.x, min(w.y, w.z)) >= 0.0;
    // Stores unconditionally (what was there where the triangle is farther
    // or misses the pixel; past the bounds' last row, a pixel of it; a lane
    // with nothing left, its slot's first texel, as its triangle's bounds
    // may lie outside the slot): gallivm branches on each lane's mask
    // around a store, and those branches mispredict (measured 1.2x
    // slower). The texel is in the lane's own slot, which no other
    // invocation touches.
    let at = select(corner, key_texel(corner, vec2<u32>(s.lo) + vec2<u32>(x, min(y, tri.ny - 1u))), live);
    let old = textureLoad(keys, at).x;
    let key = select(0u, depth_key(ks, dot(w, s.iz), tri.t), inside);
    textureStore(keys, at, vec4<u32>(max(old, key), 0u, 0u, 0u));
}

// Plots the pixel at (x, y) of the triangle's bounds and steps to the next
// one, row after row.
fn lane_step(tri: LaneTri, ks: KeyScale, corner: vec2<u32>, x: ptr<function, u32>, y: ptr<function, u32>, live: bool) {
    lane_plot(tri, ks, corner, *x, *y, live);
    *x += 1u;
    let wrap = *x == tri.nx;
    *x = select(*x, 0u, wrap);
    *y += u32(wrap);
}

// Draws four set-up triangles into the slot at `corner`, one after the
// other, four pixels of their bounds per iteration, in `trips` iterations
// (the subgroup's most). One loop for the four: a loop runs its body at
// least once whatever its trip count, and as often as its busiest lane, so
// a loop per triangle paid for triangles no lane draws and for each
// triangle's busiest lane apart (+30 % on the duck, see the README).
fn lane_draw4(a: LaneTri, b: LaneTri, c: LaneTri, d: LaneTri, trips: u32, ks: KeyScale, corner: vec2<u32>) {
    let end_a = a.trips;
    let end_b = end_a + b.trips;
    let end_c = end_b + c.trips;
    let end_d = end_c + d.trips;
    var k = 4u;
    var x = 0u;
    var y = 0u;
    for (var q = 0u; q < trips; q++) {
        // The triangle of iteration q: triangles with no trips are passed.
        let kq = u32(q >= end_a) + u32(q >= end_b) + u32(q >= end_c);
        let fresh = kq != k;
        k = kq;
        let tri = lane_pick(a, b, c, d, kq);
        x = select(x, 0u, fresh);
        y = select(y, 0u, fresh);
        let live = q < end_d;
        lane_step(tri, ks, corner, &x, &y, live);
        lane_step(tri, ks, corner, &x, &y, live);
        lane_step(tri, ks, corner, &x, &y, live);
        lane_step(tri, ks, corner, &x, &y, live);
    }
}

// What a lane drew: the tight rectangle of its drawn triangles, whether
// the vector ran out of params.draw_budget or the lane met a triangle
// crossing the near plane (both: drawn again by the host), and the loop
// iterations its workgroup has spent (or reserved) so far.
struct LaneDrawn { rect: vec4<i32>, over: bool, spent: u32 }

fn grow(lo: ptr<function, vec2<i32>>, hi: ptr<function, vec2<i32>>, tri: LaneTri) {
    if (tri.trips > 0u) {
        *lo = min(*lo, vec2<i32>(tri.s.lo));
        *hi = max(*hi, vec2<i32>(tri.s.hi));
    }
}

// Rasterizes pose p (screen rectangle `rect`) into the slot at `corner`
// (a lane that is not `live` draws nothing but takes part: the subgroup
// operations need every lane).
// `reserved` loop iterations are kept for the consumer, on top of the
// `base` the workgroup spent on earlier vectors.
//
// Per meshlet some lane sees: the groups of four triangles that face some
// lane (lane_facing_groups), then for each such group its four set-ups and
// one pixel loop as long as the busiest lane's four triangles (one
// subgroupMax per group: gallivm runs a subgroup operation as a loop over
// the lanes, and one per triangle cost 12 %).
fn lane_raster(p: GpuPose, du: Dual, rect: vec4<i32>, live: bool, corner: vec2<u32>, reserved: u32, base: u32) -> LaneDrawn {
    let ks = key_scale(p, du);
    let first = vec2<f32>(f32(rect.x), f32(rect.y));
    let last = vec2<f32>(f32(rect.z), f32(rect.w));
    let cam = camera_in_model(p, du);
    var lo_all = vec2<i32>(BIG);
    var hi_all = vec2<i32>(-1);
    // The meshlet loop, the consumer's and one for each loop's entry.
    var spent = base + params.n_meshlets + reserved + 2u;
    var over = false;
    // A triangle of this lane's crossing the near plane (Setup.cut).
    var cut = false;
    for (var m = 0u; m < params.n_meshlets; m++) {
        let ml = meshlet(m);
        let visible = live && meshlet_visible(ml, p, cam, du.stretch, first, last);
        if (!subgroupAny(visible)) {
            continue;
        }
        // The facing test's loop (a trip per eight triangles) and the
        // group loop (at most a trip per group), and their entries.
        let eights = (ml.count + 7u) / 8u;
        let groups = (ml.count + 3u) / 4u;
        if (spent + eights + groups + 2u > params.draw_budget) {
            over = true;
            break;
        }
        let end = ml.first + ml.count - 1u;
        var todo = lane_facing_groups(ml, end, cam, visible);
        spent += eights + countOneBits(todo) + 2u;
        while (todo != 0u) {
            let g = firstTrailingBit(todo);
            todo &= todo - 1u;
            let t = ml.first + 4u * g;
            let left = ml.count - 4u * g;
            // Lane j fetches texel j % 4 of triangle t + j / 4, then of
            // t + 2 + j / 4 (lane_texel).
            let ab = lane_texel(t + (lane >> 2u), lane & 3u, end);
            let cd = lane_texel(t + 2u + (lane >> 2u), lane & 3u, end);
            let a = lane_setup(p, t, first_texels(ab), cam, first, last, visible);
            let b = lane_setup(p, t + 1u, second_texels(ab), cam, first, last, visible && left > 1u);
            let c = lane_setup(p, t + 2u, first_texels(cd), cam, first, last, visible && left > 2u);
            let d = lane_setup(p, t + 3u, second_texels(cd), cam, first, last, visible && left > 3u);
            cut = cut || a.s.cut || b.s.cut || c.s.cut || d.s.cut;
            // The pixel loop and its entry.
            let most = subgroupMax(a.trips + b.trips + c.trips + d.trips);
            if (spent + most + 1u > params.draw_budget) {
                over = true;
                break;
            }
            spent += most + 1u;
            grow(&lo_all, &hi_all, a);
            grow(&lo_all, &hi_all, b);
            grow(&lo_all, &hi_all, c);
            grow(&lo_all, &hi_all, d);
            lane_draw4(a, b, c, d, most, ks, corner);
        }
        if (over) {
            break;
        }
    }
    return LaneDrawn(vec4<i32>(lo_all, hi_all), over || cut, spent);
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
    let at = key_texel(corner, vec2<u32>(x, y));
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
    var acc = pixel_sums();
    var w = LaneWalk(u32(max(rect.x, 0)), u32(max(rect.y, 0)), rect_pixels(rect));
    for (var q = 0u; q < trips; q++) {
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
        lane_take(&acc, &w, p, du, corner, rect, score);
        // TAKE terms at most since the last carry (fixed_add).
        carry_sums(&acc);
    }
    return acc;
}

// One hypothesis per invocation: draws it, then scores (or, for `bench`'s
// render timing, only empties) its slot. Returns the loop iterations the
// workgroup has spent, `base` of them before.
fn lanes(slot: u32, score: bool, base: u32) -> u32 {
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
    let drawn = lane_raster(p, du, rect, live, corner, subgroupMax(own), base);
    var tight = drawn.rect;
    if (!live || tight.z < 0) {
        tight = vec4<i32>(0, 0, -1, -1);
    }
    let trips = subgroupMax((rect_pixels(tight) + TAKE - 1u) / TAKE);
    let acc = lane_reduce(p, du, corner, tight, trips, score);
    if (live && score) {
        records[h] = score_record(acc, drawn.over);
    }
    return drawn.spent;
}

// Draws and scores vectors of the wave until none is left, each taken from
// the wave's counter. Why not one vector per workgroup: lavapipe splits a
// dispatch's workgroups among its threads in fixed shares (the first half
// to one thread, the second to the other, Mesa 22.3's lp_cs_tpool), so a
// dispatch lasted as long as its slower share: the costlier views of the
// sorted wave, or a thread sharing its core with another program. Taken
// from a counter, the work goes to whichever thread is free, as the CPU
// twin's rayon steals it (README, "Where lavapipe's time goes").
//
// All vectors share the invocation's loop cap: a workgroup takes another
// only while half the budget and twice its costliest vector so far are
// left (a vector that still runs over is drawn again by the host, as
// ever); the others then take what is left, and the host dispatches a
// workgroup per vector, so every vector is taken.
fn lanes_wave(score: bool) {
    let wave = params.first / params.slots;
    let vectors = (min(params.slots, params.n_hyp - params.first) + LANES - 1u) / LANES;
    // This loop's entry.
    var spent = 1u;
    var most = 0u;
    loop {
        var v = 0u;
        if (lane == 0u) {
            v = atomicAdd(&handed[wave], 1u);
        }
        v = subgroupBroadcast(v, 0u);
        if (v >= vectors) {
            break;
        }
        // This iteration, then the vector.
        let before = spent;
        spent = lanes(v * LANES + lane, score, spent + 1u);
        most = max(most, spent - before);
        let keep = min(max(2u * most, params.draw_budget / 2u), params.draw_budget);
        if (spent > params.draw_budget - keep) {
            break;
        }
    }
}

@compute @workgroup_size(LANES)
fn score_lanes_main(@builtin(subgroup_invocation_id) sid: u32) {
    lane = sid;
    lanes_wave(true);
}

// Rasterization alone (the slot is emptied again), so `bench` can split
// render from reduce.
@compute @workgroup_size(LANES)
fn raster_lanes_main(@builtin(subgroup_invocation_id) sid: u32) {
    lane = sid;
    lanes_wave(false);
}
