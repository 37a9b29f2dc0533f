//! The scene JSON: objects with meshes and poses, support planes, gravity.
//!
//! World frame (the default): metres, z up, gravity (0, 0, −9.81):
//! ```json
//! {"gravity": [0, 0, -9.81],
//!  "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
//!  "objects": [{"name": "cube", "mesh": "cube.obj", "units": "m",
//!               "R": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t": [0, 0, 0.025],
//!               "static": false, "density": 1000}]}
//! ```
//! Camera frame (`"frame": "camera"`): objects carry BOP poses
//! (`cam_R_m2c` row-major, `cam_t_m2c` in millimetres) and `planes` holds
//! exactly one support plane in the camera frame (`point` in millimetres).
//! The scene is moved into a world frame on that plane: origin at the plane
//! point, z along the plane normal turned towards the camera, gravity −z.
//!
//! Mesh paths are relative to the JSON file. A plane is the boundary of a
//! solid half-space: points on the side its normal points to are outside.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DMat3, DVec3};
use serde::Deserialize;

use crate::error::{Error, Result};
use crate::mesh::{Mesh, MeshUnits};
use crate::pose::{orthonormalize_rotation, Pose, ORTHONORMAL_TOL};

/// Most objects in one scene (each is tested against every other; their
/// grids and samples stay in memory together).
pub const MAX_OBJECTS: usize = 256;

/// Largest scene file read: [`MAX_OBJECTS`] objects take a few hundred
/// kilobytes; the cap only stops an endless stream such as `/dev/zero`.
pub const MAX_SCENE_FILE_BYTES: u64 = 64 << 20;

/// Largest plane file read (a plane is a few numbers).
pub const MAX_PLANE_FILE_BYTES: u64 = 1 << 20;

/// Default density of objects in kg/m³ (water; only masses depend on it).
pub const DEFAULT_DENSITY: f64 = 1000.0;

/// A support plane: the solid half-space below it is the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    pub point: DVec3,
    /// Unit normal, pointing out of the solid.
    pub normal: DVec3,
}

impl Plane {
    /// Signed distance of `x` (positive on the normal's side).
    pub fn distance(&self, x: DVec3) -> f64 {
        self.normal.dot(x - self.point)
    }

    /// A camera-frame plane with its normal made unit and turned towards
    /// the camera centre (the origin): the camera looks at a support plane
    /// from above, so that side is up.
    pub fn facing_camera(self) -> Plane {
        let normal = self.normal.normalize();
        let normal = if normal.dot(self.point) > 0.0 { -normal } else { normal };
        Plane { point: self.point, normal }
    }
}

/// One object of the scene, in the world frame.
#[derive(Clone, Debug)]
pub struct SceneObject {
    pub name: String,
    pub mesh: Arc<Mesh>,
    /// The mesh file as resolved against the JSON's folder.
    pub mesh_path: PathBuf,
    pub units: MeshUnits,
    /// Model to world.
    pub pose: Pose,
    /// Static objects (a table, a shelf) are held in place: they support
    /// others and are checked for intersections only.
    pub is_static: bool,
    /// kg/m³.
    pub density: f64,
}

/// A validated scene in the world frame (metres).
#[derive(Clone, Debug)]
pub struct Scene {
    pub gravity: DVec3,
    pub planes: Vec<Plane>,
    pub objects: Vec<SceneObject>,
}

/// The rigid transform from the camera frame to the frame of a support
/// plane given in the camera frame (metres): origin at the plane point, z
/// along the plane normal turned towards the camera (gravity −z), x along
/// the camera's x projected onto the plane.
pub fn camera_to_plane_frame(plane: &Plane) -> Pose {
    let Plane { point, normal: up } = plane.facing_camera();
    let helper = if DVec3::X.cross(up).length() > 0.1 {
        DVec3::X
    } else {
        DVec3::Z
    };
    let x = (helper - up * helper.dot(up)).normalize();
    let y = up.cross(x);
    let r = DMat3::from_cols(x, y, up).transpose(); // camera -> world
    Pose::new(r, -(r * point))
}

