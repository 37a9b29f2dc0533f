//! Visible Surface Discrepancy (Hodaň et al., ECCV 2018) as the BOP
//! toolkit computes it (`pose_error.vsd`, bop19 visibility, "step" cost):
//!
//! - depth images become **distance** images (ray length: z·‖((x−cx)/fx,
//!   (y−cy)/fy, 1)‖ with integer pixel coordinates);
//! - the ground truth is visible where it has depth and lies at most δ
//!   behind the test distance, or the test depth is missing (bop19);
//! - the estimate likewise, plus wherever the ground truth is visible and
//!   the estimate has depth;
//! - error = (#(intersection with |d_e − d_g| / diameter ≥ τ) + #(union \
//!   intersection)) / #union, and 1 for an empty union.
//!
//! The arithmetic follows the toolkit's types (f32 depth in mm, f64
//! distances, the visibility difference in f32), so pixels at a tie fall
//! the same way. The renders come from the `depth` kernel
//! ([`crate::kernels::depth`]), GPU or CPU twin; this part runs on the CPU.

use crate::bop::DepthMm;
use crate::kernels::depth::DepthTile;

/// The BOP'19 visibility tolerance δ for VSD (mm).
pub const DELTA_MM: f32 = 15.0;

/// A test image prepared for VSD: its depth and the per-column and per-row
/// factors of the distance transform.
pub struct VsdImage<'a> {
    depth: &'a DepthMm,
    pre_x: Vec<f64>,
    pre_y: Vec<f64>,
}

impl<'a> VsdImage<'a> {
    /// `k` is the row-major 3×3 intrinsics of the image.
    pub fn new(depth: &'a DepthMm, k: &[f64; 9]) -> Self {
        let pre_x = (0..depth.width).map(|x| (x as f64 - k[2]) / k[0]).collect();
        let pre_y = (0..depth.height).map(|y| (y as f64 - k[5]) / k[4]).collect();
        VsdImage { depth, pre_x, pre_y }
    }

    /// Distance (mm) of a z-depth `d` (mm) seen at pixel `(x, y)`, as
    /// `misc.depth_im_to_dist_im_fast` computes it.
    #[inline]
    pub fn distance(&self, d: f32, x: usize, y: usize) -> f64 {
        let d = d as f64;
        ((self.pre_x[x] * d).powi(2) + (self.pre_y[y] * d).powi(2) + d * d).sqrt()
    }

    #[inline]
    fn test_distance(&self, x: usize, y: usize) -> f64 {
        self.distance(self.depth.mm[y * self.depth.width as usize + x], x, y)
    }
}

/// Rendered depth of a tile at `(x, y)` in f32 mm (0 outside or background).
#[inline]
fn rendered_mm(tile: Option<&DepthTile>, x: usize, y: usize) -> f32 {
    tile.map_or(0.0, |t| (t.at(x, y) as f64 * 1000.0) as f32)
}

/// The bop19 visibility test of one pixel: model distance `dm` against the
/// test distance `dt`.
#[inline]
fn visible(dm: f64, dt: f64, delta: f32) -> bool {
    dm > 0.0 && ((dm as f32 - dt as f32) <= delta || dt == 0.0)
}

