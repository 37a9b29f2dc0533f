//! Evaluation of a BOP results file against a dataset, exactly as the BOP
//! toolkit's `eval_bop19_pose.py` does it (errors, then BOP'19 scoring),
//! with the renders for VSD on any wgpu adapter or the CPU twin; or, for
//! [`Task::Detection`], as its `eval_bop24_pose.py` does (MSSD and MSPD,
//! then BOP'24 average precision).
//!
//! Data flows one way: targets and estimates are indexed, models loaded
//! once, then images are taken in batches: depth read (in parallel), GT
//! and kept estimates rendered per object in one batched `depth` kernel
//! call, errors computed per (estimate, instance) pair in parallel, and
//! finally the matching and recalls over the whole dataset.

use std::collections::{BTreeMap, HashMap};
use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::bop::{Dataset, DepthMm, Estimate, GtInstance, ModelInfo, PoseMm, Projection, Scene, SensorRule, Target};
use crate::camera::Intrinsics;
use crate::error::{Error, Input, Result};
use crate::kernels::depth::{depth_tiles_cpu, DepthTile, GpuDepth};
use crate::kernels::RenderMesh;
use crate::mesh::Mesh;
use crate::metrics::detection::{self, DetectionTarget};
use crate::metrics::pose_error::{self, PointTree, Symmetry};
use crate::metrics::recall::{self, EstimateErrors, TargetErrors};
use crate::metrics::vsd::{self, VsdImage};
use crate::pose::Pose;
use crate::visual::Device;

/// The pose errors `evaluate` can compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ErrorType {
    Vsd,
    Mssd,
    Mspd,
    /// ADI for symmetric objects, ADD otherwise (BOP's `ad`).
    Ad,
    Add,
    Adi,
}

impl ErrorType {
    pub const ALL: [ErrorType; 6] = [ErrorType::Vsd, ErrorType::Mssd, ErrorType::Mspd, ErrorType::Ad, ErrorType::Add, ErrorType::Adi];
    /// The BOP'19 set, whose recalls make AR.
    pub const BOP19: [ErrorType; 3] = [ErrorType::Vsd, ErrorType::Mssd, ErrorType::Mspd];

    pub fn name(self) -> &'static str {
        match self {
            ErrorType::Vsd => "vsd",
            ErrorType::Mssd => "mssd",
            ErrorType::Mspd => "mspd",
            ErrorType::Ad => "ad",
            ErrorType::Add => "add",
            ErrorType::Adi => "adi",
        }
    }
}

impl std::str::FromStr for ErrorType {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        ErrorType::ALL
            .into_iter()
            .find(|e| e.name() == s.trim().to_ascii_lowercase())
            .ok_or_else(|| format!("unknown error type '{s}' (expected vsd, mssd, mspd, ad, add or adi)"))
    }
}

/// The BOP task whose scoring `evaluate` applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Task {
    /// BOP'19 6D localization: the top `inst_count` estimates per target,
    /// recall per threshold, AR.
    #[default]
    Localization,
    /// BOP'24 6D detection: every estimate (up to a cap per image), average
    /// precision per object over the MSSD and MSPD thresholds, mAP.
    Detection,
}

impl std::str::FromStr for Task {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "localization" | "localisation" | "bop19" => Ok(Task::Localization),
            "detection" | "bop24" => Ok(Task::Detection),
            _ => Err(format!("unknown task '{s}' (expected localization or detection)")),
        }
    }
}

/// What to compute and with which protocol constants (BOP'19 defaults).
#[derive(Clone, Debug)]
pub struct EvalOptions {
    pub task: Task,
    pub errors: Vec<ErrorType>,
    /// VSD visibility tolerance δ, mm.
    pub vsd_delta_mm: f32,
    /// VSD τ as fractions of the diameter.
    pub vsd_taus: Vec<f64>,
    /// Correctness thresholds of VSD and MSSD (MSSD as fractions of the diameter).
    pub thresholds: Vec<f64>,
    /// MSPD thresholds in pixels (at 640 px image width).
    pub mspd_px: Vec<f64>,
    /// Detection: MSSD thresholds in millimetres (BOP'25's `mssd_mm`).
    pub mssd_mm: Vec<f64>,
    /// Detection: estimates kept per image, the highest-scored.
    pub max_estimates_per_image: usize,
    /// Detection: instances visible less than this fraction are ignored.
    pub visib_gt_min: f64,
    /// Detection: the objects scored (the toolkit's list for the dataset,
    /// [`bop_obj_ids`]); `None`: every annotated object.
    pub scored_obj_ids: Option<Vec<u32>>,
    /// ADD/ADI/AD correctness threshold, fraction of the diameter.
    pub add_threshold: f64,
    pub max_sym_disc_step: f64,
    /// Images per batch: bounds memory (depth and renders of a batch are
    /// held at once) while giving the GPU enough poses per dispatch.
    pub batch_images: usize,
    /// Objects that `ad` scores with ADI. `None`: the objects with
    /// symmetries in `models_info.json`; the BOP toolkit uses a fixed list
    /// per dataset ([`bop_symmetric_obj_ids`]).
    pub symmetric_obj_ids: Option<Vec<u32>>,
}

/// The BOP toolkit's `symmetric_obj_ids` per dataset name (which objects
/// its `ad` error scores with ADI); `None` for an unknown name.
pub fn bop_symmetric_obj_ids(dataset: &str) -> Option<Vec<u32>> {
    Some(match dataset {
        "lm" => vec![3, 7, 10, 11],
        "lmo" => vec![10, 11],
        "tless" => (1..=30).collect(),
        "tudl" | "hope" | "hopev2" => vec![],
        "tyol" => vec![3, 4, 5, 6, 7, 8, 10, 11, 12, 13, 15, 16, 17, 18, 19, 21],
        "ruapc" => vec![8, 9, 12, 13],
        "icmi" => vec![1, 2, 6],
        "icbin" => vec![1],
        "itodd" | "itoddmv" => vec![2, 3, 4, 5, 7, 8, 9, 11, 12, 14, 17, 18, 19, 23, 24, 25, 27, 28],
        "hbs" => vec![10, 12, 18, 29],
        "hb" => vec![6, 10, 11, 12, 13, 14, 18, 24, 29],
        "ycbv" => vec![1, 13, 14, 16, 18, 19, 20, 21],
        "hot3d" => vec![1, 2, 3, 5, 22, 24, 25, 29, 30, 32],
        "handal" => vec![26, 35, 36, 37, 38, 39, 40],
        "ipd" => vec![8, 14, 18, 19, 20],
        "xyzibd" => vec![1, 2, 5, 8, 9, 11, 12, 16, 17],
        _ => return None,
    })
}

/// The objects the BOP toolkit scores per dataset name (its model `obj_ids`:
/// detection averages AP over these alone); `None` for an unknown name.
pub fn bop_obj_ids(dataset: &str) -> Option<Vec<u32>> {
    let range = |a: u32, b: u32| (a..=b).collect::<Vec<u32>>();
    Some(match dataset {
        "lm" => range(1, 15),
        "lmo" => vec![1, 5, 6, 8, 9, 10, 11, 12],
        "tless" => range(1, 30),
        "hb" => range(1, 33),
        "tudl" => range(1, 3),
        "tyol" => range(1, 21),
        "ruapc" => range(1, 14),
        "icmi" => range(1, 6),
        "icbin" => range(1, 2),
        "itodd" | "itoddmv" | "hope" | "hopev2" => range(1, 28),
        "hbs" => vec![1, 3, 4, 8, 9, 10, 12, 15, 17, 18, 19, 22, 23, 29, 32, 33],
        "ycbv" => range(1, 21),
        "hot3d" => range(1, 33),
        "handal" => range(1, 40),
        "ipd" => vec![0, 1, 4, 8, 10, 11, 14, 18, 19, 20],
        "xyzibd" => vec![1, 2, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17],
        _ => return None,
    })
}

