//! Visual plausibility: GPU kernels against their CPU twins, and both against
//! analytic ground truth. GPU tests skip (with a message) when no adapter
//! exists, and fail instead when PLAUSIBLE_REQUIRE_GPU=1.

use glam::{DVec3, Vec3};
use plausible::camera::Intrinsics;
use plausible::gpu::{test_context, BatchLimits, Context, Device, GpuOptions};
use plausible::hypotheses::around_and_random;
use plausible::kernels::raster::{render_cpu, render_gpu, RenderImage};
use plausible::kernels::score::{score_cpu, score_image, GpuScorer, ScoreKernel, ScoreParams, ScoreRecord};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::pose::{axis_angle, Pose};
use plausible::shapes;
use plausible::synth::{linemod_camera, observe, SensorNoise};
use plausible::visual::{ranks, Scorer};

fn duck() -> Mesh {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    Mesh::load(path, MeshUnits::Metres).unwrap().0.normalized(0.15)
}

fn true_pose() -> Pose {
    Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7))
}

/// The demo's setting: duck at 0.7 m, noisy observation, 128x128 ROI.
fn demo_target(mesh: &RenderMesh, noise: SensorNoise) -> ScoreTarget {
    let (obs, mask) = observe(mesh, &true_pose(), &linemod_camera(), noise, 7);
    ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap()
}

/// Compares two renderings: depth within 1e-4 m where both cover a pixel
/// away from the silhouette; coverage may differ on at most 1 % of pixels
/// (silhouette edges, ties between coplanar triangles).
fn assert_renders_match(a: &RenderImage, b: &RenderImage) {
    let n = a.depth.len();
    let w = a.width as usize;
    let covered = |img: &RenderImage, i: usize| img.depth[i] > 0.0;
    let mut coverage_diff = 0;
    let mut covered_px = 0;
    for i in 0..n {
        if covered(a, i) != covered(b, i) {
            coverage_diff += 1;
            continue;
        }
        if !covered(a, i) {
            continue;
        }
        covered_px += 1;
        let (x, y) = (i % w, i / w);
        let interior = x > 0 && y > 0 && x + 1 < w && y + 1 < a.height as usize
            && [i - 1, i + 1, i - w, i + w].iter().all(|&j| covered(a, j) && covered(b, j));
        if interior {
            assert!((a.depth[i] - b.depth[i]).abs() < 1e-4, "pixel {i}: {} vs {}", a.depth[i], b.depth[i]);
        }
    }
    assert!(covered_px > 0);
    assert!(coverage_diff as f64 <= 0.01 * covered_px as f64, "{coverage_diff} of {covered_px} pixels differ in coverage");
}

#[test]
fn render_gpu_matches_cpu_twin() {
    let ctx = test_context();
    let mesh = RenderMesh::new(&duck()).unwrap();
    let k = linemod_camera().crop(220.0, 140.0, 200.0, 200.0, 128, 128);
    let poses = around_and_random(&true_pose(), 24, 3);
    let gpu = render_gpu(&ctx, &mesh, &poses, &k).unwrap();
    for (p, g) in poses.iter().zip(&gpu) {
        let c = render_cpu(&mesh, p, &k);
        assert_renders_match(&c, g);
        // Normals of commonly covered pixels agree.
        for i in 0..c.depth.len() {
            if c.depth[i] > 0.0 && g.depth[i] > 0.0 && (c.depth[i] - g.depth[i]).abs() < 1e-5 {
                assert!(c.normals[i].dot(g.normals[i]) > 0.999);
            }
        }
    }
}

#[test]
fn score_gpu_matches_cpu_twin() {
    let ctx = test_context();
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let poses = around_and_random(&true_pose(), 256, 11);
    let params = ScoreParams::default();
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    let (gpu, _) = GpuScorer::new(&ctx, &mesh, &target, params, poses.len()).unwrap().score(&poses).unwrap();
    for (i, (c, g)) in cpu.iter().zip(&gpu).enumerate() {
        assert!((c.score - g.score).abs() < 1e-3, "hypothesis {i}: cpu {c:?} gpu {g:?}");
        assert!((c.mean_ad - g.mean_ad).abs() < 1e-3 && (c.mean_an - g.mean_an).abs() < 1e-3);
        assert_eq!(c.observed, g.observed);
    }
}

/// A scorer made while its kernel compiles on another thread
/// (`Scorer::precompile`), here by three threads at once, waits for that
/// compile and scores exactly as one on a fresh device.
#[test]
fn gpu_scorers_made_during_a_precompile_score_as_a_fresh_one() {
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let poses = around_and_random(&true_pose(), 40, 5);
    let params = ScoreParams::default();
    let score = |device: &Device| Scorer::new(device, &mesh, &target, params, poses.len()).unwrap().score(&poses, &mut |_| {}).unwrap().0;
    let fresh = score(&Device::Gpu(Box::new(test_context())));
    let device = Device::Gpu(Box::new(test_context()));
    let _compiling = Scorer::precompile(&device);
    let racing: Vec<Vec<ScoreRecord>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..3).map(|_| s.spawn(|| score(&device))).collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for records in racing {
        assert_eq!(records, fresh);
    }
}

/// Whether GPU pixels must be the twin's exactly. A software adapter
/// (lavapipe) runs the kernels' f32 arithmetic as written, so it draws the
/// twin's pixels and depths bit for bit. A hardware GPU may fuse `a * b + c`
/// into one rounding (WGSL allows it, and the SPIR-V that naga writes has no
/// `NoContraction`), which moves pixel centres lying within rounding of an
/// edge to the other side and depths by a few ulps: on an NVIDIA H200, 6 of
/// 3,234 pixels of the big-triangle test, and depths one ulp apart in the
/// loop-budget test. There the tests hold the GPU to
/// [`assert_renders_match`]'s tolerance instead (1 % of the covered pixels,
/// 0.1 mm).
fn exact_twin(ctx: &Context) -> bool {
    ctx.is_software()
}

/// Whether the adapter runs the lanes score kernel (subgroups of one fixed
/// size: lavapipe's are its SIMD vector). Where it cannot, says so.
fn lanes_available(ctx: &Context) -> bool {
    let ok = ctx.subgroup_lanes.is_some_and(|l| l >= 8);
    if !ok {
        eprintln!("SKIPPED (lanes kernel): {} has no subgroups of one fixed size of 8 lanes or more", ctx.describe());
        assert!(!ctx.is_software() || std::env::var("PLAUSIBLE_REQUIRE_GPU").as_deref() != Ok("1"), "lavapipe must run the lanes kernel");
    }
    ok
}

/// The lanes kernel's records against the workgroup kernel's and the
/// twin's scores, each failure naming `what` and the hypothesis. The two
/// kernels draw the same keys and sum in fixed point (score.wgsl), which
/// no order of addition changes: equal counts, and equal means where the
/// adapter computes each pixel's term alike in both (lavapipe; a hardware
/// compiler may round a term apart by an ulp, 1e-6 then).
fn assert_kernels_agree(ctx: &Context, what: &str, lanes: &[ScoreRecord], groups: &[ScoreRecord], cpu: &[ScoreRecord]) {
    let tol = if exact_twin(ctx) { 0.0 } else { 1e-6 };
    for (i, ((l, g), c)) in lanes.iter().zip(groups).zip(cpu).enumerate() {
        let counts = |r: &ScoreRecord| (r.valid, r.rendered, r.observed, r.front, r.behind);
        assert_eq!(counts(l), counts(g), "{what}hypothesis {i}: lanes {l:?} workgroups {g:?}");
        for (a, b) in [(l.score, g.score), (l.mean_ad, g.mean_ad), (l.mean_an, g.mean_an)] {
            assert!((a - b).abs() <= tol, "{what}hypothesis {i}: lanes {l:?} workgroups {g:?}");
        }
        assert!((l.score - c.score).abs() < 1e-3, "{what}hypothesis {i}: lanes {l:?} cpu {c:?}");
    }
}

/// A GPU kernel's records against the twin's on the same poses: on an exact
/// twin (lavapipe) equal counts and scores within 1e-5; on hardware counts
/// within 1 % of the rendered pixels (and at least `slack`) and scores
/// within 1e-3. Failures name `what` and the pose.
fn assert_matches_twin(ctx: &Context, what: &str, gpu: &[ScoreRecord], cpu: &[ScoreRecord], slack: f64) {
    assert_eq!(gpu.len(), cpu.len(), "{what}");
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let what = format!("{what}pose {i}: gpu {g:?} cpu {c:?}");
        let counts = |r: &ScoreRecord| [r.valid, r.rendered, r.front, r.behind];
        if exact_twin(ctx) {
            assert_eq!(counts(g), counts(c), "{what}");
            assert!((g.score - c.score).abs() < 1e-5, "{what}");
        } else {
            // Hardware: at most 1 % of the rendered pixels move.
            for (a, b) in counts(g).into_iter().zip(counts(c)) {
                assert!(a.abs_diff(b) as f64 <= (0.01 * c.rendered as f64).max(slack), "{what}");
            }
            assert!((g.score - c.score).abs() < 1e-3, "{what}");
        }
    }
}

