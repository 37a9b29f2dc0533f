//! The support plane from an observed depth image: the plane the physical
//! terms of `plausible score --physics` are computed against.
//!
//! The pixels outside the object's mask (grown by a few pixels, since depth
//! at silhouettes mixes object and background) are back-projected to camera
//! points; RANSAC (seeded) finds the plane with the most points within the
//! inlier distance, and a least-squares refit on its inliers (twice, with
//! the inliers recomputed in between) removes the sampling noise of the
//! three-point hypotheses. With a mask, a candidate plane must have the
//! object's points on its camera side (an object cannot rest on a plane it
//! is behind), which keeps walls and the backs of shelves out.
//!
//! The largest such plane wins, so crop or mask the depth when a bigger
//! plane than the support (a wall, a floor far below a table) fills the view.

use glam::{DMat3, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{Error, Result};
use crate::observation::DepthImage;
use crate::physical::Plane;
use crate::stop::Stop;

/// Parameters of the fit.
#[derive(Clone, Debug)]
pub struct PlaneFitParams {
    /// Largest distance (m) of an inlier from the plane.
    pub inlier_m: f64,
    /// RANSAC hypotheses.
    pub iterations: usize,
    /// Seed of the RANSAC sampling (same seed, same plane).
    pub seed: u64,
    /// Points RANSAC scores hypotheses on (a seeded subsample; the refit uses all).
    pub max_points: usize,
    /// Pixels the mask is grown by before its pixels are left out.
    pub mask_margin_px: usize,
    /// Checked between RANSAC hypotheses: a million of them take seconds,
    /// and a caller (the Python binding on Ctrl-C) may want them to end.
    pub stop: Stop,
}

impl Default for PlaneFitParams {
    fn default() -> Self {
        PlaneFitParams { inlier_m: 0.005, iterations: 500, seed: 0, max_points: 20_000, mask_margin_px: 5, stop: Stop::default() }
    }
}

/// A fitted support plane and how well it is supported by the data.
#[derive(Clone, Debug)]
pub struct PlaneFit {
    /// Camera frame, metres, unit normal towards the camera.
    pub plane: Plane,
    /// Points within the inlier distance of the final plane.
    pub inliers: usize,
    /// Back-projected points outside the (grown) mask.
    pub candidates: usize,
    /// Root-mean-square distance of the inliers to the plane (m).
    pub rms: f64,
}

/// Fewest candidate points a fit is attempted on.
pub const MIN_POINTS: usize = 500;

/// Fits the support plane to `obs` outside `mask` (see the module docs).
pub fn fit_support_plane(obs: &DepthImage, mask: Option<&[bool]>, p: &PlaneFitParams) -> Result<PlaneFit> {
    if !(p.inlier_m.is_finite() && p.inlier_m > 0.0 && p.inlier_m < 0.5) {
        return Err(Error::InvalidInput(format!(
            "plane fit: the inlier distance is {} m; it must lie in (0, 0.5) m (the default is 0.005)",
            p.inlier_m
        )));
    }
    // Over a million hypotheses is minutes of work for nothing: 500 find a
    // plane holding a tenth of the points with certainty.
    if !(1..=1_000_000).contains(&p.iterations) || p.max_points < 3 {
        return Err(Error::InvalidInput(format!(
            "plane fit: needs 1 to 1,000,000 RANSAC iterations and 3 points to score on, got {} and {}",
            p.iterations, p.max_points
        )));
    }
    let k = &obs.intrinsics;
    let (w, h) = (k.width as usize, k.height as usize);
    if let Some(m) = mask {
        if m.len() != w * h {
            return Err(Error::InvalidInput(format!("plane fit: the mask has {} pixels, the depth {}", m.len(), w * h)));
        }
    }
    let grown = mask.map(|m| grow(m, w, h, p.mask_margin_px));
    let point = |i: usize| k.pixel_point(i, obs.depth[i] as f64);
    let valid = |i: usize| obs.depth[i] > 0.0 && obs.depth[i].is_finite();
    let points: Vec<DVec3> = (0..w * h).filter(|&i| valid(i) && !grown.as_ref().is_some_and(|g| g[i])).map(point).collect();
    if points.len() < MIN_POINTS {
        return Err(Error::InvalidInput(format!(
            "cannot fit a support plane: only {} depth pixels lie outside the object's mask (at least {MIN_POINTS} are needed); \
             the depth must show the surface the object rests on",
            points.len()
        )));
    }
    // The object's points, which must lie on the camera side of the plane.
    let object: Vec<DVec3> = match mask {
        Some(m) => (0..w * h).filter(|&i| m[i] && valid(i)).map(point).collect(),
        None => Vec::new(),
    };
    let object_centre = (!object.is_empty()).then(|| object.iter().copied().sum::<DVec3>() / object.len() as f64);

    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let subset: Vec<DVec3> = if points.len() > p.max_points {
        (0..p.max_points).map(|_| points[rng.random_range(0..points.len())]).collect()
    } else {
        points.clone()
    };
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..p.iterations {
        p.stop.check()?;
        let [a, b, c] = [0; 3].map(|_| subset[rng.random_range(0..subset.len())]);
        let n = (b - a).cross(c - a);
        if n.length() < 1e-9 {
            continue;
        }
        let Some(plane) = oriented(a, n) else { continue };
        if object_centre.is_some_and(|o| plane.distance(o) <= 0.0) {
            continue;
        }
        let count = subset.iter().filter(|&&x| plane.distance(x).abs() < p.inlier_m).count();
        if best.as_ref().is_none_or(|(c, _)| count > *c) {
            best = Some((count, plane));
        }
    }
    let Some((_, mut plane)) = best else {
        return Err(Error::InvalidInput(
            "cannot fit a support plane: no plane through the depth outside the mask has the object on its camera side".into(),
        ));
    };
    for _ in 0..2 {
        let inliers: Vec<DVec3> = points.iter().copied().filter(|&x| plane.distance(x).abs() < p.inlier_m).collect();
        if inliers.len() < 3 {
            break;
        }
        // The refit must keep the object on the camera side, like RANSAC's.
        if let Some(refit) = least_squares(&inliers, plane.normal) {
            if !object_centre.is_some_and(|o| refit.distance(o) <= 0.0) {
                plane = refit;
            }
        }
    }
    let dists: Vec<f64> = points.iter().map(|&x| plane.distance(x)).filter(|d| d.abs() < p.inlier_m).collect();
    let rms = (dists.iter().map(|d| d * d).sum::<f64>() / dists.len().max(1) as f64).sqrt();
    Ok(PlaneFit { plane, inliers: dists.len(), candidates: points.len(), rms })
}

/// The plane through `point` with normal `n`, turned towards the camera.
fn oriented(point: DVec3, n: DVec3) -> Option<Plane> {
    let plane = Plane { point, normal: n }.facing_camera();
    plane.normal.is_finite().then_some(plane)
}

/// Total least squares: through the centroid, normal along the covariance's
/// smallest eigenvector (power iteration on `tr(C) I - C`, started from the
/// RANSAC normal, which is already close).
fn least_squares(points: &[DVec3], start: DVec3) -> Option<Plane> {
    let (c, cov) = crate::mesh::mass::scatter_about_mean(points);
    let shifted = DMat3::from_diagonal(DVec3::splat(cov.x_axis.x + cov.y_axis.y + cov.z_axis.z)) - cov;
    let mut n = start.normalize();
    for _ in 0..200 {
        let next = (shifted * n).normalize();
        if !next.is_finite() {
            return None;
        }
        let done = (next - n).length() < 1e-14;
        n = next;
        if done {
            break;
        }
    }
    oriented(c, n)
}

/// The mask grown by `r` pixels (a square structuring element, separable:
/// rows, then columns).
fn grow(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    // Along one line of `n` pixels: set where a set pixel lies within r.
    fn grow_line(get: impl Fn(usize) -> bool, n: usize, r: usize, mut set: impl FnMut(usize)) {
        let mut last_left: Option<usize> = None;
        let mut near = vec![false; n];
        for (i, v) in near.iter_mut().enumerate() {
            if get(i) {
                last_left = Some(i);
            }
            *v = last_left.is_some_and(|l| i - l <= r);
        }
        let mut next_right: Option<usize> = None;
        for i in (0..n).rev() {
            if get(i) {
                next_right = Some(i);
            }
            if near[i] || next_right.is_some_and(|j| j - i <= r) {
                set(i);
            }
        }
    }
    let mut rows = vec![false; w * h];
    for y in 0..h {
        grow_line(|x| mask[y * w + x], w, r, |x| rows[y * w + x] = true);
    }
    let mut out = vec![false; w * h];
    for x in 0..w {
        grow_line(|y| rows[y * w + x], h, r, |y| out[y * w + x] = true);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grow_matches_the_definition() {
        let (w, h) = (23, 17);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mask: Vec<bool> = (0..w * h).map(|_| rng.random::<f64>() < 0.05).collect();
        for r in [0, 1, 3] {
            let g = grow(&mask, w, h, r);
            for y in 0..h {
                for x in 0..w {
                    let want = (y.saturating_sub(r)..=(y + r).min(h - 1))
                        .any(|yy| (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|xx| mask[yy * w + xx]));
                    assert_eq!(g[y * w + x], want, "r {r} at ({x}, {y})");
                }
            }
        }
    }
}