/// A support plane in the camera frame, as `plausible score --plane` takes
/// it and `plausible plane` writes it:
/// ```json
/// {"point": [0.0, 95.2, 702.4], "normal": [0.0, -0.81, -0.59], "units": "mm"}
/// ```
/// `point` is any point of the plane, in `units` (`"mm"`, the BOP
/// convention and the default, or `"m"`); `normal` any non-zero vector
/// perpendicular to it (its sign does not matter: the side facing the
/// camera is up).
#[derive(Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraPlaneJson {
    pub point: Vec<f64>,
    pub normal: Vec<f64>,
    #[serde(default)]
    pub units: Option<String>,
}

impl CameraPlaneJson {
    /// A camera-frame plane (metres) as written to files: point in mm.
    pub fn from_plane(plane: &Plane) -> CameraPlaneJson {
        CameraPlaneJson {
            point: (plane.point * 1e3).to_array().to_vec(),
            normal: plane.normal.to_array().to_vec(),
            units: Some("mm".into()),
        }
    }
}

/// Parses JSON, saying so when the text holds NaN or Infinity (which JSON
/// cannot: the usual cause of a parse error in machine-written files).
fn parse<T: serde::de::DeserializeOwned>(text: &str) -> std::result::Result<T, String> {
    serde_json::from_str(text).map_err(|e| {
        let hint = if text.contains("NaN") || text.contains("Infinity") {
            " (JSON has no NaN or Infinity: every number must be finite)"
        } else {
            ""
        };
        format!("{e}{hint}")
    })
}

/// Reads a camera-frame support plane ([`CameraPlaneJson`]); the returned
/// plane is in metres with a unit normal turned towards the camera.
pub fn read_camera_plane(path: &Path) -> Result<Plane> {
    let text = crate::io::read_to_string_capped(path, MAX_PLANE_FILE_BYTES, "plane file")?;
    camera_plane_from_json(&text, path)
}

/// Parses and validates a camera-frame support plane; `name` labels errors.
pub fn camera_plane_from_json(text: &str, name: &Path) -> Result<Plane> {
    let bad = |reason: String| Error::BadJson { path: name.to_path_buf(), reason };
    let raw: CameraPlaneJson = parse(text).map_err(|e| {
        bad(format!("{e} (expected {{\"point\": [x, y, z], \"normal\": [nx, ny, nz], \"units\": \"mm\"}})"))
    })?;
    let scale = match raw.units.as_deref() {
        None | Some("mm") => 1e-3,
        Some("m") => 1.0,
        Some(u) => return Err(bad(format!("unknown units '{u}' (expected \"mm\" or \"m\")"))),
    };
    let point = vec3("point", &raw.point).map_err(bad)? * scale;
    let normal = vec3("normal", &raw.normal).map_err(bad)?;
    Plane::in_camera(point, normal).map_err(|e| {
        let hint = match e {
            PlaneError::ThroughCamera { distance_m } if scale == 1e-3 && distance_m > 1e-5 => {
                format!("; the point is {} mm from the camera: is it in metres? (add \"units\": \"m\")", crate::error::compact(point.length() * 1e3, 1))
            }
            _ => String::new(),
        };
        bad(format!("{e}{hint}"))
    })
}

/// Why numbers do not make a support plane seen by the camera.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum PlaneError {
    #[error("point and normal must be finite")]
    NotFinite,
    #[error("normal has zero length")]
    ZeroNormal,
    #[error("the plane passes {:.1} mm from the camera centre; a support plane seen by the camera lies well in front of it", .distance_m * 1e3)]
    ThroughCamera { distance_m: f64 },
}

