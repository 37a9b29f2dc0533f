//! BOP's 2D object detection and 2D object segmentation tasks (BOP'22 and
//! later): COCO-format results scored as the BOP toolkit's
//! `scripts/eval_bop22_coco.py` scores them, with pycocotools' COCOeval
//! (the fork the toolkit installs) reimplemented step for step:
//! AP over IoU 0.5:0.95, AP50, AP75, AP and AR by object size, AR at 1, 10
//! and 100 detections per image and object, and the average time per image.
//!
//! Data flows one way: [`results::read_coco_results`] → per-scene ground
//! truth ([`gt::scene_gt`]: the dataset's `scene_gt_coco.json` or the masks)
//! → groups per image and object with their IoUs → [`cocoeval::summarize`]
//! → [`CocoReport`].

pub mod cocoeval;
pub mod gt;
pub mod results;
pub mod rle;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::bop::{Dataset, TargetSource};
use crate::error::{Error, Input, Result};
use crate::metrics::pose_error::np_mean;
use cocoeval::{DtRegion, Group, GtRegion, Summary, STAT_NAMES};
use gt::{GtImage, GtSource};
use rayon::prelude::*;
use results::{CocoResult, SegmField};
use rle::{bbox_iou, mask_iou, Rle};

/// What is compared: boxes (2D detection) or masks (2D segmentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CocoTask {
    Bbox,
    Segm,
}

impl std::str::FromStr for CocoTask {
    type Err = String;
    /// The toolkit's `ann_type` (`bbox`, `segm`) or the task's name.
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('_', "-").as_str() {
            "bbox" | "2d-detection" | "detection-2d" => Ok(CocoTask::Bbox),
            "segm" | "segmentation" | "2d-segmentation" | "segmentation-2d" => Ok(CocoTask::Segm),
            _ => Err(format!("unknown 2D task '{s}' (expected bbox or segm)")),
        }
    }
}

impl CocoTask {
    /// The toolkit's `ann_type`.
    pub fn name(self) -> &'static str {
        match self {
            CocoTask::Bbox => "bbox",
            CocoTask::Segm => "segm",
        }
    }
}

/// Ground-truth boxes: of the whole silhouette, occluded parts included
/// (amodal, BOP's default), or of the visible part (modal).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BoxKind {
    #[default]
    Amodal,
    Modal,
}

impl std::str::FromStr for BoxKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "amodal" => Ok(BoxKind::Amodal),
            "modal" => Ok(BoxKind::Modal),
            _ => Err(format!("unknown box type '{s}' (expected amodal or modal)")),
        }
    }
}

/// What to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CocoOptions {
    pub task: CocoTask,
    /// Only boxes use it (masks are always the visible part).
    pub boxes: BoxKind,
}

/// One object's line of the report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ObjectAp {
    /// Ground-truth instances in the target images (ignored ones included).
    pub instances: usize,
    /// Of them, ignored (visible less than 10 %).
    pub ignored: usize,
    pub detections: usize,
    /// AP over the IoU thresholds (all sizes, 100 detections); `None`
    /// without counted instances.
    pub ap: Option<f64>,
}

/// The scores, as `scores_bop22_coco_{segm,bbox}.json` holds them (−1
/// where nothing counts), and what went into them.
#[derive(Clone, Debug, Serialize)]
pub struct CocoReport {
    pub task: CocoTask,
    pub boxes: BoxKind,
    /// The toolkit's keys: AP, AP50, AP75, AP_small, AP_medium, AP_large,
    /// AR1, AR10, AR100, AR_small, AR_medium, AR_large,
    /// average_time_per_image.
    pub scores: BTreeMap<String, f64>,
    pub per_object: BTreeMap<u32, ObjectAp>,
    pub n_results: usize,
    /// Results evaluated: of a target image and of a scored object, with
    /// the task's region.
    pub n_used: usize,
    /// Results of other images, or of objects the dataset does not score.
    pub n_ignored: usize,
    /// Results without the task's region (no bbox / no segmentation).
    pub n_without_region: usize,
    /// Results beyond the 100 highest-scored of their image and object
    /// (COCO's cap): they cannot count.
    pub n_over_cap: usize,
    pub n_images: usize,
    pub n_instances: usize,
    /// Where the ground truth came from: the dataset's files, or the masks.
    pub ground_truth: String,
    pub warnings: Vec<String>,
    pub time_s: f64,
}

impl CocoReport {
    pub fn ap(&self) -> f64 {
        self.scores["AP"]
    }
}

