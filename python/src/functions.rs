//! The module's functions: plane fitting, scene checks, stable poses,
//! hypotheses on the plane and BOP evaluation. Each takes arrays or paths
//! and returns numpy arrays or plain Python objects (dicts, lists).

use std::path::PathBuf;

use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use plausible::gpu::{Device, DeviceChoice};
use plausible::physical::check::{check_scene, CheckOptions};
use plausible::physical::simulate::{displacement_until, SimSettings};
use plausible::physical::Scene;
use plausible::support_plane::{fit_support_plane, PlaneFitParams};
use numpy::prelude::*;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{self, json_to_py};
use crate::mesh::Mesh;
use crate::{to_py, value_error};

/// Fits the support plane to the depth outside the (grown) mask by RANSAC.
#[pyfunction]
#[pyo3(signature = (k, depth, mask = None, *, inlier = 0.005, iterations = 500, seed = 0, mask_margin = 5))]
#[allow(clippy::too_many_arguments)]
pub fn fit_plane<'py>(
    py: Python<'py>,
    k: PyReadonlyArray1<f64>,
    depth: PyReadonlyArray2<f32>,
    mask: Option<PyReadonlyArray2<bool>>,
    inlier: f64,
    iterations: usize,
    seed: u64,
    mask_margin: usize,
) -> PyResult<Bound<'py, PyDict>> {
    if !(inlier.is_finite() && inlier > 0.0 && inlier < 1.0) {
        return Err(value_error(format!("inlier {inlier}: the inlier distance is in metres and must lie in (0, 1)")));
    }
    if iterations == 0 {
        return Err(value_error("iterations must be at least 1"));
    }
    let obs = convert::depth_image(k, depth)?;
    let mask = convert::mask(mask, &obs)?;
    let fit = crate::interruptible(py, |stop| {
        let params = PlaneFitParams { inlier_m: inlier, iterations, seed, mask_margin_px: mask_margin, stop, ..Default::default() };
        fit_support_plane(&obs, mask.as_deref(), &params)
    })?;
    let d = PyDict::new(py);
    d.set_item("point", fit.plane.point.to_array().to_vec().into_pyarray(py))?;
    d.set_item("normal", fit.plane.normal.to_array().to_vec().into_pyarray(py))?;
    d.set_item("inliers", fit.inliers)?;
    d.set_item("candidates", fit.candidates)?;
    d.set_item("rms", fit.rms)?;
    Ok(d)
}

/// Physical plausibility of a scene (the `plausible check` JSON as text;
/// mesh paths relative to `base`): one dict per object.
#[pyfunction]
#[pyo3(signature = (scene_json, base, name, *, samples = plausible::physical::samples::DEFAULT_SAMPLES, seed = plausible::physical::samples::DEFAULT_SEED, epsilon = None, sdf_resolution = plausible::physical::sdf::DEFAULT_RESOLUTION, friction = plausible::physical::friction::DEFAULT_FRICTION, simulate = false))]
#[allow(clippy::too_many_arguments)]
pub fn check<'py>(
    py: Python<'py>,
    scene_json: &str,
    base: PathBuf,
    name: PathBuf,
    samples: usize,
    seed: u64,
    epsilon: Option<f64>,
    sdf_resolution: usize,
    friction: f64,
    simulate: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let (checks, sims) = crate::interruptible(py, |stop| {
        let scene = Scene::from_json(scene_json, &base, &name)?;
        let opts = CheckOptions { samples, seed, epsilon, sdf_resolution, friction, stop: stop.clone() };
        let checks = check_scene(&scene, &opts)?;
        let sims = if simulate { displacement_until(&scene, &SimSettings::default(), &stop)? } else { vec![None; checks.len()] };
        Ok((checks, sims))
    })?;
    let records: Vec<_> = checks.iter().zip(&sims).map(|(o, sim)| o.record(sim.as_deref())).collect();
    let v = serde_json::to_value(&records).map_err(|e| value_error(e.to_string()))?;
    json_to_py(py, &v)
}

