//! Rigid poses (model -> camera), their validation and the BOP pose JSON.
//!
//! BOP stores `cam_R_m2c` row-major and `cam_t_m2c` in millimetres; inside
//! the library translations are metres. Conversion happens here, at the
//! boundary.

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
use serde::Deserialize;

use crate::error::{Error, Input, Result};

/// A rigid transform mapping model coordinates to camera coordinates
/// (`x_cam = r * x_model + t`), translation in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub r: DMat3,
    pub t: DVec3,
}

/// Farthest a hypothesis may lie from the camera (m), as far as a scene may
/// span ([`crate::physical::scene::MAX_POSITION_M`]): beyond, the
/// f32 kernels and the twin's f64 part ways (a pose at 1e97 m gave the GPU
/// a minimum distance of -inf and the twin -7e296).
pub const MAX_DISTANCE_M: f64 = 1e4;

/// Largest `|RᵀR - I|` that orthonormalization projects onto SO(3); beyond
/// it the matrix is scaled or sheared (2·I is not a noisy rotation).
pub const MAX_ORTHONORMALIZE_ERR: f64 = 0.1;

/// How far `RᵀR` may be from the identity before a rotation is rejected.
pub const ORTHONORMAL_TOL: f64 = 1e-3;

impl Pose {
    pub const IDENTITY: Pose = Pose { r: DMat3::IDENTITY, t: DVec3::ZERO };

    pub fn new(r: DMat3, t: DVec3) -> Self {
        Pose { r, t }
    }

    /// From a row-major 3x3 rotation and a translation in metres.
    pub fn from_row_major(r: [f64; 9], t: [f64; 3]) -> Self {
        Pose { r: DMat3::from_cols_array(&r).transpose(), t: DVec3::from_array(t) }
    }