/// The sensor the BOP toolkit evaluates on a dataset annotated per sensor
/// (its `eval_sensor`): photoneo for IPD, xyz for XYZ-IBD, 3dlong for
/// ITODD-MV; `None` for the others (HOT3D's changes by scene:
/// [`SensorRule::Hot3d`]).
pub fn bop_eval_sensor(dataset: &str) -> Option<&'static str> {
    match dataset {
        "ipd" => Some("photoneo"),
        "xyzibd" => Some("xyz"),
        "itoddmv" => Some("3dlong"),
        _ => None,
    }
}

/// Opens a dataset split for evaluation. Where the split is annotated per
/// sensor: `sensor`, or without one the sensor the BOP toolkit evaluates
/// for the dataset `name` ([`bop_eval_sensor`], HOT3D's per scene); an
/// error names the sensors when neither applies.
pub fn open_dataset(root: &std::path::Path, split: &str, sensor: Option<&str>, name: Option<&str>) -> Result<Dataset> {
    if sensor.is_some() {
        return Dataset::open_sensor(root, split, sensor);
    }
    let ds = Dataset::open(root, split)?;
    let sensors = ds.sensors()?;
    if sensors.is_empty() {
        return Ok(ds);
    }
    if name == Some("hot3d") {
        return Dataset::open_per_scene(root, split, SensorRule::Hot3d);
    }
    match name.and_then(bop_eval_sensor).filter(|s| sensors.iter().any(|x| x == s)) {
        Some(s) => Dataset::open_sensor(root, split, Some(s)),
        None => {
            // HOT3D's cameras (rgb, gray1, gray2) change by scene: the
            // toolkit's choice comes with the dataset's name.
            let hot3d = if sensors.iter().any(|s| s == "gray1") { " (HOT3D: name the dataset hot3d to read each scene with the camera the BOP toolkit evaluates)" } else { "" };
            Err(Error::InvalidInput(format!("sensor: the split '{split}' is annotated per sensor ({}): choose one{hot3d}", sensors.join(", "))).about(Input::Sensor))
        }
    }
}

/// The BOP toolkit's VSD δ per dataset name (mm): 5 for ITODD, 15 otherwise.
pub fn bop_vsd_delta_mm(dataset: &str) -> f32 {
    if dataset.starts_with("itodd") {
        5.0
    } else {
        vsd::DELTA_MM
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            task: Task::Localization,
            errors: ErrorType::BOP19.to_vec(),
            vsd_delta_mm: vsd::DELTA_MM,
            vsd_taus: recall::bop19_fractions(),
            thresholds: recall::bop19_fractions(),
            mspd_px: recall::bop19_mspd_px(),
            mssd_mm: detection::bop25_mssd_mm(),
            max_estimates_per_image: detection::MAX_ESTIMATES_PER_IMAGE,
            visib_gt_min: detection::VISIB_GT_MIN,
            scored_obj_ids: None,
            add_threshold: 0.1,
            max_sym_disc_step: pose_error::MAX_SYM_DISC_STEP,
            batch_images: 100,
            symmetric_obj_ids: None,
        }
    }
}

/// The BOP toolkit's name of the dataset in `dir`: `name` when given (one
/// the toolkit does not know is an error), else the folder's own name when
/// the toolkit knows it, else `None`.
pub fn toolkit_dataset_name(dir: &std::path::Path, name: Option<&str>) -> Result<Option<String>> {
    if let Some(n) = name {
        if bop_symmetric_obj_ids(n).is_none() {
            return Err(Error::InvalidInput(format!(
                "dataset name '{n}' is not a BOP dataset the toolkit knows (lm, lmo, tless, tudl, tyol, ruapc, icmi, icbin, itodd, hb, ycbv, hope, ...)"
            )));
        }
        return Ok(Some(n.to_string()));
    }
    let folder = dir.canonicalize().ok().and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned())).unwrap_or_default();
    Ok(bop_symmetric_obj_ids(&folder).map(|_| folder))
}

impl EvalOptions {
    /// The BOP'19 protocol for the toolkit's dataset `name` (see
    /// [`toolkit_dataset_name`]): the objects `ad` scores with ADI and VSD
    /// δ; without a name, the objects with symmetries in models_info.json
    /// and δ = 15 mm.
    pub fn for_dataset(name: Option<&str>) -> EvalOptions {
        EvalOptions {
            symmetric_obj_ids: name.and_then(bop_symmetric_obj_ids),
            vsd_delta_mm: name.map_or(vsd::DELTA_MM, bop_vsd_delta_mm),
            ..Default::default()
        }
    }

    /// The BOP'24 6D detection protocol for the toolkit's dataset `name`:
    /// MSSD and MSPD, at most 100 estimates per image (200 for XYZ-IBD),
    /// instances visible less than 10 % ignored.
    pub fn detection(name: Option<&str>) -> EvalOptions {
        EvalOptions {
            task: Task::Detection,
            errors: vec![ErrorType::Mssd, ErrorType::Mspd],
            max_estimates_per_image: detection::max_estimates_per_image(name),
            scored_obj_ids: name.and_then(bop_obj_ids),
            ..EvalOptions::for_dataset(name)
        }
    }

    fn has(&self, e: ErrorType) -> bool {
        self.errors.contains(&e)
    }

    /// Checks the numbers before any work.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &'static str, why: String| Err(Error::InvalidInput(format!("{what}: {why}")).about(Input::Setting(what)));
        if self.errors.is_empty() {
            return bad("error types", "none chosen".into());
        }
        if !(self.vsd_delta_mm.is_finite() && self.vsd_delta_mm >= 0.0) {
            return bad("VSD delta", format!("must be a non-negative number of mm, got {}", self.vsd_delta_mm));
        }
        for (what, v) in [("VSD tau", &self.vsd_taus), ("threshold", &self.thresholds), ("MSPD threshold", &self.mspd_px)] {
            if v.is_empty() || v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                return bad(what, "needs one or more positive numbers".into());
            }
        }
        // A fraction of the diameter: beyond 10 diameters every estimate
        // in view counts as correct.
        if !(self.add_threshold > 0.0 && self.add_threshold <= 10.0) {
            return bad("ADD threshold", format!("is a fraction of the object's diameter in (0, 10] (BOP uses 0.1), got {}", self.add_threshold));
        }
        if !(self.max_sym_disc_step.is_finite() && self.max_sym_disc_step >= 1e-4 && self.max_sym_disc_step <= 1.0) {
            return bad("max_sym_disc_step", format!("must lie in [1e-4, 1], got {}", self.max_sym_disc_step));
        }
        if self.task == Task::Detection {
            if let Some(e) = self.errors.iter().find(|e| !matches!(e, ErrorType::Mssd | ErrorType::Mspd)) {
                return bad("error types", format!("the detection task scores mssd and mspd (BOP'24), not {}", e.name()));
            }
            if self.mssd_mm.is_empty() || self.mssd_mm.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                return bad("MSSD mm threshold", "needs one or more positive numbers".into());
            }
            if self.max_estimates_per_image == 0 {
                return bad("estimates per image", "must be at least 1".into());
            }
            if !(0.0..=1.0).contains(&self.visib_gt_min) {
                return bad("minimum visible fraction", format!("must lie in [0, 1], got {}", self.visib_gt_min));
            }
        }
        if self.batch_images == 0 || self.batch_images > MAX_BATCH_IMAGES {
            return bad("batch size", format!("must be 1 to {MAX_BATCH_IMAGES} images (a batch's depth images are held in memory), got {}", self.batch_images));
        }
        Ok(())
    }
}

/// Largest canvas for visible fractions (3× the image each way): 30 M
/// pixels, a 1920×1080 image.
const MAX_CANVAS_PIXELS: usize = 30_000_000;