/// `poses` scored by each score kernel the adapter runs: the workgroup
/// kernel, then the lanes kernel where it is available.
fn score_with_each_kernel(ctx: &Context, mesh: &RenderMesh, target: &ScoreTarget, params: ScoreParams, poses: &[Pose]) -> Vec<(ScoreKernel, Vec<ScoreRecord>)> {
    let mut out = Vec::new();
    for kernel in [ScoreKernel::Workgroups, ScoreKernel::Lanes] {
        if kernel == ScoreKernel::Lanes && !lanes_available(ctx) {
            continue;
        }
        let mut scorer = GpuScorer::new(ctx, mesh, target, params, poses.len()).unwrap();
        scorer.set_kernel(kernel).unwrap();
        out.push((kernel, scorer.score(poses).unwrap().0));
    }
    out
}

/// The two score kernels draw the same visibility keys, so their records
/// agree: the counts exactly, and the means too, though the workgroup
/// kernel adds in a tree and the lanes kernel pixel by pixel (fixed-point
/// sums, see assert_kernels_agree).
/// Over several waves with a part-filled last vector, sheared poses, poses
/// crossing the near plane, behind the camera or off the image, and other
/// objects' depth in front; and both agree with the twin.
#[test]
fn gpu_lanes_and_workgroup_score_kernels_agree() {
    let ctx = test_context();
    if !lanes_available(&ctx) {
        return;
    }
    let mesh = RenderMesh::new(&duck()).unwrap();
    let truth = true_pose();
    let mut poses = around_and_random(&truth, 613, 21);
    let shear = glam::DMat3::from_cols(DVec3::new(1.02, 0.0, 0.0), DVec3::new(0.04, 1.0, 0.0), DVec3::new(0.0, -0.03, 0.97));
    poses.extend(around_and_random(&truth, 40, 22).iter().map(|p| Pose::new(p.r * shear, p.t)));
    for z in [0.05, 0.0, -0.3, 0.001] {
        poses.push(Pose::new(truth.r, DVec3::new(truth.t.x, truth.t.y, z)));
    }
    poses.push(Pose::new(truth.r, truth.t + DVec3::new(3.0, 0.0, 0.0)));
    let plain = demo_target(&mesh, SensorNoise::default());
    let mut occluded = plain.clone();
    let wall = RenderMesh::new(&shapes::cuboid(DVec3::new(0.03, 0.2, 0.01))).unwrap();
    occluded.set_occluders(render_cpu(&wall, &Pose::new(glam::DMat3::IDENTITY, DVec3::new(0.03, -0.01, 0.6)), &occluded.intrinsics).depth).unwrap();
    let params = ScoreParams::default();
    for target in [&plain, &occluded] {
        let mut scorer = GpuScorer::new(&ctx, &mesh, target, params, 256).unwrap();
        let mut run = |kernel| {
            scorer.set_kernel(kernel).unwrap();
            assert_eq!(scorer.kernel(), kernel);
            scorer.score(&poses).unwrap().0
        };
        let (lanes, groups) = (run(ScoreKernel::Lanes), run(ScoreKernel::Workgroups));
        let cpu = score_cpu(&mesh, target, &poses, &params);
        assert!(lanes.iter().filter(|r| r.rendered > 0).count() > 400);
        assert_kernels_agree(&ctx, "", &lanes, &groups, &cpu);
        // Chunks of 100 (waves that end mid-vector, view order per chunk),
        // one hypothesis, nine: the same records in input order.
        let mut small = GpuScorer::with_max_chunk(&ctx, &mesh, target, params, 100, 100).unwrap();
        small.set_kernel(ScoreKernel::Lanes).unwrap();
        assert_eq!(small.score(&poses).unwrap().0, lanes);
        for n in [1, 9] {
            let mut few = GpuScorer::new(&ctx, &mesh, target, params, n).unwrap();
            few.set_kernel(ScoreKernel::Lanes).unwrap();
            assert_eq!(few.score(&poses[..n]).unwrap().0, lanes[..n]);
        }
    }
}

/// The lanes kernel keeps a slot's keys in 4x4 tiles (`key_texel` in
/// score_lanes.wgsl), so regions whose sides are not multiples of 4 end in
/// part-filled tiles: on such regions, tiny to wide, it draws the same keys
/// as the workgroup kernel and the twin, also for a pose shifted
/// sideways.
#[test]
fn gpu_lanes_kernel_agrees_on_regions_of_any_size() {
    let ctx = test_context();
    if !lanes_available(&ctx) {
        return;
    }
    let mesh = RenderMesh::new(&duck()).unwrap();
    for (width, height) in [(5, 3), (37, 23), (61, 130), (130, 71), (250, 9)] {
        let f = 2.2 * width.max(height) as f64;
        let k = Intrinsics { fx: f, fy: f, cx: (width as f64 - 1.0) / 2.0, cy: (height as f64 - 1.0) / 2.0, width, height };
        let seen = Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.004, -0.003, 0.5));
        let mut poses = around_and_random(&seen, 60, 31);
        poses.push(Pose::new(seen.r, seen.t + DVec3::new(0.05, 0.0, 0.0)));
        assert_kernels_agree_seen(&ctx, &format!("{width}x{height} "), &mesh, &k, &seen, &poses);
    }
}

/// Both GPU kernels and the twin on `poses` against a synthetic view of
/// `mesh` at `seen` (camera `k`): their records agree
/// ([`assert_kernels_agree`]) and more than 20 hypotheses render.
fn assert_kernels_agree_seen(ctx: &Context, what: &str, mesh: &RenderMesh, k: &Intrinsics, seen: &Pose, poses: &[Pose]) {
    let params = ScoreParams::default();
    let (obs, mask) = observe(mesh, seen, k, SensorNoise::default(), 9);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::FullFrame, DEFAULT_ROI_MARGIN).unwrap();
    let mut scorer = GpuScorer::new(ctx, mesh, &target, params, poses.len()).unwrap();
    scorer.set_kernel(ScoreKernel::Lanes).unwrap();
    let lanes = scorer.score(poses).unwrap().0;
    scorer.set_kernel(ScoreKernel::Workgroups).unwrap();
    let groups = scorer.score(poses).unwrap().0;
    let cpu = score_cpu(mesh, &target, poses, &params);
    assert!(lanes.iter().filter(|r| r.rendered > 0).count() > 20, "{what}");
    assert_kernels_agree(ctx, what, &lanes, &groups, &cpu);
}

/// The lanes kernel fetches triangle texels for the whole subgroup at once,
/// eight planes or two triangles' texels per fetch, clamped to the
/// meshlet's last triangle (`lane_texel` in score_lanes.wgsl): on meshes
/// with fewer triangles than lanes, meshlets whose counts are not
/// multiples of 8 or 4, and an open mesh (no back faces culled), it draws
/// the workgroup kernel's and the twin's pixels.
#[test]
fn gpu_lanes_kernel_agrees_on_small_odd_and_open_meshes() {
    let ctx = test_context();
    if !lanes_available(&ctx) {
        return;
    }
    let corners = vec![DVec3::new(0.04, 0.0, 0.0), DVec3::new(-0.03, 0.03, 0.0), DVec3::new(-0.02, -0.03, 0.01), DVec3::new(0.0, 0.0, 0.05)];
    let (tetra, _) = Mesh::from_raw("tetrahedron", corners, vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]).unwrap();
    let meshes = [
        ("tetrahedron", tetra),
        ("cuboid", shapes::cuboid(DVec3::new(0.04, 0.03, 0.02))),
        ("7-sided cylinder", shapes::cylinder(0.03, 0.05, 7)),
        ("icosphere", shapes::icosphere(0.04, 1)),
        ("open box", open_box()),
    ];
    let k = Intrinsics { fx: 200.0, fy: 200.0, cx: 31.5, cy: 31.5, width: 64, height: 64 };
    let seen = Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.004, -0.003, 0.3));
    let poses = around_and_random(&seen, 61, 33);
    for (name, mesh) in meshes {
        assert_kernels_agree_seen(&ctx, &format!("{name}: "), &RenderMesh::new(&mesh).unwrap(), &k, &seen, &poses);
    }
}

