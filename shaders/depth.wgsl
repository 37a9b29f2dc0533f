// depth: z-depth (metres, 0 = background) of each pose over a pixel tile
// chosen by the host, tiles packed one after another in one output buffer.
// Evaluation (VSD, visible fractions) reads these. Prefixed with
// raster.wgsl. CPU twin: src/kernels/depth.rs (depth_tile_cpu).
//
// Loop budget (lavapipe ends every loop of an invocation after 65,535
// iterations in total): the host only sends tiles of at most
// MAX_GPU_TILE_PIXELS (kernels/depth.rs), so the two pixel loops below
// take at most 2 * 300,000 / 64 ≈ 9,400 iterations per invocation.

// An inclusive pixel rectangle and where its depths start in `depths`.
struct Tile { x0: i32, y0: i32, x1: i32, y1: i32, offset: u32, pad0: u32, pad1: u32, pad2: u32 }

@group(0) @binding(4) var<storage, read> tiles: array<Tile>;
@group(0) @binding(5) var<storage, read_write> depths: array<f32>;

fn in_rect(r: vec4<i32>, x: i32, y: i32) -> bool {
    return x >= r.x && x <= r.z && y >= r.y && y <= r.w;
}

@compute @workgroup_size(WG)
fn depth_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    let base = wid.x * params.width * params.height;
    let p = poses[h];
    let d = raster_slot(p, base, lid);
    let drawn = d.rect;
    let tile = tiles[h];
    let t = vec4<i32>(tile.x0, tile.y0, tile.x1, tile.y1);
    let n = rect_pixels(t);
    let du = dual(p);
    for (var w = rect_walk(t, lid); w.j < n; walk_step(&w, t)) {
        var key = EMPTY;
        if (in_rect(drawn, i32(w.x), i32(w.y))) {
            key = take_key(base + w.y * params.width + w.x);
        }
        // -1 in a tile's first pixel: over budget, the host renders the
        // tile on the CPU.
        depths[tile.offset + w.j] = select(resolve(p, du, key, f32(w.x), f32(w.y)).w, -1.0, w.j == 0u && d.over);
    }
    // The host's tile and the kernel's own rectangle are the same f32
    // formula, but may round apart by a pixel: empty whatever was drawn
    // outside the tile so the slot is clean for the next wave.
    if (drawn.x < t.x || drawn.y < t.y || drawn.z > t.z || drawn.w > t.w) {
        let m = rect_pixels(drawn);
        for (var w = rect_walk(drawn, lid); w.j < m; walk_step(&w, drawn)) {
            if (!in_rect(t, i32(w.x), i32(w.y))) {
                _ = take_key(base + w.y * params.width + w.x);
            }
        }
    }
}
