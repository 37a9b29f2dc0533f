//! `plausible bench`: throughput of the GPU path and its CPU twin, measured
//! side by side in the same run (wall clock; the first submit is excluded
//! by a warm-up, and each figure is the median of `--repeat` runs; `bench
//! score` alternates the GPU's runs with the twin's, so the two are timed in
//! the same moments of a machine whose speed drifts).

use std::time::{Duration, Instant};

use anyhow::{Context as _, Result};
use glam::DVec3;
use plausible::camera::Intrinsics;
use plausible::hypotheses::around_and_random;
use plausible::kernels::score::{score_cpu, GpuScorer, ScoreKernel, ScoreParams};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::physical::batch::PlanePhysics;
use plausible::physical::samples::{DEFAULT_SAMPLES, DEFAULT_SEED};
use plausible::synth::{linemod_camera, observe, plane_under, SensorNoise};
use plausible::visual::{score_poses_with_physics, scoring_mesh, Device, LodChoice};
use serde::Serialize;

use super::DeviceArgs;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub kind: BenchKind,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchKind {
    /// Visual scoring: hypotheses/s for several batch sizes, resolutions and meshes.
    Score(BenchScoreArgs),
    /// Stable-pose drop tests: drops/s, steps per drop, settle rate, clusters.
    Stable(super::stable::BenchStableArgs),
    /// Physical plausibility: signed-distance queries/s against a plane and a mesh grid.
    Physics(super::bench_physics::BenchPhysicsArgs),
    /// BOP evaluation: estimates/s for VSD, MSSD + MSPD and the BOP'19 set.
    Eval(super::bench_eval::BenchEvalArgs),
    /// Refinement and estimation over BOP frames: seconds per image by stage.
    Estimate(super::bench_estimate::BenchEstimateArgs),
}

#[derive(clap::Args, Debug)]
pub struct BenchScoreArgs {
    /// Print JSON (one object per configuration) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Timed runs per configuration (the median is reported); the GPU's and
    /// the twin's alternate, and gpu/cpu is the median of their pairs' ratios.
    #[arg(long, default_value_t = 3, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub repeat: usize,
    /// Only the 4k-triangle mesh and N <= 1024 (a quick look).
    #[arg(long)]
    pub quick: bool,
    /// Benchmark these meshes instead of the shipped ones (repeatable).
    /// Kept at their real size (`--units`), unlike the shipped meshes,
    /// which are scaled to a 0.15 m diagonal.
    #[arg(long)]
    pub mesh: Vec<std::path::PathBuf>,
    /// Units of the `--mesh` files: m, cm, mm or auto (above 5 m: mm).
    #[arg(long, default_value = "auto")]
    pub units: MeshUnits,
    /// Skip the CPU twin (not recommended: figures are meant side by side).
    #[arg(long)]
    pub no_cpu: bool,
    /// Also time scoring with the physical terms against a support plane
    /// (`score --plane --physics`: fused on the GPU, support polygons
    /// finished on the CPU; the twins on the CPU), end to end.
    #[arg(long)]
    pub physics: bool,
    /// Levels of detail of the scored mesh to measure (repeatable): `off`
    /// (the full mesh), `auto` (within a quarter of a pixel at the object) or a
    /// triangle count; every configuration is measured with each.
    #[arg(long, default_value = "off")]
    pub lod: Vec<LodChoice>,
    /// Renderers to measure (repeatable), on the GPU and the CPU alike:
    /// `auto` (the ray caster above a few triangles per region pixel on the
    /// CPU, above the rasterizer's meshlet budget on the GPU), `raster` or
    /// `bvh` (ray casting through a CWBVH).
    #[arg(long, default_value = "auto")]
    pub renderer: Vec<plausible::kernels::RendererChoice>,
    /// GPU score kernels to measure (repeatable), each a row beside the same
    /// CPU figures: `auto` (`lanes` on a software adapter where the mesh
    /// and region fit its loop budget, else `workgroups`), `workgroups` (a
    /// workgroup per hypothesis, pixels drawn with atomics: the kernel for
    /// hardware GPUs) or `lanes` (an invocation per hypothesis: for
    /// lavapipe, whose atomics run lane by lane)
    #[arg(long, value_enum, default_value = "auto")]
    pub kernel: Vec<KernelArg>,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// `--kernel` values ([`ScoreKernel`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum KernelArg {
    Auto,
    Workgroups,
    Lanes,
}