    /// Row-major rotation (BOP order).
    pub fn r_row_major(&self) -> [f64; 9] {
        self.r.transpose().to_cols_array()
    }

    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.r * p + self.t
    }

    pub fn inverse(&self) -> Pose {
        let rt = self.r.transpose();
        Pose { r: rt, t: -(rt * self.t) }
    }

    /// `self ∘ other`: apply `other` first.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose { r: self.r * other.r, t: self.r * other.t + self.t }
    }

    /// Largest entry of `|RᵀR - I|`.
    pub fn orthonormality_error(&self) -> f64 {
        let e = self.r.transpose() * self.r - DMat3::IDENTITY;
        e.to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()))
    }

    /// Angle in radians of the relative rotation between two poses.
    pub fn rotation_angle_to(&self, other: &Pose) -> f64 {
        let rel = self.r.transpose() * other.r;
        let c = ((rel.x_axis.x + rel.y_axis.y + rel.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
        c.acos()
    }

    /// Checks the pose is usable: finite, a proper rotation, in front of the
    /// camera. With `orthonormalize`, a slightly off rotation is projected
    /// onto SO(3) instead of rejected.
    pub fn validated(mut self, index: usize, orthonormalize: bool) -> Result<Pose> {
        let bad = |reason: String| Error::BadPose { index, reason };
        if !self.r.is_finite() || !self.t.is_finite() {
            return Err(bad("contains NaN or infinity".into()));
        }
        if self.r.determinant() <= 0.0 {
            return Err(bad(format!(
                "rotation has determinant {:.4}; a rotation matrix must have determinant +1 (is it a reflection, or column-major?)",
                self.r.determinant()
            )));
        }
        let err = self.orthonormality_error();
        if err > MAX_ORTHONORMALIZE_ERR {
            return Err(bad(format!(
                "rotation is far from orthonormal (max |RᵀR - I| = {err:.2e}): a scaled or sheared matrix is not a rotation, even to project"
            )));
        }
        if err > ORTHONORMAL_TOL {
            if orthonormalize {
                self.r = orthonormalize_rotation(self.r);
            } else {
                return Err(bad(format!(
                    "rotation is not orthonormal (max |RᵀR - I| = {err:.2e} > {ORTHONORMAL_TOL:.0e}); \
                     pass --orthonormalize to project it onto the nearest rotation"
                )));
            }
        } else if err > 1e-9 {
            self.r = orthonormalize_rotation(self.r);
        }
        if self.t.z <= 0.0 {
            return Err(bad(format!("translation z = {:.4} m: the object is behind the camera", self.t.z)));
        }
        if self.t.length() > MAX_DISTANCE_M {
            return Err(bad(format!("translation of {:.3e} m: more than the {MAX_DISTANCE_M} m a camera sees (units?)", self.t.length())));
        }
        Ok(self)
    }
}

/// Nearest rotation to `m` (orthogonal polar factor), by Newton iteration
/// `X <- (X + X⁻ᵀ)/2`, which converges quadratically for `det m > 0`.
pub fn orthonormalize_rotation(m: DMat3) -> DMat3 {
    let mut x = m;
    for _ in 0..30 {
        let next = (x + x.inverse().transpose()) * 0.5;
        let d = (next - x).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
        x = next;
        if d < 1e-15 {
            break;
        }
    }
    x
}

/// Rotation by `angle` radians about the unit `axis`.
pub fn axis_angle(axis: DVec3, angle: f64) -> DMat3 {
    DMat3::from_quat(DQuat::from_axis_angle(axis.normalize(), angle))
}

#[derive(Deserialize)]
struct BopPose {
    #[serde(rename = "cam_R_m2c")]
    cam_r_m2c: Vec<f64>,
    cam_t_m2c: Vec<f64>,
    #[serde(default)]
    obj_id: Option<u32>,
}

/// What a pose file that is a JSON object holds: a `{"poses": [...]}`
/// list, or the one image picked from a BOP `scene_gt.json`. Read in one
/// pass straight from the text, keeping only those poses: the other
/// images are skipped unparsed. (Through `serde_json::Value` a 154 MB
/// `{"poses": [...]}` file had taken 3.6 GB and 31 s, against 0.82 GB and
/// 2.2 s for the same poses as a plain list.)
#[derive(Default)]
struct PoseObject {
    /// The `"poses"` list (read only when no image is picked).
    poses: Option<Vec<BopPose>>,
    /// Whether the object has a `"poses"` key.
    has_poses: bool,
    /// The picked image's instances, when the object holds that image.
    frame: Option<Vec<BopPose>>,
    /// Number of keys and the smallest one, for the scene_gt.json hint.
    keys: usize,
    first_key: Option<String>,
}

/// Reads a [`PoseObject`]. An error in the picked image's instances is
/// put in `frame_error` (the message then names the image).
struct ObjectSeed<'a, 's> {
    select: Option<SceneGtSelection<'s>>,
    frame_error: &'a mut Option<String>,
}

impl<'de> serde::de::DeserializeSeed<'de> for ObjectSeed<'_, '_> {
    type Value = PoseObject;

    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> std::result::Result<PoseObject, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> serde::de::Visitor<'de> for ObjectSeed<'_, '_> {
    type Value = PoseObject;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON object")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> std::result::Result<PoseObject, A::Error> {
        use serde::de::{Error as _, IgnoredAny};
        let mut o = PoseObject::default();
        while let Some(key) = map.next_key::<String>()? {
            if key == "poses" {
                o.has_poses = true;
                // With an image picked the file is refused whatever the list holds.
                if self.select.is_some() {
                    map.next_value::<IgnoredAny>()?;
                } else {
                    o.poses = Some(map.next_value()?);
                }
                continue;
            }
            o.keys += 1;
            if self.select.is_some_and(|s| s.frame == key) {
                match map.next_value::<Vec<BopPose>>() {
                    Ok(v) => o.frame = Some(v),
                    Err(e) => {
                        *self.frame_error = Some(e.to_string());
                        return Err(A::Error::custom("the picked image"));
                    }
                }
            } else {
                map.next_value::<IgnoredAny>()?;
            }
            if o.first_key.as_ref().is_none_or(|k| key < *k) {
                o.first_key = Some(key);
            }
        }
        Ok(o)
    }
}

/// Picks the poses of one image (and object) from a BOP `scene_gt.json`.
#[derive(Clone, Copy, Debug)]
pub struct SceneGtSelection<'a> {
    /// The image id (a key of the file).
    pub frame: &'a str,
    /// Only instances of this object (all instances of the image when `None`).
    pub obj_id: Option<u32>,
}