/// Stable resting poses of `mesh` from `drops` seeded drop tests (rapier),
/// clustered modulo yaw: the discrete poses and the rolling or scattered
/// families, each with its probability and Wilson 95 % interval.
#[pyfunction]
#[pyo3(signature = (mesh, *, drops = 1000, seed = 0, collider = "hull", threads = None))]
pub fn stable_poses<'py>(py: Python<'py>, mesh: &Mesh, drops: u64, seed: u64, collider: &str, threads: Option<usize>) -> PyResult<Bound<'py, PyAny>> {
    use plausible::stable::{self, ColliderKind, RunParams};
    if drops == 0 || drops > 10_000_000 {
        return Err(value_error(format!("drops {drops}: between 1 and 10,000,000")));
    }
    let collider = match collider {
        "hull" => ColliderKind::Hull,
        "decomposition" => ColliderKind::Decomposition,
        c => return Err(value_error(format!("collider '{c}': expected \"hull\" or \"decomposition\""))),
    };
    if let Some(t) = threads.filter(|&t| t > 1024) {
        return Err(value_error(format!("threads {t}: between 1 and 1024 (None or 0: every logical CPU)")));
    }
    // 0 is every logical CPU, as the CLI's --threads 0.
    let threads = threads.filter(|&t| t > 0).unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let params = RunParams { drops, seed, collider, ..Default::default() };
    let m = mesh.inner.clone();
    let (prepared, results) = crate::interruptible(py, |stop| {
        let name = m.source.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "<arrays>".into());
        let prepared = stable::prepare(m, &name, &params)?;
        stop.check()?;
        let indices: Vec<u64> = (0..drops).collect();
        let mut results = Vec::with_capacity(drops as usize);
        stable::run_drops(&prepared, &params, &indices, threads, |r| {
            results.push(r);
            stop.check()
        })?;
        results.sort_by_key(|r| r.index);
        Ok((prepared, results))
    })?;
    // About the centre of mass, as `plausible stable-poses` stores them.
    let clusters = stable::cluster::cluster_about(&results, Default::default(), prepared.mass.com);
    let (poses, families) = stable::export::split(&clusters);
    let settled = results.iter().filter(|r| r.settled).count();
    let v = serde_json::json!({
        "sha256": prepared.sha256, "drops": drops, "settled": settled, "seed": seed,
        "clusters": poses, "families": families, "warnings": prepared.warnings,
    });
    json_to_py(py, &v)
}

/// Pose hypotheses on the support plane: resting poses (from a stable-pose
/// export's JSON text, or the quasi-static analysis of the convex hull) x
/// yaw steps x in-plane offsets around the observed object.
#[pyfunction]
#[pyo3(signature = (mesh, k, depth, mask, plane_point, plane_normal, *, stable_export = None, yaw_steps = 24, grid_radius = 0, grid_step = 0.005, min_probability = 0.01))]
#[allow(clippy::too_many_arguments)]
pub fn hypotheses<'py>(
    py: Python<'py>,
    mesh: &Mesh,
    k: PyReadonlyArray1<f64>,
    depth: PyReadonlyArray2<f32>,
    mask: PyReadonlyArray2<bool>,
    plane_point: PyReadonlyArray1<f64>,
    plane_normal: PyReadonlyArray1<f64>,
    stable_export: Option<&str>,
    yaw_steps: usize,
    grid_radius: usize,
    grid_step: f64,
    min_probability: f64,
) -> PyResult<Bound<'py, PyDict>> {
    use plausible::hypotheses::on_plane::{on_plane_hypotheses, OnPlaneParams};
    if !(0.0..1.0).contains(&min_probability) {
        return Err(value_error(format!("min_probability {min_probability}: must lie in [0, 1)")));
    }
    let obs = convert::depth_image(k, depth)?;
    let mask = convert::mask(Some(mask), &obs)?.expect("given");
    let plane = convert::plane(&plane_point, &plane_normal)?;
    let m = &mesh.inner;
    // A mesh far larger than what the mask sees (units?) is warned about;
    // one smaller than it is refused by on_plane_hypotheses.
    if let Some(w) = plausible::hypotheses::on_plane::check_mesh_size(m, &obs, &mask).map_err(to_py)? {
        crate::user_warning(py, &w)?;
    }
    let rests = convert::resting_poses(py, m, stable_export)?;
    let params = OnPlaneParams { yaw_steps, grid_radius, grid_step, min_probability, ..Default::default() };
    let hyps = py.detach(|| on_plane_hypotheses(m, &rests, &plane, &obs, &mask, &params)).map_err(to_py)?;
    let n = hyps.len();
    let d = PyDict::new(py);
    let poses: Vec<_> = hyps.iter().map(|h| h.pose).collect();
    let (r, t) = convert::pose_arrays(py, &poses)?;
    d.set_item("R", r)?;
    d.set_item("t", t)?;
    d.set_item("rest", hyps.iter().map(|h| h.rest as u32).collect::<Vec<_>>().into_pyarray(py))?;
    d.set_item("rest_probability", hyps.iter().map(|h| rests[h.rest].probability).collect::<Vec<_>>().into_pyarray(py))?;
    d.set_item("yaw", hyps.iter().map(|h| h.yaw).collect::<Vec<_>>().into_pyarray(py))?;
    let offsets: Vec<f64> = hyps.iter().flat_map(|h| h.offset.to_array()).collect();
    d.set_item("offset", offsets.into_pyarray(py).reshape([n, 2])?)?;
    Ok(d)
}