impl Plane {
    /// A support plane seen by the camera: point (metres) and normal in the
    /// camera frame, the normal made unit and turned towards the camera.
    /// Refused: a zero normal, or a plane through the camera centre (within
    /// 1 cm; a support plane lies well in front of the camera).
    pub fn in_camera(point: DVec3, normal: DVec3) -> std::result::Result<Plane, PlaneError> {
        if !(point.is_finite() && normal.is_finite()) {
            return Err(PlaneError::NotFinite);
        }
        let (normal, len) = direction(normal);
        if len <= 1e-12 {
            return Err(PlaneError::ZeroNormal);
        }
        let distance_m = normal.dot(point).abs();
        if distance_m < 0.01 {
            return Err(PlaneError::ThroughCamera { distance_m });
        }
        Ok(Plane { point, normal }.facing_camera())
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    #[serde(default)]
    frame: Option<String>,
    #[serde(default)]
    gravity: Option<Vec<f64>>,
    #[serde(default)]
    planes: Vec<RawPlane>,
    objects: Vec<RawObject>,
}

/// The frame a scene file is written in, its planes and gravity, and (for
/// a camera-frame scene) the move from the camera into the plane frame.
struct SceneFrame {
    camera: bool,
    planes: Vec<Plane>,
    gravity: DVec3,
    to_world: Pose,
}

impl SceneFrame {
    fn of(raw: &RawScene) -> std::result::Result<SceneFrame, String> {
        let camera = match raw.frame.as_deref() {
            None | Some("world") => false,
            Some("camera") => true,
            Some(f) => return Err(format!("unknown frame '{f}' (expected \"world\" or \"camera\")")),
        };
        let mut planes = Vec::new();
        for (i, p) in raw.planes.iter().enumerate() {
            let point = vec3(&format!("plane {i}: point"), &p.point)?;
            let normal = vec3(&format!("plane {i}: normal"), &p.normal)?;
            let (normal, len) = direction(normal);
            if len.is_nan() || len <= 1e-12 {
                return Err(format!("plane {i}: normal has zero length"));
            }
            planes.push(Plane { point, normal });
        }
        let mut gravity = DVec3::new(0.0, 0.0, -9.81);
        // Camera frame: world = plane frame.
        let mut to_world = Pose::IDENTITY;
        if camera {
            if raw.gravity.is_some() {
                return Err("a camera-frame scene takes gravity from its support plane; remove \"gravity\"".into());
            }
            if planes.len() != 1 {
                return Err(format!("a camera-frame scene needs exactly one support plane, found {}", planes.len()));
            }
            let p = planes[0];
            to_world = camera_to_plane_frame(&Plane { point: p.point * 1e-3, normal: p.normal });
            planes = vec![Plane { point: DVec3::ZERO, normal: DVec3::Z }];
        } else if let Some(g) = &raw.gravity {
            gravity = vec3("gravity", g)?;
            let (_, len) = direction(gravity);
            if len <= 1e-9 {
                return Err("gravity has zero length".into());
            }
            // Its length is the acceleration the simulation applies (in
            // f32) and its direction what supports: a length that
            // overflows had made the direction zero, and every object
            // "unstable" without a word.
            if len > MAX_GRAVITY {
                return Err(format!("gravity is {len:.3e} m/s² long, more than the {MAX_GRAVITY:.0e} a scene may have (the default is 9.81)"));
            }
        }
        Ok(SceneFrame { camera, planes, gravity, to_world })
    }