impl From<KernelArg> for ScoreKernel {
    fn from(k: KernelArg) -> Self {
        match k {
            KernelArg::Auto => ScoreKernel::Auto,
            KernelArg::Workgroups => ScoreKernel::Workgroups,
            KernelArg::Lanes => ScoreKernel::Lanes,
        }
    }
}

#[derive(Serialize, Debug)]
pub struct ScoreBenchRow {
    pub adapter: String,
    pub backend: String,
    pub mesh: String,
    /// Triangles scored (after the level of detail) and of the full mesh.
    pub triangles: usize,
    pub mesh_triangles: usize,
    pub lod: String,
    /// Geometric error of the scored mesh against the full one (mm).
    pub lod_error_mm: f64,
    /// The CPU twin's and the GPU's renderer (`raster` or `bvh`) and how
    /// they were chosen.
    pub cpu_renderer: String,
    pub gpu_renderer: String,
    pub renderer_choice: String,
    /// The GPU score kernel (`workgroups` or `lanes`; the ray caster has
    /// its own) and the one asked for.
    pub gpu_kernel: String,
    pub kernel_choice: String,
    pub n: usize,
    pub width: u32,
    pub height: u32,
    pub gpu_hyps_per_s: Option<f64>,
    pub cpu_hyps_per_s: Option<f64>,
    /// GPU against the twin: the median of the ratios of runs made in
    /// pairs, one right after the other (None where they were not paired).
    pub gpu_cpu: Option<f64>,
    /// Every timed run's rate, in the order run (the figures above are
    /// their medians): the spread shows a noisy machine, or a device that
    /// swings where the other does not.
    pub gpu_runs_hyps_per_s: Vec<f64>,
    pub cpu_runs_hyps_per_s: Vec<f64>,
    pub cpu_threads: usize,
    /// With --physics: visual score + physical terms, end to end.
    pub gpu_physics_hyps_per_s: Option<f64>,
    pub cpu_physics_hyps_per_s: Option<f64>,
    pub upload_ms: Option<f64>,
    pub render_ms: Option<f64>,
    pub reduce_ms: Option<f64>,
    pub readback_ms: Option<f64>,
    /// Compute pass time from GPU timestamp queries (where the adapter has them).
    pub gpu_timestamp_compute_ms: Option<f64>,
    pub timing: &'static str,
    pub machine: super::machine::Machine,
}

/// Runs one benchmark. With `--trace` its span is the trace's root; `bench
/// score` adds a span per configuration and per device measured, with the
/// library's stage spans (upload, dispatch, readback, cpu_twin) inside.
#[tracing::instrument(name = "plausible bench", level = "trace", skip_all)]
pub fn run(a: BenchArgs, verbose: u8) -> Result<()> {
    match a.kind {
        BenchKind::Score(s) => bench_score(s, verbose),
        BenchKind::Stable(s) => super::stable::bench_stable(s),
        BenchKind::Physics(p) => super::bench_physics::bench_physics(p, verbose),
        BenchKind::Eval(e) => super::bench_eval::bench_eval(e, verbose),
        BenchKind::Estimate(e) => super::bench_estimate::bench_estimate(e, verbose),
    }
}

