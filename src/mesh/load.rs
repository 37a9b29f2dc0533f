//! File-format dispatch: OBJ (tobj), glTF/GLB (gltf), PLY and STL (our own
//! small parsers, since BOP models are PLY and YCB scans are STL).

use std::path::Path;

use glam::{DMat4, DVec3};

use crate::error::{Error, Result};

/// Reads the positions and triangles of a mesh file in its own units.
/// All bodies / primitives in the file are merged into one mesh.
pub fn load_positions(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    if !path.exists() {
        return Err(Error::NotFound { path: path.to_path_buf() });
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "obj" => load_obj(path),
        "ply" => super::ply::load(path),
        "stl" => super::stl::load(path),
        "gltf" | "glb" => load_gltf(path),
        _ => Err(Error::UnsupportedFormat { path: path.to_path_buf(), ext }),
    }
}

fn malformed(path: &Path, reason: impl ToString) -> Error {
    Error::MalformedMesh { path: path.to_path_buf(), reason: reason.to_string() }
}

fn load_obj(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    let (models, _materials) = tobj::load_obj(path, &opts).map_err(|e| malformed(path, e))?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for m in models {
        let base = vertices.len() as u64;
        let p = &m.mesh.positions;
        if p.len() % 3 != 0 {
            return Err(malformed(path, "position count is not a multiple of 3"));
        }
        vertices.extend(p.chunks_exact(3).map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)));
        for t in m.mesh.indices.chunks_exact(3) {
            triangles.push([t[0] as u64 + base, t[1] as u64 + base, t[2] as u64 + base]);
        }
    }
    narrow(path, vertices, triangles)
}

/// Converts 64-bit indices to `u32`, rejecting any beyond the vertex count.
pub(super) fn narrow(
    path: &Path,
    vertices: Vec<DVec3>,
    triangles: Vec<[u64; 3]>,
) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let n = vertices.len();
    let mut out = Vec::with_capacity(triangles.len());
    for (face, t) in triangles.into_iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&i| i as usize >= n || i > u32::MAX as u64) {
            return Err(Error::IndexOutOfRange { path: path.to_path_buf(), face, index, count: n });
        }
        out.push([t[0] as u32, t[1] as u32, t[2] as u32]);
    }
    Ok((vertices, out))
}

fn load_gltf(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let (doc, buffers, _images) = gltf::import(path).map_err(|e| malformed(path, e))?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let scene = doc.default_scene().or_else(|| doc.scenes().next());
    let mut stack: Vec<(gltf::Node, DMat4)> = match &scene {
        Some(s) => s.nodes().map(|n| (n, DMat4::IDENTITY)).collect(),
        None => doc.nodes().map(|n| (n, DMat4::IDENTITY)).collect(),
    };
    while let Some((node, parent)) = stack.pop() {
        let local = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
        let world = parent * local;
        for child in node.children() {
            stack.push((child, world));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else { continue };
            let base = vertices.len() as u64;
            vertices.extend(pos.map(|p| world.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))));
            let count = vertices.len() as u64 - base;
            let idx: Vec<u64> = match reader.read_indices() {
                Some(i) => i.into_u32().map(|i| i as u64).collect(),
                None => (0..count).collect(),
            };
            if idx.len() % 3 != 0 {
                return Err(malformed(path, "index count is not a multiple of 3"));
            }
            let flip = world.determinant() < 0.0;
            for t in idx.chunks_exact(3) {
                if flip {
                    triangles.push([t[0] + base, t[2] + base, t[1] + base]);
                } else {
                    triangles.push([t[0] + base, t[1] + base, t[2] + base]);
                }
            }
        }
    }
    narrow(path, vertices, triangles)
}
