//! Levels of detail for the visual score.
//!
//! At a 128 × 128 scoring region most triangles of a scanned 40k-triangle
//! model cover less than a pixel: the rasterizer spends its time on
//! triangles that draw nothing. meshoptimizer's edge-collapse simplifier
//! (through the `meshopt` crate: a well-kept, widely used implementation,
//! so no quadric decimation is written here) gives, in one call with an
//! absolute error bound, the coarsest mesh whose geometric error stays below
//! a fraction of a pixel at the observed object (`auto`), or a mesh of
//! about N triangles (the paper's Table 1 sizes). Only the visual score
//! uses it; the physical terms and evaluation keep the full mesh.

use glam::DVec3;

use super::Mesh;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};

/// `auto` never simplifies below this many triangles.
pub const MIN_TRIANGLES: usize = 32;
/// `auto` picks the coarsest simplification whose geometric error is at
/// most this fraction of a pixel. The paper's Table 1 has 352-704 faces
/// scoring like the full LM-O models; measured here, half a pixel moved the
/// demo's true-pose score by 0.005 (990 of the duck's 4,212 triangles) and a
/// quarter by 0.001 (about 2,000), at most 20 % slower: a quarter it is.
pub const AUTO_PIXEL_FRACTION: f64 = 0.25;

/// One level: its mesh and its geometric error (metres; 0 for the full mesh).
#[derive(Clone, Debug)]
pub struct LodLevel {
    pub mesh: Mesh,
    pub error_m: f64,
}

impl LodLevel {
    /// The full mesh itself (no error).
    pub fn full(mesh: &Mesh) -> LodLevel {
        LodLevel { mesh: mesh.clone(), error_m: 0.0 }
    }
}

/// How the scoring mesh is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LodChoice {
    /// The coarsest level within [`AUTO_PIXEL_FRACTION`] of a pixel.
    #[default]
    Auto,
    /// The full mesh.
    Off,
    /// A simplification to about this many triangles.
    Faces(usize),
}

impl std::str::FromStr for LodChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "auto" => Ok(LodChoice::Auto),
            "off" => Ok(LodChoice::Off),
            n => match n.parse::<usize>() {
                Ok(f) if f >= 4 => Ok(LodChoice::Faces(f)),
                _ => Err(format!("LOD '{s}': expected auto, off or a triangle count of at least 4")),
            },
        }
    }
}

impl std::fmt::Display for LodChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LodChoice::Auto => write!(f, "auto"),
            LodChoice::Off => write!(f, "off"),
            LodChoice::Faces(n) => write!(f, "{n}"),
        }
    }
}

/// The coarsest simplification whose geometric error is at most
/// `max_error_m` (metres): one call of the simplifier with that error bound
/// and a floor of [`MIN_TRIANGLES`] (the full mesh when nothing can go).
pub fn within_error(mesh: &Mesh, max_error_m: f64) -> Result<LodLevel> {
    if mesh.triangles.len() <= MIN_TRIANGLES || max_error_m.is_nan() || max_error_m <= 0.0 {
        return Ok(LodLevel::full(mesh));
    }
    let level = simplify(&welded(mesh), MIN_TRIANGLES, max_error_m as f32)?;
    if level.mesh.triangles.len() >= mesh.triangles.len() {
        return Ok(LodLevel::full(mesh));
    }
    Ok(level)
}

/// A simplification of `mesh` to about `faces` triangles (the full mesh when
/// it has no more), with its geometric error.
pub fn with_faces(mesh: &Mesh, faces: usize) -> Result<LodLevel> {
    if faces >= mesh.triangles.len() {
        return Ok(LodLevel::full(mesh));
    }
    simplify(&welded(mesh), faces, f32::MAX)
}

/// The size of a pixel (metres) of `region` at distance `z` (metres): the
/// finer of the two focal lengths decides.
pub fn pixel_size(region: &Intrinsics, z: f64) -> f64 {
    z.max(0.0) / region.fx.max(region.fy)
}

/// A copy with coincident vertices merged (the simplifier collapses edges,
/// which needs the connectivity that per-face vertices hide) and faces
/// wound consistently ([`Mesh::orient`]): a scan's backwards patches would
/// otherwise come out of the simplifier as neither closed nor solid, and
/// the renderer could not cull its back faces.
fn welded(mesh: &Mesh) -> Mesh {
    let mut m = mesh.clone();
    m.weld();
    m.orient();
    m
}

/// meshoptimizer's simplification of `mesh` towards `target` triangles,
/// stopping where the error would pass `max_error` (metres), with unused
/// vertices dropped; the error reported is absolute (metres).
fn simplify(mesh: &Mesh, target: usize, max_error: f32) -> Result<LodLevel> {
    let positions: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.as_vec3().to_array()).collect();
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let mut error = 0.0f32;
    let out = meshopt::simplify_decoder(
        &indices,
        &positions,
        target * 3,
        max_error,
        meshopt::SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    if out.len() < 3 {
        return Err(Error::InvalidInput(format!("simplifying {} triangles to {target} left nothing", mesh.triangles.len())));
    }
    let out = without_flaps(&out);
    let mut remap = vec![u32::MAX; mesh.vertices.len()];
    let mut vertices: Vec<DVec3> = Vec::new();
    let mut map = |i: u32| {
        let slot = &mut remap[i as usize];
        if *slot == u32::MAX {
            *slot = vertices.len() as u32;
            vertices.push(mesh.vertices[i as usize]);
        }
        *slot
    };
    let triangles: Vec<[u32; 3]> = out.chunks_exact(3).map(|t| [map(t[0]), map(t[1]), map(t[2])]).collect();
    let name = mesh.source.clone().unwrap_or_else(|| "<mesh>".into());
    let (mesh, _) = Mesh::from_raw(name, vertices, triangles)?;
    Ok(LodLevel { mesh, error_m: error as f64 })
}

