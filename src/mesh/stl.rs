//! STL, binary and ASCII. Positions are repeated per face in STL, so the
//! caller welds them (see [`Mesh::weld`](super::Mesh::weld)) where
//! connectivity matters.
//!
//! A NaN or infinite corner is refused here, naming its face, before the
//! corners are welded: welding quantizes positions to integers, which
//! would turn NaN into the origin (merging it into a real vertex) and an
//! infinite corner into a bounding box that collapses every other one.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

type Parsed<T> = std::result::Result<T, String>;

pub fn load(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let vertices = corners(&bytes).map_err(|reason| Error::MalformedMesh { path: path.to_path_buf(), reason })?;
    let triangles = (0..vertices.len() as u32 / 3).map(|f| [3 * f, 3 * f + 1, 3 * f + 2]).collect();
    let mut m = super::Mesh { vertices, triangles, source: None };
    m.weld();
    Ok((m.vertices, m.triangles))
}

/// Every face's three corners, in order, all finite.
fn corners(bytes: &[u8]) -> Parsed<Vec<DVec3>> {
    // A binary STL has an 80-byte header, a u32 count and 50 bytes per face.
    // Some binary files start with "solid" too, so the size decides.
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize;
        if bytes.len() == 84 + 50 * n {
            return binary(&bytes[84..], n);
        }
    }
    ascii(bytes)
}

/// Refuses a corner that is not finite, naming its face (counted from 0).
fn finite(v: DVec3, face: usize) -> Parsed<DVec3> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("face {face} has a corner that is not finite ({}, {}, {})", v.x, v.y, v.z))
    }
}

fn binary(records: &[u8], n: usize) -> Parsed<Vec<DVec3>> {
    let mut vertices = Vec::with_capacity(3 * n);
    for (f, rec) in records.chunks_exact(50).take(n).enumerate() {
        for k in 0..3 {
            let o = 12 + 12 * k;
            let c = |i: usize| f32::from_le_bytes(rec[o + 4 * i..o + 4 * i + 4].try_into().unwrap()) as f64;
            vertices.push(finite(DVec3::new(c(0), c(1), c(2)), f)?);
        }
    }
    Ok(vertices)
}

fn ascii(bytes: &[u8]) -> Parsed<Vec<DVec3>> {
    let neither = || "neither binary STL (size mismatch) nor ASCII STL".to_string();
    let text = std::str::from_utf8(bytes).map_err(|_| neither())?;
    if !text.trim_start().starts_with("solid") {
        return Err(neither());
    }
    let mut vertices = Vec::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        if it.next() == Some("vertex") {
            let c: Vec<f64> = it.map(|s| s.parse::<f64>()).collect::<std::result::Result<_, _>>()
                .map_err(|_| "bad number in 'vertex' line".to_string())?;
            if c.len() != 3 {
                return Err("'vertex' line needs 3 numbers".into());
            }
            vertices.push(finite(DVec3::new(c[0], c[1], c[2]), vertices.len() / 3)?);
        }
    }
    if vertices.len() % 3 != 0 {
        return Err("vertex count is not a multiple of 3".into());
    }
    Ok(vertices)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binary_stl(tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut b = vec![0u8; 80];
        b.extend((tris.len() as u32).to_le_bytes());
        for t in tris {
            b.extend([0u8; 12]);
            t.iter().flatten().for_each(|c| b.extend(c.to_le_bytes()));
            b.extend([0u8; 2]);
        }
        b
    }

    #[test]
    fn non_finite_corners_are_refused_naming_the_face() {
        let ok = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        for bad in [f32::NAN, f32::INFINITY] {
            let e = corners(&binary_stl(&[ok, [[0.0, 0.0, 0.0], [bad, 0.0, 0.0], [0.0, 0.0, 1.0]]])).unwrap_err();
            assert!(e.contains("face 1") && e.contains("not finite"), "{e}");
        }
        assert_eq!(corners(&binary_stl(&[ok])).unwrap().len(), 3);
        let text = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n\
                    facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 0 1 0\nvertex 0 0 -inf\nendloop\nendfacet\nendsolid t\n";
        let e = corners(text.as_bytes()).unwrap_err();
        assert!(e.contains("face 1") && e.contains("not finite"), "{e}");
        let e = corners(text.replace("-inf", "NaN").as_bytes()).unwrap_err();
        assert!(e.contains("face 1") && e.contains("NaN"), "{e}");
    }
}
