//! Refinement and estimation of one frame's objects (the per-image work of
//! `plausible refine` and `plausible estimate`, on arrays): each object is
//! a mesh, its mask and, for refinement, its pose hypotheses.

use numpy::prelude::*;
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use plausible::gpu::{Device, DeviceChoice};
use plausible::physical::Plane;
use plausible::refine::dataset::{support_plane, Model};
use plausible::refine::estimate::{estimate_frame, EstimateModel, EstimateParams, EstimateStats, Instance};
use plausible::refine::scene::{refine_scene, SceneObject, SceneRefined, Support};
use plausible::refine::{Method, RefineParams};
use plausible::support_plane::PlaneFitParams;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert;
use crate::mesh::Mesh;
use crate::{to_py, value_error};

/// The refinement settings shared by `refine` and `estimate`.
fn params(method: &str, steps: usize, budget: Option<usize>, physics: bool, res: u32, seed: u64) -> PyResult<RefineParams> {
    let method = Method::parse(method).ok_or_else(|| value_error(format!("method '{method}': expected ref, pir, sir or rir")))?;
    if budget.is_some() && method != Method::Rir {
        return Err(value_error("budget is for method \"rir\" (the others take steps per hypothesis)"));
    }
    let p = RefineParams { method, steps: steps.max(1), budget, physics, res, seed, ..Default::default() };
    p.validate().map_err(to_py)?;
    Ok(RefineParams { steps, ..p })
}

/// The plane given as (point, normal) in metres, or fitted outside every
/// mask when the method simulates and none is given.
fn plane_for(
    given: Option<(PyReadonlyArray1<f64>, PyReadonlyArray1<f64>)>,
    needed: bool,
    depth: &plausible::observation::DepthImage,
    masks: &[Vec<bool>],
) -> PyResult<Option<Plane>> {
    if let Some((p, n)) = given {
        return convert::plane(&p, &n).map(Some);
    }
    if !needed {
        return Ok(None);
    }
    support_plane(depth, masks.iter().map(Vec::as_slice), &PlaneFitParams::default()).map(Some).map_err(to_py)
}

/// Masks checked against the depth (an empty one is allowed: that object
/// has nothing to refine against and comes back unchanged).
fn masks(ms: Vec<PyReadonlyArray2<bool>>, depth: &plausible::observation::DepthImage) -> PyResult<Vec<Vec<bool>>> {
    let (w, h) = (depth.intrinsics.width as usize, depth.intrinsics.height as usize);
    ms.into_iter()
        .enumerate()
        .map(|(i, m)| {
            if m.shape() != [h, w] {
                return Err(value_error(format!("object {i}: mask shape {:?}, but the depth image is ({h}, {w})", m.shape())));
            }
            Ok(m.as_slice().map_err(|_| value_error("mask: expected a C-contiguous array"))?.to_vec())
        })
        .collect()
}

/// Per object: the refined poses (N, 3, 3), (N, 3) metres and scores, or
/// None; with the support order and supports.
fn scene_dict<'py>(py: Python<'py>, out: &SceneRefined, plane: Option<&Plane>) -> PyResult<Bound<'py, PyDict>> {
    let objects = PyList::empty(py);
    for o in &out.objects {
        let Some(refined) = o else {
            objects.append(py.None())?;
            continue;
        };
        let d = PyDict::new(py);
        let poses: Vec<_> = refined.iter().map(|x| x.pose).collect();
        let (r, t) = convert::pose_arrays(py, &poses)?;
        d.set_item("R", r)?;
        d.set_item("t", t)?;
        d.set_item("score", refined.iter().map(|x| x.score).collect::<Vec<_>>().into_pyarray(py))?;
        d.set_item("steps", refined.iter().map(|x| x.steps as u32).collect::<Vec<_>>().into_pyarray(py))?;
        d.set_item("kept", refined.iter().map(|x| x.kept as u32).collect::<Vec<_>>().into_pyarray(py))?;
        objects.append(d)?;
    }
    let support: Vec<Option<usize>> = out.support.iter().map(|s| match s {
        Support::Plane => None,
        Support::Object(i) => Some(*i),
    }).collect();
    let d = PyDict::new(py);
    d.set_item("objects", objects)?;
    d.set_item("order", out.order.clone())?;
    d.set_item("support", support)?;
    d.set_item("plane", plane.map(|p| (p.point.to_array().to_vec(), p.normal.to_array().to_vec())))?;
    Ok(d)
}