/// BOP'19 evaluation of a results CSV on a BOP dataset, as the BOP toolkit
/// computes it: the report (AR, VSD/MSSD/MSPD recalls per object, ...) as
/// a dict, and with `records=True` also every (estimate, instance) pair's
/// errors. `task="detection"`: BOP'24 6D detection (AP over MSSD and MSPD
/// thresholds; targets default to the dataset's test_targets_bop24.json).
/// `task="bbox"` / `"segm"`: BOP's 2D detection / segmentation of a COCO
/// results JSON (eval_bop22_coco.py's AP, AR and times; `boxes` amodal or
/// modal for bbox).
#[pyfunction]
#[pyo3(signature = (dataset, results, *, targets = None, split = "test", errors = None, add_threshold = 0.1, dataset_name = None, device = "auto", adapter = None, records = false, task = "localization", max_estimates_per_image = None, sensor = None, boxes = None))]
#[allow(clippy::too_many_arguments)]
pub fn evaluate<'py>(
    py: Python<'py>,
    dataset: PathBuf,
    results: PathBuf,
    targets: Option<PathBuf>,
    split: &str,
    errors: Option<Vec<String>>,
    add_threshold: f64,
    dataset_name: Option<&str>,
    device: &str,
    adapter: Option<&str>,
    records: bool,
    task: &str,
    max_estimates_per_image: Option<usize>,
    sensor: Option<String>,
    boxes: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    use plausible::eval::{evaluate, open_dataset, task_targets, toolkit_dataset_name, ErrorType, EvalOptions, Task};
    let name = toolkit_dataset_name(&dataset, dataset_name).map_err(to_py)?;
    if let Ok(t) = task.parse::<plausible::coco::CocoTask>() {
        let pose_only = [("errors", errors.is_some()), ("records", records), ("max_estimates_per_image", max_estimates_per_image.is_some()), ("add_threshold", add_threshold != 0.1)];
        if let Some((what, _)) = pose_only.iter().find(|(_, given)| *given) {
            return Err(value_error(format!("{what} is for the 6D pose tasks, not task={task:?}")));
        }
        if boxes.is_some() && t == plausible::coco::CocoTask::Segm {
            return Err(value_error("boxes is for task='bbox': masks are always the visible part".to_string()));
        }
        let boxes: plausible::coco::BoxKind = boxes.unwrap_or("amodal").parse().map_err(value_error)?;
        return evaluate_coco(py, &dataset, &results, targets.as_deref(), split, name.as_deref(), sensor.as_deref(), plausible::coco::CocoOptions { task: t, boxes });
    }
    if boxes.is_some() {
        return Err(value_error("boxes is for task='bbox'".to_string()));
    }
    let task: Task = task.parse().map_err(|e| value_error(format!("{e}; bbox or segm for BOP's 2D tasks")))?;
    let base = match task {
        Task::Localization => EvalOptions::for_dataset(name.as_deref()),
        Task::Detection => EvalOptions::detection(name.as_deref()),
    };
    if max_estimates_per_image.is_some() && task != Task::Detection {
        return Err(value_error("max_estimates_per_image is for task='detection'".to_string()));
    }
    let mut opts = EvalOptions { add_threshold, max_estimates_per_image: max_estimates_per_image.unwrap_or(base.max_estimates_per_image), ..base };
    if let Some(errs) = errors {
        opts.errors = errs.iter().map(|e| e.parse::<ErrorType>()).collect::<Result<_, _>>().map_err(value_error)?;
    }
    opts.validate().map_err(to_py)?;
    let choice: DeviceChoice = device.parse().map_err(to_py)?;
    let (report, recs, source) = crate::interruptible(py, |stop| {
        let ds = open_dataset(&dataset, split, sensor.as_deref(), name.as_deref())?;
        let (targets, source) = task_targets(&ds, targets.as_deref(), task)?;
        if targets.is_empty() {
            return Err(plausible::Error::InvalidInput("no targets to evaluate".into()));
        }
        let results = plausible::bop::read_results(&results)?;
        let device = Device::open(choice, adapter, false)?.device;
        let (report, recs) = evaluate(&ds, &results, &targets, &device, &opts, &mut |_| stop.check())?;
        Ok((report, recs, source))
    })?;
    let mut v = with_inputs(serde_json::to_value(&report), &dataset, &results, source, "all annotated instances")?;
    if records {
        v["records"] = serde_json::to_value(&recs).map_err(|e| value_error(e.to_string()))?;
    }
    json_to_py(py, &v)
}