/// The upper median of timed runs (durations or rates; at least one).
pub(super) fn median<T: Copy + PartialOrd>(mut v: Vec<T>) -> T {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
    v[v.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The demo's view of a mesh of any size and origin: its bounding-box
/// centre on the demo's line of sight, as far away per metre of diagonal as
/// the 0.15 m duck at 0.7 m, and never nearer than that.
fn framed(base: &plausible::pose::Pose, mesh: &Mesh) -> plausible::pose::Pose {
    let (lo, hi) = mesh.bounds();
    let scale = (mesh.diagonal() / 0.15).max(1.0);
    plausible::pose::Pose::new(base.r, base.t * scale - base.r * ((lo + hi) / 2.0))
}

/// The benchmark meshes: ~1k, ~4k and ~100k triangles, all scaled to a
/// 0.15 m diagonal. The 100k mesh is the duck with every triangle split in
/// 25 (same surface, 25x the triangles).
pub fn bench_meshes(quick: bool) -> Result<Vec<(String, Mesh)>> {
    let load = |rel: &str| -> Result<Mesh> { Ok(Mesh::load(super::asset(rel).context("--mesh")?, MeshUnits::Metres)?.0.normalized(0.15)) };
    let duck = load("assets/pybullet/duck.obj")?;
    if quick {
        return Ok(vec![("duck".into(), duck)]);
    }
    let bunny = load("assets/pybullet/bunny.obj")?;
    let dense = duck.subdivided(5);
    Ok(vec![("bunny".into(), bunny), ("duck".into(), duck), ("duck/25".into(), dense)])
}

fn bench_score(mut a: BenchScoreArgs, verbose: u8) -> Result<()> {
    super::bench_eval::check_no_cpu(&a.device.device, a.no_cpu)?;
    if a.mesh.is_empty() && a.units != plausible::mesh::MeshUnits::Auto {
        anyhow::bail!("--units {:?} is for --mesh files; the shipped meshes are scaled to a 0.15 m diagonal", a.units);
    }
    // A repeated --lod or --renderer would only measure the same row twice.
    a.lod = distinct(&a.lod);
    a.renderer = distinct(&a.renderer);
    a.kernel = distinct(&a.kernel);
    let device = a.device.open(verbose, true)?;
    let (adapter, backend) = match &device {
        Device::Gpu(c) => (c.info.name.clone(), format!("{:?}", c.info.backend)),
        Device::Cpu => ("none".to_string(), "none".to_string()),
    };
    let base_truth = crate::cli::demo::demo_true_pose();
    let k = linemod_camera();
    let params = ScoreParams::default();
    let repeat = a.repeat.max(1);
    let mut configs: Vec<(usize, RoiSampling)> = vec![(256, RoiSampling::Square(128)), (1024, RoiSampling::Square(128))];
    if !a.quick {
        configs.push((4096, RoiSampling::Square(128)));
        configs.push((64, RoiSampling::FullFrame));
    }
    let meshes = if a.mesh.is_empty() {
        bench_meshes(a.quick)?
    } else {
        a.mesh
            .iter()
            .map(|p| {
                let name = p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into_owned());
                Ok((name, Mesh::load(p, a.units).with_context(|| format!("--mesh {}", p.display()))?.0))
            })
            .collect::<Result<Vec<_>>>()?
    };
    let mut rows = Vec::new();
    let machine = super::machine::Machine::detect(Some(&device));
    if !a.json {
        println!("machine: {}", machine.line());
        println!(
            "adapter: {adapter} ({backend}); CPU twin on {} threads; wall clock, median of {repeat}; GPU and twin runs alternate, gpu/cpu = median ratio of the pairs",
            rayon::current_num_threads()
        );
        print!(
            "{:>8} {:>5} {:>8} {:>6} {:>9} {:>12} {:>12} {:>7} {:>7} {:>7} {:>9} {:>9} {:>9} {:>9}",
            "mesh", "lod", "tris", "N", "region", "gpu hyp/s", "cpu hyp/s", "gpu ren", "cpu ren", "gpu/cpu", "upload", "render", "reduce", "readback"
        );
        if a.physics {
            print!(" {:>13} {:>13}", "gpu+phys h/s", "cpu+phys h/s");
        }
        println!();
    }
    let framing = !a.mesh.is_empty();
    for (name, mesh) in meshes {
        let rmesh = RenderMesh::new(&mesh)?;
        // A mesh of the user's, at its real size and origin, is seen as the
        // demo sees the duck (the shipped ones keep the demo's pose, so
        // figures stay comparable across versions).
        let truth = if framing { framed(&base_truth, &mesh) } else { base_truth };
        let (obs, mask) = observe(&rmesh, &truth, &k, SensorNoise::default(), 1);
        if !mask.contains(&true) {
            anyhow::bail!("--mesh {name}: no pixel of it is seen ({:.3} mm across, {:.2} m from the camera): are its units right (--units)?", mesh.diagonal() * 1e3, truth.t.length());
        }
        // A support plane under the true pose (normal up and towards the
        // camera, through the lowest vertex), so the perturbed hypotheses
        // mix contacts, floating and intersecting ones.
        let physics = if a.physics {
            let plane = plane_under(&mesh, &truth, DVec3::new(0.0, -1.0, -0.6));
            Some(PlanePhysics::new(&mesh, &plane, None, DEFAULT_SAMPLES, DEFAULT_SEED, None)?)
        } else {
            None
        };
        for &(n, sampling) in &configs {
            let _span = tracing::trace_span!("config", mesh = %name, hypotheses = n, sampling = ?sampling).entered();
            let target = ScoreTarget::new(&obs, Some(&mask), sampling, DEFAULT_ROI_MARGIN)?;
            let poses = around_and_random(&truth, n, 7);
            let ti: Intrinsics = target.intrinsics;
            for &lod in &a.lod {
                let scoring = scoring_mesh(&mesh, lod, &target)?;
                for &renderer in &a.renderer {
                    let mut rmesh = RenderMesh::new(&scoring.mesh)?;
                    rmesh.renderer = renderer;
                    let twin = (!a.no_cpu).then_some(Twin { rmesh: &rmesh, target: &target, params, poses: &poses });
                    for &kernel in &a.kernel {
                        let mut row = ScoreBenchRow {
                            adapter: adapter.clone(),
                            backend: backend.clone(),
                            mesh: name.clone(),
                            triangles: scoring.mesh.triangles.len(),
                            mesh_triangles: mesh.triangles.len(),
                            lod: lod.to_string(),
                            lod_error_mm: scoring.error_m * 1e3,
                            cpu_renderer: cpu_renderer_at(&rmesh, &truth, &ti).to_string(),
                            gpu_renderer: rmesh.gpu_renderer().to_string(),
                            renderer_choice: format!("{renderer:?}").to_lowercase(),
                            gpu_kernel: "-".into(),
                            kernel_choice: format!("{kernel:?}").to_lowercase(),
                            n,
                            width: ti.width,
                            height: ti.height,
                            gpu_hyps_per_s: None,
                            cpu_hyps_per_s: None,
                            gpu_cpu: None,
                            gpu_runs_hyps_per_s: Vec::new(),
                            cpu_runs_hyps_per_s: Vec::new(),
                            cpu_threads: rayon::current_num_threads(),
                            gpu_physics_hyps_per_s: None,
                            cpu_physics_hyps_per_s: None,
                            upload_ms: None,
                            render_ms: None,
                            reduce_ms: None,
                            readback_ms: None,
                            gpu_timestamp_compute_ms: None,
                            timing: "wall clock",
                            machine: machine.clone(),
                        };
                        let mut paired = false;
                        if let Device::Gpu(ctx) = &device {
                            // A mesh past the kernels' loop budget is refused, not
                            // benchmarked: the row keeps its CPU figures.
                            match plausible::kernels::check_gpu_budget(ctx, &rmesh, ti.pixels()) {
                                Ok(()) => {
                                    paired = tracing::trace_span!("gpu").in_scope(|| {
                                        measure_gpu(ctx, &rmesh, &target, params, &poses, repeat, kernel.into(), twin.as_ref(), &mut row)
                                    })?
                                }
                                Err(e) => eprintln!("{name}: GPU not measured: {e}"),
                            }
                        }
                        if let (false, Some(twin)) = (paired, &twin) {
                            tracing::trace_span!("cpu").in_scope(|| twin.measure(repeat, &mut row));
                        }
                        if let Some(physics) = &physics {
                            let _span = tracing::trace_span!("physics").entered();
                            measure_physics(&device, !a.no_cpu, physics, &rmesh, &target, params, &poses, repeat, &mut row)?;
                        }
                        if a.json {
                            println!("{}", serde_json::to_string(&row)?);
                        } else {
                            print_row(&row, a.physics);
                        }
                        rows.push(row);
                    }
                }
            }
        }
    }
    if !a.json {
        println!("(stage times in ms for the whole batch, wall clock; render = rasterization alone, reduce = fused kernel minus render;");
        if a.physics {
            println!(" +phys = visual score and physical terms against a support plane, 1024 samples, end to end: fused kernel + support polygons on the CPU;");
        }
        println!(
            " --json adds gpu_timestamp_compute_ms from GPU timestamp queries where the adapter has them: on lavapipe they are unreliable)"
        );
    }
    Ok(())
}

/// The GPU rows of a configuration: end to end (median of `repeat`), the
/// rasterization alone, and timestamps in a separate run. With a `twin`,
/// its runs alternate with the GPU's (see [`Twin`]) and the row gets both;
/// returns whether it did.
#[allow(clippy::too_many_arguments)] // one call site
fn measure_gpu(
    ctx: &plausible::gpu::Context,
    rmesh: &RenderMesh,
    target: &ScoreTarget,
    params: ScoreParams,
    poses: &[plausible::pose::Pose],
    repeat: usize,
    kernel: ScoreKernel,
    twin: Option<&Twin<'_>>,
    row: &mut ScoreBenchRow,
) -> Result<bool> {
    let n = poses.len();
    let mut scorer = GpuScorer::new(ctx, rmesh, target, params, n)?;
    if let Err(e) = scorer.set_kernel(kernel) {
        eprintln!("{}: GPU not measured: {e}", row.mesh);
        return Ok(false);
    }
    if !scorer.ray_casts() {
        row.gpu_kernel = format!("{:?}", scorer.kernel()).to_lowercase();
    }
    scorer.score(poses)?; // warm-up
    if let Some(twin) = twin {
        twin.warm_up();
    }
    let mut runs = Vec::new();
    let mut cpu_runs = Vec::new();
    for r in 0..repeat {
        // GPU then twin in even rounds, twin then GPU in odd ones (ABBA):
        // each pair runs in the same second of the machine's life, and a
        // drift in its speed falls on both alike.
        let twin_first = r % 2 == 1;
        if let (true, Some(twin)) = (twin_first, twin) {
            cpu_runs.push(twin.run());
        }
        let t = Instant::now();
        let (_, st) = scorer.score(poses)?;
        runs.push((t.elapsed(), st));
        if let (false, Some(twin)) = (twin_first, twin) {
            cpu_runs.push(twin.run());
        }
    }
    row.gpu_runs_hyps_per_s = runs.iter().map(|r| n as f64 / r.0.as_secs_f64()).collect();
    if twin.is_some() {
        let ratios = row.gpu_runs_hyps_per_s.iter().zip(&cpu_runs).map(|(g, c)| g / c).collect();
        row.gpu_cpu = Some(median(ratios));
        row.cpu_hyps_per_s = Some(median(cpu_runs.clone()));
        row.cpu_runs_hyps_per_s = cpu_runs;
    }
    runs.sort_by_key(|r| r.0);
    let (total, st) = runs[runs.len() / 2];
    let render = (0..repeat).map(|_| scorer.raster_only(poses)).collect::<Result<Option<Vec<_>>, _>>()?.map(median);
    row.gpu_hyps_per_s = Some(n as f64 / total.as_secs_f64());
    row.upload_ms = Some(ms(st.upload));
    // The ray caster's render and reduce are separate dispatches, not
    // timed apart: its whole pass counts as render.
    row.render_ms = Some(ms(render.map_or(st.compute, |r| r.min(st.compute))));
    row.reduce_ms = render.map(|r| ms(st.compute.saturating_sub(r)));
    row.readback_ms = Some(ms(st.readback));
    // Timestamps in a separate run, so their readback does not
    // disturb the wall-clock figures.
    if scorer.set_timestamps(true) {
        row.gpu_timestamp_compute_ms = scorer.score(poses)?.1.gpu_compute.map(ms);
        scorer.set_timestamps(false);
    }
    Ok(true)
}

/// The CPU twin on one configuration. Its timed runs alternate with the
/// GPU's when both are measured: this VM's vCPUs change speed by up to
/// 1.7x within a second (a plain spin loop shows it), so medians taken a
/// few seconds apart compared the machine's states, not the devices.
struct Twin<'a> {
    rmesh: &'a RenderMesh,
    target: &'a ScoreTarget,
    params: ScoreParams,
    poses: &'a [plausible::pose::Pose],
}

