//! numpy arrays to the library's types and back. Shapes are checked here
//! (the Python side has already made the arrays contiguous and of the
//! right dtype); values are checked by the library.

use glam::{DMat3, DVec3};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use plausible::camera::Intrinsics;
use plausible::observation::{check_mask, DepthImage};
use plausible::pose::Pose;
use numpy::prelude::*;
use pyo3::prelude::*;

use crate::{to_py, value_error};

/// The contiguous data of an array, or a clear error.
fn slice<'a, T: numpy::Element, D: numpy::ndarray::Dimension>(a: &'a numpy::PyReadonlyArray<'_, T, D>, what: &str) -> PyResult<&'a [T]> {
    a.as_slice().map_err(|_| value_error(format!("{what}: expected a C-contiguous array")))
}

/// A depth image (H, W) in metres with its camera matrix K (row-major 3x3).
pub fn depth_image(k: PyReadonlyArray1<f64>, depth: PyReadonlyArray2<f32>) -> PyResult<DepthImage> {
    let k = k.as_slice().map_err(|_| value_error("K: expected a contiguous array"))?;
    let shape = depth.shape();
    let (h, w) = (shape[0], shape[1]);
    if h > u32::MAX as usize || w > u32::MAX as usize {
        return Err(value_error(format!("depth: {w}x{h} pixels is too large")));
    }
    let intrinsics = Intrinsics::from_k(k, w as u32, h as u32).map_err(to_py)?;
    let data = slice(&depth, "depth")?.to_vec();
    DepthImage::from_metres(intrinsics, data).map_err(to_py)
}

/// A mask (H, W) of booleans, checked against the depth image.
pub fn mask(mask: Option<PyReadonlyArray2<bool>>, obs: &DepthImage) -> PyResult<Option<Vec<bool>>> {
    let Some(m) = mask else { return Ok(None) };
    let (w, h) = (obs.intrinsics.width, obs.intrinsics.height);
    if m.shape() != [h as usize, w as usize] {
        return Err(value_error(format!("mask: shape {:?}, but the depth image is ({h}, {w})", m.shape())));
    }
    let v = slice(&m, "mask")?.to_vec();
    check_mask(&v, w, h).map_err(to_py)?;
    Ok(Some(v))
}

/// Poses from rotations (N, 3, 3) and translations (N, 3) in metres,
/// validated (orthonormal rotation, in front of the camera, a median
/// camera distance between 2 cm and 50 m: millimetres are refused).
pub fn poses(r: PyReadonlyArray3<f64>, t: PyReadonlyArray2<f64>, orthonormalize: bool) -> PyResult<Vec<Pose>> {
    let n = r.shape()[0];
    if r.shape() != [n, 3, 3] || t.shape() != [n, 3] {
        return Err(value_error(format!(
            "poses: R must be (N, 3, 3) and t (N, 3) with the same N, got {:?} and {:?}",
            r.shape(),
            t.shape()
        )));
    }
    plausible::pose::check_pose_count(n).map_err(to_py)?;
    let r = slice(&r, "R")?;
    let t = slice(&t, "t")?;
    let poses = (0..n)
        .map(|i| {
            let m = &r[9 * i..9 * i + 9];
            let rot = DMat3::from_cols_array(&[m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8]]);
            let tr = DVec3::new(t[3 * i], t[3 * i + 1], t[3 * i + 2]);
            Pose::new(rot, tr).validated(i, orthonormalize).map_err(|e| {
                // The library's hint names the CLI flag; say it the Python way.
                value_error(e.to_string().replace("pass --orthonormalize", "pass orthonormalize=True"))
            })
        })
        .collect::<PyResult<Vec<Pose>>>()?;
    plausible::pose::check_camera_distances(&poses, plausible::pose::PoseUnits::Metres).map_err(|r| value_error(format!("t: {r}")))?;
    Ok(poses)
}

/// A 3-vector from a length-3 array.
pub fn vec3(a: &PyReadonlyArray1<f64>, what: &str) -> PyResult<DVec3> {
    let s = a.as_slice().map_err(|_| value_error(format!("{what}: expected a contiguous array")))?;
    match s {
        [x, y, z] => Ok(DVec3::new(*x, *y, *z)),
        _ => Err(value_error(format!("{what}: expected 3 numbers, got {}", s.len()))),
    }
}

/// A JSON value as the Python object `json.loads` makes of it (dicts,
/// lists, floats): the library's serde types reach Python unchanged.
pub fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(v).map_err(|e| value_error(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// A support plane from its point (metres) and normal in the camera frame,
/// checked as the plane JSON is.
pub fn plane(point: &PyReadonlyArray1<f64>, normal: &PyReadonlyArray1<f64>) -> PyResult<plausible::physical::Plane> {
    plausible::physical::Plane::in_camera(vec3(point, "plane point")?, vec3(normal, "plane normal")?)
        .map_err(|e| value_error(format!("plane: {e}")))
}

/// Poses as numpy arrays: rotations (N, 3, 3) and translations (N, 3), metres.
pub fn pose_arrays<'py>(py: Python<'py>, poses: &[Pose]) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    use numpy::IntoPyArray;
    let n = poses.len();
    let r: Vec<f64> = poses.iter().flat_map(|p| p.r_row_major()).collect();
    let t: Vec<f64> = poses.iter().flat_map(|p| p.t.to_array()).collect();
    Ok((r.into_pyarray(py).reshape([n, 3, 3])?.into_any(), t.into_pyarray(py).reshape([n, 3])?.into_any()))
}

/// The resting poses of `mesh` from a stable-pose export's text (or the
/// hull's quasi-static analysis), warning as `plausible hypotheses` does
/// when the entry used matches the mesh's file name but not its geometry,
/// or is the export's only entry and matches neither.
pub fn resting_poses(py: Python<'_>, mesh: &plausible::mesh::Mesh, export: Option<&str>) -> PyResult<Vec<plausible::hypotheses::on_plane::RestingPose>> {
    use plausible::hypotheses::on_plane::{resting_poses, ExportMatch};
    let name = mesh.source.as_ref().and_then(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (rests, how) = py.detach(|| resting_poses(mesh, export, &name)).map_err(to_py)?;
    match how {
        Some(ExportMatch::OnlyEntry) => {
            crate::user_warning(py, &format!("the stable-pose export's only mesh matches neither the geometry of {name} nor its name; using it anyway"))?
        }
        Some(ExportMatch::Name) => crate::user_warning(
            py,
            &format!("the stable-pose export's entry for {name} matches its file name only, not its geometry (another object of the same name, other units or an edited mesh?); using it anyway"),
        )?,
        Some(ExportMatch::Hash) | None => {}
    }
    Ok(rests)
}
