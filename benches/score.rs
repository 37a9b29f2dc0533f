//! Criterion benchmark of the visual score: the GPU kernel and its CPU twin
//! on the same inputs (duck, 4212 triangles, 128x128 region, 256 poses).
//! `plausible bench score` covers more sizes and prints a table / JSON.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use plausible::gpu::{Context, GpuOptions};
use plausible::hypotheses::around_and_random;
use plausible::kernels::score::{score_cpu, GpuScorer, ScoreParams};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::pose::{axis_angle, Pose};
use plausible::synth::{linemod_camera, observe, SensorNoise};

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
    match Context::new(&GpuOptions::default()) {
        Ok(ctx) => {
            let scorer = GpuScorer::new(&ctx, &rmesh, &target, params, poses.len()).unwrap();
            g.bench_function(format!("gpu ({})", ctx.info.name), |b| b.iter(|| scorer.score(&poses).unwrap()));
        }
        Err(e) => eprintln!("skipping the GPU benchmark: {e}"),
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
