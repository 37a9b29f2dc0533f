//! `plausible bench physics`: sample-hypothesis signed-distance queries per
//! second, GPU kernel and CPU twin side by side in the same run, for a
//! plane alone and for a plane plus one mesh grid.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use glam::{DMat3, DVec3};
use plausible::mesh::{Mesh, MeshUnits};
use plausible::physical::contacts::{distances_batch, evaluate_batch, Body, Environment, Obstacle};
use plausible::physical::gpu::GpuContacts;
use plausible::physical::scene::Plane;
use plausible::physical::sdf::{SdfGrid, DEFAULT_RESOLUTION};
use plausible::pose::Pose;
use plausible::visual::Device;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::bench::median;
use super::DeviceArgs;

#[derive(clap::Args, Debug)]
pub struct BenchPhysicsArgs {
    /// Print JSON (one object per configuration) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Hypotheses per batch.
    #[arg(long, default_value_t = 4096, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1_000_000))]
    pub n: usize,
    /// Surface samples per hypothesis.
    #[arg(long, default_value_t = 1024, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=50_000))]
    pub samples: usize,
    /// Timed runs per configuration (the median is reported).
    #[arg(long, default_value_t = 3, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub repeat: usize,
    /// Seed of the samples and the hypotheses.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub device: DeviceArgs,
}

#[derive(Serialize, Debug)]
pub struct PhysicsBenchRow {
    pub adapter: String,
    pub backend: String,
    /// "plane", "plane+mesh" (poses anywhere over and around the mesh: nearly
    /// every sample queries the grid) or "plane+mesh/near" (poses resting
    /// near the plane in and around the mesh's footprint).
    pub scene: String,
    pub n: usize,
    pub samples: usize,
    pub grid_nodes: usize,
    /// Sample-hypothesis signed-distance queries (classified and reduced
    /// per hypothesis) per second: the GPU kernel, upload to completion.
    pub gpu_queries_per_s: Option<f64>,
    /// The same queries on the CPU twin (grid + exact refinement near ±ε).
    pub cpu_queries_per_s: f64,
    /// Complete evaluations per second (queries, readback, exact
    /// refinement of flagged samples, support polygons).
    pub gpu_hyps_per_s: Option<f64>,
    pub cpu_hyps_per_s: f64,
    /// Fraction of samples the GPU left to exact refinement on the CPU.
    pub refined_fraction: Option<f64>,
    pub cpu_threads: usize,
    pub timing: &'static str,
    pub machine: super::machine::Machine,
}

/// Sample-hypothesis queries one configuration may hold at once: the CPU
/// twin keeps about 9 bytes per query (measured: 8.8 GB for `--n 1000000`
/// at 1024 samples), so this bounds it to about 2.4 GB.
const MAX_QUERIES: usize = 1 << 28;

pub fn bench_physics(a: BenchPhysicsArgs, verbose: u8) -> Result<()> {
    if a.n * a.samples > MAX_QUERIES {
        anyhow::bail!(
            "--n {} x --samples {} = {} sample-hypothesis queries: at most {MAX_QUERIES} (the CPU twin keeps about 9 bytes per query); lower --n or --samples",
            a.n,
            a.samples,
            a.n * a.samples
        );
    }
    let device = a.device.open(verbose, true)?;
    let (adapter, backend) = match &device {
        Device::Gpu(c) => (c.info.name.clone(), format!("{:?}", c.info.backend)),
        Device::Cpu => ("none".to_string(), "none".to_string()),
    };
    let repeat = a.repeat.max(1);
    let w = Workload::new(a.n, a.samples, a.seed)?;
    let queries = (a.n * w.body.samples.len()) as f64;
    let machine = super::machine::Machine::detect(Some(&device));
    if !a.json {
        println!("machine: {}", machine.line());
        println!(
            "adapter: {adapter} ({backend}); CPU twin on {} threads; N = {} x {} samples; wall clock, median of {repeat}",
            rayon::current_num_threads(),
            a.n,
            w.body.samples.len()
        );
        println!(
            "{:>15} {:>14} {:>14} {:>8} {:>11} {:>11} {:>9}",
            "scene", "gpu queries/s", "cpu queries/s", "gpu/cpu", "gpu hyp/s", "cpu hyp/s", "refined"
        );
    }
    for (name, poses, env) in w.scenes() {
        let mut row = PhysicsBenchRow {
            adapter: adapter.clone(),
            backend: backend.clone(),
            scene: name.to_string(),
            n: a.n,
            samples: w.body.samples.len(),
            grid_nodes: env.obstacles.iter().map(|o| o.sdf.nodes.len()).sum(),
            gpu_queries_per_s: None,
            cpu_queries_per_s: 0.0,
            gpu_hyps_per_s: None,
            cpu_hyps_per_s: 0.0,
            refined_fraction: None,
            cpu_threads: rayon::current_num_threads(),
            timing: "wall clock, median of repeats after a warm-up",
            machine: machine.clone(),
        };
        if let Device::Gpu(ctx) = &device {
            measure_gpu(ctx, &w.body, poses, &env, repeat, queries, &mut row)?;
        }
        measure_cpu(&w.body, poses, &env, repeat, queries, &mut row);
        if a.json {
            println!("{}", serde_json::to_string(&row)?);
        } else {
            print_row(&row);
        }
    }
    Ok(())
}

/// The benchmark's body (a 5 cm cube), obstacle (the duck scaled to a
/// 0.15 m diagonal, resting on the plane) and two sets of hypotheses.
struct Workload {
    body: Body,
    grid: Arc<SdfGrid>,
    duck_pose: Pose,
    /// Random rotations, positions over and around the duck (its bounding
    /// box grown by 2 cm), so most samples query the grid.
    anywhere: Vec<Pose>,
    /// Near contact (the ranking use case): the cube resting on the plane
    /// in and around the duck's footprint, tilted up to 25°, lowest corner
    /// within ±4 mm of the plane.
    near: Vec<Pose>,
}

