//! Levels of detail for the visual score.
//!
//! At a 128 × 128 scoring region most triangles of a scanned 40k-triangle
//! model cover less than a pixel: the rasterizer spends its time on
//! triangles that draw nothing. A chain of simplified meshes (meshoptimizer's
//! edge-collapse simplifier through the `meshopt` crate: a well-kept,
//! widely used implementation, so no quadric decimation is written here),
//! each about half the triangles of the one before with its geometric error
//! in metres, lets the scorer pick the coarsest mesh whose error stays
//! below a fraction of a pixel at the hypotheses' distance. Only the visual
//! score uses it; the physical terms and evaluation keep the full mesh.

use glam::DVec3;

use super::Mesh;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};

/// Each level aims at this fraction of the previous level's triangles.
const STEP: f64 = 0.5;
/// The chain stops below this many triangles.
pub const MIN_TRIANGLES: usize = 32;
/// `auto` picks the coarsest level whose geometric error is at most this
/// fraction of a pixel (the paper's Table 1: 352-704 faces score like the
/// full LM-O models at 640 × 480; half a pixel keeps the rendered depth
/// and normals within the scorer's tolerances).
pub const AUTO_PIXEL_FRACTION: f64 = 0.5;

/// One level: its mesh and its geometric error (metres; 0 for the full mesh).
#[derive(Clone, Debug)]
pub struct LodLevel {
    pub mesh: Mesh,
    pub error_m: f64,
}

/// The full mesh and its simplifications, finest first.
#[derive(Clone, Debug)]
pub struct Lod {
    pub levels: Vec<LodLevel>,
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

impl Lod {
    /// Builds the chain: the full mesh, then simplifications of about half
    /// the triangles each, until [`MIN_TRIANGLES`] or until the simplifier
    /// can remove no more than a tenth (it keeps the topology).
    pub fn build(mesh: &Mesh) -> Result<Lod> {
        let mut levels = vec![LodLevel { mesh: mesh.clone(), error_m: 0.0 }];
        let welded = welded(mesh);
        let mut n = mesh.triangles.len();
        while n > MIN_TRIANGLES {
            let target = ((n as f64 * STEP) as usize).max(MIN_TRIANGLES);
            let level = simplified(&welded, target)?;
            let got = level.mesh.triangles.len();
            if got as f64 > 0.9 * n as f64 {
                break;
            }
            n = got;
            levels.push(level);
        }
        Ok(Lod { levels })
    }

    /// The coarsest level whose error is at most [`AUTO_PIXEL_FRACTION`] of
    /// `pixel_m`, the size of a pixel (metres) at the nearest hypothesis.
    pub fn choose(&self, pixel_m: f64) -> &LodLevel {
        let bound = AUTO_PIXEL_FRACTION * pixel_m;
        self.levels.iter().rev().find(|l| l.error_m <= bound).unwrap_or(&self.levels[0])
    }
}

/// A simplification of `mesh` to about `faces` triangles (the full mesh when
/// it has no more), with its geometric error.
pub fn with_faces(mesh: &Mesh, faces: usize) -> Result<LodLevel> {
    if faces >= mesh.triangles.len() {
        return Ok(LodLevel { mesh: mesh.clone(), error_m: 0.0 });
    }
    simplified(&welded(mesh), faces)
}

/// The size of a pixel (metres) of `region` at distance `z` (metres): the
/// finer of the two focal lengths decides.
pub fn pixel_size(region: &Intrinsics, z: f64) -> f64 {
    z.max(0.0) / region.fx.max(region.fy)
}

/// A copy with coincident vertices merged: the simplifier collapses edges,
/// which needs the connectivity that per-face vertices hide.
fn welded(mesh: &Mesh) -> Mesh {
    let mut m = mesh.clone();
    m.weld();
    m
}

/// meshoptimizer's simplification of `mesh` to about `target` triangles,
/// with unused vertices dropped; the error is absolute (metres).
fn simplified(mesh: &Mesh, target: usize) -> Result<LodLevel> {
    let positions: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.as_vec3().to_array()).collect();
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let mut error = 0.0f32;
    let out = meshopt::simplify_decoder(
        &indices,
        &positions,
        target * 3,
        f32::MAX,
        meshopt::SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    if out.len() < 3 {
        return Err(Error::InvalidInput(format!("simplifying {} triangles to {target} left nothing", mesh.triangles.len())));
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(n: u32) -> Mesh {
        crate::shapes::icosphere(0.05, n)
    }

    #[test]
    fn the_chain_halves_and_its_error_grows() {
        let mesh = sphere(5);
        let lod = Lod::build(&mesh).unwrap();
        assert!(lod.levels.len() >= 5, "{} levels", lod.levels.len());
        for w in lod.levels.windows(2) {
            assert!(w[1].mesh.triangles.len() < w[0].mesh.triangles.len());
            assert!(w[1].error_m >= w[0].error_m);
        }
        // The error is a distance on the 5 cm sphere: well below its radius.
        assert!(lod.levels.last().unwrap().error_m < 0.05);
        // Every vertex of a level lies near the sphere, within its error.
        for l in &lod.levels {
            for v in &l.mesh.vertices {
                assert!((v.length() - 0.05).abs() <= l.error_m + 1e-3, "{} vs error {}", v.length(), l.error_m);
            }
        }
    }

    #[test]
    fn auto_picks_coarser_levels_for_larger_pixels() {
        let lod = Lod::build(&sphere(5)).unwrap();
        let near = lod.choose(1e-5).mesh.triangles.len();
        let far = lod.choose(1e-2).mesh.triangles.len();
        assert_eq!(near, lod.levels[0].mesh.triangles.len(), "a tiny pixel needs the full mesh");
        assert!(far < near / 4, "{far} vs {near}");
        assert!(lod.choose(1e-3).error_m <= AUTO_PIXEL_FRACTION * 1e-3);
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