#[derive(Deserialize)]
struct TargetImage {
    scene_id: u32,
    im_id: u32,
}

/// The target images: the distinct `(scene_id, im_id)` of `file`, or of
/// the dataset's `test_targets_bop19.json`, else `test_targets_bop24.json`
/// (the toolkit's default is the first; BOP'24's 2D tasks use the second),
/// else every annotated image; in first-appearance order (the toolkit's
/// scene order).
pub fn target_images(ds: &Dataset, file: Option<&Path>) -> Result<(Vec<(u32, u32)>, TargetSource)> {
    let path = match file {
        Some(f) => Some(f.to_path_buf()),
        None => [ds.targets_file(false), ds.targets_file(true)].into_iter().find(|p| p.is_file()),
    };
    let Some(path) = path else {
        let mut all = Vec::new();
        for s in ds.scene_ids()? {
            all.extend(ds.scene(s)?.gt.keys().map(|&im| (s, im)));
        }
        return Ok((all, TargetSource::AllInstances));
    };
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e).about(Input::Targets))?;
    let list: Vec<TargetImage> = serde_json::from_str(&text).map_err(|e| {
        Error::BadJson { path: path.clone(), reason: format!("not a BOP targets list ({{\"scene_id\", \"im_id\", ...}}): {e}") }.about(Input::Targets)
    })?;
    let mut seen = BTreeSet::new();
    let images = list.into_iter().map(|t| (t.scene_id, t.im_id)).filter(|k| seen.insert(*k)).collect();
    Ok((images, TargetSource::File(path)))
}

/// Average time per image as the toolkit computes it: over every result of
/// the file, one time per image in first-appearance order, numpy's mean;
/// −1 when any result lacks one. Times of one image more than 1 ms apart
/// stop the toolkit; here they are a warning and the first is kept.
fn average_time(results: &[CocoResult], warnings: &mut Vec<String>) -> f64 {
    let t = crate::eval::image_times(results.iter().map(|r| ((r.scene_id, r.image_id), r.time)));
    if !t.complete {
        return -1.0;
    }
    if !t.inconsistent.is_empty() {
        warnings.push(format!(
            "{} results give their image another time (more than 1 ms apart) than its first result; the first is used",
            t.inconsistent.len()
        ));
    }
    if t.times.is_empty() { -1.0 } else { np_mean(&t.times) }
}

/// A detection's region and area, decoded once.
struct Detection {
    image: usize,
    category: u32,
    score: f64,
    area: f64,
    bbox: [f64; 4],
    mask: Option<Rle>,
}

/// Scores `results` on the target `images` (first-appearance order) of
/// `ds`. `categories` are the objects scored (the toolkit's list for a
/// named dataset; `None`: every object of models_info.json and of the
/// ground truth). `progress` gets the number of target images read.
pub fn evaluate(
    ds: &Dataset,
    results: &[CocoResult],
    images: &[(u32, u32)],
    categories: Option<&[u32]>,
    opts: CocoOptions,
    progress: &mut dyn FnMut(usize) -> Result<()>,
) -> Result<CocoReport> {
    let start = std::time::Instant::now();
    let mut warnings = Vec::new();
    let avg_time = average_time(results, &mut warnings);
    let scenes = scenes_in_order(images);
    let gt = load_ground_truth(ds, &scenes, opts, progress, &mut warnings)?;
    let cats = scored_objects(ds, categories, &gt);
    let (gt_images, position) = (&gt.images, &gt.position);
    let scene_rank: BTreeMap<u32, usize> = scenes.iter().enumerate().map(|(i, (s, _))| (*s, i)).collect();
    let found = detections(results, &scene_rank, position, gt_images, &cats, opts)?;
    let dets = &found.list;
    let mut per_object: BTreeMap<u32, ObjectAp> = BTreeMap::new();
    for a in gt_images.iter().flat_map(|g| &g.anns).filter(|a| cats.contains(&a.category_id)) {
        let o = per_object.entry(a.category_id).or_default();
        o.instances += 1;
        o.ignored += usize::from(a.ignore);
    }
    for d in dets {
        per_object.entry(d.category).or_default().detections += 1;
    }
    let cat_list: Vec<u32> = cats.iter().copied().collect();
    let summary = if !found.any {
        warnings.push("no result of a target image holds the task's region: every score is -1, as the toolkit gives".into());
        Summary { stats: [-1.0; 12], per_category: Vec::new() }
    } else {
        cocoeval::summarize(&groups(gt_images, dets, &cats, opts.task), &cat_list)
    };
    for (c, ap) in &summary.per_category {
        if let Some(o) = per_object.get_mut(c) {
            o.ap = (*ap > -1.0).then_some(*ap);
        }
    }
    let mut scores: BTreeMap<String, f64> = STAT_NAMES.iter().zip(summary.stats).map(|(k, v)| (k.to_string(), v)).collect();
    scores.insert("average_time_per_image".into(), if found.any { avg_time } else { -1.0 });
    Ok(CocoReport {
        task: opts.task,
        boxes: opts.boxes,
        scores,
        per_object,
        n_results: results.len(),
        n_used: dets.len(),
        n_ignored: found.ignored,
        n_without_region: found.without_region,
        n_over_cap: found.over_cap,
        n_images: gt_images.len(),
        n_instances: gt_images.iter().flat_map(|g| &g.anns).filter(|a| cats.contains(&a.category_id)).count(),
        ground_truth: gt.sources.iter().cloned().collect::<Vec<_>>().join(", "),
        warnings,
        time_s: start.elapsed().as_secs_f64(),
    })
}