impl Twin<'_> {
    fn warm_up(&self) {
        score_cpu(self.rmesh, self.target, &self.poses[..self.poses.len().min(16)], &self.params);
    }

    /// One timed run: hypotheses per second.
    fn run(&self) -> f64 {
        let t = Instant::now();
        score_cpu(self.rmesh, self.target, self.poses, &self.params);
        self.poses.len() as f64 / t.elapsed().as_secs_f64()
    }

    /// The twin alone (no GPU row to pair with): `repeat` runs, their
    /// median and each, in the order run.
    fn measure(&self, repeat: usize, row: &mut ScoreBenchRow) {
        self.warm_up();
        row.cpu_runs_hyps_per_s = (0..repeat).map(|_| self.run()).collect();
        row.cpu_hyps_per_s = Some(median(row.cpu_runs_hyps_per_s.clone()));
    }
}

/// Visual score and physical terms end to end, GPU and CPU twin. Like the
/// visual rows: the scorer is made once, then each run scores, computes the
/// physical terms and finishes them.
#[allow(clippy::too_many_arguments)]
fn measure_physics(
    device: &Device,
    cpu: bool,
    physics: &PlanePhysics,
    rmesh: &RenderMesh,
    target: &ScoreTarget,
    params: ScoreParams,
    poses: &[plausible::pose::Pose],
    repeat: usize,
    row: &mut ScoreBenchRow,
) -> Result<()> {
    let n = poses.len();
    let time = |run: &dyn Fn() -> Result<()>| -> Result<f64> {
        run()?; // warm-up
        let mut runs = Vec::new();
        for _ in 0..repeat {
            let t = Instant::now();
            run()?;
            runs.push(t.elapsed());
        }
        Ok(n as f64 / median(runs).as_secs_f64())
    };
    if let Device::Gpu(ctx) = device {
        let scorer = physics.gpu_scorer(ctx, rmesh, target, params, n)?;
        row.gpu_physics_hyps_per_s = Some(time(&|| {
            let (_, contacts, _) = scorer.score_with_physics(poses, |_| {})?;
            physics.finish_fused(poses, &contacts.records, &contacts.bits);
            Ok(())
        })?);
    }
    if cpu {
        row.cpu_physics_hyps_per_s = Some(time(&|| {
            score_poses_with_physics(&Device::Cpu, rmesh, target, poses, params, physics, |_| {})?;
            Ok(())
        })?);
    }
    Ok(())
}