    /// An object's pose in the world (plane) frame: `R`, `t` in a world
    /// scene, `cam_R_m2c`, `cam_t_m2c` (mm) in a camera-frame one.
    fn object_pose(&self, o: &RawObject, label: &str) -> std::result::Result<Pose, String> {
        if self.camera {
            if o.r.is_some() || o.t.is_some() {
                return Err(format!("{label}: a camera-frame scene gives poses as cam_R_m2c / cam_t_m2c"));
            }
            let (Some(r), Some(t)) = (&o.cam_r, &o.cam_t) else {
                return Err(format!("{label}: missing cam_R_m2c or cam_t_m2c"));
            };
            let r = rotation(&format!("{label}: cam_R_m2c"), r)?;
            let t = within_reach(&format!("{label}: cam_t_m2c"), vec3(&format!("{label}: cam_t_m2c"), t)? * 1e-3)?;
            return Ok(self.to_world.compose(&Pose::new(r, t)));
        }
        if o.cam_r.is_some() || o.cam_t.is_some() {
            return Err(format!("{label}: cam_R_m2c / cam_t_m2c need \"frame\": \"camera\""));
        }
        let (Some(r), Some(t)) = (&o.r, &o.t) else {
            return Err(format!("{label}: missing R or t"));
        };
        Ok(Pose::new(rotation(&format!("{label}: R"), r)?, within_reach(&format!("{label}: t"), vec3(&format!("{label}: t"), t)?)?))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlane {
    point: Vec<f64>,
    normal: Vec<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObject {
    #[serde(default)]
    name: Option<String>,
    mesh: String,
    #[serde(default)]
    units: Option<String>,
    #[serde(default, rename = "R")]
    r: Option<Vec<f64>>,
    #[serde(default)]
    t: Option<Vec<f64>>,
    #[serde(default, rename = "cam_R_m2c")]
    cam_r: Option<Vec<f64>>,
    #[serde(default, rename = "cam_t_m2c")]
    cam_t: Option<Vec<f64>>,
    #[serde(default, rename = "static")]
    is_static: Option<bool>,
    #[serde(default)]
    density: Option<f64>,
}

/// Longest gravity taken (m/s²): a hundred thousand g, far beyond any
/// scene, still well inside f32 for the simulation.
pub const MAX_GRAVITY: f64 = 1e6;

/// A finite vector's direction and length, scaled by its largest
/// component first: `[0, -1e300, -1e300]` has a length that overflows to
/// infinity, and dividing by it had given a zero direction (a plane
/// normal of zero "passes 0.0 mm from the camera"). The length returned
/// may still be infinite; the direction is unit unless the vector is zero.
fn direction(v: DVec3) -> (DVec3, f64) {
    let m = v.abs().max_element();
    if m == 0.0 || !m.is_finite() {
        return (DVec3::ZERO, m);
    }
    let s = v / m;
    let l = s.length();
    (s / l, m * l)
}

fn vec3(what: &str, v: &[f64]) -> std::result::Result<DVec3, String> {
    if v.len() != 3 {
        return Err(format!("{what} must have 3 numbers, found {}", v.len()));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("{what} contains NaN or infinity"));
    }
    Ok(DVec3::new(v[0], v[1], v[2]))
}

/// Farthest position taken (m): beyond it f32 samples and grids lose the
/// millimetres a contact test needs, and no tabletop scene is that large.
pub const MAX_POSITION_M: f64 = crate::pose::MAX_DISTANCE_M;

fn within_reach(what: &str, t: DVec3) -> std::result::Result<DVec3, String> {
    if t.length() > MAX_POSITION_M {
        return Err(format!("{what} lies {:.3e} m from the origin, more than the {MAX_POSITION_M} m a scene may span (units?)", t.length()));
    }
    Ok(t)
}

fn rotation(what: &str, v: &[f64]) -> std::result::Result<DMat3, String> {
    if v.len() != 9 {
        return Err(format!(
            "{what} must have 9 numbers (row-major 3x3), found {}",
            v.len()
        ));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("{what} contains NaN or infinity"));
    }
    let r =
        DMat3::from_cols_array(&[v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]]).transpose();
    let det = r.determinant();
    if det <= 0.0 {
        return Err(format!(
            "{what} has determinant {det:.4}; a rotation must have determinant +1"
        ));
    }
    let e = r.transpose() * r - DMat3::IDENTITY;
    let err = e.to_cols_array().iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if err > ORTHONORMAL_TOL {
        return Err(format!(
            "{what} is not orthonormal (max |RᵀR − I| = {err:.2e} > {ORTHONORMAL_TOL:.0e})"
        ));
    }
    Ok(if err > 1e-12 {
        orthonormalize_rotation(r)
    } else {
        r
    })
}

impl Scene {
    /// Reads and validates a scene file; meshes are loaded relative to it.
    pub fn load(path: &Path) -> Result<Scene> {
        let text = crate::io::read_to_string_capped(path, MAX_SCENE_FILE_BYTES, "scene file")?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Scene::from_json(&text, &base, path)
    }