impl Workload {
    fn new(n: usize, samples: usize, seed: u64) -> Result<Workload> {
        let cube = plausible::shapes::cuboid(DVec3::splat(0.025));
        let body = Body::new(&cube, samples, seed, None)?;
        let duck: Mesh = Mesh::load(super::asset("assets/pybullet/duck.obj")?, MeshUnits::Metres)?.0.normalized(0.15);
        let grid = Arc::new(SdfGrid::bake(&duck, DEFAULT_RESOLUTION)?);
        let (lo, hi) = duck.bounds();
        let duck_pose = Pose::new(DMat3::IDENTITY, DVec3::new(0.0, 0.0, -lo.z));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let anywhere: Vec<Pose> = (0..n)
            .map(|_| {
                let r = plausible::hypotheses::random_rotation(&mut rng);
                let p = DVec3::new(
                    rng.random_range(lo.x - 0.02..hi.x + 0.02),
                    rng.random_range(lo.y - 0.02..hi.y + 0.02),
                    rng.random_range(0.0..(hi.z - lo.z) + 0.02),
                );
                Pose::new(r, p)
            })
            .collect();
        let near: Vec<Pose> = (0..n)
            .map(|_| {
                let axis = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.0);
                let r = plausible::pose::axis_angle(DVec3::Z, rng.random_range(0.0..std::f64::consts::TAU))
                    * plausible::pose::axis_angle(axis, rng.random_range(0.0..25f64.to_radians()));
                let low = cube.vertices.iter().map(|v| (r * *v).z).fold(f64::INFINITY, f64::min);
                let p = DVec3::new(
                    rng.random_range(lo.x - 0.04..hi.x + 0.04),
                    rng.random_range(lo.y - 0.04..hi.y + 0.04),
                    -low + rng.random_range(-0.004..0.004),
                );
                Pose::new(r, p)
            })
            .collect();
        Ok(Workload { body, grid, duck_pose, anywhere, near })
    }

    /// The three scenes: the plane alone, plane and duck, and plane and
    /// duck with the near-contact hypotheses.
    fn scenes(&self) -> [(&'static str, &[Pose], Environment); 3] {
        let plane = Plane { point: DVec3::ZERO, normal: DVec3::Z };
        let g = DVec3::new(0.0, 0.0, -9.81);
        let with_duck = || Environment {
            planes: vec![plane],
            obstacles: vec![Obstacle { sdf: self.grid.clone(), pose: self.duck_pose }],
            gravity: g,
        };
        [
            ("plane", &self.anywhere, Environment { planes: vec![plane], obstacles: vec![], gravity: g }),
            ("plane+mesh", &self.anywhere, with_duck()),
            ("plane+mesh/near", &self.near, with_duck()),
        ]
    }
}

/// The GPU kernel's queries per second (kernel time) and hypotheses per
/// second (with the CPU finish), medians of `repeat` after a warm-up.
fn measure_gpu(
    ctx: &plausible::gpu::Context,
    body: &Body,
    poses: &[Pose],
    env: &Environment,
    repeat: usize,
    queries: f64,
    row: &mut PhysicsBenchRow,
) -> Result<()> {
    let gpu = GpuContacts::new(ctx, body, env, poses.len(), false)?;
    let warm = gpu.run(poses)?; // first submit compiles and is slower
    row.refined_fraction = Some(gpu.refined_count(&warm) as f64 / queries);
    let mut kernel = Vec::new();
    let mut full = Vec::new();
    for _ in 0..repeat {
        let t = Instant::now();
        let out = gpu.run(poses)?;
        let ev = gpu.finish(poses, &out);
        full.push(t.elapsed());
        kernel.push(out.compute);
        std::hint::black_box(ev);
    }
    row.gpu_queries_per_s = Some(queries / median(kernel).as_secs_f64());
    row.gpu_hyps_per_s = Some(poses.len() as f64 / median(full).as_secs_f64());
    Ok(())
}

/// The CPU twin's queries and complete evaluations per second.
fn measure_cpu(body: &Body, poses: &[Pose], env: &Environment, repeat: usize, queries: f64, row: &mut PhysicsBenchRow) {
    let mut cq = Vec::new();
    let mut ch = Vec::new();
    for _ in 0..repeat {
        let t = Instant::now();
        std::hint::black_box(distances_batch(body, poses, env));
        cq.push(t.elapsed());
        let t = Instant::now();
        std::hint::black_box(evaluate_batch(body, poses, env));
        ch.push(t.elapsed());
    }
    row.cpu_queries_per_s = queries / median(cq).as_secs_f64();
    row.cpu_hyps_per_s = poses.len() as f64 / median(ch).as_secs_f64();
}

/// One table row.
fn print_row(row: &PhysicsBenchRow) {
    let opt = |v: Option<f64>, unit: f64| v.map(|x| format!("{:.1}", x / unit)).unwrap_or_else(|| "-".into());
    println!(
        "{:>15} {:>13}M {:>13}M {:>8} {:>11} {:>11.0} {:>8}%",
        row.scene,
        opt(row.gpu_queries_per_s, 1e6),
        format!("{:.1}", row.cpu_queries_per_s / 1e6),
        row.gpu_queries_per_s.map(|g| format!("{:.1}x", g / row.cpu_queries_per_s)).unwrap_or_else(|| "-".into()),
        opt(row.gpu_hyps_per_s, 1.0),
        row.cpu_hyps_per_s,
        opt(row.refined_fraction.map(|f| f * 100.0), 1.0),
    );
}
