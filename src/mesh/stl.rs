//! STL, binary and ASCII. Positions are repeated per face in STL, so the
//! caller welds them (see [`Mesh::weld`](super::Mesh::weld)) where
//! connectivity matters.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

pub fn load(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let malformed = |r: &str| Error::MalformedMesh { path: path.to_path_buf(), reason: r.to_string() };
    // A binary STL has an 80-byte header, a u32 count and 50 bytes per face.
    // Some binary files start with "solid" too, so the size decides.
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize;
        if bytes.len() == 84 + 50 * n {
            let mut vertices = Vec::with_capacity(3 * n);
            let mut triangles = Vec::with_capacity(n);
            for f in 0..n {
                let rec = &bytes[84 + 50 * f..84 + 50 * (f + 1)];
                for k in 0..3 {
                    let o = 12 + 12 * k;
                    let c = |i: usize| f32::from_le_bytes(rec[o + 4 * i..o + 4 * i + 4].try_into().unwrap()) as f64;
                    vertices.push(DVec3::new(c(0), c(1), c(2)));
                }
                let b = 3 * f as u32;
                triangles.push([b, b + 1, b + 2]);
            }
            let mut m = super::Mesh { vertices, triangles, source: None };
            m.weld();
            return Ok((m.vertices, m.triangles));
        }
    }
    let text = std::str::from_utf8(&bytes).map_err(|_| malformed("neither binary STL (size mismatch) nor ASCII STL"))?;
    if !text.trim_start().starts_with("solid") {
        return Err(malformed("neither binary STL (size mismatch) nor ASCII STL"));
    }
    let mut vertices = Vec::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        if it.next() == Some("vertex") {
            let c: Vec<f64> = it.map(|s| s.parse::<f64>()).collect::<std::result::Result<_, _>>()
                .map_err(|_| malformed("bad number in 'vertex' line"))?;
            if c.len() != 3 {
                return Err(malformed("'vertex' line needs 3 numbers"));
            }
            vertices.push(DVec3::new(c[0], c[1], c[2]));
        }
    }
    if vertices.len() % 3 != 0 {
        return Err(malformed("vertex count is not a multiple of 3"));
    }
    let triangles = (0..vertices.len() as u32 / 3).map(|f| [3 * f, 3 * f + 1, 3 * f + 2]).collect();
    let mut m = super::Mesh { vertices, triangles, source: None };
    m.weld();
    Ok((m.vertices, m.triangles))
}