/// Parses the pose file's text into its entries. Each layout is parsed
/// into its own typed structs (no untagged enum: that buffers the whole
/// document and reports "did not match any variant" instead of the field
/// and line that are wrong).
fn parse_pose_entries(path: &Path, text: &str, select: Option<SceneGtSelection>) -> Result<Vec<BopPose>> {
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let shape = "expected a list of {\"cam_R_m2c\": [9 numbers], \"cam_t_m2c\": [3 numbers, mm]}, {\"poses\": [...]}, or a BOP scene_gt.json with an image id and object id picked";
    // An image and object picked from a plain list would be ignored.
    let not_scene_gt = || bad("an image and object were picked, but this is a list of poses, not a BOP scene_gt.json".into()).about(Input::Selection);
    match text.trim_start().as_bytes().first() {
        Some(b'[') if select.is_some() => Err(not_scene_gt()),
        Some(b'[') => serde_json::from_str::<Vec<BopPose>>(text).map_err(|e| bad(format!("{e}; {shape}"))),
        Some(b'{') => {
            let mut frame_error = None;
            let seed = ObjectSeed { select, frame_error: &mut frame_error };
            let mut de = serde_json::Deserializer::from_str(text);
            let parsed = serde::de::DeserializeSeed::deserialize(seed, &mut de).and_then(|o| de.end().map(|()| o));
            if let Some(e) = frame_error {
                let frame = select.map_or("", |s| s.frame);
                return Err(bad(format!("image {frame}: {e}; {shape}")));
            }
            let o = parsed.map_err(|e| bad(format!("{e}; {shape}")))?;
            if o.has_poses && select.is_some() {
                return Err(not_scene_gt());
            }
            if let Some(poses) = o.poses {
                return Ok(poses);
            }
            // A BOP scene_gt.json: image id -> instances with obj_id.
            let Some(sel) = select else {
                return Err(bad(format!(
                    "looks like a BOP scene_gt.json ({} images): pick an image id and an object id (e.g. {})",
                    o.keys,
                    o.first_key.as_deref().unwrap_or("0")
                ))
                .about(Input::Selection));
            };
            let all = o.frame.ok_or_else(|| bad(format!("no image '{}' in the scene_gt.json", sel.frame)).about(Input::Selection))?;
            let picked: Vec<BopPose> = all.into_iter().filter(|p| sel.obj_id.is_none_or(|o| p.obj_id == Some(o))).collect();
            if picked.is_empty() {
                return Err(bad(format!("image {} has no instance of object {}", sel.frame, sel.obj_id.map_or("(any)".into(), |o| o.to_string()))).about(Input::Selection));
            }
            Ok(picked)
        }
        _ => Err(bad(format!("is not a JSON list or object; {shape}"))),
    }
}

/// Units of pose translations in a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PoseUnits {
    #[default]
    Millimetres,
    Metres,
}

/// Reads BOP-style pose hypotheses: a JSON list of
/// `{"cam_R_m2c": [9, row-major], "cam_t_m2c": [3, mm]}` or an object with a
/// `"poses"` list. Every pose is validated (see [`Pose::validated`]).
pub fn read_poses(path: &Path, units: PoseUnits, orthonormalize: bool) -> Result<Vec<Pose>> {
    read_poses_selected(path, units, orthonormalize, None)
}

/// [`read_poses`], also reading a BOP `scene_gt.json` when `select` picks an
/// image (and object).
pub fn read_poses_selected(path: &Path, units: PoseUnits, orthonormalize: bool, select: Option<SceneGtSelection>) -> Result<Vec<Pose>> {
    let text = crate::io::read_to_string_capped(path, MAX_POSE_FILE_BYTES, "pose file")?;
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let raw = parse_pose_entries(path, &text, select)?;
    drop(text);
    if raw.is_empty() {
        return Err(bad("contains no poses".into()));
    }
    check_pose_count(raw.len()).map_err(|e| bad(e.to_string()))?;
    let scale = match units {
        PoseUnits::Millimetres => 1e-3,
        PoseUnits::Metres => 1.0,
    };
    let mut out = Vec::with_capacity(raw.len());
    for (i, p) in raw.into_iter().enumerate() {
        if p.cam_r_m2c.len() != 9 || p.cam_t_m2c.len() != 3 {
            return Err(Error::BadPose {
                index: i,
                reason: format!(
                    "cam_R_m2c needs 9 numbers and cam_t_m2c 3 (got {} and {})",
                    p.cam_r_m2c.len(),
                    p.cam_t_m2c.len()
                ),
            });
        }
        let r: [f64; 9] = p.cam_r_m2c.try_into().unwrap();
        let t = [p.cam_t_m2c[0] * scale, p.cam_t_m2c[1] * scale, p.cam_t_m2c[2] * scale];
        out.push(Pose::from_row_major(r, t).validated(i, orthonormalize)?);
    }
    check_camera_distances(&out, units).map_err(bad)?;
    Ok(out)
}

