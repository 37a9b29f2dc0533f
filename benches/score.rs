//! Criterion benchmark of the visual score: the GPU kernel and its CPU twin
//! on the same inputs (duck, 4212 triangles, 128x128 region, 256 poses).
//! With the physical terms against a support plane (the fused kernel) too,
//! and the BVH ray caster (GPU kernel, twin, obvhs's CPU walk).
//! `plausible bench score [--physics]` covers more sizes and prints a table / JSON.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use plausible::gpu::{Context, GpuOptions};
use plausible::hypotheses::around_and_random;
use plausible::kernels::score::{score_cpu, GpuScorer, ScoreParams};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::pose::{axis_angle, Pose};
use plausible::physical::batch::PlanePhysics;
use plausible::synth::{linemod_camera, observe, plane_under, SensorNoise};
use plausible::visual::{score_poses_with_physics, Device};

fn bench(c: &mut Criterion) {
    let mesh = Mesh::load(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj"), MeshUnits::Metres)
        .unwrap()
        .0
        .normalized(0.15);
    let rmesh = RenderMesh::new(&mesh).unwrap();
    let truth = Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7));
    let (obs, mask) = observe(&rmesh, &truth, &linemod_camera(), SensorNoise::default(), 1);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
    let poses = around_and_random(&truth, 256, 7);
    let params = ScoreParams::default();
    let mut g = c.benchmark_group("score/duck/128x128");
    g.throughput(Throughput::Elements(poses.len() as u64));
    g.sample_size(10);
    g.bench_function("cpu_twin", |b| b.iter(|| score_cpu(&rmesh, &target, &poses, &params)));
    let gpu = match Context::new(&GpuOptions::default()) {
        Ok(ctx) => Some(Device::Gpu(Box::new(ctx))),
        Err(e) => {
            eprintln!("skipping the GPU benchmark: {e}");
            None
        }
    };
    if let Some(Device::Gpu(ctx)) = &gpu {
        let scorer = GpuScorer::new(ctx, &rmesh, &target, params, poses.len()).unwrap();
        g.bench_function(format!("gpu ({})", ctx.info.name), |b| b.iter(|| scorer.score(&poses).unwrap()));
    }
    g.finish();

    // Visual score + physical terms against a support plane under the pose
    // (1024 samples), end to end: the fused kernel and its CPU twins.
    let plane = plane_under(&mesh, &truth, DVec3::new(0.0, -1.0, -0.6));
    let physics = PlanePhysics::new(&mesh, &plane, None, 1024, 0, None).unwrap();
    let mut g = c.benchmark_group("score+plane/duck/128x128");
    g.throughput(Throughput::Elements(poses.len() as u64));
    g.sample_size(10);
    let run = |dev: &Device| score_poses_with_physics(dev, &rmesh, &target, &poses, params, &physics, |_| {}).unwrap();
    g.bench_function("cpu_twin", |b| b.iter(|| run(&Device::Cpu)));
    if let Some(dev) = &gpu {
        g.bench_function(format!("gpu ({})", dev.describe()), |b| b.iter(|| run(dev)));
    }
    g.finish();

    // The BVH ray caster (the renderer of meshes past the rasterizer's
    // budget), same inputs, 64 poses: GPU kernel, its CPU twin (the plain
    // walk the kernel mirrors) and the CPU's own renderer (obvhs's walk).
    let mut rays = rmesh.clone();
    rays.renderer = plausible::kernels::RendererChoice::RayCast;
    let few = &poses[..64];
    let bvh = rays.ray_caster().unwrap().gpu_layout();
    let mut g = c.benchmark_group("raycast/duck/128x128");
    g.throughput(Throughput::Elements(few.len() as u64));
    g.sample_size(10);
    let k = target.intrinsics;
    g.bench_function("cpu_twin", |b| {
        let (mut z, mut ids) = (vec![0.0; k.pixels()], vec![u32::MAX; k.pixels()]);
        b.iter(|| few.iter().map(|p| plausible::kernels::raycast::cast_ids(&rays, &bvh, &p.into(), &k, &mut z, &mut ids).drawn).count())
    });
    g.bench_function("cpu_obvhs_score", |b| b.iter(|| score_cpu(&rays, &target, few, &params)));
    if let Some(Device::Gpu(ctx)) = &gpu {
        let scorer = GpuScorer::new(ctx, &rays, &target, params, few.len()).unwrap();
        g.bench_function(format!("gpu_score ({})", ctx.info.name), |b| b.iter(|| scorer.score(few).unwrap()));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
