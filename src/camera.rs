//! Pinhole intrinsics in the OpenCV convention: x right, y down, z forward,
//! pixel `(u, v)` integer coordinates at pixel *centres*, depth = z.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Pinhole camera intrinsics and image size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Builds intrinsics from a row-major 3x3 `K` (BOP `cam_K`).
    pub fn from_k(k: &[f64], width: u32, height: u32) -> Result<Self> {
        let bad = |reason: String| Error::BadCamera { what: "cam_K".into(), reason };
        if k.len() != 9 {
            return Err(bad(format!("expected 9 numbers, got {}", k.len())));
        }
        if k.iter().any(|v| !v.is_finite()) {
            return Err(bad("contains NaN or infinity".into()));
        }
        let i = Intrinsics { fx: k[0], fy: k[4], cx: k[2], cy: k[5], width, height };
        if i.fx <= 0.0 || i.fy <= 0.0 {
            return Err(bad(format!("focal lengths must be positive (fx {}, fy {})", i.fx, i.fy)));
        }
        if k[1].abs() > 1e-9 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || (k[8] - 1.0).abs() > 1e-9 {
            return Err(bad("expected [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew)".into()));
        }
        Ok(i)
    }

    /// Checks the intrinsics belong to an image of this size: the principal
    /// point within half an image of it (a crop with its K adjusted may put
    /// it outside; see [`Self::principal_point_note`]), focal lengths
    /// between 1/100 and 100 image widths (fields of view from 0.6° to 179°).
    pub fn check_against_image(&self) -> std::result::Result<(), String> {
        let (w, h) = (self.width as f64, self.height as f64);
        if self.cx < -0.5 * w || self.cx > 1.5 * w || self.cy < -0.5 * h || self.cy > 1.5 * h {
            return Err(format!(
                "the principal point ({:.1}, {:.1}) lies far outside the {}x{} image: is the camera for another image size?",
                self.cx, self.cy, self.width, self.height
            ));
        }
        let side = w.max(h);
        for (name, f) in [("fx", self.fx), ("fy", self.fy)] {
            if f < side / 100.0 || f > side * 100.0 {
                return Err(format!("focal length {name} = {f} px is not plausible for a {}x{} image", self.width, self.height));
            }
        }
        Ok(())
    }

    /// A warning when the principal point lies outside the image: a
    /// camera's lies near the centre, so this is a crop with its K adjusted,
    /// or (more often) the K of another stream, e.g. one twice the size,
    /// with which every pose projects beside the object and scores 0.
    pub fn principal_point_note(&self) -> Option<String> {
        let (w, h) = (self.width as f64, self.height as f64);
        let inside = (0.0..=w).contains(&self.cx) && (0.0..=h).contains(&self.cy);
        (!inside).then(|| {
            format!(
                "the principal point ({:.1}, {:.1}) lies outside the {}x{} image: right for a crop, but is the camera for another image size (a stream twice as large)?",
                self.cx, self.cy, self.width, self.height
            )
        })
    }

    /// Projects a camera-frame point to pixel coordinates.
    pub fn project(&self, p: DVec3) -> (f64, f64) {
        (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }

    /// Camera-frame ray through pixel `(u, v)` with z = 1, so `depth * ray`
    /// is the 3D point seen there.
    pub fn ray(&self, u: f64, v: f64) -> DVec3 {
        DVec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// The camera-frame point seen at row-major pixel index `i` with depth
    /// `z` (metres).
    pub fn pixel_point(&self, i: usize, z: f64) -> DVec3 {
        let w = self.width as usize;
        self.ray((i % w) as f64, (i / w) as f64) * z
    }

    /// Intrinsics of the crop `[x0, x0 + w) x [y0, y0 + h)` (continuous pixel
    /// edges, so pixel `u` spans `[u - 0.5, u + 0.5)`... expressed here with
    /// pixel `u` covering `[u, u + 1)` in edge coordinates) resampled to
    /// `out_w x out_h` pixels.
    pub fn crop(&self, x0: f64, y0: f64, w: f64, h: f64, out_w: u32, out_h: u32) -> Intrinsics {
        let sx = out_w as f64 / w;
        let sy = out_h as f64 / h;
        // Edge coordinate e = u + 0.5; e' = (e - x0) * s; u' = e' - 0.5.
        Intrinsics {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5 - x0) * sx - 0.5,
            cy: (self.cy + 0.5 - y0) * sy - 0.5,
            width: out_w,
            height: out_h,
        }
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_keeps_projection_consistent() {
        let k = Intrinsics { fx: 572.4, fy: 573.6, cx: 325.3, cy: 242.0, width: 640, height: 480 };
        let c = k.crop(200.0, 100.0, 160.0, 160.0, 128, 128);
        let p = DVec3::new(0.03, -0.02, 0.7);
        let (u, v) = k.project(p);
        let (u2, v2) = c.project(p);
        // The same point, measured from the crop's edge in crop pixels.
        assert!(((u + 0.5 - 200.0) * 0.8 - 0.5 - u2).abs() < 1e-9);
        assert!(((v + 0.5 - 100.0) * 0.8 - 0.5 - v2).abs() < 1e-9);
    }
}