/// Most images per batch: 1,000 VGA depth images are 1.2 GB of f32.
pub const MAX_BATCH_IMAGES: usize = 1000;

/// Error columns of a pair: point errors first, then one per VSD τ.
const MSSD: usize = 0;
const MSPD: usize = 1;
const AD: usize = 2;
const ADD: usize = 3;
const ADI: usize = 4;
/// MSSD in millimetres (detection's `mssd_mm` thresholds).
const MSSD_MM: usize = 5;
const VSD0: usize = 6;

/// The errors of one estimate against one instance, for inspection.
#[derive(Clone, Debug, Serialize)]
pub struct ErrorRecord {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    /// Line of the estimate in the results file.
    pub line: usize,
    pub score: f64,
    pub gt_id: usize,
    /// VSD per τ (absent when not computed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vsd: Option<Vec<f64>>,
    /// MSSD in mm, MSPD in px, ADD/ADI in mm (absent when not computed;
    /// `null` for the toolkit's "infinite" shortcut).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mssd_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mspd_px: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub add_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adi_mm: Option<f64>,
    /// Rotation error (degrees) and translation error (mm).
    pub re_deg: f64,
    pub te_mm: f64,
}

/// Recall at one threshold.
#[derive(Clone, Debug, Serialize)]
pub struct ThresholdRecall {
    /// The threshold (and τ for VSD).
    pub threshold: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tau: Option<f64>,
    pub recall: f64,
    pub tp: usize,
}

/// Detection: AP at one threshold.
#[derive(Clone, Debug, Serialize)]
pub struct ThresholdAp {
    pub threshold: f64,
    /// Mean over the objects.
    pub ap: f64,
    pub per_object: BTreeMap<u32, f64>,
}

/// Scores of one object.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ObjectScores {
    /// Instances that count (localization: valid; detection: visible enough).
    pub targets: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ar: Option<f64>,
    /// Detection: mean of the object's AP over MSSD and MSPD.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ap: Option<f64>,
    /// Localization: AR (mean recall over the thresholds) per error type,
    /// and for ad/add/adi the recall at the ADD threshold. Detection: AP
    /// (mean over the thresholds) for mssd, mssd_mm and mspd.
    pub by_error: BTreeMap<String, f64>,
}

/// Wall time per stage, seconds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    pub load_s: f64,
    pub render_s: f64,
    pub vsd_s: f64,
    pub point_errors_s: f64,
    pub scoring_s: f64,
    pub total_s: f64,
}

/// The result of an evaluation.
#[derive(Clone, Debug, Default, Serialize)]
pub struct EvalReport {
    pub task: Task,
    /// Mean of AR_VSD, AR_MSSD and AR_MSPD (when all three were computed).
    pub ar: Option<f64>,
    pub ar_vsd: Option<f64>,
    pub ar_mssd: Option<f64>,
    pub ar_mspd: Option<f64>,
    /// Recall at `add_threshold` × diameter for ad, add, adi.
    pub recall_ad: Option<f64>,
    pub recall_add: Option<f64>,
    pub recall_adi: Option<f64>,
    pub add_threshold: f64,
    /// Detection: BOP'24's mAP (mean of the MSSD and MSPD mAPs), each the
    /// mean over objects of the AP averaged over thresholds; `ap_mssd` is
    /// also BOP'25's mAP and `ap_mssd_mm` BOP'25's mAP in mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ap: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ap_mssd: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ap_mspd: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ap_mssd_mm: Option<f64>,
    pub per_object: BTreeMap<u32, ObjectScores>,
    pub per_threshold: BTreeMap<String, Vec<ThresholdRecall>>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub per_threshold_ap: BTreeMap<String, Vec<ThresholdAp>>,
    /// Estimates evaluated (localization: the kept top-`inst_count` of each
    /// target; detection: those of the images' annotated objects).
    pub n_estimates: usize,
    /// Estimates of the file that are not for a target (ignored), and
    /// those dropped by the top-`inst_count` rule (localization) or beyond
    /// the cap per image (detection).
    pub n_ignored: usize,
    pub n_not_top: usize,
    /// Ground-truth instances that count (localization: the valid ones, the
    /// recall denominator; detection: those visible enough).
    pub n_targets: usize,
    pub n_images: usize,
    /// Where visible fractions came from.
    pub visibility: String,
    /// Mean time per image from the results file, −1 when unknown.
    pub average_time_per_image: f64,
    pub device: String,
    pub time_s: Timings,
}

/// One object's model, prepared once.
struct Model {
    info: ModelInfo,
    /// Vertices as the file has them (mm), for the point errors.
    pts: Vec<DVec3>,
    syms: Vec<Symmetry>,
    tree: Option<PointTree>,
    render: Option<RenderMesh>,
}

fn load_models(ds: &Dataset, obj_ids: &[u32], opts: &EvalOptions, need_render: bool) -> Result<HashMap<u32, Model>> {
    let need_tree = opts.has(ErrorType::Adi) || opts.has(ErrorType::Ad);
    obj_ids
        .par_iter()
        .map(|&id| {
            let info = ds.models_info[&id].clone();
            let path = ds.model_path(id);
            let (pts, tris) = ds.model_points(id).map_err(|e| match e {
                Error::NotFound { .. } => Error::InvalidInput(format!(
                    "object {id} is a target (in the targets file, or annotated in the ground truth when there is none) but its model {} was not found",
                    path.display()
                )),
                e => e,
            })?;
            check_points(&path, &pts)?;
            let render = if need_render {
                let metres: Vec<DVec3> = pts.iter().map(|p| *p * 1e-3).collect();
                let (mesh, _) = Mesh::from_raw(&path, metres, tris)?;
                Some(RenderMesh::new(&mesh)?)
            } else {
                None
            };
            let syms = pose_error::symmetries(&info, opts.max_sym_disc_step);
            let tree = need_tree.then(|| PointTree::new(&pts));
            Ok((id, Model { info, pts, syms, tree, render }))
        })
        .collect()
}

/// The point errors need vertices, all finite: without any, every
/// estimate would have error 0 (every one correct), and a NaN would be
/// skipped by some errors and break the nearest-neighbour search of others.
fn check_points(path: &std::path::Path, pts: &[DVec3]) -> Result<()> {
    if pts.is_empty() {
        return Err(Error::MalformedMesh { path: path.to_path_buf(), reason: "the model has no vertices: its pose errors would all be 0".into() });
    }
    crate::mesh::check_finite(path, pts)
}

/// Estimates per (scene, image, object) in file order.
type EstimateIndex<'a> = HashMap<(u32, u32, u32), Vec<&'a Estimate>>;

/// The kept estimates of a target in falling score order, ties in file
/// order (the toolkit's stable sort, where −0 and 0 are a tie): the
/// `inst_count` highest-scored for localization, all for detection.
fn kept<'a>(index: &EstimateIndex<'a>, t: &Target, task: Task) -> Vec<&'a Estimate> {
    let mut v = index.get(&(t.scene_id, t.im_id, t.obj_id)).cloned().unwrap_or_default();
    v.sort_by(falling_score);
    if task == Task::Localization {
        v.truncate(t.inst_count as usize);
    }
    v
}

/// Falling score for the toolkit's stable sorts (`sorted(key=score,
/// reverse=True)`): −0 and 0 tie, and so does NaN, which reading refuses.
fn falling_score(a: &&Estimate, b: &&Estimate) -> std::cmp::Ordering {
    crate::metrics::falling(a.score, b.score)
}

