//! `plausible bench estimate`: seconds per image of `refine` (RIR on given
//! estimates) and `estimate` on the frames with many objects, GPU and CPU
//! twin side by side in the same run, with the time split by stage.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context as _, Result};
use plausible::bop::dataset::Target;
use plausible::bop::{read_results, Dataset};
use plausible::refine::dataset::{image_jobs, load_models, refine_image, ImageStats, Masks};
use plausible::refine::estimate::{estimate_image, load_estimate_models, EstimateParams, EstimateStats};
use plausible::refine::{RefineParams, RefineTimes};
use plausible::visual::Device;
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct BenchEstimateArgs {
    /// BOP dataset (default: the shipped 12-frame LM-O subset).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Estimates to refine (default: the shipped perturbed estimates).
    #[arg(long)]
    pub init: Option<PathBuf>,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Only images with at least this many annotated objects that have a
    /// model (the full LM-O test frames have 6-8; the shipped subset ships
    /// 3 of the models).
    #[arg(long, default_value_t = 1)]
    pub min_objects: usize,
    /// At most this many images (the first in scene/image order; a count,
    /// where `estimate --images` takes image ids).
    #[arg(long, default_value_t = 4)]
    pub max_images: usize,
    /// Refine without the simulation (SIR/RIR without PIR).
    #[arg(long)]
    pub no_physics: bool,
    /// Print JSON (one object per row) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Skip the CPU twin (not recommended: figures are meant side by side).
    #[arg(long)]
    pub no_cpu: bool,
    /// The device measured beside the CPU twin.
    #[arg(long, default_value = "gpu", value_parser = ["gpu", "cpu"])]
    pub device: String,
    /// With `--device gpu`: the first adapter whose name contains this text.
    #[arg(long)]
    pub adapter: Option<String>,
}

#[derive(Serialize, Debug)]
pub struct EstimateBenchRow {
    pub what: &'static str,
    pub device: String,
    pub images: usize,
    pub objects_per_image: f64,
    pub seconds_per_image: f64,
    /// Per image: plane fit and hypotheses scored alone (estimate only;
    /// the hypotheses summed over threads).
    pub plane_s: f64,
    pub hypotheses_s: f64,
    /// Per image: the scene's stages (views and occluders, scoring, ICP,
    /// simulation).
    pub scene_s: f64,
    pub score_s: f64,
    pub icp_s: f64,
    pub simulate_s: f64,
    pub machine: super::machine::Machine,
}

