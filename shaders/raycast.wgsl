// raycast: the visibility buffer of each hypothesis by casting one ray per
// pixel through the mesh's compressed wide BVH (CWBVH, built by obvhs, in
// its 80-byte node layout), the alternative to raster.wgsl's rasterizer for
// meshes with many triangles per pixel: its cost grows with the pixels and
// the tree's depth, not with the triangle count. Prefixed with raster.wgsl
// (parameters, poses, triangles, the visibility slots and screen_rect).
//
// One workgroup per (8x8 tile of the region, hypothesis of the wave), one
// ray per invocation; tiles run along x and, past the adapter's workgroups
// per dimension, on along z. lavapipe ends a shader's loops after 65,535
// iterations in total per SIMD vector (a loop runs while any lane is in
// it): each node visited costs a vector at most 41 iterations (the node,
// 8 children, up to 3 triangles each, up to 8 pushes), so a ray gives up
// after MAX_NODES nodes, raising `overflow` so the host rasterizes
// instead (never a silent miss). The key written is the rasterizer's: quantized inverse
// depth over the hypothesis' range, then the triangle id, so the score
// kernel's reduction (score_traced_main) consumes it unchanged.
//
// Rays are cast in model space: from the camera centre -Rᵀt along
// Rᵀ (dx, dy, 1), so the hit distance is the camera depth. Closed meshes
// see front faces only; nothing nearer than params.near is hit.
//
// CPU twin: src/kernels/raycast.rs (cast_ids).

// CwBvhNode words: 0-2 p (f32), 3 e[0..3] | imask << 24, 4 child_base_idx,
// 5 primitive_base_idx, 6-7 child_meta[8], 8-9 child_min_x[8],
// 10-11 child_max_x, 12-13 child_min_y, 14-15 child_max_y, 16-17 child_min_z,
// 18-19 child_max_z (bytes little-endian).
// As texels: five per node (the words four by four), NODE_ROW nodes per
// row, so a node is read with five vector gathers on lavapipe instead of
// a loop over lanes per word (kernels/raycast.rs NODE_ROW).
@group(0) @binding(11) var nodes: texture_2d<u32>;
// The render mesh's triangle id of each BVH primitive.
@group(0) @binding(12) var<storage, read> prims: array<u32>;
// Set to 1 when a ray ran out of budget or stack (the host then rasterizes).
@group(0) @binding(13) var<storage, read_write> overflow: array<atomic<u32>>;

// Nodes per row of the node texture (kernels/raycast.rs NODE_ROW).
const NODE_ROW: u32 = 1024u;
const TILE: u32 = 8u;
// Nodes one ray may visit: 1,400 * 41 = 57,400 iterations.
const MAX_NODES: u32 = 1400u;
// Pending nodes: near-first depth-first order keeps at most 7 per level,
// and the host refuses trees deeper than 24 levels.
const STACK: u32 = 176u;
// Relative slack on a child box's exit distance, so rounding never prunes
// a box the hit lies on (flat boxes, rays along a face).
const BOX_SLACK: f32 = 1.0001;

// Texel k (words 4k..4k+3) of node n.
fn node_texel(n: u32, k: u32) -> vec4<u32> {
    return textureLoad(nodes, vec2<u32>((n % NODE_ROW) * 5u + k, n / NODE_ROW), 0);
}

// Byte b (0-7) of the little-endian word pair (lo, hi).
fn pair_byte(lo: u32, hi: u32, b: u32) -> u32 {
    return (select(hi, lo, b < 4u) >> ((b % 4u) * 8u)) & 0xffu;
}

// Nearest hit of the ray (o, d) with triangle t beyond near and before
// best: its distance, or best (Möller–Trumbore in obvhs's edge layout:
// e1 = v0 - v1, e2 = v2 - v0, ng = e1 x e2, front faces have det > 0).
fn hit_triangle(t: u32, o: vec3<f32>, d: vec3<f32>, best: f32) -> f32 {
    let v0 = tri_texel(t, 0u).xyz;
    let e1 = v0 - tri_texel(t, 1u).xyz;
    let e2 = tri_texel(t, 2u).xyz - v0;
    let ng = cross(e1, e2);
    let c = v0 - o;
    let r = cross(d, c);
    let det = dot(ng, d);
    if (det == 0.0 || (params.cull != 0u && det < 0.0)) {
        return best;
    }
    let inv = 1.0 / det;
    let u = dot(r, e2) * inv;
    let v = dot(r, e1) * inv;
    if (u < 0.0 || v < 0.0 || u + v > 1.0) {
        return best;
    }
    let dist = dot(ng, c) * inv;
    if (dist >= params.near && dist < best) {
        return dist;
    }
    return best;
}

// obvhs's safe reciprocal: ±1/EPSILON for components too close to zero.
fn safe_inverse(x: f32) -> f32 {
    if (abs(x) <= 1.1920929e-7) {
        return sign(x) / 1.1920929e-7;
    }
    return 1.0 / x;
}