/// The estimates detection looks at: the `cap` highest-scored of each
/// image, in the toolkit's order (`load_bop_results` with
/// `max_num_estimates_per_image`): images as they first appear in the file,
/// each image's estimates by falling score, ties in file order.
fn top_per_image(results: &[Estimate], cap: usize) -> Vec<&Estimate> {
    let mut order: Vec<(u32, u32)> = Vec::new();
    let mut per_image: HashMap<(u32, u32), Vec<&Estimate>> = HashMap::new();
    for e in results {
        let v = per_image.entry((e.scene_id, e.im_id)).or_insert_with(|| {
            order.push((e.scene_id, e.im_id));
            Vec::new()
        });
        v.push(e);
    }
    let mut out = Vec::with_capacity(results.len().min(order.len().saturating_mul(cap)));
    for key in order {
        let mut v = per_image.remove(&key).expect("every image has its list");
        v.sort_by(falling_score);
        out.extend(v.into_iter().take(cap));
    }
    out
}

/// The targets of detection: every annotated object of the images of
/// `targets`, with its instance count, in the toolkit's order (scenes as
/// they first appear, then their images as they first appear, then each
/// image's objects as they are first annotated). Which objects were listed
/// does not matter: BOP'24 targets name images only, and the toolkit
/// rebuilds the objects from the annotations (`inout.get_im_targets`).
pub fn detection_targets(ds: &Dataset, targets: &[Target]) -> Result<Vec<Target>> {
    images_objects(&open_scenes(ds, targets)?, targets)
}

/// The scenes of `targets`, each opened (read and checked) once.
fn open_scenes(ds: &Dataset, targets: &[Target]) -> Result<BTreeMap<u32, Scene>> {
    let ids: std::collections::BTreeSet<u32> = targets.iter().map(|t| t.scene_id).collect();
    ids.into_iter().map(|s| Ok((s, ds.scene(s)?))).collect()
}

/// [`detection_targets`] over the scenes already opened.
fn images_objects(scenes: &BTreeMap<u32, Scene>, targets: &[Target]) -> Result<Vec<Target>> {
    let mut images: Vec<(u32, Vec<u32>)> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for t in targets {
        if !seen.insert((t.scene_id, t.im_id)) {
            continue;
        }
        match images.iter_mut().find(|(s, _)| *s == t.scene_id) {
            Some((_, ims)) => ims.push(t.im_id),
            None => images.push((t.scene_id, vec![t.im_id])),
        }
    }
    let mut out = Vec::new();
    for (scene_id, ims) in images {
        let scene = &scenes[&scene_id];
        for im_id in ims {
            let gt = scene.gt.get(&im_id).ok_or_else(|| Error::BadJson {
                path: scene.file("scene_gt"),
                reason: format!("target image {im_id} is not annotated"),
            })?;
            let mut objs: Vec<(u32, u32)> = Vec::new();
            for g in gt {
                match objs.iter_mut().find(|(o, _)| *o == g.obj_id) {
                    Some((_, n)) => *n += 1,
                    None => objs.push((g.obj_id, 1)),
                }
            }
            out.extend(objs.into_iter().map(|(obj_id, inst_count)| Target { scene_id, im_id, obj_id, inst_count }));
        }
    }
    Ok(out)
}

/// The targets `task` evaluates: those of `file`, else of the dataset's own
/// file (for detection BOP'24's image list first, `test_targets_bop24.json`,
/// then `test_targets_bop19.json`), else every annotated instance.
/// Detection takes the images of whichever it reads ([`detection_targets`]).
pub fn task_targets(ds: &Dataset, file: Option<&std::path::Path>, task: Task) -> Result<(Vec<Target>, crate::bop::TargetSource)> {
    let bop24 = ds.targets_file(true);
    let file = file.map(std::path::Path::to_path_buf).or_else(|| (task == Task::Detection && bop24.is_file()).then_some(bop24));
    ds.targets(file.as_deref())
}

/// One (estimate, instance) pair to compute errors for.
struct Pair<'a> {
    target: usize,
    est_rank: usize,
    est: &'a Estimate,
    gt_id: usize,
    gt: GtInstance,
}

/// Per-image inputs of a batch.
struct Frame {
    im_id: u32,
    /// The image's camera (MSPD projects through it, lens or pinhole).
    camera: Projection,
    /// Image width (MSPD is scaled to 640 px).
    width: u32,
    depth: Option<DepthMm>,
    /// The pinhole intrinsics checked against the depth image, and the K
    /// they came from (when depth is read).
    pinhole: Option<(Intrinsics, [f64; 9])>,
}

impl Frame {
    fn depth_and_intrinsics(&self) -> (&DepthMm, &Intrinsics, &[f64; 9]) {
        let d = self.depth.as_ref().expect("depth is read when rendering");
        let (i, k) = self.pinhole.as_ref().expect("intrinsics come with the depth");
        (d, i, k)
    }
}

/// Evaluates `results` on `targets` of `ds`. `progress(images_done)` is
/// called as images finish; an error it returns stops the evaluation there
/// and is returned (a caller's interrupt). Returns the report and every
/// pair's errors.
pub fn evaluate(
    ds: &Dataset,
    results: &[Estimate],
    targets: &[Target],
    device: &Device,
    opts: &EvalOptions,
    progress: &mut dyn FnMut(usize) -> Result<()>,
) -> Result<(EvalReport, Vec<ErrorRecord>)> {
    opts.validate()?;
    let t_start = Instant::now();
    let mut report = EvalReport { task: opts.task, add_threshold: opts.add_threshold, device: device.describe(), ..Default::default() };
    // Open every scene before the long work, so a bad file fails at once.
    let scenes = open_scenes(ds, targets)?;
    let mut detection_targets_;
    let (targets, results): (&[Target], Vec<&Estimate>) = match opts.task {
        Task::Localization => (targets, results.iter().collect()),
        Task::Detection => {
            detection_targets_ = images_objects(&scenes, targets)?;
            // Objects outside the toolkit's list for the dataset are not scored.
            if let Some(ids) = &opts.scored_obj_ids {
                let annotated = detection_targets_.len();
                detection_targets_.retain(|t| ids.contains(&t.obj_id));
                if annotated > 0 && detection_targets_.is_empty() {
                    return Err(Error::InvalidInput(format!(
                        "none of the objects annotated in the target images is one the BOP toolkit scores for this dataset ({ids:?}): is the dataset name right?"
                    )));
                }
            }
            let capped = top_per_image(results, opts.max_estimates_per_image);
            report.n_not_top = results.len() - capped.len();
            (&detection_targets_, capped)
        }
    };
    let target_keys: std::collections::HashSet<(u32, u32, u32)> = targets.iter().map(|t| (t.scene_id, t.im_id, t.obj_id)).collect();
    let mut index: EstimateIndex = HashMap::new();
    // Rows of objects the dataset does not have are ignored, as the
    // toolkit does (it never looks at them), and said; a file none of whose
    // objects is there is for another dataset, an error.
    let unknown: Vec<&Estimate> = results.iter().copied().filter(|e| !ds.models_info.contains_key(&e.obj_id)).collect();
    if let Some(first) = unknown.first() {
        let where_ = format!("results line {}: object {}", first.line, first.obj_id);
        if unknown.len() == results.len() {
            return Err(Error::InvalidInput(format!("no results line names an object of the dataset's models_info.json ({where_}): are they for another dataset?")));
        }
        tracing::warn!("{} results lines name objects not in the dataset's models_info.json (the first: {where_}); they are ignored, as the BOP toolkit does", unknown.len());
    }
    for &e in &results {
        if target_keys.contains(&(e.scene_id, e.im_id, e.obj_id)) {
            index.entry((e.scene_id, e.im_id, e.obj_id)).or_default().push(e);
        } else {
            report.n_ignored += 1;
        }
    }
    if index.is_empty() && !results.is_empty() {
        tracing::warn!(
            "none of the {} results lines is for a target (scene, image and object of the targets): every target is a miss; are the results for another split or targets file?",
            results.len()
        );
    }
    report.average_time_per_image = average_time_per_image(results.iter().copied());
    let mut obj_ids: Vec<u32> = targets.iter().map(|t| t.obj_id).collect();
    obj_ids.sort_unstable();
    obj_ids.dedup();
    // Each target with its position in `targets` (detection's tie order).
    let mut by_scene: BTreeMap<u32, BTreeMap<u32, Vec<(usize, Target)>>> = BTreeMap::new();
    for (rank, t) in targets.iter().enumerate() {
        by_scene.entry(t.scene_id).or_default().entry(t.im_id).or_default().push((rank, *t));
    }
    report.n_images = by_scene.values().map(|m| m.len()).sum();
    let computed_visibility = by_scene.keys().any(|s| scenes[s].gt_info.is_none());
    let need_depth = opts.has(ErrorType::Vsd) || computed_visibility;
    let t0 = Instant::now();
    let models = tracing::trace_span!("load_models", objects = obj_ids.len()).in_scope(|| load_models(ds, &obj_ids, opts, need_depth))?;
    report.time_s.load_s += t0.elapsed().as_secs_f64();
    report.visibility = if computed_visibility {
        format!("computed from depth (bop19 rule, δ = {} mm) where scene_gt_info.json is missing", opts.vsd_delta_mm)
    } else {
        "scene_gt_info.json".into()
    };
    let mut all_targets: Vec<DetectionTarget> = Vec::new();
    let mut records = Vec::new();
    let mut done = 0;
    for (scene_id, images) in &by_scene {
        let scene = &scenes[scene_id];
        let images: Vec<(&u32, &Vec<(usize, Target)>)> = images.iter().collect();
        for batch in images.chunks(opts.batch_images) {
            // Depth for VSD, or for the visible fractions of a scene without
            // scene_gt_info (the others keep theirs: HOT3D has no depth).
            let need_depth = opts.has(ErrorType::Vsd) || scene.gt_info.is_none();
            let ctx = BatchCtx { scene, models: &models, opts, device, need_depth };
            let _span = tracing::trace_span!("batch", scene = scene.id, images = batch.len()).entered();
            let (t, r) = ctx.run(batch, &index, &mut report)?;
            all_targets.extend(t);
            records.extend(r);
            done += batch.len();
            progress(done)?;
        }
    }
    report.n_estimates = all_targets.iter().map(|t| t.errors.estimates.len()).sum();
    report.n_not_top += index.values().map(|v| v.len()).sum::<usize>() - report.n_estimates;
    report.n_targets = all_targets.iter().map(|t| t.counted.len()).sum();
    let t0 = Instant::now();
    match opts.task {
        Task::Localization => {
            let targets: Vec<TargetErrors> = all_targets.into_iter().map(|t| t.errors).collect();
            tracing::trace_span!("recall").in_scope(|| score(&targets, opts, &mut report));
        }
        Task::Detection => tracing::trace_span!("average_precision").in_scope(|| score_detection(&all_targets, opts, &mut report)),
    }
    report.time_s.scoring_s = t0.elapsed().as_secs_f64();
    report.time_s.total_s = t_start.elapsed().as_secs_f64();
    Ok((report, records))
}