/// Triangles of more than 256 pixels are filled by the workgroup kernel's
/// whole workgroup (`shade` in raster.wgsl), which summed the barycentric
/// weights in another order than the twin and the lanes kernel: on this
/// pose pixel centres lie exactly on the cylinder's edges, and 2 pixels
/// fell on the other side (found by helper-34). Every kernel now draws
/// the twin's pixels.
#[test]
fn gpu_big_triangles_draw_the_twins_pixels_with_either_kernel() {
    let ctx = test_context();
    let mesh = RenderMesh::new(&shapes::cylinder(0.06, 0.1, 16)).unwrap();
    let k = Intrinsics { fx: 90.0, fy: 90.0, cx: 31.5, cy: 31.5, width: 64, height: 64 };
    let seen = Pose::new(axis_angle(DVec3::new(0.2, 1.0, 0.4), 0.7), DVec3::new(0.005, -0.004, 0.2));
    let (obs, mask) = observe(&mesh, &seen, &k, SensorNoise::default(), 5);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::FullFrame, DEFAULT_ROI_MARGIN).unwrap();
    let poses = [Pose::new(glam::DMat3::IDENTITY, DVec3::new(0.0, 0.0, 0.21556337721897109)), seen];
    let params = ScoreParams::default();
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    for (kernel, gpu) in score_with_each_kernel(&ctx, &mesh, &target, params, &poses) {
        assert_matches_twin(&ctx, &format!("{kernel:?} "), &gpu, &cpu, 0.0);
    }
    let img = render_gpu(&ctx, &mesh, &poses, &target.intrinsics).unwrap();
    for (p, g) in poses.iter().zip(&img) {
        let c = render_cpu(&mesh, p, &target.intrinsics);
        match exact_twin(&ctx) {
            true => assert_eq!(g.depth.iter().filter(|d| **d > 0.0).count(), c.depth.iter().filter(|d| **d > 0.0).count()),
            false => assert_renders_match(&c, g),
        }
    }
}