/// VSD of an estimate against a ground-truth pose, one error per τ (`taus`
/// are fractions of the diameter), given their renders (`None` = nothing in
/// the image).
pub fn vsd(img: &VsdImage, est: Option<&DepthTile>, gt: Option<&DepthTile>, delta: f32, taus: &[f64], diameter: f64) -> Vec<f64> {
    let rects: Vec<[usize; 4]> = [est, gt].iter().flatten().map(|t| t.rect).collect();
    if rects.is_empty() {
        return vec![1.0; taus.len()];
    }
    let x0 = rects.iter().map(|r| r[0]).min().unwrap();
    let y0 = rects.iter().map(|r| r[1]).min().unwrap();
    let x1 = rects.iter().map(|r| r[2]).max().unwrap();
    let y1 = rects.iter().map(|r| r[3]).max().unwrap();
    let mut union = 0usize;
    let mut inter = 0usize;
    let mut dists: Vec<f64> = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let de = rendered_mm(est, x, y);
            let dg = rendered_mm(gt, x, y);
            if de == 0.0 && dg == 0.0 {
                continue;
            }
            let dt = img.test_distance(x, y);
            let dist_e = if de > 0.0 { img.distance(de, x, y) } else { 0.0 };
            let dist_g = if dg > 0.0 { img.distance(dg, x, y) } else { 0.0 };
            let vis_g = visible(dist_g, dt, delta);
            let vis_e = visible(dist_e, dt, delta) || (vis_g && dist_e > 0.0);
            if vis_g || vis_e {
                union += 1;
            }
            if vis_g && vis_e {
                inter += 1;
                dists.push((dist_g - dist_e).abs() / diameter);
            }
        }
    }
    if union == 0 {
        return vec![1.0; taus.len()];
    }
    let comp = union - inter;
    taus.iter()
        .map(|&tau| {
            let cost = dists.iter().filter(|&&d| d >= tau).count();
            (cost + comp) as f64 / union as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(width: u32, height: u32, mm: f32) -> DepthMm {
        DepthMm { width, height, mm: vec![mm; (width * height) as usize] }
    }

    fn tile(rect: [usize; 4], m: f32) -> DepthTile {
        let n = (rect[2] - rect[0] + 1) * (rect[3] - rect[1] + 1);
        DepthTile { rect, depth: vec![m; n] }
    }

    const K: [f64; 9] = [100.0, 0.0, 5.0, 0.0, 100.0, 5.0, 0.0, 0.0, 1.0];

    #[test]
    fn identical_renders_score_zero_and_disjoint_ones_one() {
        let depth = flat(10, 10, 1000.0);
        let img = VsdImage::new(&depth, &K);
        let a = tile([2, 2, 5, 5], 1.0);
        let taus = [0.05, 0.5];
        assert_eq!(vsd(&img, Some(&a), Some(&a), DELTA_MM, &taus, 100.0), vec![0.0, 0.0]);
        let b = tile([6, 6, 8, 8], 1.0);
        assert_eq!(vsd(&img, Some(&a), Some(&b), DELTA_MM, &taus, 100.0), vec![1.0, 1.0]);
        assert_eq!(vsd(&img, None, None, DELTA_MM, &taus, 100.0), vec![1.0, 1.0]);
    }

    #[test]
    fn step_cost_by_hand() {
        // Test surface at 1 m; GT on it; estimate 10 mm nearer over the same
        // 4x4 pixels. |d_e - d_g| ≈ 10 mm (distance, slightly more off-axis)
        // = 0.1 of a 100 mm diameter.
        let depth = flat(10, 10, 1000.0);
        let img = VsdImage::new(&depth, &K);
        let gt = tile([2, 2, 5, 5], 1.0);
        let est = tile([2, 2, 5, 5], 0.99);
        let e = vsd(&img, Some(&est), Some(&gt), DELTA_MM, &[0.05, 0.2], 100.0);
        assert_eq!(e, vec![1.0, 0.0]);
        // Estimate shifted by two columns: union 24, intersection 8, all
        // intersecting pixels agree.
        let est = tile([4, 2, 7, 5], 1.0);
        let e = vsd(&img, Some(&est), Some(&gt), DELTA_MM, &[0.05], 100.0);
        assert!((e[0] - 16.0 / 24.0).abs() < 1e-12, "{e:?}");
    }

    #[test]
    fn occluded_pixels_are_invisible_and_missing_depth_is_visible() {
        // The test surface is 50 mm in front of the object (an occluder) on
        // the left half, and missing (0) on the right half.
        let mut depth = flat(10, 10, 950.0);
        for y in 0..10 {
            for x in 5..10 {
                depth.mm[y * 10 + x] = 0.0;
            }
        }
        let img = VsdImage::new(&depth, &K);
        let gt = tile([0, 0, 9, 9], 1.0);
        let est = tile([0, 0, 9, 9], 0.9); // 100 mm nearer: visible where occluded too
                                           // GT visible only on the right half (50 px); the estimate is in front
                                           // of the occluder, so visible everywhere (100 px): union 100, inter
                                           // 50, every intersecting pixel off by 0.1 m = 1 diameter.
        let e = vsd(&img, Some(&est), Some(&gt), DELTA_MM, &[0.5, 2.0], 100.0);
        assert_eq!(e, vec![1.0, 0.5]);
    }
}