/// Each image's time as the toolkit's `check_consistent_timings` gathers
/// them, shared by the 6D and the 2D tasks.
pub(crate) struct ImageTimes {
    /// In first-appearance order (the toolkit's numpy mean sums them
    /// pairwise in that order), the first estimate standing for its image.
    pub times: Vec<f64>,
    /// Estimates whose time is more than 1 ms from their image's first, in
    /// file order, as (scene, image).
    pub inconsistent: Vec<(u32, u32)>,
    /// False when an estimate had no time (the scan stops there).
    pub complete: bool,
}

/// Gathers [`ImageTimes`] from ((scene, image), time) in file order.
pub(crate) fn image_times(items: impl IntoIterator<Item = ((u32, u32), Option<f64>)>) -> ImageTimes {
    let mut out = ImageTimes { times: Vec::new(), inconsistent: Vec::new(), complete: true };
    let mut slot: HashMap<(u32, u32), usize> = HashMap::new();
    for (key, time) in items {
        let Some(t) = time else {
            out.complete = false;
            break;
        };
        match slot.get(&key) {
            Some(&i) if (out.times[i] - t).abs() > 0.001 => out.inconsistent.push(key),
            Some(_) => {}
            None => {
                slot.insert(key, out.times.len());
                out.times.push(t);
            }
        }
    }
    out
}

/// The toolkit's `average_time_per_image`: −1 unless every estimate has a
/// time ≥ 0 and all estimates of an image agree within 1 ms (its
/// `check_consistent_timings`), the first of them standing for the image.
fn average_time_per_image<'a>(results: impl IntoIterator<Item = &'a Estimate>) -> f64 {
    let t = image_times(results.into_iter().map(|e| ((e.scene_id, e.im_id), (e.time >= 0.0).then_some(e.time))));
    if let Some((scene, im)) = t.inconsistent.first() {
        tracing::warn!("estimates of scene {scene} image {im} carry different times; average time per image is unknown");
        return -1.0;
    }
    if !t.complete || t.times.is_empty() {
        return -1.0;
    }
    pose_error::np_mean(&t.times)
}

/// What a batch of images needs from the caller.
struct BatchCtx<'a> {
    scene: &'a Scene,
    models: &'a HashMap<u32, Model>,
    opts: &'a EvalOptions,
    device: &'a Device,
    need_depth: bool,
}