#[test]
fn gpu_sheared_poses_score_as_the_deformed_mesh() {
    // A pose whose linear part A = R·M is not a rotation (a scaled or
    // sheared matrix, as results files may hold) scores as the mesh
    // deformed by M at R, on the rasterizer and the ray caster, GPU and
    // CPU alike: normals and rays go through A⁻ᵀ and A⁻¹ (kernels/mod.rs
    // Dual), the bounding sphere grows with A's stretch.
    let ctx = test_context();
    let raw = duck();
    let mesh = RenderMesh::new(&raw).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let params = ScoreParams::default();
    let truth = true_pose();
    let shears = [
        glam::DMat3::from_diagonal(DVec3::splat(1.03)),
        glam::DMat3::from_cols(DVec3::X, DVec3::new(0.04, 1.0, 0.0), DVec3::new(0.0, -0.03, 1.0)),
        // Not a rotation, yet its stretch bound is exactly 1: the normals
        // are normalized all the same.
        glam::DMat3::from_diagonal(DVec3::new(1.0, 0.98, 0.98)),
        glam::DMat3::from_diagonal(DVec3::splat(0.97)),
    ];
    for renderer in [plausible::kernels::RendererChoice::Raster, plausible::kernels::RendererChoice::RayCast] {
        for m in shears {
            let mut sheared = mesh.clone();
            sheared.renderer = renderer;
            let mut deformed = RenderMesh::new(&Mesh { vertices: raw.vertices.iter().map(|v| m * *v).collect(), ..raw.clone() }).unwrap();
            deformed.renderer = renderer;
            let poses: Vec<Pose> = around_and_random(&truth, 24, 3).iter().map(|p| Pose::new(p.r * m, p.t)).collect();
            let rigid: Vec<Pose> = around_and_random(&truth, 24, 3);
            let want = score_cpu(&deformed, &target, &rigid, &params);
            let cpu = score_cpu(&sheared, &target, &poses, &params);
            let (gpu, _) = GpuScorer::new(&ctx, &sheared, &target, params, poses.len()).unwrap().score(&poses).unwrap();
            for (i, ((w, c), g)) in want.iter().zip(&cpu).zip(&gpu).enumerate() {
                for (what, x) in [("cpu", c), ("gpu", g)] {
                    assert!(
                        (w.score - x.score).abs() < 2e-3 && (w.mean_ad - x.mean_ad).abs() < 2e-3 && (w.mean_an - x.mean_an).abs() < 2e-3,
                        "{renderer:?} {m} hypothesis {i}: {what} {x:?}, deformed mesh {w:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn gpu_forced_small_limits_split_batches_with_same_results() {
    let ctx = test_context();
    // 16 KiB bindings: 341 poses per chunk, 4 visibility slots of a 32x32
    // region, capped at 3 workgroups.
    let small = Context::new(&GpuOptions {
        adapter: None,
        limits: Some(BatchLimits { max_storage_binding: 16 << 10, max_buffer: 1 << 30, max_workgroups: 3 }),
    })
    .unwrap();
    let mesh = RenderMesh::new(&shapes::cuboid(DVec3::new(0.03, 0.04, 0.05))).unwrap();
    let truth = Pose::new(axis_angle(DVec3::new(1.0, 1.0, 0.0), 0.5), DVec3::new(0.0, 0.0, 0.5));
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 160.0, cy: 120.0, width: 320, height: 240 };
    let (obs, mask) = observe(&mesh, &truth, &k, SensorNoise::default(), 3);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(32), DEFAULT_ROI_MARGIN).unwrap();
    let poses = around_and_random(&truth, 1000, 5);
    let params = ScoreParams::default();
    let split = GpuScorer::new(&small, &mesh, &target, params, poses.len()).unwrap();
    assert!(split.chunk_size() < poses.len() / 2, "chunk {}", split.chunk_size());
    let (a, _) = split.score(&poses).unwrap();
    let (b, _) = GpuScorer::new(&ctx, &mesh, &target, params, poses.len()).unwrap().score(&poses).unwrap();
    let c = score_cpu(&mesh, &target, &poses, &params);
    assert_eq!(a.len(), poses.len());
    for ((x, y), z) in a.iter().zip(&b).zip(&c) {
        assert!((x.score - y.score).abs() < 1e-6);
        assert!((x.score - z.score).abs() < 1e-3);
    }

    // The ray caster under the same limits: a 16x16 region's 4 tiles run
    // 3 along x and on along z; 32x32 (16 tiles) needs more than 3 x 3
    // workgroups and is refused, not cut short.
    let mut rays = mesh.clone();
    rays.renderer = plausible::kernels::RendererChoice::RayCast;
    let target16 = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(16), DEFAULT_ROI_MARGIN).unwrap();
    let few = &poses[..200];
    let (r, _) = GpuScorer::new(&small, &rays, &target16, params, few.len()).unwrap().score(few).unwrap();
    for (i, (g, c)) in r.iter().zip(score_cpu(&rays, &target16, few, &params)).enumerate() {
        assert!((g.score - c.score).abs() < 1e-3, "hypothesis {i}: gpu {g:?} cpu {c:?}");
    }
    assert!(GpuScorer::new(&small, &rays, &target, params, 10).is_err());
}

/// Regression: lavapipe stops an invocation's loops after 65535 iterations
/// in total. Long batches (many hypotheses per workgroup) and big triangles
/// (one invocation filling a large area) used to be cut short silently.
#[test]
fn gpu_long_batches_and_big_triangles_match_the_cpu_twin() {
    let ctx = test_context();
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let poses = around_and_random(&true_pose(), 4096, 9);
    let params = ScoreParams::default();
    let (gpu, _) = GpuScorer::new(&ctx, &mesh, &target, params, poses.len()).unwrap().score(&poses).unwrap();
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    let bad = gpu.iter().zip(&cpu).filter(|(g, c)| (g.score - c.score).abs() > 1e-3).count();
    assert_eq!(bad, 0, "{bad} of 4096 hypotheses differ");

    // A box filling most of a 640x480 frame: faces of ~100k pixels each.
    let cube = RenderMesh::new(&shapes::cuboid(DVec3::new(0.2, 0.15, 0.1))).unwrap();
    let k = linemod_camera();
    let poses: Vec<Pose> = (0..3)
        .map(|i| Pose::new(axis_angle(DVec3::new(1.0, 0.5, 0.2), 0.2 * i as f64), DVec3::new(0.0, 0.0, 0.6)))
        .collect();
    let gpu = render_gpu(&ctx, &cube, &poses, &k).unwrap();
    for (p, g) in poses.iter().zip(&gpu) {
        let c = render_cpu(&cube, p, &k);
        assert!(c.depth.iter().filter(|&&d| d > 0.0).count() > 100_000);
        assert_renders_match(&c, g);
    }
}

/// Depth of a sphere of radius `r` centred at `c` along the pixel's ray.
fn sphere_depth(k: &Intrinsics, c: DVec3, r: f64, u: f64, v: f64) -> Option<f64> {
    let d = k.ray(u, v);
    // |s d - c|² = r², with z = s (ray has z = 1).
    let a = d.dot(d);
    let b = -2.0 * d.dot(c);
    let cc = c.dot(c) - r * r;
    let disc = b * b - 4.0 * a * cc;
    (disc >= 0.0).then(|| (-b - disc.sqrt()) / (2.0 * a))
}

#[test]
fn gpu_sphere_depth_matches_analytic_surface() {
    let r = 0.05;
    let mesh = RenderMesh::new(&shapes::icosphere(r, 5)).unwrap();
    let pose = Pose::new(axis_angle(DVec3::new(1.0, 2.0, 3.0), 0.4), DVec3::new(0.01, -0.02, 0.6));
    let k = Intrinsics { fx: 600.0, fy: 600.0, cx: 63.5, cy: 63.5, width: 128, height: 128 };
    let mut images = vec![render_cpu(&mesh, &pose, &k)];
    {
        let ctx = test_context();
        images.extend(render_gpu(&ctx, &mesh, &[pose], &k).unwrap());
    }
    for img in &images {
        let mut checked = 0;
        for v in 0..128 {
            for u in 0..128 {
                let i = v * 128 + u;
                // Skip the outermost ring where the polyhedron's silhouette
                // and the sphere's differ.
                if sphere_depth(&k, pose.t, r * 0.97, u as f64, v as f64).is_none() {
                    continue;
                }
                let z = sphere_depth(&k, pose.t, r, u as f64, v as f64).unwrap();
                assert!(img.depth[i] > 0.0);
                assert!((img.depth[i] as f64 - z).abs() < 5e-4, "pixel ({u},{v}): {} vs {z}", img.depth[i]);
                // The rendered normal points out of the sphere, towards the camera.
                let p = k.ray(u as f64, v as f64) * z;
                let n = (p - pose.t).normalize().as_vec3();
                assert!(img.normals[i].dot(n) > 0.99);
                checked += 1;
            }
        }
        assert!(checked > 1000, "only {checked} pixels checked");
    }
}

#[test]
fn gpu_pose_scored_against_its_own_rendering_scores_at_least_0_99() {
    // Native ROI pixels coincide with the camera's, so the noise-free
    // observation is exactly this pose's rendering. (With --res resampling,
    // the nearest-sample observation is shifted by up to half a source pixel
    // against the ROI's pixel centres, which costs a few per cent of a_d on
    // sloped surfaces; that is a property of resampling, not of the score.)
    let mesh = RenderMesh::new(&duck()).unwrap();
    let (obs, mask) = observe(&mesh, &true_pose(), &linemod_camera(), SensorNoise { sigma: 0.0, dropout: 0.0 }, 1);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Native, DEFAULT_ROI_MARGIN).unwrap();
    let params = ScoreParams::default();
    let rec = score_cpu(&mesh, &target, &[true_pose()], &params)[0];
    assert!(rec.score >= 0.99, "{rec:?}");
    assert!(rec.mean_ad > 0.9999, "{rec:?}");
    {
        let ctx = test_context();
        let (g, _) = GpuScorer::new(&ctx, &mesh, &target, params, 1).unwrap().score(&[true_pose()]).unwrap();
        assert!(g[0].score >= 0.99, "{:?}", g[0]);
    }
}

#[test]
fn gpu_score_decreases_with_rotation_error() {
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let axis = DVec3::new(0.2, -0.5, 1.0);
    let poses: Vec<Pose> = (0..=6)
        .map(|i| {
            let angle = (5.0 * i as f64).to_radians();
            Pose::new(axis_angle(axis, angle) * true_pose().r, true_pose().t)
        })
        .collect();
    let s: Vec<f32> = score_cpu(&mesh, &target, &poses, &ScoreParams::default()).iter().map(|r| r.score).collect();
    for w in s.windows(2) {
        assert!(w[1] < w[0], "scores not decreasing: {s:?}");
    }
    {
        let ctx = test_context();
        let (g, _) = GpuScorer::new(&ctx, &mesh, &target, ScoreParams::default(), 7).unwrap().score(&poses).unwrap();
        for w in g.windows(2) {
            assert!(w[1].score < w[0].score);
        }
    }
}

#[test]
fn gpu_true_pose_ranks_first_among_1024_on_demo_data() {
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let poses = around_and_random(&true_pose(), 1024, 42);
    let recs = GpuScorer::new(&test_context(), &mesh, &target, ScoreParams::default(), 1024).unwrap().score(&poses).unwrap().0;
    assert_eq!(ranks(&recs)[0], 1, "true pose score {:?}", recs[0]);
}

#[test]
fn score_image_follows_the_definition() {
    // Two pixels observed, one of them rendered 5 mm away with a normal at
    // 60 degrees; one pixel rendered only.
    let k = Intrinsics { fx: 100.0, fy: 100.0, cx: 1.0, cy: 0.0, width: 3, height: 1 };
    let n = Vec3::new(0.0, 0.0, -1.0);
    let target = ScoreTarget {
        intrinsics: k,
        depth: vec![0.5, 0.5, 0.0],
        normals: vec![n, n, Vec3::ZERO],
        crop: (0.0, 0.0, 3.0, 1.0),
        occluder: Vec::new(),
    };
    let tilted = Vec3::new(3f32.sqrt() / 2.0, 0.0, -0.5);
    let rec = score_image(&target, &[0.505, 0.0, 0.6], &[tilted, Vec3::ZERO, n], &ScoreParams::default());
    assert_eq!((rec.valid, rec.rendered, rec.observed), (3, 2, 2));
    let ad = 1.0 - 0.005 / 0.02;
    let an = 1.0 - 0.5 / 0.7;
    assert!((rec.mean_ad - ad / 3.0).abs() < 1e-5);
    assert!((rec.mean_an - an / 3.0).abs() < 1e-5);
    assert!((rec.score - 0.5 * (ad + an) / 3.0).abs() < 1e-5);
    // Another object 0.55 m away at the third pixel hides the rendering
    // there (0.6 m): it leaves V; one 0.65 m away does not.
    let mut scene = target.clone();
    scene.set_occluders(vec![0.0, 0.0, 0.55]).unwrap();
    let hidden = score_image(&scene, &[0.505, 0.0, 0.6], &[tilted, Vec3::ZERO, n], &ScoreParams::default());
    assert_eq!((hidden.valid, hidden.rendered, hidden.observed), (2, 1, 2));
    assert!((hidden.score - 0.5 * (ad + an) / 2.0).abs() < 1e-5);
    scene.set_occluders(vec![0.0, 0.0, 0.65]).unwrap();
    assert_eq!(score_image(&scene, &[0.505, 0.0, 0.6], &[tilted, Vec3::ZERO, n], &ScoreParams::default()), rec);
    assert!(scene.set_occluders(vec![0.0; 2]).is_err() && scene.set_occluders(vec![f32::NAN; 3]).is_err());
    // Empty V scores 0.
    let empty = ScoreTarget { depth: vec![0.0; 3], ..target };
    assert_eq!(score_image(&empty, &[0.0; 3], &[Vec3::ZERO; 3], &ScoreParams::default()).score, 0.0);
}

#[test]
fn hypothesis_outside_the_image_is_valid_and_scores_low() {
    let mesh = RenderMesh::new(&duck()).unwrap();
    let target = demo_target(&mesh, SensorNoise::default());
    let far = Pose::new(true_pose().r, DVec3::new(3.0, 0.0, 0.7));
    let rec = score_cpu(&mesh, &target, &[far], &ScoreParams::default())[0];
    assert_eq!(rec.rendered, 0);
    assert_eq!(rec.score, 0.0);
    assert_eq!(rec.valid as usize, target.observed_pixels());
}

/// An object cut by the image border: the square region is clipped to the
/// image (past it there is no sensor), so the true pose scores about as
/// well as a whole view does, and not as a pose half of whose pixels are
/// unobserved (it scored 0.38 against 0.87 when the region reached past
/// the border).
#[test]
fn truncated_object_true_pose_scores_like_a_whole_view() {
    let mesh = RenderMesh::new(&duck()).unwrap();
    let whole = demo_target(&mesh, SensorNoise::default());
    let whole_score = score_cpu(&mesh, &whole, &[true_pose()], &ScoreParams::default())[0].score;
    let k = linemod_camera();
    // The duck's centre on the right border of the image.
    let edge = Pose::new(true_pose().r, DVec3::new((k.width as f64 - k.cx) / k.fx * 0.7, -0.01, 0.7));
    let (obs, mask) = observe(&mesh, &edge, &k, SensorNoise::default(), 7);
    let cut = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
    assert!(cut.intrinsics.width < 100 && cut.intrinsics.height == 128, "{}x{}", cut.intrinsics.width, cut.intrinsics.height);
    assert!(cut.crop.0 + cut.crop.2 <= k.width as f64 + 1e-9);
    let cut_score = score_cpu(&mesh, &cut, &[edge], &ScoreParams::default())[0].score;
    assert!(cut_score > 0.8 && (cut_score - whole_score).abs() < 0.08, "cut {cut_score}, whole {whole_score}");
}

/// The scene-level score: the duck half hidden behind a box. Scored alone,
/// the true pose loses the pixels behind the box (rendered, not observed);
/// with the box's depth as occluder they leave V and the true pose scores
/// as if unoccluded. GPU and CPU twin agree on 256 poses around it.
#[test]
fn gpu_scene_level_score_hides_pixels_behind_other_objects_like_the_cpu_twin() {
    let duck = RenderMesh::new(&duck()).unwrap();
    let cam = linemod_camera();
    let box_mesh = RenderMesh::new(&shapes::cuboid(DVec3::new(0.04, 0.12, 0.01))).unwrap();
    let box_pose = Pose::new(glam::DMat3::IDENTITY, DVec3::new(0.06, -0.01, 0.6));
    let (d, b) = (render_cpu(&duck, &true_pose(), &cam), render_cpu(&box_mesh, &box_pose, &cam));
    let nearest = |i: usize| match (d.depth[i], b.depth[i]) {
        (0.0, x) | (x, 0.0) => x,
        (x, y) => x.min(y),
    };
    let depth: Vec<f32> = (0..cam.pixels()).map(nearest).collect();
    let mask: Vec<bool> = (0..cam.pixels()).map(|i| d.depth[i] > 0.0 && (b.depth[i] == 0.0 || d.depth[i] < b.depth[i])).collect();
    let hidden = (0..cam.pixels()).filter(|&i| d.depth[i] > 0.0 && !mask[i]).count();
    assert!(hidden > 1000, "the box hides part of the duck ({hidden} pixels)");
    let obs = plausible::observation::DepthImage { intrinsics: cam, depth };
    let alone = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
    let mut scene = alone.clone();
    scene.set_occluders(render_cpu(&box_mesh, &box_pose, &scene.intrinsics).depth).unwrap();
    let params = ScoreParams::default();
    let s_alone = score_cpu(&duck, &alone, &[true_pose()], &params)[0];
    let s_scene = score_cpu(&duck, &scene, &[true_pose()], &params)[0];
    eprintln!("true pose: alone {s_alone:?}, in the scene {s_scene:?}");
    assert!(s_scene.score > 0.9 && s_scene.score > s_alone.score + 0.15, "alone {} scene {}", s_alone.score, s_scene.score);
    assert!(s_scene.rendered < s_alone.rendered && s_scene.observed == s_alone.observed);
    let poses = around_and_random(&true_pose(), 256, 5);
    let cpu = score_cpu(&duck, &scene, &poses, &params);
    let ctx = test_context();
    let (gpu, _) = GpuScorer::new(&ctx, &duck, &scene, params, poses.len()).unwrap().score(&poses).unwrap();
    for (i, (c, g)) in cpu.iter().zip(&gpu).enumerate() {
        assert!((c.score - g.score).abs() < 1e-3, "hypothesis {i}: cpu {c:?} gpu {g:?}");
        assert!(c.rendered.abs_diff(g.rendered) <= 2 + c.rendered / 100, "hypothesis {i}: cpu {c:?} gpu {g:?}");
    }
    // A scorer built alone and given the scene's observation afterwards
    // (one buffer write) scores as one built on it; another region is refused.
    let mut reused = GpuScorer::new(&ctx, &duck, &alone, params, poses.len()).unwrap();
    reused.set_observation(&scene).unwrap();
    assert_eq!(reused.score(&poses).unwrap().0, gpu);
    let other = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(64), DEFAULT_ROI_MARGIN).unwrap();
    assert!(reused.set_observation(&other).is_err());
}