/// `indices` without flaps: triangles that appear more than once with the
/// same corners in the same order. meshoptimizer's edge collapses
/// occasionally fold two neighbours onto one another (LM-O's can, simplified
/// to a quarter pixel at 128×128, keeps one such pair). The pair adds no
/// surface a closed mesh needs, but it makes the mesh non-manifold, and
/// rendering then cannot cull back faces: twice the triangles and pixels
/// for the rasterizer, which is what `--lod auto` exists to save.
fn without_flaps(indices: &[u32]) -> Vec<u32> {
    // Each triangle's corners rotated so the smallest comes first: the same
    // key for the same oriented triangle.
    let key = |t: &[u32]| {
        let r = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
        [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
    };
    let mut count = std::collections::HashMap::<[u32; 3], u32>::new();
    for t in indices.chunks_exact(3) {
        *count.entry(key(t)).or_default() += 1;
    }
    indices.chunks_exact(3).filter(|t| count[&key(t)] == 1).flatten().copied().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(n: u32) -> Mesh {
        crate::shapes::icosphere(0.05, n)
    }

    #[test]
    fn the_error_bound_holds_and_larger_bounds_remove_more() {
        let mesh = sphere(5);
        let mut last = usize::MAX;
        for bound in [1e-5, 1e-4, 1e-3, 1e-2] {
            let l = within_error(&mesh, bound).unwrap();
            let n = l.mesh.triangles.len();
            assert!(l.error_m <= bound, "{} > {bound}", l.error_m);
            assert!(n <= last, "{n} after {last}");
            // Every vertex stays near the 5 cm sphere, within the error.
            for v in &l.mesh.vertices {
                assert!((v.length() - 0.05).abs() <= l.error_m + 1e-3);
            }
            last = n;
        }
        assert!(last < mesh.triangles.len() / 8, "{last} of {}", mesh.triangles.len());
        assert_eq!(within_error(&mesh, 0.0).unwrap().mesh.triangles.len(), mesh.triangles.len());
    }

    #[test]
    fn folded_pairs_are_dropped_and_the_rest_kept() {
        // A tetrahedron (closed) and a flap: one triangle on an edge of it
        // twice, as the simplifier leaves it.
        let tet = [0, 2, 1, 0, 1, 3, 1, 2, 3, 0, 3, 2];
        let mut with_flap = tet.to_vec();
        with_flap.extend([1, 0, 4, 0, 4, 1]); // the same triangle, rotated
        assert_eq!(without_flaps(&with_flap), tet.to_vec());
        // Opposite orientations are a two-sided sheet, not a fold: kept.
        let mut sheet = tet.to_vec();
        sheet.extend([1, 0, 4, 0, 1, 4]);
        assert_eq!(without_flaps(&sheet), sheet);
    }

    #[test]
    fn simplifying_a_closed_model_keeps_it_closed() {
        // The LM-O models shipped in assets/, at the error bounds `--lod
        // auto` picks for 128x128 to 640x480 regions and beyond: still the
        // boundary of a solid, so the renderer may cull back faces (the
        // eggbox at 1 mm has an edge where two sheets touch, which is fine;
        // its scan has faces wound backwards, which welded() turns round).
        for id in [1, 10, 11] {
            let path = format!("{}/assets/lmo-synth/models/obj_{id:06}.ply", env!("CARGO_MANIFEST_DIR"));
            let (mesh, _) = Mesh::load(&path, crate::mesh::MeshUnits::Millimetres).unwrap();
            assert!(mesh.is_closed(), "{path}");
            for bound in [2e-4, 5e-4, 1e-3, 2e-3, 5e-3] {
                let l = within_error(&mesh, bound).unwrap();
                assert!(l.mesh.bounds_solid(), "{path} at {bound} m: {} triangles", l.mesh.triangles.len());
            }
        }
    }

    #[test]
    fn faces_and_choices_parse() {
        let m = sphere(4);
        let l = with_faces(&m, 200).unwrap();
        assert!(l.mesh.triangles.len() <= 220 && l.mesh.triangles.len() >= 100, "{}", l.mesh.triangles.len());
        assert_eq!(with_faces(&m, 1 << 20).unwrap().mesh.triangles.len(), m.triangles.len());
        assert_eq!("auto".parse::<LodChoice>(), Ok(LodChoice::Auto));
        assert_eq!("off".parse::<LodChoice>(), Ok(LodChoice::Off));
        assert_eq!("352".parse::<LodChoice>(), Ok(LodChoice::Faces(352)));
        assert!("2".parse::<LodChoice>().is_err() && "x".parse::<LodChoice>().is_err() && "-5".parse::<LodChoice>().is_err());
    }
}