@compute @workgroup_size(64)
fn raycast_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = params.first + wid.y;
    if (h >= params.n_hyp) {
        return;
    }
    let p = poses[h];
    let du = dual(p);
    let rect = screen_rect(p, du);
    let tiles_x = (params.width + TILE - 1u) / TILE;
    let tile = wid.x + wid.z * nwg.x;
    let x = i32((tile % tiles_x) * TILE + lid % TILE);
    let y = i32((tile / tiles_x) * TILE + lid / TILE);
    if (x < rect.x || x > rect.z || y < rect.y || y > rect.w) {
        return;
    }
    // The camera ray in model space: origin -A⁻¹t, direction A⁻¹(dx, dy, 1)
    // (A⁻¹ = Aᵀ for a rotation), so the hit's parameter is its depth.
    let o = camera_in_model(p, du);
    let dx = (f32(x) - params.cx) / params.fx;
    let dy = (f32(y) - params.cy) / params.fy;
    let d = du.q0 * dx + du.q1 * dy + du.q2;
    let inv = vec3<f32>(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    // Children are laid out so that visiting slot k ^ oct, k = 7 down to
    // 0, goes near to far for this ray's octant.
    let oct = select(0u, 4u, d.x >= 0.0) | select(0u, 2u, d.y >= 0.0) | select(0u, 1u, d.z >= 0.0);

    var stack: array<u32, STACK>;
    var sp = 1u;
    stack[0] = 0u;
    var best = 3.4e38;
    var best_id = 0xffffffffu;
    var visited = 0u;
    var failed = false;
    while (sp > 0u && !failed) {
        visited += 1u;
        if (visited > MAX_NODES) {
            failed = true;
            break;
        }
        sp -= 1u;
        let n = stack[sp];
        let n0 = node_texel(n, 0u);
        let n1 = node_texel(n, 1u);
        let nx = node_texel(n, 2u);
        let ny = node_texel(n, 3u);
        let nz = node_texel(n, 4u);
        let np = bitcast<vec3<f32>>(n0.xyz);
        let w3 = n0.w;
        let scale = vec3<f32>(bitcast<f32>((w3 & 0xffu) << 23u), bitcast<f32>(((w3 >> 8u) & 0xffu) << 23u), bitcast<f32>(((w3 >> 16u) & 0xffu) << 23u));
        let imask = w3 >> 24u;
        let child_base = n1.x;
        let prim_base = n1.y;
        // Bit k: the child in slot k ^ oct is an inner node the ray enters.
        var enter = 0u;
        for (var k = 8u; k > 0u; k--) {
            let c = (k - 1u) ^ oct;
            let info = pair_byte(n1.z, n1.w, c);
            if (info == 0u) {
                continue;
            }
            let qlo = vec3<f32>(f32(pair_byte(nx.x, nx.y, c)), f32(pair_byte(ny.x, ny.y, c)), f32(pair_byte(nz.x, nz.y, c)));
            let qhi = vec3<f32>(f32(pair_byte(nx.z, nx.w, c)), f32(pair_byte(ny.z, ny.w, c)), f32(pair_byte(nz.z, nz.w, c)));
            let t0 = (np + scale * qlo - o) * inv;
            let t1 = (np + scale * qhi - o) * inv;
            let tn = min(t0, t1);
            let tf = max(t0, t1);
            let t_in = max(max(tn.x, tn.y), max(tn.z, params.near));
            let t_out = min(min(tf.x, tf.y), min(tf.z, best)) * BOX_SLACK;
            if (t_in > t_out) {
                continue;
            }
            if ((imask & (1u << c)) != 0u) {
                enter |= 1u << (k - 1u);
                continue;
            }
            // Leaf: up to three primitives from prim_base + (info & 31).
            let first = prim_base + (info & 31u);
            let count = countOneBits(info & 0xe0u);
            for (var q = 0u; q < count; q++) {
                let id = prims[first + q];
                let hit = hit_triangle(id, o, d, best);
                if (hit < best) {
                    best = hit;
                    best_id = id;
                }
            }
        }
        // Far children first, so the nearest is popped next.
        while (enter != 0u) {
            let k = firstTrailingBit(enter);
            enter &= enter - 1u;
            let c = k ^ oct;
            if (sp == STACK) {
                failed = true;
                break;
            }
            stack[sp] = child_base + countOneBits(imask & ((1u << c) - 1u));
            sp += 1u;
        }
    }
    if (failed) {
        atomicStore(&overflow[0], 1u);
        return;
    }
    if (best_id == 0xffffffffu) {
        return;
    }
    let base = wid.y * params.width * params.height;
    atomicStore(&vis[base + u32(y) * params.width + u32(x)], depth_key(key_scale(p, du), 1.0 / best, best_id));
}