/// A 2M-triangle mesh (the duck, every triangle split in 22² = 484): the
/// GPU ray-casts its full mesh (past the rasterizer's meshlet budget) and
/// scores it like the CPU, or, made to rasterize, refuses it by name of the
/// limit; with `--lod auto` GPU and CPU score the same simplification within
/// the twin tolerance; the CPU twin scores the full mesh like the 4k duck it
/// was made from.
#[test]
fn gpu_two_million_triangles_are_simplified_or_refused_never_wrong() {
    use plausible::gpu::Device;
    use plausible::visual::{score_poses, scoring_mesh, LodChoice};
    let ctx = test_context();
    let small = duck();
    let big = small.subdivided(22);
    assert!(big.triangles.len() > 2_000_000, "{}", big.triangles.len());
    let target = demo_target(&RenderMesh::new(&small).unwrap(), SensorNoise::default());
    let poses = around_and_random(&true_pose(), 8, 5);
    let params = ScoreParams::default();
    let gpu = Device::Gpu(Box::new(ctx));

    let full = RenderMesh::new(&big).unwrap();
    let mut rasterized = full.clone();
    rasterized.renderer = plausible::kernels::RendererChoice::Raster;
    let e = score_poses(&gpu, &rasterized, &target, &poses, params).unwrap_err().to_string();
    assert!(e.contains(&format!("{} triangles", big.triangles.len())) && e.contains("at most 8192 meshlets"), "{e}");
    assert_eq!(full.gpu_renderer(), plausible::kernels::CpuRenderer::RayCast);
    let (g_full, _) = score_poses(&gpu, &full, &target, &poses, params).unwrap();

    let lod = scoring_mesh(&big, LodChoice::Auto, &target).unwrap();
    assert!(lod.mesh.triangles.len() < 10_000, "{}", lod.describe());
    let rlod = RenderMesh::new(&lod.mesh).unwrap();
    let (g, _) = score_poses(&gpu, &rlod, &target, &poses, params).unwrap();
    let (c, _) = score_poses(&Device::Cpu, &rlod, &target, &poses, params).unwrap();
    let (reference, _) = score_poses(&Device::Cpu, &RenderMesh::new(&small).unwrap(), &target, &poses, params).unwrap();
    // The CPU twin ray-casts the full mesh (about 500 triangles per pixel
    // of the hypothesis' rectangle).
    let renderer = plausible::kernels::raster::cpu_renderer_at(&full, &(&true_pose()).into(), &target.intrinsics);
    assert_eq!(renderer, Some(plausible::kernels::CpuRenderer::RayCast));
    let (c_full, _) = score_poses(&Device::Cpu, &full, &target, &poses, params).unwrap();
    for i in 0..poses.len() {
        assert!((g[i].score - c[i].score).abs() < 1e-3, "pose {i}: gpu {:?} cpu {:?}", g[i], c[i]);
        assert!((c[i].score - reference[i].score).abs() < 0.01, "pose {i}: lod {:?} vs 4k {:?}", c[i], reference[i]);
        assert!((c_full[i].score - reference[i].score).abs() < 1e-3, "pose {i}: 2M {:?} vs 4k {:?}", c_full[i], reference[i]);
        assert!((g_full[i].score - c_full[i].score).abs() < 1e-3, "pose {i}: 2M gpu {:?} cpu {:?}", g_full[i], c_full[i]);
    }
}

/// Meshes the renderers are compared on: a scanned LM-O model (closed,
/// back faces culled), the duck, and an open box (one face missing).
fn renderer_meshes() -> [Mesh; 3] {
    let ape = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/lmo-synth/models/obj_000001.ply");
    let ape = Mesh::load(ape, MeshUnits::Millimetres).unwrap().0;
    [ape, duck(), open_box()]
}

fn open_box() -> Mesh {
    let mut open = shapes::cuboid(DVec3::new(0.1, 0.08, 0.06));
    open.triangles.truncate(10);
    open
}

/// `mesh` prepared for the rasterizer and, a copy, for the BVH ray caster.
fn raster_and_rays(mesh: &Mesh) -> (RenderMesh, RenderMesh) {
    use plausible::kernels::RendererChoice;
    let mut raster = RenderMesh::new(mesh).unwrap();
    raster.renderer = RendererChoice::Raster;
    let mut rays = raster.clone();
    rays.renderer = RendererChoice::RayCast;
    (raster, rays)
}

/// A 128x128 crop of the LineMOD camera, and the full frame.
fn crop_and_full() -> [Intrinsics; 2] {
    let full = linemod_camera();
    [full.crop(220.0, 140.0, 200.0, 200.0, 128, 128), full]
}

