//! `plausible.Mesh`: a triangle mesh in metres, loaded from a file or made
//! from arrays (trimesh's `mesh.vertices, mesh.faces` work as they are).

use glam::DVec3;
use numpy::{PyArray2, PyReadonlyArray2};
use numpy::prelude::*;
use pyo3::prelude::*;

use crate::{to_py, value_error};

/// A validated triangle mesh in metres.
#[pyclass(module = "plausible._native", frozen)]
pub struct Mesh {
    pub(crate) inner: plausible::mesh::Mesh,
    warnings: Vec<String>,
}

/// Any 2-D array-like of numbers of a `kinds` numpy kind (`f` float, `i`
/// and `u` integers) as a C-contiguous array of `dtype`: trimesh's uint32
/// faces, float32 vertices and plain lists all work; complex numbers,
/// strings and float indices are refused rather than cast.
fn numbers<'py, T: numpy::Element>(obj: &Bound<'py, PyAny>, kinds: &str, dtype: &str, what: &str) -> PyResult<PyReadonlyArray2<'py, T>> {
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("asarray", (obj,)).map_err(|e| value_error(format!("{what}: not an array of numbers ({e})")))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if !kinds.contains(kind.as_str()) {
        let got = a.getattr("dtype")?.str()?.to_string();
        return Err(value_error(format!("{what}: expected {} numbers, got dtype {got}", if kinds == "iu" { "integer" } else { "real" })));
    }
    // The shape before the copy: a broadcast view costs nothing until then.
    let shape: Vec<usize> = a.getattr("shape")?.extract()?;
    if shape.len() != 2 || shape[1] != 3 {
        let shape = a.getattr("shape")?.str()?.to_string();
        return Err(value_error(format!("{what}: expected shape (N, 3), got {shape}")));
    }
    let kw = pyo3::types::PyDict::new(obj.py());
    kw.set_item("dtype", dtype)?;
    let c = np.call_method("ascontiguousarray", (a,), Some(&kw))?;
    Ok(c.extract::<PyReadonlyArray2<T>>()?)
}