    /// Parses and validates scene JSON; `base` resolves mesh paths and
    /// `name` labels errors.
    pub fn from_json(text: &str, base: &Path, name: &Path) -> Result<Scene> {
        let bad = |reason: String| Error::BadJson { path: name.to_path_buf(), reason };
        let raw: RawScene = parse(text).map_err(bad)?;
        if raw.objects.is_empty() {
            return Err(bad("the scene has no objects".into()));
        }
        if raw.objects.len() > MAX_OBJECTS {
            return Err(bad(format!(
                "the scene has {} objects; at most {MAX_OBJECTS} are checked together (every object is tested against every other, with a signed-distance grid each)",
                raw.objects.len()
            )));
        }
        let frame = SceneFrame::of(&raw).map_err(bad)?;
        let mut cache: Vec<(PathBuf, MeshUnits, Arc<Mesh>)> = Vec::new();
        let mut objects = Vec::new();
        for (i, o) in raw.objects.iter().enumerate() {
            let oname = o.name.clone().unwrap_or_else(|| {
                Path::new(&o.mesh).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| format!("object{i}"))
            });
            let label = format!("object {i} ('{oname}')");
            let units: MeshUnits = match &o.units {
                Some(u) => u.parse().map_err(|e: String| bad(format!("{label}: {e}")))?,
                None => MeshUnits::Auto,
            };
            let pose = frame.object_pose(o, &label).map_err(bad)?;
            let density = o.density.unwrap_or(DEFAULT_DENSITY);
            if !(density.is_finite() && density > 0.0) {
                return Err(bad(format!("{label}: density must be a positive number, got {density}")));
            }
            let mesh_path = base.join(&o.mesh);
            let mesh = match cache.iter().find(|(p, u, _)| *p == mesh_path && *u == units) {
                Some((_, _, m)) => m.clone(),
                None => {
                    if mesh_path.is_dir() {
                        return Err(bad(format!("{label}: mesh '{}' is a folder, not a mesh file ({})", o.mesh, mesh_path.display())));
                    }
                    if !mesh_path.exists() {
                        return Err(bad(format!("{label}: mesh '{}' not found (looked for {})", o.mesh, mesh_path.display())));
                    }
                    let (m, _) = Mesh::load(&mesh_path, units).map_err(|e| bad(format!("{label}: {e}")))?;
                    let m = Arc::new(m);
                    cache.push((mesh_path.clone(), units, m.clone()));
                    m
                }
            };
            objects.push(SceneObject { name: oname, mesh, mesh_path, units, pose, is_static: o.is_static.unwrap_or(false), density });
        }
        Ok(Scene { gravity: frame.gravity, planes: frame.planes, objects })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A normal or gravity whose length overflows f64 still has a
    /// direction: it had been divided by an infinite length, giving zero.
    #[test]
    fn huge_normals_and_gravity_keep_their_direction() {
        let p = Plane::in_camera(DVec3::new(0.0, 0.0, 0.7), DVec3::new(0.0, -1e300, -1e300)).unwrap();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!((p.normal - DVec3::new(0.0, -h, -h)).length() < 1e-12, "{:?}", p.normal);
        assert_eq!(Plane::in_camera(DVec3::new(0.0, 0.0, 0.7), DVec3::new(0.0, 1e-300, 0.0)), Err(PlaneError::ZeroNormal));
        let base = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics"));
        let scene = |gravity: &str, normal: &str| {
            let json = format!(
                r#"{{"gravity": {gravity}, "planes": [{{"point": [0, 0, 0], "normal": {normal}}}], "objects": [{{"mesh": "cube.obj", "units": "m", "R": [1,0,0,0,1,0,0,0,1], "t": [0, 0, 0.025]}}]}}"#
            );
            Scene::from_json(&json, base, Path::new("scene.json"))
        };
        let s = scene("[0, 0, -9.81]", "[0, 0, 1e300]").unwrap();
        assert_eq!(s.planes[0].normal, DVec3::Z);
        let s = scene("[0, 0, -1e-8]", "[1e200, 0, 1e200]").unwrap();
        assert!((s.planes[0].normal - DVec3::new(h, 0.0, h)).length() < 1e-12);
        assert_eq!(s.gravity, DVec3::new(0.0, 0.0, -1e-8));
        let e = scene("[0, 0, -1e300]", "[0, 0, 1]").unwrap_err().to_string();
        assert!(e.contains("gravity is 1.000e300 m/s² long"), "{e}");
        assert!(scene("[0, 0, 1e-300]", "[0, 0, 1]").unwrap_err().to_string().contains("gravity has zero length"));
    }
}