/// The GPU ray caster's CPU twin walks obvhs's CWBVH as the kernel does
/// and finds what obvhs's own traversal finds: the same triangle at every
/// pixel but at most 0.1 % (rounding at triangle edges), and never runs
/// out of budget; for a scanned LM-O model, the duck and an open mesh, at
/// 128x128 and at full frame.
#[test]
fn ray_caster_twin_hits_what_obvhs_hits() {
    use plausible::kernels::raycast::cast_ids;
    use plausible::kernels::GpuPose;
    for mesh in renderer_meshes() {
        let rm = RenderMesh::new(&mesh).unwrap();
        let caster = rm.ray_caster().unwrap();
        let bvh = caster.gpu_layout();
        for k in crop_and_full() {
            let n = k.pixels();
            let (mut hits, mut differ) = (0, 0);
            for p in around_and_random(&true_pose(), 12, 23) {
                let gp = GpuPose::from(&p);
                let (mut z1, mut i1) = (vec![0.0; n], vec![u32::MAX; n]);
                let (mut z2, mut i2) = (vec![0.0; n], vec![u32::MAX; n]);
                let a = caster.cast_ids(&rm, &gp, &k, &mut z1, &mut i1);
                let b = cast_ids(&rm, &bvh, &gp, &k, &mut z2, &mut i2);
                assert!(!b.overflow);
                hits += i2.iter().filter(|&&i| i != u32::MAX).count();
                differ += i1.iter().zip(&i2).filter(|(x, y)| x != y).count();
                if a.is_some() {
                    assert!(b.drawn.is_some());
                }
            }
            assert!(hits > 0 && differ * 1000 <= hits, "{differ} of {hits} pixels differ");
        }
    }
}

/// The GPU ray caster (`raycast.wgsl`, then the score reduction) scores
/// like the CPU's ray caster within the rasterizer's twin tolerance, for
/// the duck (closed: back faces culled) and an open box, with hypotheses
/// around the truth and far from it.
#[test]
fn score_gpu_ray_caster_matches_cpu() {
    let ctx = test_context();
    let target = demo_target(&RenderMesh::new(&duck()).unwrap(), SensorNoise::default());
    let poses = around_and_random(&true_pose(), 96, 11);
    let params = ScoreParams::default();
    for mesh in [duck(), open_box()] {
        let mut rm = RenderMesh::new(&mesh).unwrap();
        rm.renderer = plausible::kernels::RendererChoice::RayCast;
        let scorer = GpuScorer::new(&ctx, &rm, &target, params, poses.len()).unwrap();
        assert!(scorer.ray_casts());
        let (gpu, _) = scorer.score(&poses).unwrap();
        let cpu = score_cpu(&rm, &target, &poses, &params);
        assert!(cpu.iter().filter(|c| c.rendered > 0).count() > poses.len() / 2);
        for (i, (c, g)) in cpu.iter().zip(&gpu).enumerate() {
            assert!((c.score - g.score).abs() < 1e-3, "hypothesis {i}: cpu {c:?} gpu {g:?}");
            assert!((c.mean_ad - g.mean_ad).abs() < 1e-3 && (c.mean_an - g.mean_an).abs() < 1e-3);
            assert_eq!(c.observed, g.observed);
        }
    }
}

/// Meshlet culling (whole meshlets facing away from the camera, behind the
/// near plane or outside the region) only skips work: renderings with the
/// meshlets' culling disabled are identical, on the CPU twin and the GPU,
/// for a scanned LM-O model (closed, back faces culled), the duck, and an
/// open mesh, with poses partly outside the image and close to the camera.
#[test]
fn meshlet_culling_changes_no_pixel() {
    let ctx = test_context();
    let k = Intrinsics { fx: 572.4, fy: 573.6, cx: 325.3, cy: 242.0, width: 160, height: 120 };
    for mesh in renderer_meshes() {
        let culled = RenderMesh::new(&mesh).unwrap();
        assert!(culled.meshlets.len() > 1 || mesh.triangles.len() <= 64);
        // The same meshlets with culling switched off: a cone cutoff above 1
        // and a sphere that holds everything.
        let mut all = culled.clone();
        for m in &mut all.meshlets {
            m.cone[3] = 2.0;
            m.sphere = [0.0, 0.0, 0.0, 1e3];
        }
        let centre = DVec3::new(0.0, 0.0, 0.45);
        let mut poses = around_and_random(&Pose::new(axis_angle(DVec3::new(0.2, 1.0, 0.1), 1.0), centre), 40, 17);
        poses.push(Pose::new(axis_angle(DVec3::X, 0.7), DVec3::new(0.1, 0.05, 0.3))); // partly outside
        poses.push(Pose::new(axis_angle(DVec3::Y, 2.0), DVec3::new(0.0, 0.0, 0.06))); // through the near plane
        // Culling does reject meshlets here (back faces and the region).
        let gp = plausible::kernels::GpuPose::from(&poses[0]);
        let rejected = culled
            .meshlets
            .iter()
            .filter(|m| !plausible::kernels::raster::meshlet_visible(m, &gp, gp.inverse_translation(), 1.0, culled.cull_back_faces, &k, (0.0, 0.0), (159.0, 119.0)))
            .count();
        assert!(rejected > 0 || !culled.cull_back_faces, "no meshlet culled");
        let with_gpu = render_gpu(&ctx, &culled, &poses, &k).unwrap();
        let without_gpu = render_gpu(&ctx, &all, &poses, &k).unwrap();
        for (i, p) in poses.iter().enumerate() {
            let (a, b) = (render_cpu(&culled, p, &k), render_cpu(&all, p, &k));
            assert_eq!(a.depth, b.depth, "CPU twin, pose {i}");
            assert_eq!(with_gpu[i].depth, without_gpu[i].depth, "GPU, pose {i}");
        }
    }
}

/// Back faces are culled only where that changes nothing: rendering with
/// them culled gives the depth of drawing every face, on a scan with faces
/// wound backwards (LM-O's eggbox, which `Mesh::orient` turns round; before,
/// they were culled as holes), on the ape, and on their simplifications for
/// `--lod auto` (meshoptimizer can leave a folded pair of faces, dropped,
/// or sheets touching along an edge, which still bound a solid). Silhouette
/// pixels may differ where a back face ties with the front one.
#[test]
fn back_face_culling_changes_no_pixel_on_solid_models() {
    let ctx = test_context();
    let k = Intrinsics { fx: 572.4, fy: 573.6, cx: 80.0, cy: 60.0, width: 160, height: 120 };
    for id in [10, 1] {
        let path = format!("{}/assets/lmo-synth/models/obj_{id:06}.ply", env!("CARGO_MANIFEST_DIR"));
        let full = Mesh::load(&path, MeshUnits::Millimetres).unwrap().0;
        for bound in [0.0, 2e-4, 1e-3] {
            let mesh = plausible::mesh::lod::within_error(&full, bound).unwrap().mesh;
            let culled = RenderMesh::new(&mesh).unwrap();
            assert!(culled.cull_back_faces, "obj {id} at {bound} m");
            let mut all = culled.clone();
            all.cull_back_faces = false;
            let centre = DVec3::new(0.0, 0.0, 0.5);
            let poses = around_and_random(&Pose::new(axis_angle(DVec3::new(0.2, 1.0, 0.1), 1.0), centre), 12, 5);
            let (gpu_culled, gpu_all) = (render_gpu(&ctx, &culled, &poses, &k).unwrap(), render_gpu(&ctx, &all, &poses, &k).unwrap());
            for (i, p) in poses.iter().enumerate() {
                for (what, a, b) in [("CPU twin", render_cpu(&culled, p, &k), render_cpu(&all, p, &k)), ("GPU", gpu_culled[i].clone(), gpu_all[i].clone())] {
                    let covered = b.depth.iter().filter(|&&d| d > 0.0).count();
                    let differ = a.depth.iter().zip(&b.depth).filter(|(x, y)| (*x - *y).abs() > 1e-4).count();
                    assert!(covered > 100 && differ * 200 <= covered, "{what}, obj {id} at {bound} m, pose {i}: {differ} of {covered} pixels differ");
                }
            }
        }
    }
}

/// A mesh wound inside out is turned outward before rendering: with its
/// back faces culled as given, the far side would show. It renders like
/// the mesh itself, on the CPU twin and on the GPU.
#[test]
fn an_inside_out_mesh_renders_like_the_mesh() {
    let ctx = test_context();
    let k = Intrinsics { fx: 572.4, fy: 573.6, cx: 80.0, cy: 60.0, width: 160, height: 120 };
    let mesh = duck();
    let mut inside_out = mesh.clone();
    inside_out.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    let (a, b) = (RenderMesh::new(&mesh).unwrap(), RenderMesh::new(&inside_out).unwrap());
    assert!(a.cull_back_faces && b.cull_back_faces);
    let poses = around_and_random(&Pose::new(axis_angle(DVec3::new(0.2, 1.0, 0.1), 1.0), DVec3::new(0.0, 0.0, 0.5)), 8, 3);
    let (ga, gb) = (render_gpu(&ctx, &a, &poses, &k).unwrap(), render_gpu(&ctx, &b, &poses, &k).unwrap());
    for (i, p) in poses.iter().enumerate() {
        let (ca, cb) = (render_cpu(&a, p, &k), render_cpu(&b, p, &k));
        assert!(ca.depth.iter().filter(|&&d| d > 0.0).count() > 100, "pose {i} draws nothing");
        assert_eq!(ca.depth, cb.depth, "CPU twin, pose {i}");
        assert_eq!(ga[i].depth, gb[i].depth, "GPU, pose {i}");
    }
}