/// The target images' ground truth, in the toolkit's merged image order.
struct GroundTruth {
    images: Vec<GtImage>,
    /// (scene, image) → index in `images`.
    position: BTreeMap<(u32, u32), usize>,
    /// Where it came from, for the report.
    sources: BTreeSet<String>,
    /// Categories listed by ground-truth files: COCOeval scores those.
    file_categories: Option<BTreeSet<u32>>,
    /// Whether some scene's was built from the masks.
    any_masks: bool,
}

/// Reads or builds each scene's ground truth: a scene's file at once,
/// masks a few images at a time (for the progress bar and for stopping).
fn load_ground_truth(
    ds: &Dataset,
    scenes: &[(u32, BTreeSet<u32>)],
    opts: CocoOptions,
    progress: &mut dyn FnMut(usize) -> Result<()>,
    warnings: &mut Vec<String>,
) -> Result<GroundTruth> {
    let mut gt = GroundTruth { images: Vec::new(), position: BTreeMap::new(), sources: BTreeSet::new(), file_categories: None, any_masks: false };
    let mut next_id = 1;
    for (s, ims) in scenes {
        let scene = ds.scene(*s)?;
        let parts: Vec<BTreeSet<u32>> = if gt::gt_file(&scene, opts.boxes).is_file() {
            vec![ims.clone()]
        } else {
            ims.iter().copied().collect::<Vec<_>>().chunks(16).map(|c| c.iter().copied().collect()).collect()
        };
        for part in parts {
            let (images, source) = gt::scene_gt(&scene, &part, opts.boxes, opts.task == CocoTask::Segm)?;
            let from_masks = matches!(source, GtSource::Masks { .. });
            let label = match source {
                GtSource::File { path, categories } => {
                    if categories.as_ref().is_none_or(|c| c.is_empty()) {
                        warnings.push(format!("{} lists no categories: COCOeval scores none of its objects", path.display()));
                    }
                    gt.file_categories.get_or_insert_with(BTreeSet::new).extend(categories.unwrap_or_default());
                    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default() + " files"
                }
                GtSource::Masks { full } => {
                    gt.any_masks = true;
                    format!("the masks (mask_visib{})", if full { ", mask" } else { "" })
                }
            };
            gt.sources.insert(label);
            for mut im in images {
                if from_masks {
                    // Numbered across the scene's parts, as one call would.
                    for a in &mut im.anns {
                        a.id = next_id;
                        next_id += 1;
                    }
                }
                gt.position.insert((*s, im.im_id), gt.images.len());
                gt.images.push(im);
            }
            progress(gt.images.len())?;
        }
    }
    Ok(gt)
}

/// The objects scored: those the ground-truth files list (what COCOeval
/// scores in the toolkit), and for scenes built from the masks the
/// dataset's (`categories`, its toolkit list when named, else every object
/// of models_info.json and of the ground truth).
fn scored_objects(ds: &Dataset, categories: Option<&[u32]>, gt: &GroundTruth) -> BTreeSet<u32> {
    let dataset = || -> BTreeSet<u32> {
        match categories {
            Some(c) => c.iter().copied().collect(),
            None => ds.models_info.keys().copied().chain(gt.images.iter().flat_map(|g| g.anns.iter().map(|a| a.category_id))).collect(),
        }
    };
    match (&gt.file_categories, gt.any_masks) {
        (Some(fc), false) => fc.clone(),
        (Some(fc), true) => dataset().into_iter().chain(fc.iter().copied()).collect(),
        (None, _) => dataset(),
    }
}

