//! Lens camera models of the BOP-H3 datasets: a scene camera given as
//! `cam_model` (`projection_model_type`, `projection_params`,
//! `image_width`, `image_height`) instead of a pinhole `cam_K`.
//!
//! HOT3D's Aria and Quest 3 cameras are fisheyes (`FISHEYE624`: an arctan
//! projection, six radial, two tangential and four thin-prism terms);
//! HANDAL and HOPEv2 in the H3 layout write their pinhole cameras the same
//! way (`PinholePlane`). The BOP toolkit projects these with Meta's Hand
//! Tracking Toolkit (`hand_tracking_toolkit.camera`, its
//! `pose_error_htt.mspd`), so the models, their names, the order of their
//! coefficients and every formula below follow that toolkit: project the
//! camera-frame point (`xy / z`, or `xy / |xy| · atan2(|xy|, z)` for the
//! fisheyes), distort it with the model's polynomial, then scale by the
//! focal lengths and shift by the principal point (pixel centres at
//! integer coordinates, as OpenCV). All in f64.

use glam::DVec3;

use crate::camera::Intrinsics;
use crate::error::{Error, Result};

/// A camera model of the Hand Tracking Toolkit, by its
/// `projection_model_type` name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LensKind {
    /// `PinholePlane`: perspective, no distortion.
    PinholePlane,
    /// `OpenCV`: perspective; k1, k2, k3, p1, p2 (this order: the HTT's,
    /// not OpenCV's k1, k2, p1, p2, k3).
    OpenCv,
    /// `Rational`: perspective; k1, k2, k3, p1, p2, k4, k5, k6 (OpenCV's
    /// rational radial term).
    Rational,
    /// `OculusVisionFishEye`: arctan; k1..k4, p1..p4.
    Fisheye44,
    /// `OculusVisionFishEye62`: arctan; k1..k4, p1, p2, k5, k6.
    Fisheye62,
    /// `OculusVisionFishEye624` or `CameraModelType.FISHEYE624` (Aria,
    /// Quest 3): arctan; k1..k6, p1, p2, s1..s4.
    Fisheye624,
}

impl LensKind {
    /// The model of a `projection_model_type` name (the HTT's
    /// `model_by_name`).
    pub fn from_name(name: &str) -> Option<LensKind> {
        Some(match name {
            "PinholePlane" => LensKind::PinholePlane,
            "OpenCV" => LensKind::OpenCv,
            "Rational" => LensKind::Rational,
            "OculusVisionFishEye" => LensKind::Fisheye44,
            "OculusVisionFishEye62" => LensKind::Fisheye62,
            "OculusVisionFishEye624" | "CameraModelType.FISHEYE624" => LensKind::Fisheye624,
            _ => return None,
        })
    }

    /// The names [`Self::from_name`] takes, for error messages.
    pub const NAMES: &'static str =
        "PinholePlane, OpenCV, Rational, OculusVisionFishEye, OculusVisionFishEye62, OculusVisionFishEye624, CameraModelType.FISHEYE624";

    /// A short name for messages.
    pub fn name(self) -> &'static str {
        match self {
            LensKind::PinholePlane => "PinholePlane",
            LensKind::OpenCv => "OpenCV",
            LensKind::Rational => "Rational",
            LensKind::Fisheye44 => "fisheye 44",
            LensKind::Fisheye62 => "fisheye 62",
            LensKind::Fisheye624 => "fisheye 624",
        }
    }

    /// How many distortion coefficients the model takes.
    pub fn n_coeffs(self) -> usize {
        match self {
            LensKind::PinholePlane => 0,
            LensKind::OpenCv => 5,
            LensKind::Rational | LensKind::Fisheye44 | LensKind::Fisheye62 => 8,
            LensKind::Fisheye624 => 12,
        }
    }

    /// Whether the model projects by angle (the fisheyes) rather than
    /// perspective.
    pub fn is_fisheye(self) -> bool {
        matches!(self, LensKind::Fisheye44 | LensKind::Fisheye62 | LensKind::Fisheye624)
    }
}

