//! `plausible estimate`: poses of every target object in BOP images from
//! stable-pose hypotheses on the fitted support plane, scored and refined
//! (RIR); resumable and shardable like `refine`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use plausible::bop::Dataset;
use plausible::refine::estimate::{estimate_image, load_estimate_models, EstimateParams, EstimateStats};
use plausible::refine::{Method, RefineParams};

use super::refine::{check_settings, load_scenes, path_setting, read_digest, shard_of, skip_done, ResultsAppender};

#[derive(clap::Args, Debug)]
pub struct EstimateArgs {
    /// BOP dataset folder (models/, the split with depth/ and, for the
    /// oracle masks, mask_visib/, and usually test_targets_bop19.json).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Split folder inside the dataset.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Sensor of a split annotated per sensor (scene_gt_{sensor}.json,
    /// depth_{sensor}/, mask_visib_{sensor}/: BOP-H3 and the BOP'24
    /// industrial datasets, e.g. photoneo for ipd, xyz for xyzibd).
    #[arg(long)]
    pub sensor: Option<String>,
    /// Targets file (default: test_targets_bop19.json; without one every
    /// annotated object of every image).
    #[arg(long)]
    pub targets: Option<PathBuf>,
    /// Resting poses: a `stable-poses` database (SQLite) or its `export`
    /// JSON holding the dataset's models (default: the quasi-static
    /// analysis of each convex hull).
    #[arg(long)]
    pub stable: Option<PathBuf>,
    /// Results CSV (BOP format, score = visual-alignment score, time = the
    /// image's seconds). Written image by image; images already in it are
    /// skipped (a killed run resumes).
    #[arg(long)]
    pub out: PathBuf,
    /// Yaw steps per resting pose (15° apart by default).
    #[arg(long, default_value_t = 24)]
    pub yaw_steps: usize,
    /// Best-scored hypotheses refined per instance (RIR over them).
    #[arg(long, default_value_t = 5)]
    pub top: usize,
    /// Refinement of the best hypotheses: ref (ICP), pir (ICP after a short
    /// simulation among the placed objects), sir (PIR steps kept only if
    /// the score improves) or rir (SIR steps spread by UCB1).
    #[arg(long, default_value = "rir", value_parser = ["ref", "pir", "sir", "rir"])]
    pub method: String,
    /// Refinement steps per refined hypothesis (0: no refinement).
    #[arg(long, default_value_t = 2)]
    pub steps: usize,
    /// Refine without the simulation between ICP steps (SIR without PIR).
    #[arg(long)]
    pub no_physics: bool,
    /// Level of detail of the mesh the visual score renders: `off` (the
    /// full model, default), `auto` (the coarsest simplification within a
    /// quarter of a pixel at each object) or a triangle count (the paper's
    /// Table 1: 704, 352, 70, 34). ICP, the simulation and the evaluation
    /// keep the full model.
    #[arg(long, default_value = "off")]
    pub lod: plausible::mesh::lod::LodChoice,
    #[command(flatten)]
    pub run: super::refine::ImageRunArgs,
}

/// The resting poses of `--stable`: a `stable-poses export` JSON as it is,
/// or a `stable-poses` SQLite database exported in memory. A database is
/// told by its header; a pipe (`<(cat export.json)`) is read once, as
/// JSON, since sniffing it would eat its first bytes.
pub fn read_stable(path: &std::path::Path) -> Result<String> {
    let not_export = || format!("--stable {}: not a stable-poses export JSON or database", path.display());
    let regular = std::fs::metadata(path).is_ok_and(|m| m.is_file());
    let mut head = [0u8; 16];
    let is_sqlite = regular
        && std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head)).is_ok_and(|_| &head == b"SQLite format 3\0");
    if is_sqlite {
        let db = plausible::stable::db::Db::open_existing(path).with_context(|| format!("--stable {}", path.display()))?;
        let ex = plausible::stable::export::export(&db, None).with_context(|| format!("--stable {}", path.display()))?;
        return Ok(serde_json::to_string(&ex)?);
    }
    let bytes = plausible::io::read_capped(path, plausible::stable::export::MAX_EXPORT_BYTES, "stable-poses export").with_context(not_export)?;
    if bytes.starts_with(b"SQLite format 3\0") {
        bail!("--stable {}: a stable-poses database must be a file (SQLite cannot read one from a pipe); give its path, or its `export` JSON", path.display());
    }
    let text = plausible::io::text_of(path, bytes).with_context(not_export)?;
    serde_json::from_str::<serde_json::Value>(&text).with_context(not_export)?;
    Ok(text)
}

