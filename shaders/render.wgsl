// render: depth (z, metres) and camera-frame unit normal per ROI pixel for
// each hypothesis, written as vec4(normal, depth) (zero = background).
// Prefixed with raster.wgsl. CPU twin: src/kernels/raster.rs (render_cpu).

@group(0) @binding(4) var<storage, read_write> images: array<vec4<f32>>;

@compute @workgroup_size(WG)
fn render_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    // One hypothesis per workgroup and slot; a dispatch is one wave of
    // hypotheses starting at params.first.
    let h = params.first + wid.x;
    if (h >= params.n_hyp) {
        return;
    }
    let npix = params.width * params.height;
    let base = wid.x * npix;
    let p = poses[h];
    let drawn = raster_slot(p, base, lid);
    let rect = drawn.rect;
    let du = dual(p);
    for (var i = lid; i < npix; i += WG) {
        let x = i32(i % params.width);
        let y = i32(i / params.width);
        var key = EMPTY;
        if (x >= rect.x && x <= rect.z && y >= rect.y && y <= rect.w) {
            key = take_key(base + i);
        }
        var out = resolve(p, du, key, f32(x), f32(y));
        if (i == 0u && drawn.over) {
            out = vec4<f32>(-1.0); // over budget: the host renders it on the CPU
        }
        images[h * npix + i] = out;
    }
}