/// A lens camera: model, image size, focal lengths, principal point and
/// distortion coefficients (unused ones zero).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensCamera {
    pub kind: LensKind,
    pub width: u32,
    pub height: u32,
    /// Focal lengths (fx, fy), pixels.
    pub f: [f64; 2],
    /// Principal point (cx, cy), pixels.
    pub c: [f64; 2],
    /// Distortion coefficients in the model's order.
    pub coeffs: [f64; 12],
}

impl LensCamera {
    /// Builds a camera from BOP's `cam_model` fields. The parameters are
    /// fx, fy, cx, cy and the coefficients, except a `FISHEYE624` of 15
    /// (Aria's single focal length: f, cx, cy and 12 coefficients), as the
    /// BOP toolkit reads them.
    pub fn from_bop(model: &str, width: f64, height: f64, params: &[f64]) -> Result<LensCamera> {
        let bad = |reason: String| Error::BadCamera { what: "cam_model".into(), reason };
        let kind = LensKind::from_name(model)
            .ok_or_else(|| bad(format!("unknown projection_model_type '{model}' (known: {})", LensKind::NAMES)))?;
        let size = |v: f64, what: &str| {
            if v.fract() == 0.0 && (1.0..=65535.0).contains(&v) {
                Ok(v as u32)
            } else {
                Err(bad(format!("{what} {v} is not a whole number of pixels in 1..65535")))
            }
        };
        let (width, height) = (size(width, "image_width")?, size(height, "image_height")?);
        if let Some(v) = params.iter().find(|v| !v.is_finite()) {
            return Err(bad(format!("projection_params holds {v}")));
        }
        // Only Aria's `CameraModelType.FISHEYE624` has the single focal
        // length form (the toolkit's "Aria data hack").
        let (f, c, rest) = if model == "CameraModelType.FISHEYE624" && params.len() == 15 {
            ([params[0]; 2], [params[1], params[2]], &params[3..])
        } else if params.len() >= 4 {
            ([params[0], params[1]], [params[2], params[3]], &params[4..])
        } else {
            return Err(bad(format!("projection_params has {} numbers; {model} takes fx, fy, cx, cy then {} coefficients", params.len(), kind.n_coeffs())));
        };
        if rest.len() != kind.n_coeffs() {
            let aria = if model == "CameraModelType.FISHEYE624" { " (or f, cx, cy and 12: 15 numbers)" } else { "" };
            return Err(bad(format!(
                "projection_params has {} numbers; {model} takes fx, fy, cx, cy then {} coefficients{aria}",
                params.len(),
                kind.n_coeffs()
            )));
        }
        if f.iter().any(|&v| v <= 0.0) {
            return Err(bad(format!("focal lengths must be positive (fx {}, fy {})", f[0], f[1])));
        }
        // The size is known, so the pinhole check applies: a principal point
        // far outside the image or a focal length of a pixel would score
        // every estimate 0 (or every MSPD 0) without a word.
        Intrinsics { fx: f[0], fy: f[1], cx: c[0], cy: c[1], width, height }.check_against_image().map_err(bad)?;
        let mut coeffs = [0.0; 12];
        coeffs[..rest.len()].copy_from_slice(rest);
        Ok(LensCamera { kind, width, height, f, c, coeffs })
    }

    /// The pinhole K (row-major 3×3) of a `PinholePlane` camera; `None`
    /// for a lens with distortion.
    pub fn pinhole_k(&self) -> Option<[f64; 9]> {
        (self.kind == LensKind::PinholePlane).then(|| [self.f[0], 0.0, self.c[0], 0.0, self.f[1], self.c[1], 0.0, 0.0, 1.0])
    }

    /// Projects a camera-frame point to window coordinates (pixels): the
    /// HTT's `eye_to_window`. A point at z ≤ 0 gives what the formulas give
    /// (infinite or behind-the-camera coordinates for the perspective
    /// models), as in the toolkit.
    pub fn project(&self, v: DVec3) -> [f64; 2] {
        let p = if self.kind.is_fisheye() { arctan(v) } else { [v.x / v.z, v.y / v.z] };
        let q = self.distort(p);
        [q[0] * self.f[0] + self.c[0], q[1] * self.f[1] + self.c[1]]
    }