/// The BVH ray caster (the CPU renderer for very large meshes) draws what
/// the rasterizer twin draws: the same coverage within 1 % of the pixels
/// (silhouette edges) and the same depth inside, for a closed scanned
/// model, the duck and an open mesh, at 128x128 and at full frame.
#[test]
fn ray_caster_renders_like_the_rasterizer() {
    for mesh in renderer_meshes() {
        let (raster, rays) = raster_and_rays(&mesh);
        assert!(rays.ray_caster().is_some());
        for k in crop_and_full() {
            for p in around_and_random(&true_pose(), 12, 23) {
                assert_renders_match(&render_cpu(&raster, &p, &k), &render_cpu(&rays, &p, &k));
            }
        }
    }
}

/// `n` triangles of 7 cm stacked in the plane z = 0, each moved sideways by
/// up to 2 mm (a fixed sequence).
fn stack_of(n: u32) -> Mesh {
    let mut rng = 12345u64;
    let mut jitter = || {
        rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((rng >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 0.004
    };
    let mut stack = Mesh { vertices: Vec::new(), triangles: Vec::new(), source: None };
    for i in 0..n {
        let (dx, dy) = (jitter(), jitter());
        for (x, y) in [(-0.03, -0.03), (-0.03, 0.04), (0.04, -0.03)] {
            stack.vertices.push(DVec3::new(x + dx, y + dy, 0.0));
        }
        stack.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    stack
}

/// The lanes kernel's workgroups take vectors of hypotheses from a counter
/// while their loop budget lasts (`lanes_wave` in score_lanes.wgsl), so a
/// vector may start with much of the budget spent by those before it. On
/// 1,800 stacked triangles seen square on (one view direction, so vectors
/// are runs of 8 poses in input order) from 0.5 m (about 41,000 loop
/// iterations a vector) and 1.2 m (about 16,000), two runs of the far
/// poses then one of the near: a workgroup that drew two far vectors has
/// spent 32,000 and may take a near one, which then runs over (two or
/// three vectors of the 38 on lavapipe, depending on which thread took
/// which) and is drawn again. Every record is the twin's; with the budget
/// not carried from vector to vector, lavapipe cut loops short and a near
/// pose came back with 3 of its 60 pixels.
#[test]
fn gpu_lanes_vectors_sharing_a_loop_budget_score_as_the_twin() {
    let ctx = test_context();
    if !lanes_available(&ctx) {
        return;
    }
    let mut mesh = RenderMesh::new(&stack_of(1800)).unwrap();
    mesh.renderer = plausible::kernels::RendererChoice::Raster;
    let truth = Pose::new(glam::DMat3::IDENTITY, DVec3::new(0.0, 0.0, 0.5));
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 31.5, cy: 23.5, width: 64, height: 48 };
    let (obs, mask) = observe(&mesh, &truth, &k, SensorNoise::default(), 3);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(16), DEFAULT_ROI_MARGIN).unwrap();
    let poses: Vec<Pose> =
        (0..300).map(|i| Pose::new(axis_angle(DVec3::Z, 0.1 * i as f64), DVec3::new(0.0, 0.0, [1.2, 1.2, 0.5][(i / 8) % 3]))).collect();
    let params = ScoreParams::default();
    let mut scorer = GpuScorer::new(&ctx, &mesh, &target, params, poses.len()).unwrap();
    scorer.set_kernel(ScoreKernel::Lanes).unwrap();
    let gpu = scorer.score(&poses).unwrap().0;
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    assert!(cpu.iter().filter(|r| r.rendered > 40).count() >= 90);
    // A region of about 60 drawn pixels: on hardware one may move.
    assert_matches_twin(&ctx, "", &gpu, &cpu, 1.0);
}

/// Means over a large region hold to the twin's f64 sums. One triangle far
/// bigger than the 350x350 region lies parallel to a flat observed surface
/// 1 m away, `off` behind it, so every pixel has a_d = 1 - off / tau and
/// a_n = 1. The kernels sum a_d and a_n in 64-bit fixed point
/// (score.wgsl): the lanes kernel, which adds all 122,500 pixels of a
/// hypothesis in one invocation, drifted to a_d 0.99790 instead of
/// 0.99609 with an f32 running sum, and its records then depended on which
/// kernel drew a hypothesis.
#[test]
fn gpu_means_over_a_large_region_match_the_twins_sums() {
    let ctx = test_context();
    let (mesh, _) = Mesh::from_raw("big triangle", vec![DVec3::new(-3.0, -3.0, 0.0), DVec3::new(3.0, -3.0, 0.0), DVec3::new(0.0, 3.0, 0.0)], vec![[0, 1, 2]]).unwrap();
    let mesh = RenderMesh::new(&mesh).unwrap();
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 175.0, cy: 175.0, width: 350, height: 350 };
    let obs = plausible::observation::DepthImage { intrinsics: k, depth: vec![1.0; k.pixels()] };
    let target = ScoreTarget::new(&obs, None, RoiSampling::FullFrame, DEFAULT_ROI_MARGIN).unwrap();
    let params = ScoreParams::default();
    // Offsets of 0 to 20 mm in steps of 2^-16 m ≈ 0.015 mm, each exact in
    // binary, as is 1 - off / tau for tau = 20 mm.
    let offsets: Vec<f64> = (0..64).map(|i| (i * 20) as f64 / 65536.0).collect();
    let poses: Vec<Pose> = offsets.iter().map(|o| Pose::new(glam::DMat3::IDENTITY, DVec3::new(0.0, 0.0, 1.0 + o))).collect();
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    for (o, c) in offsets.iter().zip(&cpu) {
        assert_eq!(c.rendered, k.pixels() as u32);
        assert!((c.mean_ad as f64 - (1.0 - o / params.tau as f64)).abs() < 1e-5, "offset {o}: {c:?}");
        assert_eq!(c.mean_an, 1.0, "offset {o}: {c:?}");
    }
    for (kernel, gpu) in score_with_each_kernel(&ctx, &mesh, &target, params, &poses) {
        assert_matches_twin(&ctx, &format!("{kernel:?} "), &gpu, &cpu, 0.0);
        for ((o, g), c) in offsets.iter().zip(&gpu).zip(&cpu) {
            // Each pixel's term in f32 on both sides (one ulp of a 1 m
            // depth is 6e-6 of tau); the sums themselves agree to 2^-25.
            let tol = if exact_twin(&ctx) { 1e-6 } else { 1e-4 };
            assert!((g.mean_ad - c.mean_ad).abs() <= tol, "{kernel:?} offset {o}: gpu {g:?} cpu {c:?}");
        }
    }
}