pub fn bench_estimate(a: BenchEstimateArgs, verbose: u8) -> Result<()> {
    if a.max_images == 0 || a.max_images > 100_000 {
        bail!("--max-images must be between 1 and 100000");
    }
    let root = match &a.dataset {
        Some(d) => d.clone(),
        None => super::asset("assets/lmo-synth").context("--dataset")?,
    };
    let init_path = a.init.clone().unwrap_or_else(|| root.join("perturbed.csv"));
    let ds = Dataset::open(&root, &a.split).context("--dataset")?;
    // The images (those with targets), each with every annotated object
    // that has a model as a target: the frames as they are, not the
    // evaluation's subset.
    let (targets, _) = ds.targets(None).context("the dataset's targets")?;
    let mut images: Vec<(u32, u32)> = targets.iter().map(|t| (t.scene_id, t.im_id)).collect();
    images.dedup();
    let mut scenes = HashMap::new();
    let mut chosen: Vec<((u32, u32), Vec<Target>)> = Vec::new();
    for (scene_id, im_id) in images {
        if chosen.len() == a.max_images {
            break;
        }
        if let std::collections::hash_map::Entry::Vacant(v) = scenes.entry(scene_id) {
            v.insert(ds.scene(scene_id).with_context(|| format!("scene {scene_id}"))?);
        }
        let mut count: std::collections::BTreeMap<u32, u32> = Default::default();
        for g in scenes[&scene_id].gt.get(&im_id).into_iter().flatten().filter(|g| ds.model_path(g.obj_id).is_file()) {
            *count.entry(g.obj_id).or_default() += 1;
        }
        if count.len() >= a.min_objects {
            let ts = count.into_iter().map(|(obj_id, inst_count)| Target { scene_id, im_id, obj_id, inst_count }).collect();
            chosen.push(((scene_id, im_id), ts));
        }
    }
    if chosen.is_empty() {
        bail!("no image of {} has {} or more annotated objects (--min-objects)", root.display(), a.min_objects);
    }
    let init = read_results(&init_path).context("--init")?;
    let jobs: Vec<_> = image_jobs(&init).into_iter().filter(|j| chosen.iter().any(|(k, _)| *k == (j.scene_id, j.im_id))).collect();
    if jobs.is_empty() {
        bail!("--init {}: no estimates for the chosen images", init_path.display());
    }
    let mut objs: Vec<u32> = chosen.iter().flat_map(|(_, ts)| ts.iter().map(|t| t.obj_id)).chain(jobs.iter().flat_map(|j| j.estimates.iter().map(|e| e.obj_id))).collect();
    objs.sort_unstable();
    objs.dedup();
    let devices = super::bench_eval::side_by_side(&a.device, a.adapter.as_deref(), a.no_cpu, verbose)?;
    let refine_p = RefineParams { physics: !a.no_physics, ..Default::default() };
    let est_p = EstimateParams { refine: refine_p.clone(), ..Default::default() };
    let models = load_models(&ds, &objs, &refine_p).context("loading the models")?;
    let est_models = load_estimate_models(&ds, &objs, &refine_p, None).context("loading the models and resting poses")?;
    let masks = Masks::Oracle;
    let mut rows = Vec::new();
    for device in &devices {
        // Refine: RIR on the given estimates.
        let mut r_row = new_row("refine", device, jobs.len());
        let t = Instant::now();
        let mut total = ImageStats::default();
        for job in &jobs {
            total += refine_image(&scenes[&job.scene_id], job, &models, device, &masks, &refine_p, false)?.stats;
        }
        finish(&mut r_row, t.elapsed().as_secs_f64(), total.objects, &total.times);
        rows.push(r_row);
        // Estimate: hypotheses from resting poses, scene refinement.
        let mut e_row = new_row("estimate", device, chosen.len());
        let t = Instant::now();
        let mut total = EstimateStats::default();
        for ((scene_id, im_id), ts) in &chosen {
            total += estimate_image(&scenes[scene_id], *im_id, ts, &est_models, device, &masks, &est_p, false)?.stats;
        }
        finish(&mut e_row, t.elapsed().as_secs_f64(), total.instances, &total.scene);
        e_row.plane_s = total.plane_s / chosen.len() as f64;
        e_row.hypotheses_s = total.hypotheses_s / chosen.len() as f64;
        rows.push(e_row);
    }
    if a.json {
        for r in &rows {
            println!("{}", serde_json::to_string(r)?);
        }
        return Ok(());
    }
    println!("machine: {}", super::machine::Machine::detect(devices.first()).line());
    println!(
        "{}: {} images with >= {} objects; wall clock per image, one run (stages per image; hypotheses summed over threads)",
        root.display(),
        chosen.len(),
        a.min_objects
    );
    println!(
        "{:<9} {:<40} {:>8} {:>9} {:>7} {:>8} {:>7} {:>7} {:>7} {:>9}",
        "what", "device", "objects", "s/image", "plane", "hyps", "scene", "score", "icp", "simulate"
    );
    for r in &rows {
        println!(
            "{:<9} {:<40} {:>8.1} {:>9.3} {:>7.3} {:>8.3} {:>7.3} {:>7.3} {:>7.3} {:>9.3}",
            r.what, r.device, r.objects_per_image, r.seconds_per_image, r.plane_s, r.hypotheses_s, r.scene_s, r.score_s, r.icp_s, r.simulate_s
        );
    }
    Ok(())
}

fn new_row(what: &'static str, device: &Device, images: usize) -> EstimateBenchRow {
    EstimateBenchRow {
        what,
        device: device.describe(),
        images,
        objects_per_image: 0.0,
        seconds_per_image: 0.0,
        plane_s: 0.0,
        hypotheses_s: 0.0,
        scene_s: 0.0,
        score_s: 0.0,
        icp_s: 0.0,
        simulate_s: 0.0,
        machine: super::machine::Machine::detect(Some(device)),
    }
}

fn finish(r: &mut EstimateBenchRow, wall: f64, objects: usize, t: &RefineTimes) {
    let n = r.images as f64;
    r.seconds_per_image = wall / n;
    r.objects_per_image = objects as f64 / n;
    (r.scene_s, r.score_s, r.icp_s, r.simulate_s) = (t.scene / n, t.score / n, t.icp / n, t.simulate / n);
}