    /// The model's distortion polynomial at projected point `p`.
    fn distort(&self, p: [f64; 2]) -> [f64; 2] {
        let k = &self.coeffs;
        match self.kind {
            LensKind::PinholePlane => p,
            LensKind::OpenCv => opencv(p, [k[0], k[1], k[2]], None, k[3], k[4]),
            LensKind::Rational => opencv(p, [k[0], k[1], k[2]], Some([k[5], k[6], k[7]]), k[3], k[4]),
            LensKind::Fisheye44 => fisheye44(p, k),
            LensKind::Fisheye62 => {
                let [x, y] = radial6(p, [k[0], k[1], k[2], k[3], k[6], k[7]]);
                tangential([x, y], k[4], k[5])
            }
            LensKind::Fisheye624 => {
                let [x, y] = radial6(p, [k[0], k[1], k[2], k[3], k[4], k[5]]);
                let r2 = x * x + y * y;
                let [tx, ty] = tangential([x, y], k[6], k[7]);
                let r4 = r2 * r2;
                [tx + (k[8] * r2 + k[9] * r4), ty + (k[10] * r2 + k[11] * r4)]
            }
        }
    }
}

/// The arctan (equidistant) projection: `xy / |xy| · atan2(|xy|, z)`, with
/// the HTT's guard of 2⁻¹²⁸ on |xy| for points on the axis.
fn arctan(v: DVec3) -> [f64; 2] {
    let r = (v.x * v.x + v.y * v.y).sqrt();
    let s = r.atan2(v.z) / r.max(2f64.powi(-128));
    [v.x * s, v.y * s]
}

/// The fisheyes' radial term of six coefficients, r² clamped to π² (the
/// HTT's guard against the polynomial's blow-up far outside the lens).
fn radial6(p: [f64; 2], k: [f64; 6]) -> [f64; 2] {
    let r2 = (p[0] * p[0] + p[1] * p[1]).clamp(-(std::f64::consts::PI.powi(2)), std::f64::consts::PI.powi(2));
    let (r4, r6) = (r2 * r2, r2 * r2 * r2);
    let (r8, r10, r12) = (r4 * r4, r4 * r6, r6 * r6);
    let radial = 1.0 + k[0] * r2 + k[1] * r4 + k[2] * r6 + k[3] * r8 + k[4] * r10 + k[5] * r12;
    [p[0] * radial, p[1] * radial]
}

/// The fisheyes' tangential term (p1 with r² + 2x² on x, p2 on y: the
/// HTT's order, the reverse of OpenCV's).
fn tangential([x, y]: [f64; 2], p1: f64, p2: f64) -> [f64; 2] {
    let (x2, y2, xy) = (x * x, y * y, x * y);
    let r2 = x2 + y2;
    [x + (2.0 * p2 * xy + p1 * (r2 + 2.0 * x2)), y + (2.0 * p1 * xy + p2 * (r2 + 2.0 * y2))]
}

/// OpenCV's radial (`num / den`; the five-coefficient model has no
/// denominator, the rational one always divides, even by 1 + 0·r², which
/// is NaN for an infinite r as in the toolkit) and tangential terms.
fn opencv([x, y]: [f64; 2], num: [f64; 3], den: Option<[f64; 3]>, p1: f64, p2: f64) -> [f64; 2] {
    let (x2, y2, xy) = (x * x, y * y, x * y);
    let r2 = x2 + y2;
    let (r4, r6) = (r2 * r2, r2 * r2 * r2);
    let mut radial = 1.0 + num[0] * r2 + num[1] * r4 + num[2] * r6;
    if let Some(den) = den {
        radial /= 1.0 + den[0] * r2 + den[1] * r4 + den[2] * r6;
    }
    [x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2), y * radial + 2.0 * p2 * xy + p1 * (r2 + 2.0 * y2)]
}

