//! `plausible eval`: BOP'19 evaluation of a results file (AR from VSD, MSSD,
//! MSPD; ADD/ADI), or BOP'24 6D detection (AP from MSSD, MSPD), as the BOP
//! toolkit computes them, on any GPU or the CPU.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use plausible::bop::{read_results, write_results, TargetSource};
use plausible::eval::{detection_targets, evaluate, open_dataset, gt_as_results, task_targets, toolkit_dataset_name, ErrorType, EvalOptions, EvalReport, Task};
use plausible::Input;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// BOP dataset folder: models_eval/ or models/ (with models_info.json),
    /// the split folder, and usually test_targets_bop19.json.
    #[arg(long)]
    pub dataset: PathBuf,
    /// Split folder inside the dataset.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Sensor of a split annotated per sensor (scene_gt_{sensor}.json,
    /// depth_{sensor}/, ...: BOP-H3 and the BOP'24 industrial datasets).
    /// Default: the one the BOP toolkit evaluates (photoneo for ipd, xyz for
    /// xyzibd, 3dlong for itoddmv; for hot3d, by scene: gray1 on Quest 3,
    /// rgb on Aria). Cameras may be pinhole (cam_K) or lens models
    /// (cam_model: HOT3D's fisheyes take MSSD and MSPD, not VSD).
    #[arg(long)]
    pub sensor: Option<String>,
    /// Results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in
    /// mm); for --task bbox|segm a COCO results JSON (.json, .json.gz).
    #[arg(long, required_unless_present = "gt_as_results")]
    pub results: Option<PathBuf>,
    /// Targets file (default: test_targets_bop19.json in the dataset, for
    /// --task detection test_targets_bop24.json first; without one, every
    /// annotated instance is a target).
    #[arg(long)]
    pub targets: Option<PathBuf>,
    /// BOP task: `localization` (BOP'19: the top inst_count estimates per
    /// target, recall, AR) or `detection` (BOP'24: every estimate up to
    /// --max-estimates-per-image, average precision per object over MSSD and
    /// MSPD thresholds, mAP; instances under 10 % visible ignored).
    ///
    /// BOP's 2D tasks take a COCO results JSON (scene_id, image_id,
    /// category_id, score, bbox, segmentation as RLE, time) and give COCO's
    /// AP and AR as the toolkit's eval_bop22_coco.py does: `bbox` (2D
    /// detection, boxes per --boxes) or `segm` (2D segmentation).
    #[arg(long, default_value = "localization")]
    pub task: EvalTask,
    /// --task bbox: ground-truth boxes of the whole silhouette (`amodal`,
    /// BOP's default, from mask/) or of the visible part (`modal`).
    #[arg(long)]
    pub boxes: Option<plausible::coco::BoxKind>,
    /// Error types, comma-separated: vsd, mssd, mspd (their mean recall is
    /// BOP's AR), ad (ADI for symmetric objects, ADD otherwise), add, adi.
    /// Default: vsd,mssd,mspd; for --task detection mssd,mspd (the only ones
    /// it takes).
    #[arg(long, value_delimiter = ',')]
    pub errors: Vec<ErrorType>,
    /// --task detection: estimates kept per image, the highest-scored
    /// (default: the toolkit's, 100; 200 for xyzibd).
    #[arg(long)]
    pub max_estimates_per_image: Option<usize>,
    /// Correctness threshold of ad/add/adi, as a fraction of the diameter.
    #[arg(long, default_value_t = 0.1)]
    pub add_threshold: f64,
    /// Write the report as JSON here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write every (estimate, instance) pair's errors here, one JSON object a line.
    #[arg(long)]
    pub errors_out: Option<PathBuf>,
    /// Write the ground truth of the targets as a results file here, and
    /// evaluate it (its AR is 1 by construction: a check of the setup); for
    /// --task bbox|segm a COCO results JSON (every AP 1).
    #[arg(long, conflicts_with = "results")]
    pub gt_as_results: Option<PathBuf>,
    /// BOP dataset name (lm, lmo, tless, ycbv, itodd, ...) for the toolkit's
    /// per-dataset constants: the objects `ad` scores with ADI, and VSD δ
    /// (5 mm for ITODD, else 15 mm). Default: the dataset folder's name when
    /// it is one of them; otherwise symmetric objects are those with
    /// symmetries in models_info.json and δ is 15 mm.
    #[arg(long)]
    pub dataset_name: Option<String>,
    /// Images per batch (memory holds one batch's depth and renders).
    #[arg(long, default_value_t = 100)]
    pub batch_images: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub dev: super::AutoDeviceArgs,
}

