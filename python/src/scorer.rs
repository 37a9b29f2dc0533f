//! `plausible.Scorer`: one mesh against one observation, built once and
//! called many times. The GPU pipeline, mesh and observation stay uploaded
//! between calls; the GIL is released while the kernels run.

use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use plausible::gpu::{Device, DeviceChoice};
use plausible::kernels::score::{ScoreParams, ScoreRecord};
use plausible::kernels::RenderMesh;
use plausible::observation::{RoiSampling, ScoreTarget};
use plausible::physical::batch::PlanePhysics;
use plausible::physical::{Evaluation, Plane};
use plausible::pose::Pose;
use plausible::visual::{ranks, ranks_with_physics, score_poses_with_physics, scoring_mesh, LodChoice};
use numpy::prelude::*;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert;
use crate::mesh::Mesh;
use crate::{to_py, value_error};

/// Hypotheses the GPU buffers are sized for; larger calls are split.
const BATCH_HINT: usize = 4096;

/// The support plane and sampling a cached [`PlanePhysics`] was built for.
#[derive(Clone, PartialEq)]
struct PhysicsKey {
    point: [f64; 3],
    normal: [f64; 3],
    samples: usize,
    seed: u64,
    epsilon: Option<f64>,
}

/// Scores pose hypotheses of one mesh against one depth observation.
#[pyclass(module = "plausible._native")]
pub struct Scorer {
    scorer: plausible::visual::Scorer,
    device: Device,
    mesh: plausible::mesh::Mesh,
    rmesh: RenderMesh,
    target: ScoreTarget,
    params: ScoreParams,
    physics: Option<(PhysicsKey, PlanePhysics)>,
    note: Option<String>,
    /// Which mesh the visual score renders, and why.
    lod: String,
}

