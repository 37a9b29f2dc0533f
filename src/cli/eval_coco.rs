//! `plausible eval --task bbox|segm`: BOP's 2D detection and segmentation
//! tasks on COCO results, as the toolkit's eval_bop22_coco.py scores them.

use std::io::Write;

use anyhow::{bail, Context as _, Result};
use plausible::bop::TargetSource;
use plausible::coco::results::{read_coco_results, write_coco_results};
use plausible::coco::cocoeval::STAT_NAMES;
use plausible::coco::{evaluate, gt_as_results, target_images, BoxKind, CocoOptions, CocoReport, CocoTask};
use plausible::eval::{bop_obj_ids, open_dataset, toolkit_dataset_name};

use super::eval::EvalArgs;

/// Refuses the 6D-pose flags, which mean nothing here.
fn refuse_pose_flags(a: &EvalArgs, task: CocoTask) -> Result<()> {
    let given = [
        ("--errors", !a.errors.is_empty()),
        ("--max-estimates-per-image", a.max_estimates_per_image.is_some()),
        ("--errors-out", a.errors_out.is_some()),
        ("--add-threshold", a.add_threshold != 0.1),
        ("--batch-images", a.batch_images != 100),
    ];
    if let Some((flag, _)) = given.iter().find(|(_, g)| *g) {
        bail!("{flag} is for the 6D pose tasks (localization, detection), not --task {}", task.name());
    }
    if a.boxes.is_some() && task == CocoTask::Segm {
        bail!("--boxes is for --task bbox: masks are always the visible part");
    }
    Ok(())
}

/// Evaluates a COCO results file.
#[tracing::instrument(name = "plausible eval (2D)", level = "trace", skip_all)]
pub fn run(a: EvalArgs, task: CocoTask) -> Result<()> {
    refuse_pose_flags(&a, task)?;
    if a.dev.device != "auto" || a.dev.adapter.is_some() {
        eprintln!("note: BOP's 2D tasks render nothing and run on the CPU: --device and --adapter are not used");
    }
    let opts = CocoOptions { task, boxes: a.boxes.unwrap_or_default() };
    let Some(results_path) = a.results.as_deref().or(a.gt_as_results.as_deref()) else { bail!("give --results: a COCO results JSON") };
    let name = toolkit_dataset_name(&a.dataset, a.dataset_name.as_deref()).context("--dataset-name")?;
    let outputs = [("--out", a.out.as_deref()), ("--gt-as-results", a.gt_as_results.as_deref())];
    super::distinct_files(&outputs, &[("--results", a.results.as_deref()), ("--targets", a.targets.as_deref())])?;
    for p in [&a.out, &a.gt_as_results].into_iter().flatten() {
        plausible::io::check_writable(p)?;
    }
    let ds = open_dataset(&a.dataset, &a.split, a.sensor.as_deref(), name.as_deref()).map_err(|e| {
        let flag = super::dataset_flag(&e, a.sensor.is_some());
        anyhow::anyhow!(e).context(flag)
    })?;
    super::outside_dataset(&ds, &outputs)?;
    let (images, source) = target_images(&ds, a.targets.as_deref()).map_err(|e| { let f = super::targets_flag(&e); anyhow::anyhow!(e).context(f) })?;
    if images.is_empty() {
        bail!("--targets: no target images");
    }
    if source == TargetSource::AllInstances {
        eprintln!("note: no targets file: every annotated image is a target");
    }
    let results = match &a.gt_as_results {
        None => read_coco_results(results_path).context("--results")?,
        Some(out) => {
            let gt = gt_as_results(&ds, &images, opts)?;
            write_coco_results(out, &gt)?;
            eprintln!("wrote the ground truth of {} images as {} results to {}", images.len(), gt.len(), out.display());
            gt
        }
    };
    let categories = name.as_deref().and_then(bop_obj_ids);
    match (&name, &categories) {
        (Some(n), Some(c)) => eprintln!("BOP dataset '{n}': objects {c:?} are scored"),
        _ => eprintln!("note: '{}' is not a BOP dataset name the toolkit knows: every object of models_info.json is scored (--dataset-name sets it)", a.dataset.display()),
    }
    let pb = super::progress(images.len() as u64, "images");
    if a.quiet {
        pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let report = evaluate(&ds, &results, &images, categories.as_deref(), opts, &mut |done| {
        pb.set_position(done as u64);
        Ok(())
    })
    .with_context(|| format!("evaluating {} on the dataset {}", results_path.display(), a.dataset.display()))?;
    pb.finish_and_clear();
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    print_report(&report);
    if let Some(p) = &a.out {
        let mut v = serde_json::to_value(&report)?;
        v["dataset"] = serde_json::json!(a.dataset.display().to_string());
        v["results"] = serde_json::json!(results_path.display().to_string());
        v["targets"] = serde_json::json!(match &source {
            TargetSource::File(f) | TargetSource::ImageList(f) => f.display().to_string(),
            TargetSource::AllInstances => "all annotated images".into(),
        });
        plausible::io::write_atomically(p, |w| {
            serde_json::to_writer_pretty(&mut *w, &v)?;
            writeln!(w)
        })?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

fn fmt(v: f64) -> String {
    if v < 0.0 { "-".into() } else { format!("{v:.4}") }
}

/// The table: AP per object, then COCO's twelve numbers.
pub fn print_report(r: &CocoReport) {
    let what = match (r.task, r.boxes) {
        (CocoTask::Segm, _) => "masks".to_string(),
        (CocoTask::Bbox, b) => format!("{} boxes", if b == BoxKind::Amodal { "amodal" } else { "modal" }),
    };
    println!(
        "evaluated {} of {} results ({what}) against {} instances in {} images in {:.2} s; ground truth from {}",
        r.n_used, r.n_results, r.n_instances, r.n_images, r.time_s, r.ground_truth
    );
    if r.n_ignored > 0 || r.n_without_region > 0 || r.n_over_cap > 0 {
        println!(
            "ignored {} results of other images or unscored objects, {} without the task's region, {} beyond the 100 best of their image and object",
            r.n_ignored, r.n_without_region, r.n_over_cap
        );
    }
    println!("{:>5} {:>9} {:>8} {:>10} {:>7}", "obj", "instances", "ignored", "detections", "AP");
    for (o, s) in &r.per_object {
        println!("{o:>5} {:>9} {:>8} {:>10} {:>7}", s.instances, s.ignored, s.detections, s.ap.map_or("-".into(), fmt));
    }
    let s = &r.scores;
    // AP then AR, six numbers a line, in the toolkit's order.
    for line in STAT_NAMES.chunks(6) {
        println!("{}", line.iter().map(|k| format!("{k} {}", fmt(s[*k]))).collect::<Vec<_>>().join("  "));
    }
    let t = s["average_time_per_image"];
    println!("average time per image: {}", if t < 0.0 { "not given".into() } else { format!("{t:.3} s") });
    println!("(COCO AP/AR over IoU 0.5:0.95 as BOP's eval_bop22_coco.py gives them; '-' = nothing to count, the toolkit's -1)");
}