impl BatchCtx<'_> {
    fn run(
        &self,
        batch: &[(&u32, &Vec<(usize, Target)>)],
        index: &EstimateIndex,
        report: &mut EvalReport,
    ) -> Result<(Vec<DetectionTarget>, Vec<ErrorRecord>)> {
        let t0 = Instant::now();
        let frames = tracing::trace_span!("read_frames").in_scope(|| self.read_frames(batch))?;
        report.time_s.load_s += t0.elapsed().as_secs_f64();
        let visib = tracing::trace_span!("visibility").in_scope(|| self.visible_fractions(&frames, report))?;
        let mut targets = Vec::new();
        let mut pairs = Vec::new();
        for (fi, (im_id, tlist)) in batch.iter().enumerate() {
            let gt = &self.scene.gt[im_id];
            let objs: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
            for (rank, t) in tlist.iter() {
                let ests = kept(index, t, self.opts.task);
                let ti = targets.len();
                for (rank, est) in ests.iter().enumerate() {
                    for (gt_id, g) in gt.iter().enumerate().filter(|(_, g)| g.obj_id == t.obj_id) {
                        pairs.push((fi, Pair { target: ti, est_rank: rank, est, gt_id, gt: *g }));
                    }
                }
                let valid = recall::valid_instances(&objs, &visib[im_id], t.obj_id, t.inst_count);
                let counted = match self.opts.task {
                    Task::Localization => valid.clone(),
                    Task::Detection => valid.iter().copied().filter(|&g| visib[im_id][g] >= self.opts.visib_gt_min).collect(),
                };
                let estimates = ests.iter().map(|e| EstimateErrors { score: e.score, errors: Vec::new() }).collect();
                targets.push(DetectionTarget { errors: TargetErrors { obj_id: t.obj_id, valid, estimates }, counted, rank: *rank });
            }
        }
        let t0 = Instant::now();
        let point_errors = tracing::trace_span!("point_errors", pairs = pairs.len()).entered();
        let mut errors: Vec<Vec<f64>> = pairs.par_iter().map(|(fi, p)| self.point_errors(&frames[*fi], p)).collect();
        drop(point_errors);
        report.time_s.point_errors_s += t0.elapsed().as_secs_f64();
        if self.opts.has(ErrorType::Vsd) {
            tracing::trace_span!("vsd_errors").in_scope(|| self.vsd_errors(&frames, &pairs, &mut errors, report))?;
        }
        let mut records = Vec::with_capacity(pairs.len());
        for ((fi, p), errs) in pairs.iter().zip(errors) {
            records.push(self.record(frames[*fi].im_id, p, &errs));
            targets[p.target].errors.estimates[p.est_rank].errors.push((p.gt_id, errs));
        }
        Ok((targets, records))
    }

    fn read_frames(&self, batch: &[(&u32, &Vec<(usize, Target)>)]) -> Result<Vec<Frame>> {
        batch
            .par_iter()
            .map(|(&im_id, _)| {
                if !self.scene.gt.contains_key(&im_id) {
                    return Err(Error::BadJson {
                        path: self.scene.file("scene_gt"),
                        reason: format!("target image {im_id} is not annotated"),
                    });
                }
                let camera = self.scene.frame_camera(im_id)?.projection;
                if self.need_depth {
                    self.scene.pinhole_k(im_id).map_err(|e| match (&self.scene.gt_info, self.opts.has(ErrorType::Vsd)) {
                        (None, false) => Error::InvalidInput(format!(
                            "{} is missing: without it the visible fractions are computed from depth, which needs a pinhole camera ({e})",
                            self.scene.file("scene_gt_info").display()
                        )),
                        _ => e,
                    })?;
                }
                let depth = if self.need_depth { Some(self.scene.read_depth(im_id)?) } else { None };
                let (width, pinhole) = match &depth {
                    Some(d) => (d.width, Some(self.scene.pinhole(im_id, d.width, d.height)?)),
                    None => (self.scene.image_size(im_id)?.0, None),
                };
                Ok(Frame { im_id, camera, width, depth, pinhole })
            })
            .collect()
    }

    /// Visible fraction of every instance of the batch's images, from
    /// `scene_gt_info.json` or computed from the depth.
    fn visible_fractions(&self, frames: &[Frame], report: &mut EvalReport) -> Result<HashMap<u32, Vec<f64>>> {
        if let Some(info) = &self.scene.gt_info {
            return frames
                .iter()
                .map(|f| {
                    info.get(&f.im_id).cloned().map(|v| (f.im_id, v)).ok_or_else(|| Error::BadJson {
                        path: self.scene.file("scene_gt_info"),
                        reason: format!("no entry for image {}", f.im_id),
                    })
                })
                .collect();
        }
        let t0 = Instant::now();
        let mut out = HashMap::new();
        for f in frames {
            let (depth, k, kk) = f.depth_and_intrinsics();
            let mesh_of = |obj: u32| self.models.get(&obj).and_then(|m| m.render.as_ref());
            let fr = frame_visibility(self.device, &self.scene.gt[&f.im_id], mesh_of, depth, k, kk, self.opts.vsd_delta_mm)?;
            out.insert(f.im_id, fr);
        }
        report.time_s.render_s += t0.elapsed().as_secs_f64();
        Ok(out)
    }

    /// MSSD, MSPD and the ADD family of one pair (normalized columns; VSD
    /// columns are filled later).
    fn point_errors(&self, f: &Frame, p: &Pair) -> Vec<f64> {
        let m = &self.models[&p.est.obj_id];
        let d = m.info.diameter;
        let (e, g) = (&p.est.pose, &p.gt.pose);
        let mut out = vec![f64::NAN; VSD0 + self.opts.vsd_taus.len()];
        let overlap = pose_error::spheres_overlap(e.t, g.t, d);
        let far = |f: &dyn Fn() -> f64| if overlap { f() } else { f64::INFINITY };
        if self.opts.has(ErrorType::Mssd) {
            out[MSSD_MM] = far(&|| pose_error::mssd(e, g, &m.pts, &m.syms));
            out[MSSD] = out[MSSD_MM] / d;
        }
        if self.opts.has(ErrorType::Mspd) {
            out[MSPD] = pose_error::mspd(e, g, &f.camera, &m.pts, &m.syms) * (640.0 / f.width as f64);
        }
        let add = || far(&|| pose_error::add(e, g, &m.pts)) / d;
        let adi = || far(&|| pose_error::adi(e, g, &m.pts, m.tree.as_ref().expect("point tree"))) / d;
        if self.opts.has(ErrorType::Add) {
            out[ADD] = add();
        }
        if self.opts.has(ErrorType::Adi) {
            out[ADI] = adi();
        }
        if self.opts.has(ErrorType::Ad) {
            let symmetric = match &self.opts.symmetric_obj_ids {
                Some(ids) => ids.contains(&p.est.obj_id),
                None => m.info.is_symmetric(),
            };
            out[AD] = if symmetric {
                if self.opts.has(ErrorType::Adi) {
                    out[ADI]
                } else {
                    adi()
                }
            } else if self.opts.has(ErrorType::Add) {
                out[ADD]
            } else {
                add()
            };
        }
        out
    }

    /// Renders the batch's estimates and instances per object (one batched
    /// kernel call per object and camera) and fills the VSD columns.
    fn vsd_errors(&self, frames: &[Frame], pairs: &[(usize, Pair)], errors: &mut [Vec<f64>], report: &mut EvalReport) -> Result<()> {
        // Which pairs need renders (the toolkit's sphere shortcut gives 1).
        let need: Vec<bool> = pairs
            .iter()
            .map(|(_, p)| pose_error::sphere_projections_overlap(0.5 * self.models[&p.est.obj_id].info.diameter, p.est.pose.t, p.gt.pose.t))
            .collect();
        // Unique poses to render, grouped by object and camera (images with
        // the same intrinsics share one batched kernel call).
        let mut groups: BTreeMap<GroupKey, (Intrinsics, Vec<PoseMm>)> = BTreeMap::new();
        let mut slot: HashMap<(usize, RenderKey), usize> = HashMap::new();
        let mut idx = Vec::with_capacity(pairs.len());
        for ((fi, p), &n) in pairs.iter().zip(&need) {
            if !n {
                idx.push(None);
                continue;
            }
            let (_, k, _) = frames[*fi].depth_and_intrinsics();
            let key = (p.est.obj_id, camera_key(k));
            let group = &mut groups.entry(key).or_insert_with(|| (*k, Vec::new())).1;
            let mut add = |rk: RenderKey, pose: PoseMm| {
                *slot.entry((*fi, rk)).or_insert_with(|| {
                    group.push(pose);
                    group.len() - 1
                })
            };
            let e = add(RenderKey::Estimate(p.target, p.est_rank), p.est.pose);
            let g = add(RenderKey::Gt(p.gt_id), p.gt.pose);
            idx.push(Some((key, e, g)));
        }
        let render = tracing::trace_span!("render", groups = groups.len()).entered();
        let t0 = Instant::now();
        let mut renders: HashMap<GroupKey, Vec<Option<DepthTile>>> = HashMap::new();
        for (key, (k, poses)) in &groups {
            let mesh = self.models[&key.0].render.as_ref().expect("render mesh");
            let metres: Vec<Pose> = poses.iter().map(|p| p.to_pose()).collect();
            renders.insert(*key, render_depth(self.device, mesh, &metres, k)?);
        }
        report.time_s.render_s += t0.elapsed().as_secs_f64();
        drop(render);
        let _vsd = tracing::trace_span!("vsd").entered();
        let t0 = Instant::now();
        let images: Vec<VsdImage> = frames
            .iter()
            .map(|f| {
                let (d, _, k) = f.depth_and_intrinsics();
                VsdImage::new(d, k)
            })
            .collect();
        let taus = &self.opts.vsd_taus;
        errors.par_iter_mut().zip(pairs.par_iter().zip(idx.par_iter())).for_each(|(out, ((fi, p), ix))| {
            let v = match ix {
                None => vec![1.0; taus.len()],
                Some((key, e, g)) => {
                    let r = &renders[key];
                    let d = self.models[&p.est.obj_id].info.diameter;
                    vsd::vsd(&images[*fi], r[*e].as_ref(), r[*g].as_ref(), self.opts.vsd_delta_mm, taus, d)
                }
            };
            out[VSD0..].copy_from_slice(&v);
        });
        report.time_s.vsd_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    fn record(&self, im_id: u32, p: &Pair, errs: &[f64]) -> ErrorRecord {
        let d = self.models[&p.est.obj_id].info.diameter;
        let has = |e| self.opts.has(e);
        let finite = |v: f64| v.is_finite().then_some(v);
        ErrorRecord {
            scene_id: self.scene.id,
            im_id,
            obj_id: p.est.obj_id,
            line: p.est.line,
            score: p.est.score,
            gt_id: p.gt_id,
            vsd: has(ErrorType::Vsd).then(|| errs[VSD0..].to_vec()),
            mssd_mm: if has(ErrorType::Mssd) { finite(errs[MSSD] * d) } else { None },
            mspd_px: if has(ErrorType::Mspd) { finite(errs[MSPD]) } else { None },
            add_mm: if has(ErrorType::Add) { finite(errs[ADD] * d) } else { None },
            adi_mm: if has(ErrorType::Adi) { finite(errs[ADI] * d) } else { None },
            re_deg: pose_error::re(&p.est.pose.r, &p.gt.pose.r),
            te_mm: pose_error::te(p.est.pose.t, p.gt.pose.t),
        }
    }
}

