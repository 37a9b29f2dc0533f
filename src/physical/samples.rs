//! Area-weighted surface samples and the contact tolerance ε derived from
//! their spacing.
//!
//! Samples are drawn once per mesh in model coordinates (a triangle with
//! probability proportional to its area, then a uniform point in it), from a
//! `ChaCha8Rng` seeded by the caller, so the same seed gives the same
//! samples on every machine.

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{Error, Result};
use crate::mesh::Mesh;

/// Default number of surface samples per object (the paper's and
/// SporeAgent's 1024 points).
pub const DEFAULT_SAMPLES: usize = 1024;

/// Most surface samples per object. The GPU kernels loop over an object's
/// samples inside one shader invocation, and lavapipe silently ends every
/// loop of an invocation after 65,535 iterations in total (see the README),
/// so a larger count would give wrong results there rather than an error.
/// 50,000 samples are a sample every ~0.3 mm on a 15 cm object.
pub const MAX_SAMPLES: usize = 50_000;

/// Default seed of the surface sampling.
pub const DEFAULT_SEED: u64 = 0;

/// Smallest and largest default ε in metres (the reference values: 2 mm in
/// plausible-poses with 1 mm grids, 5 mm in SporeAgent with 1024 points).
pub const EPSILON_MIN: f64 = 0.002;
pub const EPSILON_MAX: f64 = 0.005;

/// `count` points uniformly distributed over the surface of `mesh` (model
/// coordinates), reproducible from `seed`.
pub fn surface_samples(mesh: &Mesh, count: usize, seed: u64) -> Result<Vec<DVec3>> {
    Ok(surface_samples_on_faces(mesh, count, seed)?.into_iter().map(|(p, _)| p).collect())
}

/// [`surface_samples`] with the triangle each sample lies on (for its
/// normal); the same points for the same seed.
pub fn surface_samples_on_faces(mesh: &Mesh, count: usize, seed: u64) -> Result<Vec<(DVec3, usize)>> {
    if count == 0 {
        return Err(Error::InvalidInput(
            "the number of surface samples must be at least 1".into(),
        ));
    }
    if count > MAX_SAMPLES {
        return Err(Error::InvalidInput(format!(
            "{count} surface samples per object: at most {MAX_SAMPLES} are taken (the GPU kernels' bound, kept on the CPU so both give the same answers); use fewer"
        )));
    }
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for i in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(i);
        total += 0.5 * (b - a).cross(c - a).length();
        cumulative.push(total);
    }
    if total.is_nan() || total <= 0.0 || !total.is_finite() {
        return Err(Error::InvalidInput(
            "cannot sample a mesh with zero surface area".into(),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(count);
    for _ in 0..count {
        let r: f64 = rng.random::<f64>() * total;
        let i = cumulative
            .partition_point(|&c| c <= r)
            .min(cumulative.len() - 1);
        let [a, b, c] = mesh.corners(i);
        // Uniform in the triangle: the square-root trick.
        let (u, v): (f64, f64) = (rng.random(), rng.random());
        let su = u.sqrt();
        out.push((a * (1.0 - su) + b * (su * (1.0 - v)) + c * (su * v), i));
    }
    Ok(out)
}

/// Mean spacing of `count` samples on a surface of `area` m²: `sqrt(area / count)`.
pub fn sample_spacing(area: f64, count: usize) -> f64 {
    (area / count.max(1) as f64).sqrt()
}

/// Default ε for a given sample spacing: half the spacing, clamped to
/// [2 mm, 5 mm]. Half the spacing keeps a resting edge detectable: a face
/// tilted by θ puts samples within ε of the support in a strip ε / sin θ
/// wide, which holds samples once it is comparable to the spacing.
pub fn default_epsilon(spacing: f64) -> f64 {
    (0.5 * spacing).clamp(EPSILON_MIN, EPSILON_MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_counts_outside_what_the_kernels_take_are_errors() {
        let m = crate::shapes::cuboid(DVec3::splat(0.05));
        assert!(surface_samples(&m, 0, 0).unwrap_err().to_string().contains("at least 1"));
        assert!(surface_samples(&m, MAX_SAMPLES + 1, 0).unwrap_err().to_string().contains("use fewer"));
        assert_eq!(surface_samples(&m, MAX_SAMPLES, 0).unwrap().len(), MAX_SAMPLES);
    }

    #[test]
    fn samples_are_on_the_surface_and_area_weighted() {
        let half = DVec3::new(0.05, 0.02, 0.01);
        let m = crate::shapes::cuboid(half);
        let s = surface_samples(&m, 20000, 7).unwrap();
        assert_eq!(s, surface_samples(&m, 20000, 7).unwrap());
        let mut top = 0;
        for p in &s {
            let on = (p.x.abs() - half.x).abs() < 1e-12
                || (p.y.abs() - half.y).abs() < 1e-12
                || (p.z.abs() - half.z).abs() < 1e-12;
            assert!(on, "{p} not on the box surface");
            assert!(
                p.x.abs() <= half.x + 1e-12
                    && p.y.abs() <= half.y + 1e-12
                    && p.z.abs() <= half.z + 1e-12
            );
            if (p.z - half.z).abs() < 1e-12 {
                top += 1;
            }
        }
        // Top face: 0.1 * 0.04 of a total 2 (0.1*0.04 + 0.1*0.02 + 0.04*0.02) = 0.0136 m².
        let expect = 20000.0 * 0.004 / 0.0136;
        assert!(
            (top as f64 - expect).abs() < 4.0 * expect.sqrt(),
            "{top} vs {expect}"
        );
        assert!(surface_samples(&m, 0, 0).is_err());
    }

    #[test]
    fn epsilon_scales_with_spacing_within_the_reference_range() {
        assert_eq!(default_epsilon(0.001), 0.002);
        assert!((default_epsilon(0.008) - 0.004).abs() < 1e-12);
        assert_eq!(default_epsilon(0.05), 0.005);
    }
}