/// Refines every object's hypotheses among the others in support order
/// (REF, PIR, SIR or RIR). `leads[i]`: the hypothesis that stands for object
/// i among the others until it is refined.
#[pyfunction]
#[pyo3(signature = (k, depth, meshes, masks_in, rs, ts, leads, *, plane = None, method = "rir", steps = 2, budget = None, physics = true, res = 128, seed = 0, device = "auto", adapter = None))]
#[allow(clippy::too_many_arguments)]
pub fn refine<'py>(
    py: Python<'py>,
    k: PyReadonlyArray1<f64>,
    depth: PyReadonlyArray2<f32>,
    meshes: Vec<PyRef<'py, Mesh>>,
    masks_in: Vec<PyReadonlyArray2<bool>>,
    rs: Vec<PyReadonlyArray3<f64>>,
    ts: Vec<PyReadonlyArray2<f64>>,
    leads: Vec<usize>,
    plane: Option<(PyReadonlyArray1<f64>, PyReadonlyArray1<f64>)>,
    method: &str,
    steps: usize,
    budget: Option<usize>,
    physics: bool,
    res: u32,
    seed: u64,
    device: &str,
    adapter: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let n = meshes.len();
    if masks_in.len() != n || rs.len() != n || ts.len() != n || leads.len() != n {
        return Err(value_error("one mask, one set of hypotheses and one lead per mesh"));
    }
    let p = params(method, steps, budget, physics, res, seed)?;
    let obs = convert::depth_image(k, depth)?;
    let masks = masks(masks_in, &obs)?;
    // Start from the nearest rotations, as `plausible refine` does: other
    // methods' rotations are often rounded (LM-O's own ground truth is off
    // by up to 2e-3), and refining moves the pose anyway.
    let hyps: Vec<_> = rs.into_iter().zip(ts).map(|(r, t)| convert::poses(r, t, true)).collect::<PyResult<_>>()?;
    let plane = plane_for(plane, p.method.simulates(p.physics), &obs, &masks)?;
    let mesh_data: Vec<plausible::mesh::Mesh> = meshes.iter().map(|m| m.inner.clone()).collect();
    let choice: DeviceChoice = device.parse().map_err(to_py)?;
    let out = crate::interruptible(py, |stop| {
            let p = RefineParams { stop, ..p };
            let device = Device::open(choice, adapter, false)?.device;
            let models: Vec<Model> = mesh_data.into_iter().map(|m| Model::new(m, &p)).collect::<plausible::Result<_>>()?;
            let objects: Vec<SceneObject> = (0..n)
                .map(|i| SceneObject { model: &models[i], mask: &masks[i], hypotheses: hyps[i].clone(), lead: leads[i] })
                .collect();
            refine_scene(&device, &obs, plane.as_ref(), &objects, usize::MAX, &p)
        })?;
    scene_dict(py, &out, plane.as_ref())
}