#[tracing::instrument(name = "plausible estimate", level = "trace", skip_all)]
pub fn run(a: EstimateArgs, verbose: u8) -> Result<()> {
    let mut params = EstimateParams { top: a.top, ..Default::default() };
    params.hypotheses.yaw_steps = a.yaw_steps;
    params.refine = RefineParams { method: Method::parse(&a.method).context("--method")?, steps: a.steps.max(1), physics: !a.no_physics, lod: a.lod, ..Default::default() };
    super::refine::check_no_physics(a.no_physics, params.refine.method)?;
    params.refine.validate().context("check --steps")?;
    params.refine.steps = a.steps;
    if a.top == 0 || a.top > 100 {
        bail!("--top {}: between 1 and 100 hypotheses are refined", a.top);
    }
    if a.yaw_steps == 0 || a.yaw_steps > 360 {
        bail!("--yaw-steps {}: between 1 and 360", a.yaw_steps);
    }
    let (shard, masks) = a.run.shard_and_masks()?;
    let ds = Dataset::open_sensor(&a.dataset, &a.split, a.sensor.as_deref()).map_err(|e| {
        let flag = super::dataset_flag(&e, a.sensor.is_some());
        anyhow::anyhow!(e).context(flag)
    })?;
    let _lock = a.run.prepare_outputs(&ds, &a.out, &[("--stable", a.stable.as_deref()), ("--targets", a.targets.as_deref())])?;
    let stable = a.stable.as_deref().map(read_stable).transpose()?;
    let (targets, source) = ds.targets(a.targets.as_deref()).map_err(|e| { let f = super::targets_flag(&e); anyhow::anyhow!(e).context(f) })?;
    // Which instances an image's estimates are for: the targets file by
    // content (a resumed run with other targets would mix two sets).
    // (And the file, whose digest earlier versions recorded instead.)
    let (targets_setting, targets_file) = match &source {
        plausible::bop::dataset::TargetSource::File(p) | plausible::bop::dataset::TargetSource::ImageList(p) => {
            (Some(read_digest(targets.iter().map(|t| format!("{} {} {} {}", t.scene_id, t.im_id, t.obj_id, t.inst_count)))), Some(p.clone()))
        }
        plausible::bop::dataset::TargetSource::AllInstances => (None, None),
    };
    if targets.is_empty() {
        match &targets_file {
            Some(p) => bail!("--targets {}: lists no target", p.display()),
            None => bail!("--dataset {}: annotates no instance to estimate", a.dataset.display()),
        }
    }
    let mut by_image: BTreeMap<(u32, u32), Vec<_>> = BTreeMap::new();
    for t in targets {
        by_image.entry((t.scene_id, t.im_id)).or_default().push(t);
    }
    let by_image = a.run.select_images(by_image.into_iter().collect(), |(k, _)| *k, "targets")?;
    let mut jobs: Vec<((u32, u32), Vec<_>)> = shard_of(by_image, shard);
    // What decides an image's estimates (not which images: those may be
    // added to one output by scene, image or shard).
    let mut settings = serde_json::json!({
        "command": "estimate",
        "dataset": path_setting(&a.dataset),
        "split": a.split,
        // The resting poses read, not the file's bytes: a stable-poses
        // rerun that adds nothing still rewrites its database.
        "stable": stable.as_deref().map(|text| plausible::stable::db::sha256_hex_reader(text.as_bytes())).transpose()?,
        "targets": targets_setting,
        "models": ds.models_digest()?,
        "yaw_steps": a.yaw_steps,
        "top": a.top,
        "method": a.method,
        "steps": a.steps,
        "no_physics": a.no_physics,
        "lod": a.lod.to_string(),
        "masks": a.run.masks_setting(),
    });
    if let Some(s) = &a.sensor {
        // Only when given: the records of runs without one stay valid.
        settings["sensor"] = serde_json::json!(s);
    }
    check_settings(&a.out, &settings, &[("targets", &|| targets_file.as_deref().and_then(super::refine::legacy_file_digest))])?;
    skip_done(&mut jobs, &a.out, |(k, _)| *k, |(_, ts)| ts.iter().map(|t| t.inst_count as usize).sum())?;
    let mut objs: Vec<u32> = jobs.iter().flat_map(|(_, ts)| ts.iter().map(|t| t.obj_id)).collect();
    objs.sort_unstable();
    objs.dedup();
    let mask_keys: Vec<(u32, u32, u32)> = jobs.iter().flat_map(|((s, i), ts)| ts.iter().map(|t| (*s, *i, t.obj_id))).collect::<std::collections::BTreeSet<_>>().into_iter().collect();
    a.run.check_masks(&masks, &mask_keys, "those objects are not estimated")?;
    let scenes = load_scenes(&ds, jobs.iter().map(|(k, _)| *k))?;
    let device = a.run.dev.open(verbose)?;
    // Compiled while the models load (Scorer::precompile).
    let _compiling = plausible::visual::Scorer::precompile(&device);
    let source = match &a.stable {
        Some(p) => format!("{} (--stable)", p.display()),
        None => "the quasi-static analysis of each hull".to_string(),
    };
    let refined = match a.steps {
        0 => "not refined (--steps 0)".to_string(),
        n => format!("refined by {} ({n} steps)", params.refine.method.name().to_uppercase()),
    };
    eprintln!("estimating {} images: resting poses from {source} x {} yaws, best {} {refined}; {}", jobs.len(), a.yaw_steps, a.top, masks.describe());
    let models = load_estimate_models(&ds, &objs, &params.refine, stable.as_deref()).map_err(|e| {
        // Problems of the resting poses are the --stable file's.
        let context = match &a.stable {
            Some(p) if e.input() == Some(plausible::Input::StablePoses) => format!("--stable {}", p.display()),
            _ => "loading the models".to_string(),
        };
        anyhow::anyhow!(e).context(context)
    })?;
    let mut out = ResultsAppender::open(&a.out)?;
    let pb = a.run.progress(jobs.len());
    let mut total = EstimateStats::default();
    for ((scene_id, im_id), ts) in &jobs {
        let r = estimate_image(&scenes[scene_id], *im_id, ts, &models, &device, &masks, &params, a.run.explain.is_some())
            .with_context(|| format!("scene {scene_id} image {im_id}"))?;
        a.run.save_picture(*scene_id, *im_id, r.picture.as_ref())?;
        out.append((*scene_id, *im_id), &r.estimates)?;
        total += r.stats;
        pb.inc(1);
    }
    pb.finish_and_clear();
    let n = jobs.len().max(1) as f64;
    println!(
        "estimated {} instances in {} images ({} without observed points); {} hypotheses; {:.3} s per image (plane {:.3} s, hypotheses and scoring alone {:.3} s summed over threads, scene: re-scoring and refinement in support order {:.3} s)",
        total.instances - total.skipped,
        jobs.len(),
        total.skipped,
        total.hypotheses,
        total.seconds / n,
        total.plane_s / n,
        total.hypotheses_s / n,
        total.refine_s / n
    );
    let wanted: usize = jobs.iter().flat_map(|(_, ts)| ts.iter().map(|t| t.inst_count as usize)).sum();
    if total.instances < wanted {
        eprintln!(
            "note: {} of the {wanted} target instances have no mask with a pixel ({}): they are not estimated",
            wanted - total.instances,
            masks.describe()
        );
    }
    println!("wrote {}", a.out.display());
    if let Some(p) = &a.run.summary {
        let v = serde_json::json!({
            "images": jobs.len(), "instances": total.instances, "skipped": total.skipped, "hypotheses": total.hypotheses,
            "masks": masks.describe(), "resting_poses": source, "method": params.refine.method.name(), "physics": params.refine.method.simulates(params.refine.physics), "yaw_steps": a.yaw_steps, "top": a.top, "steps": a.steps,
            "seconds": total.seconds, "seconds_per_image": total.seconds / n,
            "stage_seconds_per_image": {"plane": total.plane_s / n, "hypotheses_and_scoring": total.hypotheses_s / n, "scene_refinement": total.refine_s / n},
            "scene_refinement_stages_per_image": total.scene.json(n),
        });
        plausible::io::write_atomically(p, |w| {
            use std::io::Write;
            serde_json::to_writer_pretty(&mut *w, &v)?;
            writeln!(w)
        })?;
    }
    Ok(())
}