#[pymethods]
impl Scorer {
    /// `k`: row-major 3x3 camera matrix; `depth` (H, W) metres (0 or NaN =
    /// none); `mask` (H, W) booleans or None (the whole frame); the region
    /// resampled to `res` x `res` pixels, clipped to the image (0 = native
    /// pixels).
    #[new]
    #[pyo3(signature = (mesh, k, depth, mask = None, *, res = 128, tau = 0.02, alpha = 0.7, margin = 0.25, device = "auto", adapter = None, lod = "auto"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        mesh: &Mesh,
        k: PyReadonlyArray1<f64>,
        depth: PyReadonlyArray2<f32>,
        mask: Option<PyReadonlyArray2<bool>>,
        res: u32,
        tau: f64,
        alpha: f64,
        margin: f64,
        device: &str,
        adapter: Option<String>,
        lod: &str,
    ) -> PyResult<Scorer> {
        if !(tau.is_finite() && tau > 0.0 && tau <= 1.0) {
            return Err(value_error(format!("tau {tau}: the depth tolerance is in metres and must lie in (0, 1] (usually 0.02)")));
        }
        if !(alpha > 0.0 && alpha <= 2.0) {
            return Err(value_error(format!("alpha {alpha}: the normal tolerance (on 1 - cos of the angle) must lie in (0, 2] (usually 0.7)")));
        }
        // Checked as given, then narrowed to the kernels' f32: a positive
        // value that rounds to 0 there would score with a zero tolerance.
        let (tau, alpha) = (narrow("tau", tau)?, narrow("alpha", alpha)?);
        let obs = convert::depth_image(k, depth)?;
        let mask = convert::mask(mask, &obs)?;
        let sampling = if res == 0 { RoiSampling::Native } else { RoiSampling::Square(res) };
        let target = ScoreTarget::new(&obs, mask.as_deref(), sampling, margin).map_err(to_py)?;
        target.check_observed().map_err(to_py)?;
        let choice: DeviceChoice = device.parse().map_err(to_py)?;
        let lod: LodChoice = lod.parse().map_err(value_error)?;
        let mesh = mesh.inner.clone();
        let params = ScoreParams { tau, alpha };
        // Ctrl-C ends the construction between its stages (a mesh of
        // millions of triangles spends seconds in each).
        crate::interruptible(py, move |stop| {
            let opened = Device::open(choice, adapter.as_deref(), false)?;
            // The kernel compiles while the mesh is prepared.
            let _compiling = plausible::visual::Scorer::precompile(&opened.device);
            stop.check()?;
            let scoring = scoring_mesh(&mesh, lod, &target)?;
            stop.check()?;
            let rmesh = RenderMesh::new(&scoring.mesh)?;
            stop.check()?;
            let (device, too_big) = opened.device.for_mesh(choice, &rmesh, target.intrinsics.pixels());
            let note = too_big.or(opened.note);
            let scorer = plausible::visual::Scorer::new(&device, &rmesh, &target, params, BATCH_HINT)?;
            Ok(Scorer { scorer, device, mesh, rmesh, target, params, physics: None, note, lod: scoring.describe() })
        })
    }

    /// Scores poses R (N, 3, 3), t (N, 3) in metres. Returns columns:
    /// score, a_d, a_n, valid, rendered, observed, rank; with `plane`
    /// (point, normal in metres, camera frame) also the physical terms.
    #[pyo3(signature = (r, t, plane = None, *, samples = plausible::physical::samples::DEFAULT_SAMPLES, seed = plausible::physical::samples::DEFAULT_SEED, epsilon = None, orthonormalize = false))]
    #[allow(clippy::too_many_arguments)]
    fn score<'py>(
        &mut self,
        py: Python<'py>,
        r: PyReadonlyArray3<f64>,
        t: PyReadonlyArray2<f64>,
        plane: Option<(PyReadonlyArray1<f64>, PyReadonlyArray1<f64>)>,
        samples: usize,
        seed: u64,
        epsilon: Option<f64>,
        orthonormalize: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let poses = convert::poses(r, t, orthonormalize)?;
        if let Some(w) = self.target.distance_mismatch(&poses) {
            crate::user_warning(py, &w)?;
        }
        let pixels = self.target.intrinsics.pixels();
        let Some((point, normal)) = plane else {
            let scorer = &self.scorer;
            let records = in_chunks(py, &poses, pixels, |chunk| Ok(scorer.score(chunk, &mut |_| {})?.0))?;
            let rank = ranks(&records);
            return records_dict(py, &records, &rank);
        };
        let key = PhysicsKey {
            point: convert::vec3(&point, "plane point")?.to_array(),
            normal: convert::vec3(&normal, "plane normal")?.to_array(),
            samples,
            seed,
            epsilon,
        };
        let (records, evals): (Vec<_>, Vec<_>) = in_chunks(py, &poses, pixels, |chunk| {
            let (r, e) = self.score_physics(key.clone(), chunk)?;
            Ok(r.into_iter().zip(e).collect())
        })?
        .into_iter()
        .unzip();
        let rank = ranks_with_physics(&records, &evals);
        let d = records_dict(py, &records, &rank)?;
        add_physics(py, &d, &evals)?;
        Ok(d)
    }

    /// The device the kernels run on, and why (a fallback, a software
    /// adapter passed over), e.g. "CPU twin (2 threads)".
    #[getter]
    fn device(&self) -> String {
        match &self.note {
            Some(n) => format!("{} ({n})", self.device.describe()),
            None => self.device.describe(),
        }
    }

    /// Which mesh the visual score renders (level of detail) and why.
    #[getter]
    fn scoring_mesh(&self) -> String {
        self.lod.clone()
    }

    /// Side of the scored region (pixels) and its crop in the image (x0, y0, w, h).
    #[getter]
    fn region(&self) -> ((u32, u32), (f64, f64, f64, f64)) {
        ((self.target.intrinsics.width, self.target.intrinsics.height), self.target.crop)
    }

    fn __repr__(&self) -> String {
        format!("Scorer({} triangles on {})", self.mesh.triangles.len(), self.device())
    }
}

impl Scorer {
    /// Visual and physical terms on the plane of `key`, reusing the
    /// prepared physics when the plane and sampling are unchanged.
    fn score_physics(&mut self, key: PhysicsKey, poses: &[Pose]) -> plausible::Result<(Vec<ScoreRecord>, Vec<Evaluation>)> {
        if self.physics.as_ref().is_none_or(|(k, _)| *k != key) {
            let plane = Plane::in_camera(glam::DVec3::from_array(key.point), glam::DVec3::from_array(key.normal))
                .map_err(|r| plausible::Error::InvalidInput(format!("plane: {r}")))?;
            let p = PlanePhysics::new(&self.mesh, &plane, None, key.samples, key.seed, key.epsilon)?;
            self.physics = Some((key, p));
        }
        let physics = &self.physics.as_ref().expect("just built").1;
        let (records, evals, _) = score_poses_with_physics(&self.device, &self.rmesh, &self.target, poses, self.params, physics, |_| {})?;
        Ok((records, evals))
    }
}