/// The results of a COCO evaluation, sorted out.
struct Detections {
    /// Of scored objects, with regions decoded and areas set.
    list: Vec<Detection>,
    /// Whether any result of a target image has the task's region (of any
    /// object): without one pycocotools' `loadRes` fails and the toolkit
    /// reports −1 everywhere; with some, none of them scored, AP is 0.
    any: bool,
    /// Results of other images, or of objects the dataset does not score.
    ignored: usize,
    /// Results without the task's region.
    without_region: usize,
    /// Beyond the 100 best of their image and object.
    over_cap: usize,
}

/// The results evaluated, in the toolkit's merged order (scenes in target
/// order, file order within a scene), with their regions decoded and their
/// areas as pycocotools' `loadRes` sets them: the box's w·h when the first
/// merged result (of any object) has a box, else the mask's pixel count.
fn detections(
    results: &[CocoResult],
    scene_rank: &BTreeMap<u32, usize>,
    position: &BTreeMap<(u32, u32), usize>,
    gt_images: &[GtImage],
    cats: &BTreeSet<u32>,
    opts: CocoOptions,
) -> Result<Detections> {
    let has_region = |r: &CocoResult| match opts.task {
        CocoTask::Bbox => r.bbox.is_some(),
        CocoTask::Segm => r.segmentation.is_some(),
    };
    let without_region = results.iter().filter(|r| !has_region(r)).count();
    let mut merged: Vec<(usize, &CocoResult)> =
        results.iter().enumerate().filter(|(_, r)| has_region(r) && position.contains_key(&(r.scene_id, r.image_id))).collect();
    // Stable: file order within a scene.
    merged.sort_by_key(|(_, r)| scene_rank[&r.scene_id]);
    let bad = |i: usize, reason: String| Error::InvalidInput(format!("result {i} (scene {}, image {}): {reason}", results[i].scene_id, results[i].image_id));
    if opts.task == CocoTask::Segm {
        // The toolkit checks every result's mask before anything else.
        if let Some((i, Some(SegmField::Bad(why)))) = results.iter().enumerate().map(|(i, r)| (i, &r.segmentation)).find(|(_, s)| matches!(s, Some(SegmField::Bad(_)))) {
            return Err(bad(i, why.clone()));
        }
    }
    let box_area = merged.first().is_some_and(|(_, r)| r.bbox.is_some());
    if let Some((i, _)) = merged.iter().find(|(_, r)| box_area && r.bbox.is_none()) {
        return Err(bad(*i, "has no bbox while the first result has one (pycocotools takes every area from the boxes then, and stops here)".into()));
    }
    // Per image and object COCOeval keeps the 100 highest-scored (stably);
    // the rest cannot count, so their masks are not even decoded.
    let mut by_group: BTreeMap<(usize, u32), Vec<(usize, &CocoResult)>> = BTreeMap::new();
    for &(i, r) in merged.iter().filter(|(_, r)| cats.contains(&r.category_id)) {
        by_group.entry((position[&(r.scene_id, r.image_id)], r.category_id)).or_default().push((i, r));
    }
    let cap = cocoeval::MAX_DETS[cocoeval::MAX_DETS.len() - 1];
    let mut kept: Vec<(usize, usize, &CocoResult)> = Vec::new();
    let mut over_cap = 0;
    for ((image, _), mut rs) in by_group {
        if rs.len() > cap {
            let mut order: Vec<usize> = (0..rs.len()).collect();
            order.sort_by(|&a, &b| crate::metrics::falling(rs[a].1.score, rs[b].1.score));
            let mut keep = vec![false; rs.len()];
            order.iter().take(cap).for_each(|&k| keep[k] = true);
            over_cap += rs.len() - cap;
            rs = rs.into_iter().zip(keep).filter(|(_, k)| *k).map(|(r, _)| r).collect();
        }
        kept.extend(rs.into_iter().map(|(i, r)| (i, image, r)));
    }
    kept.sort_by_key(|&(i, ..)| i);
    let list = kept
        .par_iter()
        .map(|&(i, image, r)| {
            let g = &gt_images[image];
            let mask = match (&r.segmentation, opts.task) {
                (Some(s), CocoTask::Segm) => {
                    let m = s.decode().map_err(|e| bad(i, format!("segmentation: {e}")))?;
                    if (m.h, m.w) != (g.height, g.width) {
                        return Err(bad(i, format!("mask size is {}x{} (width x height) but the image is {}x{}", m.w, m.h, g.width, g.height)));
                    }
                    Some(m)
                }
                _ => None,
            };
            let area = match (r.bbox, &mask) {
                (Some(b), _) if box_area => b[2] * b[3],
                (_, Some(m)) => m.area() as f64,
                _ => unreachable!("a result has a box, or a mask here"),
            };
            Ok(Detection { image, category: r.category_id, score: r.score, area, bbox: r.bbox.unwrap_or_default(), mask })
        })
        .collect::<Result<Vec<_>>>()?;
    let ignored = results.len() - without_region - list.len() - over_cap;
    Ok(Detections { list, any: !merged.is_empty(), ignored, without_region, over_cap })
}