/// Identifies a render of an image: a kept estimate (target, rank) or an
/// annotated instance (gt id).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum RenderKey {
    Estimate(usize, usize),
    Gt(usize),
}

/// Renders are grouped by object and camera (intrinsics bits and size).
type GroupKey = (u32, ([u64; 4], u32, u32));

fn camera_key(k: &Intrinsics) -> ([u64; 4], u32, u32) {
    ([k.fx.to_bits(), k.fy.to_bits(), k.cx.to_bits(), k.cy.to_bits()], k.width, k.height)
}

/// Depth tiles of `poses` on `device` (GPU kernel or CPU twin).
pub fn render_depth(device: &Device, mesh: &RenderMesh, poses: &[Pose], k: &Intrinsics) -> Result<Vec<Option<DepthTile>>> {
    match device {
        Device::Gpu(ctx) => GpuDepth::for_poses(ctx, mesh, k, poses)?.render(poses),
        Device::Cpu => Ok(depth_tiles_cpu(mesh, poses, k)),
    }
}

/// The visible fraction of one instance as BOP's `calc_gt_info.py` computes
/// it: the object rendered alone on a canvas three times the image (so
/// parts outside the image count), visible pixels by the bop19 rule against
/// the test depth, divided by all rendered pixels.
fn visible_fraction(
    device: &Device,
    mesh: &RenderMesh,
    pose: &PoseMm,
    k: &Intrinsics,
    depth: &DepthMm,
    kk: &[f64; 9],
    delta: f32,
) -> Result<f64> {
    let (w, h) = (k.width as usize, k.height as usize);
    if 9 * w * h > MAX_CANVAS_PIXELS {
        return Err(Error::InvalidInput(format!(
            "a {w}x{h} image is too large to compute visible fractions the BOP way (a 3x canvas of {} pixels); give the scene a scene_gt_info.json",
            9 * w * h
        )));
    }
    let canvas = Intrinsics { cx: k.cx + w as f64, cy: k.cy + h as f64, width: k.width * 3, height: k.height * 3, ..*k };
    let tile = render_depth(device, mesh, &[pose.to_pose()], &canvas)?.pop().flatten();
    let Some(tile) = tile else { return Ok(0.0) };
    let all = tile.covered();
    if all == 0 {
        return Ok(0.0);
    }
    let img = VsdImage::new(depth, kk);
    let mut visible = 0usize;
    for y in 0..h {
        for x in 0..w {
            let d = (tile.at(x + w, y + h) as f64 * 1000.0) as f32;
            if d > 0.0 {
                let dm = img.distance(d, x, y);
                let dt = img.distance(depth.mm[y * w + x], x, y);
                if (dm as f32 - dt as f32) <= delta || dt == 0.0 {
                    visible += 1;
                }
            }
        }
    }
    Ok(visible as f64 / all as f64)
}

/// Visible fractions of every instance in the first `max_images` images of
/// `scene`, computed from the depth as [`evaluate`] does without
/// `scene_gt_info.json` with the BOP'19 tolerance of 15 mm (`evaluate`
/// takes the dataset's, 5 mm for ITODD, as `calc_gt_info.py` does);
/// instances whose model file is missing get 0.
pub fn visible_fractions(ds: &Dataset, scene: &Scene, device: &Device, max_images: usize) -> Result<BTreeMap<u32, Vec<f64>>> {
    let mut meshes = HashMap::new();
    scene.gt.keys().take(max_images).map(|&im| Ok((im, image_visibility(ds, scene, im, device, vsd::DELTA_MM, &mut meshes)?))).collect()
}

/// Render meshes by object id, loaded on first use (`None`: no model file).
type MeshCache = HashMap<u32, Option<RenderMesh>>;

/// Visible fractions of the instances of image `im` of `scene`, computed
/// from its depth with the visibility tolerance `delta_mm`.
fn image_visibility(ds: &Dataset, scene: &Scene, im: u32, device: &Device, delta_mm: f32, meshes: &mut MeshCache) -> Result<Vec<f64>> {
    let gt = scene.gt.get(&im).map(Vec::as_slice).unwrap_or_default();
    let depth = scene.read_depth(im)?;
    let (k, kk) = scene.pinhole(im, depth.width, depth.height)?;
    for g in gt {
        if let std::collections::hash_map::Entry::Vacant(e) = meshes.entry(g.obj_id) {
            let path = ds.model_path(g.obj_id);
            let mesh = if path.exists() { Some(RenderMesh::new(&ds.model_mesh(g.obj_id)?)?) } else { None };
            e.insert(mesh);
        }
    }
    let mesh_of = |obj: u32| meshes.get(&obj).and_then(Option::as_ref);
    frame_visibility(device, gt, mesh_of, &depth, &k, &kk, delta_mm)
}

/// Visible fractions of an image's instances (0 for objects without a
/// render mesh), the BOP way ([`visible_fraction`]).
fn frame_visibility<'m>(
    device: &Device,
    gt: &[GtInstance],
    mesh_of: impl Fn(u32) -> Option<&'m RenderMesh>,
    depth: &DepthMm,
    k: &Intrinsics,
    kk: &[f64; 9],
    delta: f32,
) -> Result<Vec<f64>> {
    gt.iter()
        .map(|g| match mesh_of(g.obj_id) {
            Some(m) => visible_fraction(device, m, &g.pose, k, depth, kk, delta),
            None => Ok(0.0),
        })
        .collect()
}