/// A positive tolerance checked in f64, as the kernels' f32: one that is
/// not zero but rounds to zero there is refused rather than scored with no
/// tolerance at all.
fn narrow(name: &str, value: f64) -> PyResult<f32> {
    let v = value as f32;
    if v == 0.0 && value != 0.0 {
        return Err(value_error(format!("{name} {value:e}: too small for the kernels' 32-bit floats (it would be 0)")));
    }
    Ok(v)
}

/// Poses in the first chunk of [`in_chunks`] for a region of `pixels`:
/// [`BATCH_HINT`] at the default 128 x 128 pixels, fewer as a pose costs
/// more pixels (at least one).
fn first_chunk(pixels: usize) -> usize {
    (BATCH_HINT.saturating_mul(128 * 128) / pixels.max(1)).clamp(1, BATCH_HINT)
}

/// `score` over `poses` in chunks, with Ctrl-C looked for between them
/// (each pose's result is its own, so chunks change nothing). The first
/// chunk is sized by what a pose costs ([`first_chunk`] of the region's
/// `pixels`: 4096 poses at 128 x 128, 64 at 1024 x 1024, 4 at 4096 x
/// 4096) and each one that took under 0.25 s doubles the next: a fast GPU
/// makes few calls (a call with physics builds its GPU scorer), a
/// software one still ends within about a second of Ctrl-C at any `res`.
fn in_chunks<T: Send>(py: Python<'_>, poses: &[Pose], pixels: usize, mut score: impl FnMut(&[Pose]) -> plausible::Result<Vec<T>> + Send) -> PyResult<Vec<T>> {
    crate::interruptible(py, |stop| {
        let mut out = Vec::with_capacity(poses.len());
        let (mut at, mut size) = (0, first_chunk(pixels));
        while at < poses.len() {
            stop.check()?;
            let chunk = &poses[at..at.saturating_add(size).min(poses.len())];
            at += chunk.len();
            let start = std::time::Instant::now();
            out.extend(score(chunk)?);
            if start.elapsed() < std::time::Duration::from_millis(250) {
                size = size.saturating_mul(2);
            }
        }
        Ok(out)
    })
}

/// The visual columns, one numpy array each.
fn records_dict<'py>(py: Python<'py>, records: &[ScoreRecord], rank: &[usize]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let col_f = |f: fn(&ScoreRecord) -> f32| records.iter().map(f).collect::<Vec<f32>>().into_pyarray(py);
    let col_u = |f: fn(&ScoreRecord) -> u32| records.iter().map(f).collect::<Vec<u32>>().into_pyarray(py);
    d.set_item("score", col_f(|r| r.score))?;
    d.set_item("a_d", col_f(|r| r.mean_ad))?;
    d.set_item("a_n", col_f(|r| r.mean_an))?;
    d.set_item("valid", col_u(|r| r.valid))?;
    d.set_item("rendered", col_u(|r| r.rendered))?;
    d.set_item("observed", col_u(|r| r.observed))?;
    d.set_item("rank", rank.iter().map(|&r| r as u32).collect::<Vec<u32>>().into_pyarray(py))?;
    Ok(d)
}

/// The physical columns: verdict, counts, minimum distance and stability
/// margin in metres (NaN where there is none), feasible, stable.
fn add_physics(py: Python<'_>, d: &Bound<'_, PyDict>, evals: &[Evaluation]) -> PyResult<()> {
    d.set_item("verdict", evals.iter().map(|e| e.verdict.as_str()).collect::<Vec<_>>())?;
    let col_u = |f: fn(&Evaluation) -> u32| evals.iter().map(f).collect::<Vec<u32>>().into_pyarray(py);
    d.set_item("intersecting", col_u(|e| e.intersecting))?;
    d.set_item("contact", col_u(|e| e.contact))?;
    d.set_item("supported", col_u(|e| e.supported))?;
    d.set_item("min_distance", evals.iter().map(|e| e.min_distance).collect::<Vec<f64>>().into_pyarray(py))?;
    d.set_item("stability_margin", evals.iter().map(|e| e.stability_margin.unwrap_or(f64::NAN)).collect::<Vec<f64>>().into_pyarray(py))?;
    d.set_item("feasible", evals.iter().map(|e| e.feasible).collect::<Vec<bool>>().into_pyarray(py))?;
    d.set_item("stable", evals.iter().map(|e| e.stable).collect::<Vec<bool>>().into_pyarray(py))?;
    Ok(())
}