/// The values of `v` in their first order, each once.
fn distinct<T: PartialEq + Copy>(v: &[T]) -> Vec<T> {
    v.iter().enumerate().filter(|(i, x)| !v[..*i].contains(x)).map(|(_, x)| *x).collect()
}

/// The CPU renderer the mesh gets at the true pose (hypotheses around it
/// get the same, or the other near the crossover).
fn cpu_renderer_at(rmesh: &RenderMesh, pose: &plausible::pose::Pose, k: &Intrinsics) -> plausible::kernels::CpuRenderer {
    plausible::kernels::raster::cpu_renderer_at(rmesh, &pose.into(), k).unwrap_or(plausible::kernels::CpuRenderer::Raster)
}

/// One table row.
fn print_row(row: &ScoreBenchRow, physics: bool) {
    let f = |v: Option<f64>, p: usize| v.map(|x| format!("{x:.p$}")).unwrap_or_else(|| "-".into());
    let ratio = row.gpu_cpu.map_or_else(|| "-".into(), |r| format!("{r:.2}x"));
    print!(
        "{:>8} {:>5} {:>8} {:>6} {:>9} {:>12} {:>12} {:>7} {:>7} {:>7} {:>9} {:>9} {:>9} {:>9}",
        row.mesh,
        row.lod,
        row.triangles,
        row.n,
        format!("{}x{}", row.width, row.height),
        f(row.gpu_hyps_per_s, 0),
        f(row.cpu_hyps_per_s, 0),
        if row.gpu_kernel == "lanes" { "lanes" } else { &row.gpu_renderer },
        row.cpu_renderer,
        ratio,
        f(row.upload_ms, 2),
        f(row.render_ms, 2),
        f(row.reduce_ms, 2),
        f(row.readback_ms, 2)
    );
    if physics {
        print!(" {:>13} {:>13}", f(row.gpu_physics_hyps_per_s, 0), f(row.cpu_physics_hyps_per_s, 0));
    }
    println!();
}