/// Estimates every object's pose from its mask: resting poses (an export's
/// JSON text per object, or the hull's quasi-static analysis) x yaws on the
/// support plane, scored, and the best `top` refined among the others.
#[pyfunction]
#[pyo3(signature = (k, depth, meshes, masks_in, stable, *, plane = None, method = "rir", steps = 2, top = 5, yaw_steps = 24, physics = true, res = 128, seed = 0, device = "auto", adapter = None))]
#[allow(clippy::too_many_arguments)]
pub fn estimate<'py>(
    py: Python<'py>,
    k: PyReadonlyArray1<f64>,
    depth: PyReadonlyArray2<f32>,
    meshes: Vec<PyRef<'py, Mesh>>,
    masks_in: Vec<PyReadonlyArray2<bool>>,
    stable: Vec<Option<String>>,
    plane: Option<(PyReadonlyArray1<f64>, PyReadonlyArray1<f64>)>,
    method: &str,
    steps: usize,
    top: usize,
    yaw_steps: usize,
    physics: bool,
    res: u32,
    seed: u64,
    device: &str,
    adapter: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let n = meshes.len();
    if masks_in.len() != n || stable.len() != n {
        return Err(value_error("one mask and one stable-pose entry (or None) per mesh"));
    }
    if top == 0 || top > 100 {
        return Err(value_error(format!("top {top}: between 1 and 100 hypotheses are refined")));
    }
    if yaw_steps == 0 || yaw_steps > 360 {
        return Err(value_error(format!("yaw_steps {yaw_steps}: between 1 and 360")));
    }
    let mut ep = EstimateParams { top, refine: params(method, steps, None, physics, res, seed)?, ..Default::default() };
    ep.hypotheses.yaw_steps = yaw_steps;
    let obs = convert::depth_image(k, depth)?;
    let masks = masks(masks_in, &obs)?;
    // A mesh whose size does not fit what its mask sees (mesh units?) is
    // warned about, never refused: a loose mask, or one shared by two
    // instances, must not end the call (`hypotheses` refuses the smaller).
    for (i, (m, mask)) in meshes.iter().zip(&masks).enumerate() {
        match plausible::hypotheses::on_plane::check_mesh_size(&m.inner, &obs, mask) {
            Ok(None) => {}
            Ok(Some(w)) => crate::user_warning(py, &format!("object {i}: {w}"))?,
            Err(e) => crate::user_warning(py, &format!("object {i}: {e}"))?,
        }
    }
    let plane = plane_for(plane, true, &obs, &masks)?.expect("fitted when not given");
    let rests: Vec<_> = meshes.iter().zip(&stable).map(|(m, s)| convert::resting_poses(py, &m.inner, s.as_deref())).collect::<PyResult<_>>()?;
    let mesh_data: Vec<plausible::mesh::Mesh> = meshes.iter().map(|m| m.inner.clone()).collect();
    let choice: DeviceChoice = device.parse().map_err(to_py)?;
    let (out, instance) = crate::interruptible(py, |stop| {
            let ep = EstimateParams { refine: RefineParams { stop, ..ep.refine.clone() }, ..ep };
            let device = Device::open(choice, adapter, false)?.device;
            let models: Vec<EstimateModel> = mesh_data
                .into_iter()
                .zip(rests)
                .map(|(m, rests)| Ok(EstimateModel { model: Model::new(m, &ep.refine)?, rests }))
                .collect::<plausible::Result<_>>()?;
            let instances: Vec<Instance> = (0..n).map(|i| Instance { model: &models[i], mask: &masks[i] }).collect();
            let mut stats = EstimateStats::default();
            let fe = estimate_frame(&device, &obs, &plane, &instances, &ep, &mut stats)?;
            let best: Vec<_> = (0..n).map(|i| fe.best(i)).collect();
            Ok((fe.scene, best))
        })?;
    let d = scene_dict(py, &out, Some(&plane))?;
    let best = PyList::empty(py);
    for b in &instance {
        match b {
            Some(r) => {
                let e = PyDict::new(py);
                e.set_item("R", r.pose.r_row_major().to_vec().into_pyarray(py).reshape([3, 3])?)?;
                e.set_item("t", r.pose.t.to_array().to_vec().into_pyarray(py))?;
                e.set_item("score", r.score)?;
                best.append(e)?;
            }
            None => best.append(py.None())?,
        }
    }
    d.set_item("best", best)?;
    Ok(d)
}