/// Matching and recalls over every target; fills the report's AR fields.
fn score(targets: &[TargetErrors], opts: &EvalOptions, report: &mut EvalReport) {
    let mut per_obj_sums: BTreeMap<u32, BTreeMap<String, (f64, usize)>> = BTreeMap::new();
    let mut ar_of = |name: &str, rows: Vec<(f64, Option<f64>, usize)>, report: &mut EvalReport| -> f64 {
        let mut out = Vec::new();
        let mut sum = 0.0;
        for (th, tau, col) in &rows {
            let r = recall::recall(targets, *th, *col);
            sum += r.recall;
            for (o, rec) in &r.per_object {
                let e = per_obj_sums.entry(*o).or_default().entry(name.to_string()).or_default();
                e.0 += rec;
                e.1 += 1;
            }
            out.push(ThresholdRecall { threshold: *th, tau: *tau, recall: r.recall, tp: r.tp });
        }
        report.per_threshold.insert(name.to_string(), out);
        sum / rows.len() as f64
    };
    if opts.has(ErrorType::Vsd) {
        let rows = opts
            .vsd_taus
            .iter()
            .enumerate()
            .flat_map(|(i, &tau)| opts.thresholds.iter().map(move |&th| (th, Some(tau), VSD0 + i)))
            .collect();
        report.ar_vsd = Some(ar_of("vsd", rows, report));
    }
    if opts.has(ErrorType::Mssd) {
        report.ar_mssd = Some(ar_of("mssd", opts.thresholds.iter().map(|&t| (t, None, MSSD)).collect(), report));
    }
    if opts.has(ErrorType::Mspd) {
        report.ar_mspd = Some(ar_of("mspd", opts.mspd_px.iter().map(|&t| (t, None, MSPD)).collect(), report));
    }
    for (e, col) in [(ErrorType::Ad, AD), (ErrorType::Add, ADD), (ErrorType::Adi, ADI)] {
        if opts.has(e) {
            let r = ar_of(e.name(), vec![(opts.add_threshold, None, col)], report);
            match e {
                ErrorType::Ad => report.recall_ad = Some(r),
                ErrorType::Add => report.recall_add = Some(r),
                _ => report.recall_adi = Some(r),
            }
        }
    }
    if let (Some(a), Some(b), Some(c)) = (report.ar_vsd, report.ar_mssd, report.ar_mspd) {
        report.ar = Some((a + b + c) / 3.0);
    }
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for t in targets {
        *counts.entry(t.obj_id).or_default() += t.valid.len();
    }
    for (o, sums) in per_obj_sums {
        let by_error: BTreeMap<String, f64> = sums.into_iter().map(|(k, (s, n))| (k, s / n as f64)).collect();
        let ar = match (by_error.get("vsd"), by_error.get("mssd"), by_error.get("mspd")) {
            (Some(a), Some(b), Some(c)) => Some((a + b + c) / 3.0),
            _ => None,
        };
        report.per_object.insert(o, ObjectScores { targets: counts.get(&o).copied().unwrap_or(0), ar, ap: None, by_error });
    }
}

/// Detection: AP per object and threshold for MSSD (as a fraction of the
/// diameter and in mm) and MSPD, their means over thresholds and objects
/// (`eval_bop24_pose.py`); fills the report's AP fields.
fn score_detection(targets: &[DetectionTarget], opts: &EvalOptions, report: &mut EvalReport) {
    let mut sets: Vec<(&str, &[f64], usize)> = Vec::new();
    if opts.has(ErrorType::Mssd) {
        sets.push(("mssd", &opts.thresholds, MSSD));
        sets.push(("mssd_mm", &opts.mssd_mm, MSSD_MM));
    }
    if opts.has(ErrorType::Mspd) {
        sets.push(("mspd", &opts.mspd_px, MSPD));
    }
    let mut counted: BTreeMap<u32, usize> = BTreeMap::new();
    for t in targets {
        *counted.entry(t.errors.obj_id).or_default() += t.counted.len();
    }
    // By id, the order of the toolkit's scores files (`json.dumps(sort_keys)`
    // sorts the integer ids), which the last bits of its numpy means follow.
    let objects: Vec<u32> = counted.iter().filter(|(_, n)| **n > 0).map(|(o, _)| *o).collect();
    for (name, thresholds, column) in sets {
        let per_threshold: Vec<BTreeMap<u32, f64>> = thresholds.iter().map(|&th| detection::object_ap(targets, th, column)).collect();
        let mut means = Vec::with_capacity(objects.len());
        for o in &objects {
            let aps: Vec<f64> = per_threshold.iter().map(|m| m[o]).collect();
            let ap = pose_error::np_mean(&aps);
            means.push(ap);
            let scores = report.per_object.entry(*o).or_default();
            scores.targets = counted[o];
            scores.by_error.insert(name.to_string(), ap);
        }
        let ap = pose_error::np_mean(&means);
        let rows = thresholds
            .iter()
            .zip(per_threshold)
            .map(|(&threshold, per_object)| {
                let ap = pose_error::np_mean(&objects.iter().map(|o| per_object[o]).collect::<Vec<_>>());
                ThresholdAp { threshold, ap, per_object }
            })
            .collect();
        report.per_threshold_ap.insert(name.to_string(), rows);
        match name {
            "mssd" => report.ap_mssd = Some(ap),
            "mssd_mm" => report.ap_mssd_mm = Some(ap),
            _ => report.ap_mspd = Some(ap),
        }
    }
    if let (Some(a), Some(b)) = (report.ap_mssd, report.ap_mspd) {
        report.ap = Some(pose_error::np_mean(&[a, b]));
    }
    for s in report.per_object.values_mut() {
        if let (Some(a), Some(b)) = (s.by_error.get("mssd"), s.by_error.get("mspd")) {
            s.ap = Some(pose_error::np_mean(&[*a, *b]));
        }
    }
}

/// The ground truth of `targets` as a results file: for each target its
/// valid instances (the most visible `inst_count`, by `scene_gt_info.json`
/// or, where a scene has none, computed from the depth on `device` with
/// `opts`' tolerance as [`evaluate`] does), score 1, time −1. Its AR is 1.
pub fn gt_as_results(ds: &Dataset, targets: &[Target], device: &Device, opts: &EvalOptions) -> Result<Vec<Estimate>> {
    let mut out = Vec::new();
    let mut scenes: BTreeMap<u32, Scene> = BTreeMap::new();
    let mut computed: HashMap<(u32, u32), Vec<f64>> = HashMap::new();
    let mut meshes = MeshCache::new();
    for t in targets {
        let scene = match scenes.entry(t.scene_id) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => e.insert(ds.scene(t.scene_id)?),
        };
        let gt = scene.gt.get(&t.im_id).ok_or_else(|| Error::BadJson {
            path: scene.file("scene_gt"),
            reason: format!("target image {} is not annotated", t.im_id),
        })?;
        let objs: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
        let vis = match scene.gt_info.as_ref().and_then(|i| i.get(&t.im_id)) {
            Some(vis) => vis,
            None => match computed.entry((t.scene_id, t.im_id)) {
                std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::hash_map::Entry::Vacant(e) => e.insert(image_visibility(ds, scene, t.im_id, device, opts.vsd_delta_mm, &mut meshes)?),
            },
        };
        let ids = recall::valid_instances(&objs, vis, t.obj_id, t.inst_count);
        for i in ids {
            out.push(Estimate {
                scene_id: t.scene_id,
                im_id: t.im_id,
                obj_id: t.obj_id,
                score: 1.0,
                pose: gt[i].pose,
                time: -1.0,
                line: 0,
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(im_id: u32, time: f64) -> Estimate {
        let pose = PoseMm { r: glam::DMat3::IDENTITY, t: glam::DVec3::new(0.0, 0.0, 700.0) };
        Estimate { scene_id: 2, im_id, obj_id: 1, score: 1.0, pose, time, line: 0 }
    }

    /// A setting out of range is refused naming it, by its name and in the
    /// error's mark (the CLI blames the flag that gave it).
    #[test]
    fn settings_out_of_range_are_named() {
        let e = EvalOptions { add_threshold: 20.0, ..Default::default() }.validate().unwrap_err();
        assert_eq!(e.input(), Some(Input::Setting("ADD threshold")), "{e}");
        let e = EvalOptions { batch_images: 0, ..Default::default() }.validate().unwrap_err();
        assert_eq!(e.input(), Some(Input::Setting("batch size")), "{e}");
        assert!(e.to_string().starts_with("batch size: "), "{e}");
    }

    #[test]
    fn times_of_an_image_agree_within_a_millisecond_as_in_the_toolkit() {
        assert_eq!(average_time_per_image(&[at(1, 0.5), at(1, 0.5005), at(2, 1.5)]), 1.0);
        assert_eq!(average_time_per_image(&[at(1, 0.5), at(1, 0.502), at(2, 1.5)]), -1.0);
        assert_eq!(average_time_per_image(&[at(1, 0.5), at(2, -1.0)]), -1.0);
        assert_eq!(average_time_per_image(&[]), -1.0);
    }
}