/// `OculusVisionFishEye`: four radial terms, then a tangential term scaled
/// by 1 + p3·r² + p4·r⁴ of the radially distorted point.
fn fisheye44(p: [f64; 2], k: &[f64; 12]) -> [f64; 2] {
    let r2 = p[0] * p[0] + p[1] * p[1];
    let (r4, r6) = (r2 * r2, r2 * r2 * r2);
    let radial = 1.0 + k[0] * r2 + k[1] * r4 + k[2] * r6 + k[3] * (r4 * r4);
    let (x, y) = (p[0] * radial, p[1] * radial);
    let (x2, y2, xy) = (x * x, y * y, x * y);
    let r2 = x2 + y2;
    let scale = 1.0 + k[6] * r2 + k[7] * (r2 * r2);
    [x + (2.0 * k[4] * xy + k[5] * (r2 + 2.0 * x2)) * scale, y + (2.0 * k[5] * xy + k[4] * (r2 + 2.0 * y2)) * scale]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pinhole_plane_is_the_pinhole_projection() {
        let cam = LensCamera::from_bop("PinholePlane", 640.0, 480.0, &[600.0, 610.0, 320.5, 240.25]).unwrap();
        let v = DVec3::new(0.1, -0.05, 0.7);
        let [u, w] = cam.project(v);
        assert!((u - (600.0 * 0.1 / 0.7 + 320.5)).abs() < 1e-12 && (w - (610.0 * -0.05 / 0.7 + 240.25)).abs() < 1e-12);
        assert_eq!(cam.pinhole_k(), Some([600.0, 0.0, 320.5, 0.0, 610.0, 240.25, 0.0, 0.0, 1.0]));
    }

    #[test]
    fn fisheye_without_distortion_is_equidistant() {
        // Zero coefficients: the image radius is f·θ, θ the angle off the axis.
        let mut params = vec![500.0, 700.0, 690.0];
        params.extend([0.0; 12]);
        let cam = LensCamera::from_bop("CameraModelType.FISHEYE624", 1408.0, 1408.0, &params).unwrap();
        for theta in [0.0f64, 0.3, 1.2, 1.9] {
            let v = DVec3::new(theta.sin() * 0.6, theta.sin() * 0.8, theta.cos());
            let [u, w] = cam.project(v * 2.5);
            let r = ((u - 700.0).powi(2) + (w - 690.0).powi(2)).sqrt();
            assert!((r - 500.0 * theta).abs() < 1e-9, "θ {theta}: r {r}");
        }
        assert_eq!(cam.pinhole_k(), None);
        assert!(cam.kind.is_fisheye());
    }

    #[test]
    fn fisheye624_terms_at_a_point() {
        // Each term alone, against the formulas written out by hand.
        let (x, y, z) = (0.2f64, -0.1, 0.5);
        let r = (x * x + y * y).sqrt();
        let th = r.atan2(z);
        let (px, py) = (x / r * th, y / r * th);
        let r2 = px * px + py * py;
        let mut coeffs = [0.0; 12];
        coeffs[1] = 0.05; // k2
        coeffs[6] = 1e-3; // p1
        coeffs[9] = 2e-3; // s2
        let mut params = vec![400.0, 410.0, 320.0, 240.0];
        params.extend(coeffs);
        let cam = LensCamera::from_bop("OculusVisionFishEye624", 640.0, 480.0, &params).unwrap();
        let radial = 1.0 + 0.05 * r2 * r2;
        let (qx, qy) = (px * radial, py * radial);
        let q2 = qx * qx + qy * qy;
        let tx = qx + 1e-3 * (q2 + 2.0 * qx * qx);
        let ty = qy + 2.0 * 1e-3 * qx * qy;
        let (sx, sy) = (tx + 2e-3 * q2 * q2, ty);
        let [u, v] = cam.project(DVec3::new(x, y, z));
        assert!((u - (400.0 * sx + 320.0)).abs() < 1e-9 && (v - (410.0 * sy + 240.0)).abs() < 1e-9, "{u} {v}");
    }

    #[test]
    fn opencv_models_match_the_brown_conrady_formula() {
        let (x, y) = (0.3f64, 0.2);
        let (k1, k2, k3, p1, p2) = (-0.2, 0.05, -0.01, 1e-3, -2e-3);
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let px = |radial: f64| [500.0 * (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)) + 320.0, 500.0 * (y * radial + 2.0 * p2 * x * y + p1 * (r2 + 2.0 * y * y)) + 240.0];
        let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9;
        let cam = |model: &str, extra: &[f64]| {
            let mut p = vec![500.0, 500.0, 320.0, 240.0, k1, k2, k3, p1, p2];
            p.extend(extra);
            LensCamera::from_bop(model, 640.0, 480.0, &p).unwrap().project(DVec3::new(x, y, 1.0))
        };
        assert!(close(cam("OpenCV", &[]), px(radial)));
        // Rational with a zero denominator polynomial is the same model; with k4 it divides.
        assert!(close(cam("Rational", &[0.0, 0.0, 0.0]), px(radial)));
        assert!(close(cam("Rational", &[0.1, 0.0, 0.0]), px(radial / (1.0 + 0.1 * r2))));
    }

    #[test]
    fn every_model_matches_the_hand_tracking_toolkit() {
        // htt_projections.json: hand_tracking_toolkit.camera's eye_to_window
        // of points from the axis to 80° off it (one behind a fisheye), for
        // every model it names (make_htt_projections.py).
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/hot3d-synth/htt_projections.json");
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let cases = v["cases"].as_array().unwrap();
        assert_eq!(cases.len(), 8);
        let nums = |x: &serde_json::Value| x.as_array().unwrap().iter().map(|n| n.as_f64().unwrap()).collect::<Vec<f64>>();
        for c in cases {
            let model = c["projection_model_type"].as_str().unwrap();
            let params = nums(&c["projection_params"]);
            let cam = LensCamera::from_bop(model, 1408.0, 1408.0, &params).unwrap();
            for (p, w) in c["points"].as_array().unwrap().iter().zip(c["window"].as_array().unwrap()) {
                let (p, w) = (nums(p), nums(w));
                let got = cam.project(DVec3::new(p[0], p[1], p[2]));
                for i in 0..2 {
                    assert!((got[i] - w[i]).abs() <= 1e-9 * w[i].abs().max(1.0), "{model} {params:?} at {p:?}: {got:?} vs {w:?}");
                }
            }
        }
    }

    #[test]
    fn bad_cameras_are_refused_with_the_reason() {
        let err = |m: &str, w: f64, p: &[f64]| LensCamera::from_bop(m, w, 480.0, p).unwrap_err().to_string();
        assert!(err("Kannala", 640.0, &[1.0; 8]).contains("unknown projection_model_type 'Kannala'"));
        assert!(err("PinholePlane", 640.0, &[500.0, 500.0, 320.0]).contains("has 3 numbers"));
        assert!(err("PinholePlane", 640.0, &[500.0, 500.0, 320.0, 240.0, 0.1]).contains("then 0 coefficients"));
        assert!(err("CameraModelType.FISHEYE624", 640.0, &[500.0; 14]).contains("15 numbers"));
        // The single focal length form is Aria's FISHEYE624 alone, as in the toolkit.
        assert!(err("OculusVisionFishEye624", 640.0, &[500.0; 15]).contains("has 15 numbers"));
        assert!(err("PinholePlane", 640.5, &[500.0, 500.0, 320.0, 240.0]).contains("image_width 640.5"));
        assert!(err("PinholePlane", 0.0, &[500.0, 500.0, 320.0, 240.0]).contains("image_width 0"));
        assert!(err("PinholePlane", 640.0, &[-500.0, 500.0, 320.0, 240.0]).contains("positive"));
        assert!(err("PinholePlane", 640.0, &[f64::NAN, 500.0, 320.0, 240.0]).contains("NaN"));
        assert!(err("PinholePlane", 640.0, &[500.0, 500.0, 1e300, 240.0]).contains("principal point"));
        assert!(err("PinholePlane", 640.0, &[1e-300, 500.0, 320.0, 240.0]).contains("not plausible"));
    }
}
