//! `plausible bench eval`: BOP evaluation throughput (estimates/s) for VSD,
//! MSSD + MSPD, the whole BOP'19 set and BOP'24 detection, GPU and CPU twin
//! side by side in the same run, on the shipped LM-O frames (or any dataset);
//! and BOP's 2D tasks (COCO results), which run on the CPU.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context as _, Result};
use plausible::bop::{read_results, Dataset};
use plausible::eval::{evaluate, ErrorType, EvalOptions, Task};
use plausible::visual::Device;
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct BenchEvalArgs {
    /// BOP dataset (default: the shipped 12-frame LM-O subset).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Results file (default: the shipped perturbed estimates).
    #[arg(long)]
    pub results: Option<PathBuf>,
    /// BOP dataset name (lmo, tless, hot3d, ...) for the toolkit's
    /// per-dataset settings; default: the dataset folder's name when it is one.
    #[arg(long)]
    pub dataset_name: Option<String>,
    /// COCO results for the 2D detection and segmentation rows (default:
    /// the dataset's coco.json when it has one, as the shipped subset does;
    /// without one those rows are left out).
    #[arg(long)]
    pub coco_results: Option<PathBuf>,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Timed runs per row (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Print JSON (one object per row) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Skip the CPU twin (not recommended: figures are meant side by side).
    #[arg(long)]
    pub no_cpu: bool,
    /// The device measured beside the CPU twin: `gpu` (any wgpu adapter,
    /// lavapipe included) or `cpu` (the twin alone).
    #[arg(long, default_value = "gpu", value_parser = ["gpu", "cpu"])]
    pub device: String,
    /// With `--device gpu`: the first adapter whose name contains this text.
    #[arg(long)]
    pub adapter: Option<String>,
}

#[derive(Serialize, Debug)]
pub struct EvalBenchRow {
    pub what: String,
    pub device: String,
    pub estimates: usize,
    pub images: usize,
    pub estimates_per_s: f64,
    pub wall_s: f64,
    pub render_s: f64,
    pub ar: Option<f64>,
    pub machine: super::machine::Machine,
}

/// Refuses `--no-cpu` with `--device cpu`: nothing would be measured.
pub fn check_no_cpu(device: &str, no_cpu: bool) -> Result<()> {
    if no_cpu && device == "cpu" {
        anyhow::bail!("--no-cpu with --device cpu leaves nothing to measure");
    }
    Ok(())
}

/// The device measured and, unless `no_cpu` or it is the twin already,
/// the CPU twin beside it, in that order.
pub fn side_by_side(device: &str, adapter: Option<&str>, no_cpu: bool, verbose: u8) -> Result<Vec<Device>> {
    check_no_cpu(device, no_cpu)?;
    let mut devices = vec![super::open_device(device, adapter, verbose, true)?];
    if !no_cpu && !matches!(devices[0], Device::Cpu) {
        devices.push(Device::Cpu);
    }
    Ok(devices)
}

pub fn bench_eval(a: BenchEvalArgs, verbose: u8) -> Result<()> {
    if a.repeat == 0 || a.repeat > 1000 {
        anyhow::bail!("--repeat must be between 1 and 1000");
    }
    let root = match &a.dataset {
        Some(d) => d.clone(),
        None => super::asset("assets/lmo-synth").context("--dataset")?,
    };
    let results_path = a.results.clone().unwrap_or_else(|| root.join("perturbed.csv"));
    let name = plausible::eval::toolkit_dataset_name(&root, a.dataset_name.as_deref()).context("--dataset-name")?;
    let ds = plausible::eval::open_dataset(&root, &a.split, None, name.as_deref()).context("--dataset")?;
    let results = read_results(&results_path).context("--results")?;
    let devices = super::bench_eval::side_by_side(&a.device, a.adapter.as_deref(), a.no_cpu, verbose)?;
    let local = |errors: Vec<ErrorType>| EvalOptions { errors, ..Default::default() };
    let mut sets: Vec<(&str, EvalOptions)> = vec![
        ("vsd", local(vec![ErrorType::Vsd])),
        ("mssd+mspd", local(vec![ErrorType::Mssd, ErrorType::Mspd])),
        ("bop19 (vsd+mssd+mspd)", local(ErrorType::BOP19.to_vec())),
        ("bop24 detection", EvalOptions::detection(name.as_deref())),
    ];
    if !pinhole_cameras(&ds)? {
        eprintln!("note: {} has lens cameras (cam_model): VSD needs a pinhole, its rows are left out", root.display());
        sets.retain(|(_, o)| !o.errors.contains(&ErrorType::Vsd));
    }
    let mut rows = pose_rows(&ds, &results, &sets, &devices, a.repeat)?;
    if a.dataset.is_none() {
        // HOT3D's fisheyes: MSPD through the lens model (an arctan and a
        // polynomial per point) beside the pinhole rows above.
        let hot3d = super::asset("assets/hot3d-synth").context("the shipped HOT3D-layout dataset")?;
        let ds = plausible::eval::open_dataset(&hot3d, "test", None, Some("hot3d"))?;
        let results = read_results(&hot3d.join("estimates.csv"))?;
        let sets = [("bop24 det. hot3d fisheye", EvalOptions::detection(Some("hot3d")))];
        rows.extend(pose_rows(&ds, &results, &sets, &devices, a.repeat)?);
    }
    let coco = a.coco_results.clone().or_else(|| Some(root.join("coco.json")).filter(|p| p.is_file()));
    if let Some(p) = coco {
        rows.extend(bench_coco(&ds, &p, name.as_deref(), a.repeat)?);
    }
    if a.json {
        for r in &rows {
            println!("{}", serde_json::to_string(r)?);
        }
        return Ok(());
    }
    println!("machine: {}", super::machine::Machine::detect(devices.first()).line());
    if rows[0].estimates == 0 {
        eprintln!("warning: {} holds no estimate of the dataset's targets: nothing was evaluated", results_path.display());
    }
    println!("{} ({} images; wall clock, median of {})", root.display(), rows[0].images, a.repeat);
    println!("{:<24} {:<44} {:>9} {:>12} {:>9} {:>9}", "task (errors)", "device", "estimates", "estimates/s", "wall s", "render s");
    for r in &rows {
        println!("{:<24} {:<44} {:>9} {:>12.0} {:>9.3} {:>9.3}", r.what, r.device, r.estimates, r.estimates_per_s, r.wall_s, r.render_s);
    }
    Ok(())
}

/// BOP's 2D tasks (masks, then amodal boxes) on the CPU, where they run:
/// results read, ground truth built from the masks, COCOeval.
fn bench_coco(ds: &Dataset, path: &std::path::Path, name: Option<&str>, repeat: usize) -> Result<Vec<EvalBenchRow>> {
    use plausible::coco::{evaluate, results::read_coco_results, target_images, BoxKind, CocoOptions, CocoTask};
    let results = read_coco_results(path).context("--coco-results")?;
    let (images, _) = target_images(ds, None)?;
    let cats = name.and_then(plausible::eval::bop_obj_ids);
    let mut rows = Vec::new();
    for (what, task) in [("2d segmentation (segm)", CocoTask::Segm), ("2d detection (bbox)", CocoTask::Bbox)] {
        let opts = CocoOptions { task, boxes: BoxKind::Amodal };
        let (wall, r) = median_run(repeat, || evaluate(ds, &results, &images, cats.as_deref(), opts, &mut |_| Ok(())))?;
        rows.push(EvalBenchRow {
            what: what.to_string(),
            device: format!("CPU ({} threads)", rayon::current_num_threads()),
            estimates: r.n_used,
            images: r.n_images,
            estimates_per_s: r.n_used as f64 / wall,
            wall_s: wall,
            render_s: 0.0,
            ar: Some(r.ap()),
            machine: super::machine::Machine::detect(None),
        });
    }
    Ok(rows)
}

/// One warm-up run (pipelines compiled, files in the page cache), then
/// `repeat` timed ones: the median wall time and that run's output.
/// Whether the first annotated image of the split has a pinhole camera
/// (`cam_K` or a `PinholePlane` lens): the VSD rows need one.
fn pinhole_cameras(ds: &Dataset) -> Result<bool> {
    let Some(&first) = ds.scene_ids()?.first() else { return Ok(true) };
    let scene = ds.scene(first)?;
    Ok(scene.camera.values().next().is_none_or(|c| c.projection.k().is_some()))
}

/// One row per error set and device: `evaluate`'s median wall time.
fn pose_rows(ds: &Dataset, results: &[plausible::bop::Estimate], sets: &[(&str, EvalOptions)], devices: &[Device], repeat: usize) -> Result<Vec<EvalBenchRow>> {
    let (targets, _) = ds.targets(None)?;
    let (det_targets, _) = plausible::eval::task_targets(ds, None, Task::Detection)?;
    let mut rows = Vec::new();
    for (what, opts) in sets {
        let targets = if opts.task == Task::Detection { &det_targets } else { &targets };
        for device in devices {
            let (wall, (r, _)) = median_run(repeat, || evaluate(ds, results, targets, device, opts, &mut |_| Ok(())))?;
            rows.push(EvalBenchRow {
                what: what.to_string(),
                device: device.describe(),
                estimates: r.n_estimates,
                images: r.n_images,
                estimates_per_s: r.n_estimates as f64 / wall,
                wall_s: wall,
                render_s: r.time_s.render_s,
                ar: r.ar.or(r.ar_vsd).or(r.ar_mssd).or(r.ap),
                machine: super::machine::Machine::detect(Some(device)),
            });
        }
    }
    Ok(rows)
}

fn median_run<T>(repeat: usize, mut run: impl FnMut() -> plausible::Result<T>) -> Result<(f64, T)> {
    run()?;
    let mut runs = Vec::with_capacity(repeat);
    for _ in 0..repeat {
        let t = Instant::now();
        let out = run()?;
        runs.push((t.elapsed().as_secs_f64(), out));
    }
    runs.sort_by(|x, y| x.0.total_cmp(&y.0));
    Ok(runs.swap_remove(runs.len() / 2))
}