/// The upper median of `values` (the middle one, or the upper of the two
/// middle ones), `None` when empty: what the unit checks of poses, results
/// and depth compare with their bounds.
pub(crate) fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(*values.select_nth_unstable_by(mid, f64::total_cmp).1)
}

/// The most poses one call scores (2^24, about 1.6 GB of poses and as
/// much again of records): beyond it a caller that meant it scores in
/// chunks, and one that did not gets an error instead of an allocation
/// failure that aborts the process.
pub const MAX_POSES: usize = 1 << 24;

/// Largest pose file read (2 GiB): [`MAX_POSES`] poses written with short
/// numbers, about 120 bytes a pose. Beyond it, or on an endless stream
/// such as `/dev/zero`, reading stops with an error.
pub const MAX_POSE_FILE_BYTES: u64 = 2 << 30;

/// Refuses more than [`MAX_POSES`] poses, before anything is allocated
/// for them.
pub fn check_pose_count(n: usize) -> Result<()> {
    if n > MAX_POSES {
        return Err(Error::InvalidInput(format!("{n} poses: at most {MAX_POSES} are scored at once; give them in chunks")));
    }
    Ok(())
}

/// Refuses poses whose median camera-to-object distance is no real scene,
/// under 2 cm or over 50 m: their translations almost certainly hold the
/// other unit (`read_as` says which one they were taken for), and scoring
/// them would give every pose zero without a word. Returns the reason.
pub fn check_camera_distances(poses: &[Pose], read_as: PoseUnits) -> std::result::Result<(), String> {
    let Some(median) = median(poses.iter().map(|p| p.t.length()).collect()) else { return Ok(()) };
    match read_as {
        PoseUnits::Millimetres if median < 0.02 => Err(format!(
            "median camera distance is {:.1} mm: the translations look like metres, but were read as millimetres (read them as metres if they really are)",
            median * 1e3
        )),
        PoseUnits::Metres if median > 1e5 => Err(format!("median camera distance is {median:.3e} m: no scene a camera sees")),
        PoseUnits::Metres if median > 50.0 => Err(format!("median camera distance is {median:.1} m: the translations look like millimetres, but were read as metres")),
        PoseUnits::Metres if median < 0.02 => Err(format!("median camera distance is {:.1} mm: the objects would touch the camera; are the translations in metres?", median * 1e3)),
        _ => {
            // One pose in the other unit among right ones: 1000 times
            // nearer or farther than the others, no real hypothesis.
            let odd = poses.iter().map(|p| p.t.length()).position(|d| !(median / 100.0..=median * 100.0).contains(&d));
            match odd {
                Some(i) => Err(format!(
                    "pose {i} is {:.4} m from the camera while the median is {median:.3} m: is it in another unit than the others?",
                    poses[i].t.length()
                )),
                None => Ok(()),
            }
        }
    }
}

/// Writes poses in the BOP pose JSON format (translations in millimetres).
pub fn poses_to_json(poses: &[Pose]) -> serde_json::Value {
    serde_json::Value::Array(
        poses
            .iter()
            .map(|p| {
                serde_json::json!({
                    "cam_R_m2c": p.r_row_major(),
                    "cam_t_m2c": (p.t * 1e3).to_array(),
                })
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn row_major_round_trip() {
        let r = axis_angle(DVec3::new(1.0, 2.0, 3.0), 0.7);
        let p = Pose::new(r, DVec3::new(0.1, 0.2, 0.5));
        let q = Pose::from_row_major(p.r_row_major(), p.t.to_array());
        assert!((p.r - q.r).to_cols_array().iter().all(|v| v.abs() < 1e-15));
        // Row-major: element [1] is R[0][1] = second column's x.
        assert_eq!(p.r_row_major()[1], p.r.y_axis.x);
    }

    #[test]
    fn orthonormalize_recovers_rotation() {
        let r = axis_angle(DVec3::new(0.3, -1.0, 0.2), 1.1);
        let noisy = r + DMat3::from_cols_array(&[0.01, 0.0, 0.003, 0.0, -0.004, 0.0, 0.002, 0.0, 0.0]);
        let fixed = orthonormalize_rotation(noisy);
        assert!(Pose::new(fixed, DVec3::Z).orthonormality_error() < 1e-12);
        assert!(Pose::new(fixed, DVec3::Z).rotation_angle_to(&Pose::new(r, DVec3::Z)) < 0.02);
    }
}