/// One group per image and scored object with ground truth or detections,
/// each with its IoU.
fn groups<'a>(gt_images: &'a [GtImage], dets: &'a [Detection], cats: &BTreeSet<u32>, task: CocoTask) -> Vec<Group<'a>> {
    let mut by_key: BTreeMap<(usize, u32), (Vec<usize>, Vec<usize>)> = BTreeMap::new();
    for (i, g) in gt_images.iter().enumerate() {
        for (k, a) in g.anns.iter().enumerate().filter(|(_, a)| cats.contains(&a.category_id)) {
            by_key.entry((i, a.category_id)).or_default().0.push(k);
        }
    }
    for (d, det) in dets.iter().enumerate() {
        by_key.entry((det.image, det.category)).or_default().1.push(d);
    }
    by_key
        .into_iter()
        .map(|((image, category), (gk, dk))| {
            let anns = &gt_images[image].anns;
            let gt = gk.iter().map(|&k| GtRegion { id: anns[k].id, area: anns[k].area, crowd: anns[k].crowd, ignore: anns[k].ignore }).collect();
            let dt = dk.iter().map(|&d| DtRegion { score: dets[d].score, area: dets[d].area }).collect();
            let iou: Box<dyn Fn(usize, usize) -> f64 + Send + Sync> = match task {
                CocoTask::Bbox => Box::new(move |d, g| bbox_iou(&dets[dk[d]].bbox, &anns[gk[g]].bbox, anns[gk[g]].crowd)),
                CocoTask::Segm => Box::new(move |d, g| {
                    let (dm, gm) = (dets[dk[d]].mask.as_ref().expect("decoded"), anns[gk[g]].mask.as_ref().expect("decoded"));
                    mask_iou(dm, gm, anns[gk[g]].crowd)
                }),
            };
            Group { image, category, gt, dt, iou }
        })
        .collect()
}

/// The ground truth of the target images as results: every instance with
/// score 1, its visible mask (compressed RLE) and its box (of `opts.boxes`),
/// no time. Evaluated, every AP is 1: a check of the setup.
pub fn gt_as_results(ds: &Dataset, images: &[(u32, u32)], opts: CocoOptions) -> Result<Vec<CocoResult>> {
    let mut out = Vec::new();
    for (s, ims) in scenes_in_order(images) {
        let scene = ds.scene(s)?;
        let (gt, _) = gt::scene_gt(&scene, &ims, opts.boxes, true)?;
        for g in gt {
            for a in g.anns {
                let m = a.mask.as_ref().expect("masks were asked for");
                out.push(CocoResult {
                    scene_id: s,
                    image_id: g.im_id,
                    category_id: a.category_id,
                    score: 1.0,
                    bbox: Some(a.bbox),
                    segmentation: Some(SegmField::Rle(results::Segmentation { counts: results::Counts::Compressed(m.to_compressed()), size: [m.h, m.w] })),
                    time: None,
                });
            }
        }
    }
    Ok(out)
}

/// Scenes in first-appearance order, images ascending within each: the
/// order of the toolkit's merged image ids, which COCOeval sorts.
fn scenes_in_order(images: &[(u32, u32)]) -> Vec<(u32, BTreeSet<u32>)> {
    let mut scenes: Vec<(u32, BTreeSet<u32>)> = Vec::new();
    for &(s, im) in images {
        match scenes.iter_mut().find(|(id, _)| *id == s) {
            Some((_, ims)) => {
                ims.insert(im);
            }
            None => scenes.push((s, BTreeSet::from([im]))),
        }
    }
    scenes
}