/// BOP's 2D tasks: the report of `plausible eval --task bbox|segm --out`.
#[allow(clippy::too_many_arguments)]
fn evaluate_coco<'py>(
    py: Python<'py>,
    dataset: &std::path::Path,
    results: &std::path::Path,
    targets: Option<&std::path::Path>,
    split: &str,
    name: Option<&str>,
    sensor: Option<&str>,
    opts: plausible::coco::CocoOptions,
) -> PyResult<Bound<'py, PyAny>> {
    use plausible::coco::{evaluate, results::read_coco_results, target_images};
    let (report, source) = crate::interruptible(py, |stop| {
        let ds = plausible::eval::open_dataset(dataset, split, sensor, name)?;
        let (images, source) = target_images(&ds, targets)?;
        if images.is_empty() {
            return Err(plausible::Error::InvalidInput("no target images".into()));
        }
        let r = read_coco_results(results)?;
        let cats = name.and_then(plausible::eval::bop_obj_ids);
        let report = evaluate(&ds, &r, &images, cats.as_deref(), opts, &mut |_| stop.check())?;
        Ok((report, source))
    })?;
    json_to_py(py, &with_inputs(serde_json::to_value(&report), dataset, results, source, "all annotated images")?)
}

/// A report as JSON with what was evaluated, as `plausible eval --out`
/// writes it.
fn with_inputs(
    report: serde_json::Result<serde_json::Value>,
    dataset: &std::path::Path,
    results: &std::path::Path,
    source: plausible::bop::TargetSource,
    all: &str,
) -> PyResult<serde_json::Value> {
    let mut v = report.map_err(|e| value_error(e.to_string()))?;
    v["dataset"] = serde_json::json!(dataset.display().to_string());
    v["results"] = serde_json::json!(results.display().to_string());
    v["targets"] = serde_json::json!(match source {
        plausible::bop::TargetSource::File(f) | plausible::bop::TargetSource::ImageList(f) => f.display().to_string(),
        plausible::bop::TargetSource::AllInstances => all.to_string(),
    });
    Ok(v)
}

/// The devices this machine offers: the adapter `gpu` would use (or why
/// there is none) and what `auto` picks.
#[pyfunction]
#[pyo3(signature = (adapter = None))]
pub fn device_info(py: Python<'_>, adapter: Option<&str>) -> PyResult<(String, String)> {
    py.detach(|| {
        let gpu = match Device::open(DeviceChoice::Gpu, adapter, false) {
            Ok(o) => o.device.describe(),
            Err(e) => e.to_string(),
        };
        // As a Scorer(device="auto") would open it: a named adapter that is
        // missing is an error there, not the CPU twin.
        let auto = Device::open(DeviceChoice::Auto, adapter, false).map(|o| o.device.describe()).unwrap_or_else(|e| e.to_string());
        Ok((gpu, auto))
    })
}


/// Reads a BOP frame: the camera (a scene_camera.json entry, a whole
/// scene_camera.json with `frame`, or a dataset camera.json), the 16-bit
/// depth PNG (to metres) and optionally an 8-bit mask PNG; all checked
/// against each other as `plausible score` checks them.
#[pyfunction]
#[pyo3(signature = (camera, depth, mask = None, frame = None))]
#[allow(clippy::type_complexity)]
pub fn read_frame<'py>(
    py: Python<'py>,
    camera: PathBuf,
    depth: PathBuf,
    mask: Option<PathBuf>,
    frame: Option<&str>,
) -> PyResult<(Bound<'py, numpy::PyArray2<f64>>, Bound<'py, numpy::PyArray2<f32>>, Option<Bound<'py, numpy::PyArray2<bool>>>)> {
    use plausible::observation::{read_camera_file, read_depth_png, read_mask_png, CameraFile};
    let (obs, m) = py
        .detach(|| -> plausible::Result<_> {
            let (cam, kind) = read_camera_file(&camera, frame)?;
            if let (Some(f), CameraFile::Single) = (frame, kind) {
                return Err(plausible::Error::InvalidInput(format!(
                    "frame {f}: {} holds one camera, not a scene_camera.json of frames, so there is nothing to pick",
                    camera.display()
                )));
            }
            let obs = read_depth_png(&depth, &cam)?;
            let m = match &mask {
                Some(p) => Some(read_mask_png(p, obs.intrinsics.width, obs.intrinsics.height)?),
                None => None,
            };
            Ok((obs, m))
        })
        .map_err(to_py)?;
    let i = &obs.intrinsics;
    if let Some(note) = i.principal_point_note() {
        crate::user_warning(py, &format!("{}: {note}", camera.display()))?;
    }
    let (w, h) = (i.width as usize, i.height as usize);
    let k = vec![i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0].into_pyarray(py).reshape([3, 3])?;
    let d = obs.depth.into_pyarray(py).reshape([h, w])?;
    let m = m.map(|m| m.into_pyarray(py).reshape([h, w])).transpose()?;
    Ok((k, d, m))
}
