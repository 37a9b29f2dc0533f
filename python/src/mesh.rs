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

/// Metres per unit of `units` (`m` or `mm`).
pub fn unit_scale(units: &str) -> PyResult<f64> {
    match units {
        "m" => Ok(1.0),
        "mm" => Ok(1e-3),
        _ => Err(value_error(format!("units '{units}': expected \"m\" or \"mm\""))),
    }
}

#[pymethods]
impl Mesh {
    /// A mesh from vertices (V, 3) in `units` and faces (F, 3) of vertex
    /// indices; checked like a file (finite vertices, indices in range,
    /// degenerate faces dropped).
    #[new]
    #[pyo3(signature = (vertices, faces, units = "m", name = "<arrays>"))]
    fn new(vertices: PyReadonlyArray2<f64>, faces: PyReadonlyArray2<i64>, units: &str, name: &str) -> PyResult<Mesh> {
        let scale = unit_scale(units)?;
        let (vs, fs) = (vertices.shape(), faces.shape());
        if vs[1] != 3 || fs[1] != 3 {
            return Err(value_error(format!("vertices must be (V, 3) and faces (F, 3), got {vs:?} and {fs:?}")));
        }
        let v = vertices.as_slice().map_err(|_| value_error("vertices: expected a C-contiguous array"))?;
        let f = faces.as_slice().map_err(|_| value_error("faces: expected a C-contiguous array"))?;
        let verts: Vec<DVec3> = v.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2]) * scale).collect();
        let mut tris = Vec::with_capacity(f.len() / 3);
        for (i, c) in f.chunks_exact(3).enumerate() {
            let idx = |k: usize| {
                u32::try_from(c[k]).map_err(|_| value_error(format!("{name}: face {i} refers to vertex {}, which does not exist", c[k])))
            };
            tris.push([idx(0)?, idx(1)?, idx(2)?]);
        }
        let (inner, report) = plausible::mesh::Mesh::from_raw(name, verts, tris).map_err(to_py)?;
        Ok(Mesh { inner, warnings: report.warnings })
    }

    /// Loads .obj, .ply, .stl, .gltf or .glb; `units` "m", "mm" or "auto"
    /// (a diagonal above 5 m is taken as millimetres).
    #[staticmethod]
    #[pyo3(signature = (path, units = "auto"))]
    fn load(py: Python<'_>, path: std::path::PathBuf, units: &str) -> PyResult<Mesh> {
        let units: plausible::mesh::MeshUnits = units.parse().map_err(value_error)?;
        let (inner, report) = py.detach(|| plausible::mesh::Mesh::load(&path, units)).map_err(to_py)?;
        Ok(Mesh { inner, warnings: report.warnings })
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
