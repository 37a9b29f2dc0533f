//! Criterion benchmarks of the stable-pose pipeline's parts: one drop test,
//! clustering, and the quasi-static analysis. End-to-end throughput (drops/s
//! on all cores) is `plausible bench stable`.

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::shapes;
use plausible::stable::analytic::{stable_poses, AnalyticParams};
use plausible::stable::cluster::{cluster, ClusterParams};
use plausible::stable::hull::Hull;
use plausible::stable::{self, drop, RunParams};

fn asset(rel: &str) -> Mesh {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets")
        .join(rel);
    Mesh::load(path, MeshUnits::Metres)
        .expect("asset")
        .0
        .normalized(0.15)
}

fn benches(c: &mut Criterion) {
    let params = RunParams::default();
    let cube = stable::prepare(shapes::cuboid(DVec3::splat(0.04)), "cube", &params).expect("cube");
    let duck =
        stable::prepare(asset("pybullet/duck_vhacd.obj"), "duck_vhacd", &params).expect("duck");
    // One world of drops (drop::DROPS_PER_WORLD) per iteration, the unit
    // run_drops schedules; criterion reports the time per world.
    let per = drop::DROPS_PER_WORLD;
    let mut world = 0u64;
    c.bench_function("drop_world/cube", |b| {
        b.iter(|| {
            world += 1;
            drop::simulate_world(&cube.body, &params.sim, &cube.sha256, 0, world * per..(world + 1) * per)
        })
    });
    c.bench_function("drop_world/duck_vhacd", |b| {
        b.iter(|| {
            world += 1;
            drop::simulate_world(&duck.body, &params.sim, &duck.sha256, 0, world * per..(world + 1) * per)
        })
    });
    let idx: Vec<u64> = (0..300).collect();
    let mut drops = Vec::new();
    stable::run_drops(&duck, &params, &idx, 2, |r| {
        drops.push(r);
        Ok(())
    })
    .expect("drops");
    c.bench_function("cluster/300_duck_drops", |b| {
        b.iter(|| cluster(&drops, ClusterParams::default()))
    });
    let box_scan = asset("ycb/003_cracker_box.stl");
    let hull = Hull::of_points("box", &box_scan.vertices).expect("hull");
    let com = plausible::mesh::mass::MassProperties::of_mesh(&box_scan)
        .expect("mass")
        .0
        .com;
    c.bench_function("analytic/cracker_box_hull", |b| {
        b.iter(|| stable_poses(&hull, com, AnalyticParams::default()).expect("analytic"))
    });
}

criterion_group! {
    name = stable_benches;
    config = Criterion::default().sample_size(20);
    targets = benches
}
criterion_main!(stable_benches);