/// `--task`: one of the 6D pose tasks, or one of BOP's 2D tasks on COCO
/// results.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EvalTask {
    Pose(Task),
    Coco(plausible::coco::CocoTask),
}

impl std::str::FromStr for EvalTask {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match (s.parse::<plausible::coco::CocoTask>(), s.parse::<Task>()) {
            (Ok(t), _) => Ok(EvalTask::Coco(t)),
            (_, Ok(t)) => Ok(EvalTask::Pose(t)),
            _ => Err(format!("unknown task '{s}' (expected localization or detection for 6D poses, bbox or segm for BOP's 2D tasks)")),
        }
    }
}

/// Evaluates a results file. With `--trace` its span is the trace's root:
/// open (dataset, targets, results, device), evaluate (load_models, one
/// span per image batch, recall), report, write.
#[tracing::instrument(name = "plausible eval", level = "trace", skip_all)]
pub fn run(a: EvalArgs, verbose: u8) -> Result<()> {
    let task = match a.task {
        EvalTask::Coco(t) => return super::eval_coco::run(a, t),
        EvalTask::Pose(t) => t,
    };
    if a.boxes.is_some() {
        bail!("--boxes is for --task bbox (BOP's 2D detection)");
    }
    if let Some(r) = a.results.as_deref().filter(|r| r.to_string_lossy().ends_with(".json") || r.to_string_lossy().ends_with(".json.gz")) {
        bail!("--results {}: a JSON file holds COCO results of BOP's 2D tasks: give --task bbox or --task segm (the 6D pose tasks read a CSV)", r.display());
    }
    let open = tracing::trace_span!("open").entered();
    let name = toolkit_dataset_name(&a.dataset, a.dataset_name.as_deref()).context("--dataset-name")?;
    let base = match task {
        Task::Localization => EvalOptions::for_dataset(name.as_deref()),
        Task::Detection => EvalOptions::detection(name.as_deref()),
    };
    if a.max_estimates_per_image.is_some() && task != Task::Detection {
        bail!("--max-estimates-per-image is for --task detection (localization keeps the top inst_count of each target)");
    }
    let opts = EvalOptions {
        errors: if a.errors.is_empty() { base.errors.clone() } else { a.errors.clone() },
        add_threshold: a.add_threshold,
        batch_images: a.batch_images,
        max_estimates_per_image: a.max_estimates_per_image.unwrap_or(base.max_estimates_per_image),
        ..base
    };
    opts.validate().map_err(|e| {
        // The library names the setting; say which flag gave it.
        let flag = match e.input() {
            Some(Input::Setting("error types")) => "--errors",
            Some(Input::Setting("ADD threshold")) => "--add-threshold",
            Some(Input::Setting("batch size")) => "--batch-images",
            Some(Input::Setting("estimates per image")) => "--max-estimates-per-image",
            _ => "the dataset's evaluation settings",
        };
        anyhow::anyhow!(e).context(flag)
    })?;
    let outputs = [("--out", a.out.as_deref()), ("--errors-out", a.errors_out.as_deref()), ("--gt-as-results", a.gt_as_results.as_deref())];
    super::distinct_files(&outputs, &[("--results", a.results.as_deref()), ("--targets", a.targets.as_deref())])?;
    for p in [&a.out, &a.errors_out, &a.gt_as_results].into_iter().flatten() {
        plausible::io::check_writable(p)?;
    }
    let ds = open_dataset(&a.dataset, &a.split, a.sensor.as_deref(), name.as_deref()).map_err(|e| {
        let flag = super::dataset_flag(&e, a.sensor.is_some());
        anyhow::anyhow!(e).context(flag)
    })?;
    if let (None, Some(s)) = (&a.sensor, &ds.sensor) {
        eprintln!("sensor {s}: the one the BOP toolkit evaluates for {} (--sensor picks another)", name.as_deref().unwrap_or_default());
    }
    if let Some(rule) = ds.sensor_rule {
        eprintln!("sensor by scene: {}, as the BOP toolkit evaluates it (--sensor picks one for all)", rule.describe());
    }
    super::outside_dataset(&ds, &outputs)?;
    match &name {
        Some(n) => eprintln!("BOP dataset '{n}': VSD δ {} mm, ad uses ADI for objects {:?}", opts.vsd_delta_mm, opts.symmetric_obj_ids.as_deref().unwrap_or(&[])),
        None => eprintln!("note: '{}' is not a BOP dataset name the toolkit knows: ad uses ADI for the objects with symmetries in models_info.json (--dataset-name sets it)", a.dataset.display()),
    }
    let (targets, source) = task_targets(&ds, a.targets.as_deref(), task).map_err(|e| { let f = super::targets_flag(&e); anyhow::anyhow!(e).context(f) })?;
    if let TargetSource::File(f) | TargetSource::ImageList(f) = &source {
        // The dataset's own targets file, found without --targets.
        super::distinct_files(&outputs, &[("the dataset's targets file", Some(f))])?;
    }
    if targets.is_empty() {
        bail!("no targets to evaluate");
    }
    match (&source, task) {
        (TargetSource::AllInstances, _) => eprintln!("note: no targets file: every annotated instance is a target"),
        (TargetSource::ImageList(f), Task::Localization) => eprintln!(
            "note: {} names images only (BOP'24 targets): every annotated instance of those images is a localization target (--task detection gives BOP'24's detection AP)",
            f.display()
        ),
        (TargetSource::File(f), Task::Detection) => {
            eprintln!("note: {} names objects (BOP'19 targets): detection takes its images and every annotated object in them", f.display())
        }
        _ => {}
    }
    let device = a.dev.open(verbose)?;
    let results = match (&a.results, &a.gt_as_results) {
        (Some(r), _) => read_results(r).context("--results")?,
        (None, Some(out)) => {
            // Detection's ground truth: every instance of the listed images.
            let gt = match task {
                Task::Localization => gt_as_results(&ds, &targets, &device, &opts)?,
                Task::Detection => gt_as_results(&ds, &detection_targets(&ds, &targets)?, &device, &opts)?,
            };
            write_results(out, &gt)?;
            eprintln!("wrote the ground truth of {} targets as {} estimates to {}", targets.len(), gt.len(), out.display());
            gt
        }
        (None, None) => bail!("give --results or --gt-as-results"),
    };
    if results.is_empty() {
        eprintln!("warning: the results hold no estimate: every target counts as missed");
    }
    drop(open);
    let n_images = {
        let mut ims: Vec<(u32, u32)> = targets.iter().map(|t| (t.scene_id, t.im_id)).collect();
        ims.sort_unstable();
        ims.dedup();
        ims.len()
    };
    let pb = super::progress(n_images as u64, "images");
    if a.quiet {
        pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let results_name = a.results.as_ref().or(a.gt_as_results.as_ref()).map(|p| p.display().to_string()).unwrap_or_default();
    let (report, records) = tracing::trace_span!("evaluate")
        .in_scope(|| evaluate(&ds, &results, &targets, &device, &opts, &mut |done| {
            pb.set_position(done as u64);
            Ok(())
        }))
        .with_context(|| format!("evaluating {results_name} on the dataset {}", a.dataset.display()))?;
    pb.finish_and_clear();
    tracing::trace_span!("report").in_scope(|| print_report(&report, &opts));
    let _write = tracing::trace_span!("write").entered();
    if let Some(p) = &a.out {
        let mut v = serde_json::to_value(&report)?;
        v["dataset"] = serde_json::json!(a.dataset.display().to_string());
        v["results"] = serde_json::json!(a.results.as_ref().or(a.gt_as_results.as_ref()).map(|p| p.display().to_string()));
        v["targets"] = serde_json::json!(match &source {
            TargetSource::File(f) | TargetSource::ImageList(f) => f.display().to_string(),
            TargetSource::AllInstances => "all annotated instances".into(),
        });
        plausible::io::write_atomically(p, |w| {
            serde_json::to_writer_pretty(&mut *w, &v)?;
            writeln!(w)
        })?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = &a.errors_out {
        plausible::io::write_atomically(p, |w| {
            for r in &records {
                serde_json::to_writer(&mut *w, r)?;
                writeln!(w)?;
            }
            Ok(())
        })?;
        eprintln!("wrote {} error records to {}", records.len(), p.display());
    }
    Ok(())
}

fn fmt(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.4}"))
}

/// The table: recall per object and error type, AR, then the totals
/// (detection: AP per object and error type, mAP).
pub fn print_report(r: &EvalReport, opts: &EvalOptions) {
    if r.task == Task::Detection {
        return print_detection_report(r, opts);
    }
    println!(
        "evaluated {} estimates against {} targets in {} images in {:.2} s on {} (visibility: {})",
        r.n_estimates, r.n_targets, r.n_images, r.time_s.total_s, r.device, r.visibility
    );
    if r.n_ignored > 0 || r.n_not_top > 0 {
        println!(
            "ignored {} estimates for non-target objects or images, {} beyond the top inst_count of their target",
            r.n_ignored, r.n_not_top
        );
    }
    let cols: Vec<&str> =
        ["vsd", "mssd", "mspd", "ad", "add", "adi"].into_iter().filter(|c| opts.errors.iter().any(|e| e.name() == *c)).collect();
    let mut head = format!("{:>5} {:>8} {:>7}", "obj", "targets", "AR");
    for c in &cols {
        head += &format!(" {:>7}", c.to_uppercase());
    }
    println!("{head}");
    for (o, s) in &r.per_object {
        let mut line = format!("{o:>5} {:>8} {:>7}", s.targets, fmt(s.ar));
        for c in &cols {
            line += &format!(" {:>7}", fmt(s.by_error.get(*c).copied()));
        }
        println!("{line}");
    }
    let mut line = format!("{:>5} {:>8} {:>7}", "all", r.n_targets, fmt(r.ar));
    for c in &cols {
        let v = match *c {
            "vsd" => r.ar_vsd,
            "mssd" => r.ar_mssd,
            "mspd" => r.ar_mspd,
            "ad" => r.recall_ad,
            "add" => r.recall_add,
            _ => r.recall_adi,
        };
        line += &format!(" {:>7}", fmt(v));
    }
    println!("{line}");
    println!("(VSD, MSSD, MSPD: average recall over the BOP'19 thresholds; AD/ADD/ADI: recall at {} x diameter)", r.add_threshold);
}

/// The detection table: AP per object (mean over thresholds) for MSSD,
/// MSSD in mm and MSPD, their mean, then the mAPs.
fn print_detection_report(r: &EvalReport, opts: &EvalOptions) {
    println!(
        "evaluated {} estimates against {} instances visible at least {} % in {} images in {:.2} s on {} (visibility: {})",
        r.n_estimates,
        r.n_targets,
        opts.visib_gt_min * 100.0,
        r.n_images,
        r.time_s.total_s,
        r.device,
        r.visibility
    );
    if r.n_ignored > 0 || r.n_not_top > 0 {
        println!("ignored {} estimates for objects not annotated in their image or for other images, {} beyond the cap per image", r.n_ignored, r.n_not_top);
    }
    let cols: Vec<&str> = ["mssd", "mspd", "mssd_mm"].into_iter().filter(|c| r.per_threshold_ap.contains_key(*c)).collect();
    let mut head = format!("{:>5} {:>9} {:>7}", "obj", "instances", "AP");
    for c in &cols {
        head += &format!(" {:>10}", format!("AP_{}", c.to_uppercase().replace("_MM", "_mm")));
    }
    println!("{head}");
    for (o, s) in &r.per_object {
        let mut line = format!("{o:>5} {:>9} {:>7}", s.targets, fmt(s.ap));
        for c in &cols {
            line += &format!(" {:>10}", fmt(s.by_error.get(*c).copied()));
        }
        println!("{line}");
    }
    let mut line = format!("{:>5} {:>9} {:>7}", "all", r.n_targets, fmt(r.ap));
    for c in &cols {
        let v = match *c {
            "mssd" => r.ap_mssd,
            "mspd" => r.ap_mspd,
            _ => r.ap_mssd_mm,
        };
        line += &format!(" {:>10}", fmt(v));
    }
    println!("{line}");
    println!(
        "(BOP'24 6D detection: AP per object averaged over the thresholds, then over the objects; AP = mean of AP_MSSD and AP_MSPD (bop24_mAP); AP_MSSD is also bop25_mAP and AP_MSSD_mm bop25_mAP_mm)"
    );
}