/// Face indices (F, 3) as u32 vertex indices. Unsigned arrays are read as
/// uint64 and signed ones as int64, so no index wraps on the way (a uint64
/// 2**64 - 1 cast to int64 would read as -1).
fn face_indices(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[u32; 3]>> {
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("asarray", (obj,)).map_err(|e| value_error(format!("faces: not an array of numbers ({e})")))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    fn read<T: numpy::Element + Copy + std::fmt::Display>(a: PyReadonlyArray2<'_, T>, name: &str, index: impl Fn(T) -> Option<u32>) -> PyResult<Vec<[u32; 3]>> {
        let f = a.as_slice().map_err(|_| value_error("faces: expected a C-contiguous array"))?;
        let mut tris = Vec::with_capacity(f.len() / 3);
        for (i, c) in f.chunks_exact(3).enumerate() {
            let idx = |k: usize| index(c[k]).ok_or_else(|| value_error(format!("{name}: face {i} refers to vertex {}, which does not exist", c[k])));
            tris.push([idx(0)?, idx(1)?, idx(2)?]);
        }
        Ok(tris)
    }
    if kind == "u" {
        read(numbers::<u64>(&a, "u", "uint64", "faces")?, name, |v| u32::try_from(v).ok())
    } else {
        read(numbers::<i64>(&a, "iu", "int64", "faces")?, name, |v| u32::try_from(v).ok())
    }
}

/// Metres per unit of `units` (`m` or `mm`).
pub fn unit_scale(units: &str) -> PyResult<f64> {
    match units {
        "m" => Ok(1.0),
        "mm" => Ok(1e-3),
        _ => Err(value_error(format!("units '{units}': expected \"m\" or \"mm\""))),
    }
}

impl Mesh {
    /// The mesh, with what loading noticed both kept (`warnings`) and
    /// emitted as `UserWarning`s, as the CLI prints them: a mesh in the
    /// wrong unit would otherwise score zero without a word.
    fn warned(py: Python<'_>, inner: plausible::mesh::Mesh, warnings: Vec<String>) -> PyResult<Mesh> {
        let name = inner.source.as_ref().map_or_else(|| "mesh".to_string(), |p| p.display().to_string());
        for w in &warnings {
            crate::user_warning(py, &format!("{name}: {w}"))?;
        }
        Ok(Mesh { inner, warnings })
    }
}

#[pymethods]
impl Mesh {
    /// A mesh from vertices (V, 3) in `units` and faces (F, 3) of vertex
    /// indices; checked like a file (finite vertices, indices in range,
    /// degenerate faces dropped).
    #[new]
    #[pyo3(signature = (vertices, faces, units = "m", name = "<arrays>"))]
    fn new(py: Python<'_>, vertices: &Bound<'_, PyAny>, faces: &Bound<'_, PyAny>, units: &str, name: &str) -> PyResult<Mesh> {
        let scale = unit_scale(units)?;
        let vertices = numbers::<f64>(vertices, "fiu", "float64", "vertices")?;
        let tris = face_indices(faces, name)?;
        let v = vertices.as_slice().map_err(|_| value_error("vertices: expected a C-contiguous array"))?;
        let verts: Vec<DVec3> = v.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2]) * scale).collect();
        let (inner, report) = plausible::mesh::Mesh::from_raw(name, verts, tris).map_err(to_py)?;
        Mesh::warned(py, inner, report.warnings)
    }

    /// Pickling (and `copy`): the mesh is rebuilt from its vertices in
    /// metres and faces, bit for bit, with its source and the warnings its
    /// loading gave (kept, not emitted again). Meshes reach other processes
    /// this way (multiprocessing).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let py = slf.py();
        let me = slf.get();
        let source = me.inner.source.clone();
        let args = (me.vertices(py), me.faces(py), source, me.warnings.clone());
        Ok((slf.get_type().getattr("_restore")?, args.into_pyobject(py)?.into_any()))
    }

    /// The inverse of `__reduce__`: the mesh from the state it gave,
    /// checked as any mesh from arrays is, and refused unless it comes back
    /// exactly (no face dropped on the way).
    #[staticmethod]
    fn _restore(vertices: PyReadonlyArray2<'_, f64>, faces: PyReadonlyArray2<'_, u32>, source: Option<std::path::PathBuf>, warnings: Vec<String>) -> PyResult<Mesh> {
        let (v, f) = (vertices.as_array(), faces.as_array());
        if v.ncols() != 3 || f.ncols() != 3 {
            return Err(value_error(format!("Mesh state: vertices must be (V, 3) and faces (F, 3), got {:?} and {:?}", v.shape(), f.shape())));
        }
        let verts: Vec<DVec3> = v.rows().into_iter().map(|r| DVec3::new(r[0], r[1], r[2])).collect();
        let tris: Vec<[u32; 3]> = f.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        let count = tris.len();
        let name = source.clone().unwrap_or_else(|| "<arrays>".into());
        let (mut inner, _) = plausible::mesh::Mesh::from_raw(name, verts, tris).map_err(to_py)?;
        if inner.triangles.len() != count {
            return Err(value_error(format!("Mesh state: {} of its {count} faces are degenerate, so it was not a plausible.Mesh's", count - inner.triangles.len())));
        }
        inner.source = source;
        Ok(Mesh { inner, warnings })
    }

    /// Loads .obj, .ply, .stl, .gltf or .glb; `units` "m", "cm", "mm" or "auto"
    /// (a diagonal above 5 m is taken as millimetres).
    #[staticmethod]
    #[pyo3(signature = (path, units = "auto"))]
    fn load(py: Python<'_>, path: std::path::PathBuf, units: &str) -> PyResult<Mesh> {
        let units: plausible::mesh::MeshUnits = units.parse().map_err(value_error)?;
        let (inner, report) = py.detach(|| plausible::mesh::Mesh::load(&path, units)).map_err(to_py)?;
        Mesh::warned(py, inner, report.warnings)
    }

    /// Vertices (V, 3), metres.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let flat: Vec<f64> = self.inner.vertices.iter().flat_map(|v| v.to_array()).collect();
        let n = self.inner.vertices.len();
        flat.into_pyarray(py).reshape([n, 3]).expect("V x 3 values")
    }

    /// Faces (F, 3) of vertex indices.
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<u32>> {
        let flat: Vec<u32> = self.inner.triangles.iter().flatten().copied().collect();
        let n = self.inner.triangles.len();
        flat.into_pyarray(py).reshape([n, 3]).expect("F x 3 values")
    }

    /// What loading noticed (units guessed, open boundary, dropped faces).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    /// Length of the bounding-box diagonal, metres.
    #[getter]
    fn diagonal(&self) -> f64 {
        self.inner.diagonal()
    }

    /// SHA-256 of the geometry in metres (the stable-pose database's key).
    #[getter]
    fn sha256(&self) -> String {
        plausible::stable::mesh_sha256(&self.inner)
    }

    fn __len__(&self) -> usize {
        self.inner.triangles.len()
    }

    fn __repr__(&self) -> String {
        let name = self.inner.source.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
        format!(
            "Mesh('{name}', {} vertices, {} triangles, diagonal {:.4} m)",
            self.inner.vertices.len(),
            self.inner.triangles.len(),
            self.inner.diagonal()
        )
    }
}