/// A mesh that reaches behind the camera is drawn where it lies beyond the
/// near plane, by every renderer alike. A 4 m square tilted through the
/// camera's plane (both its triangles cross it) covers the whole image at
/// 0.17-0.95 m. The rasterizer twin clips the triangles at the near plane
/// (`raster::clipped`) and draws what the ray caster sees; the GPU
/// rasterizers hand such a hypothesis to the twin (score with either
/// kernel, render, depth). Until 2026-12-05 the rasterizers drew nothing of
/// it while the ray casters drew the part in front (a fuzz found GPU
/// records of 0 pixels against the twin's 303).
#[test]
fn gpu_meshes_crossing_the_near_plane_draw_their_part_beyond_it() {
    use plausible::kernels::depth::{depth_tiles_cpu, GpuDepth};
    use plausible::kernels::RendererChoice;
    let ctx = test_context();
    let corners = [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)].map(|(x, y)| DVec3::new(x, y, 0.0));
    let (square, _) = Mesh::from_raw("square", corners.to_vec(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let (raster, rays) = raster_and_rays(&square);
    let k = Intrinsics { fx: 60.0, fy: 60.0, cx: 31.5, cy: 23.5, width: 64, height: 48 };
    let tilted = |a: f64, t: DVec3| Pose::new(axis_angle(DVec3::X, a), t);
    let seen = tilted(std::f64::consts::FRAC_PI_3, DVec3::new(0.0, 0.3, 0.8));
    let crossing = [seen, tilted(1.0, DVec3::new(0.05, 0.25, 0.7)), tilted(1.1, DVec3::new(-0.1, 0.3, 0.9))];
    // And one wholly beyond the plane, drawn on the GPU as ever.
    let poses = [&crossing[..], &[tilted(0.3, DVec3::new(0.0, 0.0, 3.0))]].concat();
    for p in &crossing {
        let (r, c) = (render_cpu(&raster, p, &k), render_cpu(&rays, p, &k));
        assert!(r.depth.iter().filter(|d| **d > 0.0).count() > k.pixels() * 9 / 10, "the square fills the image");
        assert_renders_match(&r, &c);
    }
    // Any tilt, the plane 0-4 cm from the camera, its corner or edge in view:
    // the rasterizer twin still draws what the ray caster sees.
    let (tile, _) = Mesh::from_raw("tile", corners.map(|c| c * 0.1).to_vec(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let (tile_raster, tile_rays) = raster_and_rays(&tile);
    let mut checked = 0;
    for (i, p) in around_and_random(&seen, 40, 7).into_iter().enumerate() {
        let shift = DVec3::new(((i % 5) as f64 - 2.0) * 0.1, ((i % 3) as f64 - 1.0) * 0.1, 0.0);
        let p = Pose::new(p.r, p.r * shift + DVec3::new(0.0, 0.0, 0.01 * (i % 5) as f64));
        let (r, c) = (render_cpu(&tile_raster, &p, &k), render_cpu(&tile_rays, &p, &k));
        let n = c.depth.iter().filter(|d| **d > 0.0).count();
        if n > 100 && n < k.pixels() {
            assert_renders_match(&r, &c);
            checked += 1;
        }
    }
    assert!(checked > 10, "{checked} poses see the square");
    // A 20 m square 5 cm from the camera, its diagonal across the image: the
    // two clipped triangles meet without a crack (every pixel's ray hits the
    // square beyond the near plane, by an exact float64 count). Clipped at
    // the near plane alone, two pixels on the diagonal were lost: corners
    // 1 mm from the camera project thousands of pixels out (raster.rs
    // near_frustum).
    let (big, _) = Mesh::from_raw("big square", corners.map(|c| c * 5.0).to_vec(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let mut big = RenderMesh::new(&big).unwrap();
    big.renderer = RendererChoice::Raster;
    let r = [0.5633777055929099, 0.0, 0.8261994679500033, 0.5357641552508874, 0.7612416688041095, -0.36533257673609876, -0.6289374617473279, 0.6484682888748952, 0.428866584772577];
    let p = Pose::new(glam::DMat3::from_cols_array(&r).transpose(), DVec3::new(-0.0018623100565173848, -0.0022596789111481792, 0.04990904340458038));
    let k = Intrinsics { fx: 134.02179746791018, fy: 129.43667560296316, cx: 33.10121428368295, cy: 20.846825837082598, width: 64, height: 48 };
    assert_eq!(render_cpu(&big, &p, &k).depth.iter().filter(|d| **d > 0.0).count(), k.pixels());
    for (p, g) in poses.iter().zip(render_gpu(&ctx, &raster, &poses, &k).unwrap()) {
        let c = render_cpu(&raster, p, &k);
        match exact_twin(&ctx) {
            true => assert_eq!(g.depth, c.depth),
            false => assert_renders_match(&c, &g),
        }
    }
    let gpu_depth = GpuDepth::new(&ctx, &raster, &k).unwrap().render(&poses).unwrap();
    for (g, c) in gpu_depth.iter().zip(depth_tiles_cpu(&raster, &poses, &k)) {
        let (g, c) = (g.as_ref().unwrap(), c.unwrap());
        assert_eq!(g.rect, c.rect);
        assert!(g.depth.iter().zip(&c.depth).all(|(a, b)| (a - b).abs() <= 1e-4), "depth tiles differ");
    }
    let (obs, mask) = observe(&rays, &seen, &k, SensorNoise::default(), 4);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::FullFrame, DEFAULT_ROI_MARGIN).unwrap();
    let params = ScoreParams::default();
    let cpu = score_cpu(&raster, &target, &poses, &params);
    assert!(cpu[0].rendered > 2000 && cpu[0].score > 0.7, "{:?}", cpu[0]);
    for (kernel, gpu) in score_with_each_kernel(&ctx, &raster, &target, params, &poses) {
        assert_matches_twin(&ctx, &format!("{kernel:?} "), &gpu, &cpu, 0.0);
    }
}

/// Triangles that overlap many times over (50,000 stacked in one plane)
/// would need far more loop iterations than lavapipe allows an invocation.
/// The ray caster's rays give up (kernel and twin alike) and the scorer
/// rasterizes instead; the rasterizing kernels (score, render, depth) stop
/// at their draw budget and hand those hypotheses to the CPU twin. Every
/// path returns the twin's result, never a partial image.
#[test]
fn gpu_kernels_over_their_loop_budget_hand_over_to_the_twin() {
    use plausible::kernels::depth::{depth_tiles_cpu, GpuDepth};
    use plausible::kernels::raycast::cast_ids;
    use plausible::kernels::{GpuPose, RendererChoice};
    let ctx = test_context();
    let stack = stack_of(50_000);
    let truth = Pose::new(axis_angle(DVec3::X, 0.0), DVec3::new(0.0, 0.0, 0.5));
    let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 31.5, cy: 23.5, width: 64, height: 48 };
    let (raster, rays) = raster_and_rays(&stack);
    let (obs, mask) = observe(&raster, &truth, &k, SensorNoise::default(), 3);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(16), DEFAULT_ROI_MARGIN).unwrap();
    let poses = around_and_random(&truth, 4, 5);
    let params = ScoreParams::default();

    let ti = target.intrinsics;
    let (mut z, mut ids) = (vec![0.0; ti.pixels()], vec![u32::MAX; ti.pixels()]);
    let cast = cast_ids(&rays, &rays.ray_caster().unwrap().gpu_layout(), &GpuPose::from(&truth), &ti, &mut z, &mut ids);
    assert!(cast.overflow);

    // The rasterizer with each of its two score kernels, then the ray caster.
    let kernels = [(&raster, ScoreKernel::Workgroups), (&raster, ScoreKernel::Lanes), (&rays, ScoreKernel::Auto)];
    for (mesh, kernel) in kernels {
        let mut scorer = GpuScorer::new(&ctx, mesh, &target, params, poses.len()).unwrap();
        if kernel == ScoreKernel::Lanes && !lanes_available(&ctx) {
            continue;
        }
        scorer.set_kernel(kernel).unwrap();
        assert_eq!(scorer.ray_casts(), mesh.renderer == RendererChoice::RayCast);
        let (gpu, _) = scorer.score(&poses).unwrap();
        let cpu = score_cpu(mesh, &target, &poses, &params);
        assert!(cpu[0].rendered > 0);
        for (i, (c, g)) in cpu.iter().zip(&gpu).enumerate() {
            assert!((c.score - g.score).abs() < 1e-6 && c.rendered == g.rendered, "{kernel:?} hypothesis {i}: cpu {c:?} gpu {g:?}");
        }
    }
    for (p, img) in poses.iter().zip(render_gpu(&ctx, &raster, &poses, &ti).unwrap()) {
        match exact_twin(&ctx) {
            true => assert_eq!(img, render_cpu(&raster, p, &ti)),
            false => assert_renders_match(&render_cpu(&raster, p, &ti), &img),
        }
    }
    let tiles = GpuDepth::new(&ctx, &raster, &k).unwrap().render(&poses).unwrap();
    let cpu_tiles = depth_tiles_cpu(&raster, &poses, &k);
    if exact_twin(&ctx) {
        assert_eq!(tiles, cpu_tiles);
    } else {
        for (g, c) in tiles.iter().zip(&cpu_tiles) {
            let (Some(g), Some(c)) = (g, c) else {
                assert!(g.is_none() && c.is_none(), "a tile on one side only");
                continue;
            };
            assert_eq!(g.rect, c.rect);
            if g.covered() + c.covered() > 0 {
                let image = |t: &plausible::kernels::depth::DepthTile| RenderImage { width: t.width() as u32, height: (t.depth.len() / t.width()) as u32, depth: t.depth.clone(), normals: vec![] };
                assert_renders_match(&image(c), &image(g));
            }
        }
    }

    // Past the rasterizer's meshlet budget too (530,000 stacked triangles,
    // ray-cast by default): rays out of budget, no rasterizer to fall back
    // on, so the twin scores them.
    let huge = RenderMesh::new(&stack_of(530_000)).unwrap();
    assert!(huge.meshlets.len() > plausible::kernels::MAX_GPU_MESHLETS);
    let target8 = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(8), DEFAULT_ROI_MARGIN).unwrap();
    let two = &poses[..2];
    let scorer = GpuScorer::new(&ctx, &huge, &target8, params, two.len()).unwrap();
    assert!(scorer.ray_casts());
    let (gpu, _) = scorer.score(two).unwrap();
    let cpu = score_cpu(&huge, &target8, two, &params);
    assert!(cpu[0].rendered > 0);
    assert_eq!(gpu, cpu);
}
