//! A BOP dataset on disk: models and their `models_info.json`, the scenes
//! of a split (`scene_gt.json`, `scene_camera.json`, `scene_gt_info.json`,
//! 16-bit depth PNGs, `mask_visib/`), and the evaluation targets.
//!
//! Everything is read as the files store it (millimetres, row-major R), in
//! [`PoseMm`]; [`PoseMm::to_pose`] converts to the library's metres at the
//! point where a pose leaves the BOP world (rendering). Every malformed
//! file is an error naming the file (and serde's line and column).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use serde::de::DeserializeOwned;
use serde::Deserialize;

use crate::camera::Intrinsics;
use crate::lens::LensCamera;
use super::tiff_depth::{depth_size, is_tiff, read_tiff_depth};
use crate::observation::MAX_IMAGE_SIDE;
use crate::error::{Error, Input, Result};
use crate::pose::Pose;

/// How far `RᵀR` of a BOP rotation may be from the identity. BOP files are
/// not exactly orthonormal (LM-O's own ground truth is off by up to 2e-3),
/// and the toolkit uses them as they are, so only matrices that are no
/// rotation at all are refused.
pub const BOP_ORTHONORMAL_TOL: f64 = 0.05;

/// A pose as BOP files store it: model to camera, translation in mm. The
/// rotation is kept exactly as written (not re-orthonormalized), as the BOP
/// toolkit uses it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseMm {
    pub r: DMat3,
    pub t: DVec3,
}

/// The largest translation component a pose may have (mm): far beyond
/// any camera's range, and small enough that every error (squared
/// distances included) stays finite; a translation of 1e300 mm gave an
/// infinite translation error, and ICP a pose just as absurd.
pub const MAX_TRANSLATION_MM: f64 = 1e9;

impl PoseMm {
    /// From a row-major rotation and a translation in mm.
    pub fn from_row_major(r: &[f64], t: &[f64]) -> std::result::Result<PoseMm, String> {
        if r.len() != 9 || t.len() != 3 {
            return Err(format!("expected 9 rotation and 3 translation numbers, got {} and {}", r.len(), t.len()));
        }
        if r.iter().chain(t).any(|v| !v.is_finite()) {
            return Err("pose holds NaN or infinity".into());
        }
        if let Some(v) = t.iter().find(|v| v.abs() > MAX_TRANSLATION_MM) {
            return Err(format!("t holds {v:e} mm, more than {MAX_TRANSLATION_MM:e} mm (1,000 km) from the camera: not a pose"));
        }
        let p = PoseMm { r: DMat3::from_cols_array(&r.try_into().unwrap()).transpose(), t: DVec3::new(t[0], t[1], t[2]) };
        let err = p.to_pose().orthonormality_error();
        if err > BOP_ORTHONORMAL_TOL {
            return Err(format!("R is not a rotation (|RᵀR − I| up to {err:.2e})"));
        }
        // Orthonormal with determinant −1 is a mirror image, not a pose.
        if p.r.determinant() < 0.0 {
            return Err("R is not a rotation: its determinant is −1 (a reflection; a row or column flipped?)".into());
        }
        Ok(p)
    }

    /// Row-major rotation, as BOP files write it.
    pub fn r_row_major(&self) -> [f64; 9] {
        self.r.transpose().to_cols_array()
    }

    /// The same pose in metres, with the file's rotation as it is (the BOP
    /// toolkit evaluates it so).
    pub fn to_pose(&self) -> Pose {
        Pose::new(self.r, self.t * 1e-3)
    }

    /// The same pose in metres with the nearest rotation: where a pose is
    /// refined, so that a file's rounded (slightly sheared) rotation neither
    /// shears the rendered object nor reaches the output, and the library's
    /// Python `refine` and the CLI start from the same pose.
    pub fn to_rigid_pose(&self) -> Pose {
        Pose::new(crate::pose::orthonormalize_rotation(self.r), self.t * 1e-3)
    }
}

/// A continuous rotational symmetry (`models_info.json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContinuousSymmetry {
    pub axis: DVec3,
    /// A point on the axis, mm.
    pub offset: DVec3,
}

/// One object's entry of `models_info.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// Largest distance between two model points, mm.
    pub diameter: f64,
    /// Discrete symmetries as 4×4 row-major matrices, translation in mm.
    pub symmetries_discrete: Vec<[f64; 16]>,
    pub symmetries_continuous: Vec<ContinuousSymmetry>,
}

impl ModelInfo {
    pub fn is_symmetric(&self) -> bool {
        !self.symmetries_discrete.is_empty() || !self.symmetries_continuous.is_empty()
    }
}

/// One annotated object instance of an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtInstance {
    pub obj_id: u32,
    pub pose: PoseMm,
}

/// One image's camera (`scene_camera.json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameCamera {
    /// How the camera projects: `cam_K` or BOP-H3's `cam_model`.
    pub projection: Projection,
    /// Depth PNG value × `depth_scale` = millimetres (needed only where
    /// depth is read: RGB-only splits may leave it out).
    pub depth_scale: Option<f64>,
}

/// A scene camera's projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// `cam_K`: row-major 3×3 pinhole intrinsics.
    Pinhole([f64; 9]),
    /// `cam_model`: a lens model with its image size (HOT3D's fisheyes;
    /// the H3 layout's pinholes as `PinholePlane`).
    Lens(LensCamera),
}

impl Projection {
    /// The pinhole intrinsics: `cam_K`, or a `PinholePlane` model's.
    pub fn k(&self) -> Option<[f64; 9]> {
        match self {
            Projection::Pinhole(k) => Some(*k),
            Projection::Lens(l) => l.pinhole_k(),
        }
    }

    /// The image size a `cam_model` gives; `None` for `cam_K`.
    pub fn image_size(&self) -> Option<(u32, u32)> {
        match self {
            Projection::Pinhole(_) => None,
            Projection::Lens(l) => Some((l.width, l.height)),
        }
    }
}

/// An evaluation target: `inst_count` instances of `obj_id` in an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Target {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    pub inst_count: u32,
}

/// A depth image as the BOP toolkit reads it: PNG value × depth_scale in
/// f32 millimetres (0 = no measurement).
#[derive(Clone, Debug)]
pub struct DepthMm {
    pub width: u32,
    pub height: u32,
    pub mm: Vec<f32>,
}

/// A dataset split on disk.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    pub split: String,
    /// `models_eval/` when present (what BOP evaluates with), else `models/`.
    pub models_dir: PathBuf,
    pub models_info: BTreeMap<u32, ModelInfo>,
    /// Image size from the dataset's `camera.json` (`camera_{sensor}.json`),
    /// when it has one.
    pub image_size: Option<(u32, u32)>,
    /// The sensor of a split annotated per sensor (BOP-H3 and the BOP'24
    /// industrial datasets: `scene_gt_{sensor}.json`,
    /// `scene_camera_{sensor}.json`, `scene_gt_info_{sensor}.json`,
    /// `depth_{sensor}/`); `None` for the classic layout.
    pub sensor: Option<String>,
    /// Where the sensor changes by scene (HOT3D), the rule that picks it;
    /// `sensor` is then `None`.
    pub sensor_rule: Option<SensorRule>,
}

/// Which sensor's annotations a scene is read with, for a split whose
/// sensor changes by scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorRule {
    /// HOT3D as the BOP toolkit evaluates it (`dataset_params`'
    /// `hot3d_eval_modality`): the Quest 3 scenes 0–1848 by their first
    /// monochrome camera (`gray1`), the Aria scenes 1849–3831 by their RGB
    /// camera (`rgb`).
    Hot3d,
}

impl SensorRule {
    /// The sensor of a scene; `None` for a scene the rule does not cover.
    pub fn sensor(self, scene_id: u32) -> Option<&'static str> {
        match (self, scene_id) {
            (SensorRule::Hot3d, 0..=1848) => Some("gray1"),
            (SensorRule::Hot3d, 1849..=3831) => Some("rgb"),
            (SensorRule::Hot3d, _) => None,
        }
    }

    /// The rule in words, for messages.
    pub fn describe(self) -> &'static str {
        match self {
            SensorRule::Hot3d => "gray1 for HOT3D's Quest 3 scenes (0-1848), rgb for its Aria scenes (1849-3831)",
        }
    }
}

impl Dataset {
    /// Opens `root` (the folder holding `models*/` and `<split>/`).
    pub fn open(root: &Path, split: &str) -> Result<Dataset> {
        Dataset::open_sensor(root, split, None)
    }

    /// Opens `root` reading the annotations and depth of `sensor` (a split
    /// annotated per sensor; `None`: the classic one-camera layout).
    pub fn open_sensor(root: &Path, split: &str, sensor: Option<&str>) -> Result<Dataset> {
        if let Some(s) = sensor {
            if s.is_empty() || !s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
                return Err(Error::InvalidInput(format!("sensor '{s}': a name of letters, digits, '_' or '-' (photoneo, xyz, 3dlong, ...)")).about(Input::Sensor));
            }
        }
        if !root.exists() {
            return Err(Error::NotFound { path: root.to_path_buf() });
        }
        if !root.is_dir() {
            return Err(Error::InvalidInput(format!("{}: a dataset is a folder, this is a file", root.display())));
        }
        let models_dir =
            ["models_eval", "models"].iter().map(|d| root.join(d)).find(|d| d.join("models_info.json").is_file()).ok_or_else(|| {
                Error::InvalidInput(format!("{}: neither models_eval/ nor models/ holds a models_info.json", root.display()))
            })?;
        let models_info = read_models_info(&models_dir.join("models_info.json"))?;
        let split_dir = root.join(split);
        if !split_dir.is_dir() {
            return Err(Error::InvalidInput(format!("{}: no split folder '{split}'", root.display())));
        }
        // A sensor's image size is its own camera file's, else its depth
        // images' (never the classic camera.json: another camera's width
        // would scale MSPD).
        let camera = match sensor {
            Some(s) => root.join(format!("camera_{s}.json")),
            None => root.join("camera.json"),
        };
        let image_size = read_image_size(&camera)?;
        let ds = Dataset {
            root: root.to_path_buf(),
            split: split.to_string(),
            models_dir,
            models_info,
            image_size,
            sensor: sensor.map(str::to_string),
            sensor_rule: None,
        };
        if let Some(s) = sensor {
            // A sensor the split has no annotations for is said now, by name.
            if let Some(&first) = ds.scene_ids()?.first() {
                let dir = ds.scene_dir(first);
                if !dir.join(format!("scene_gt_{s}.json")).is_file() {
                    return Err(ds.missing_annotations(&dir, &dir.join(format!("scene_gt_{s}.json"))));
                }
            }
        }
        Ok(ds)
    }

    /// Opens `root`, a split whose sensor changes by scene, reading each
    /// scene with the sensor `rule` picks for it.
    pub fn open_per_scene(root: &Path, split: &str, rule: SensorRule) -> Result<Dataset> {
        let mut ds = Dataset::open(root, split)?;
        ds.sensor_rule = Some(rule);
        Ok(ds)
    }

    /// What a scene's annotation files' names end with: `_{sensor}` or
    /// nothing.
    fn suffix(&self, scene_id: u32) -> Result<String> {
        if let Some(rule) = self.sensor_rule {
            return rule.sensor(scene_id).map(|s| format!("_{s}")).ok_or_else(|| {
                Error::InvalidInput(format!(
                    "{}: scene {scene_id} has no sensor by the rule that picks one per scene ({})",
                    self.scene_dir(scene_id).display(),
                    rule.describe()
                ))
            });
        }
        Ok(self.sensor.as_deref().map(|s| format!("_{s}")).unwrap_or_default())
    }

    /// Whether `path` (absolute, symlinks resolved) is where this dataset
    /// reads from: under a models folder or the split folder, its
    /// `camera.json` (`camera_{sensor}.json`) or its targets files. Writing an output there
    /// would change the dataset.
    pub fn reads_at(&self, path: &Path) -> bool {
        let canon = |p: PathBuf| p.canonicalize().unwrap_or(p);
        let folders = [self.models_dir.clone(), self.root.join("models"), self.root.join("models_eval"), self.root.join(&self.split)];
        folders.into_iter().map(canon).any(|d| path.starts_with(d))
            || [self.root.join("camera.json"), self.default_targets(), self.targets_file(true)]
                .into_iter()
                .chain(self.sensor.as_deref().map(|s| self.root.join(format!("camera_{s}.json"))))
                .map(canon)
                .any(|f| path == f)
    }

    /// The targets file read when none is given.
    fn default_targets(&self) -> PathBuf {
        self.targets_file(false)
    }

    /// The dataset's own targets file: `test_targets_bop19.json`, or with
    /// `bop24` BOP'24's `test_targets_bop24.json` (images only, for the
    /// detection task).
    pub fn targets_file(&self, bop24: bool) -> PathBuf {
        self.root.join(if bop24 { "test_targets_bop24.json" } else { "test_targets_bop19.json" })
    }

    /// The model file of an object (`obj_000001.ply`).
    pub fn model_path(&self, obj_id: u32) -> PathBuf {
        self.models_dir.join(format!("obj_{obj_id:06}.ply"))
    }

    /// An object's model: its vertices (mm, all finite) and triangles,
    /// checked against its `models_info.json` diameter.
    pub fn model_points(&self, obj_id: u32) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
        let path = self.model_path(obj_id);
        let (pts, tris) = crate::mesh::load_positions(&path)?;
        crate::mesh::check_finite(&path, &pts)?;
        if let Some(info) = self.models_info.get(&obj_id) {
            check_model_size(&path, obj_id, &pts, info.diameter)?;
        }
        Ok((pts, tris))
    }

    /// SHA-256 over every model file of `models_info.json` (its id and the
    /// file's digest, a line each; a missing file as `-`): what a resumable
    /// output records, so that a model edited between a kill and the rerun
    /// refuses the resume instead of mixing two geometries in one file.
    /// Over all the dataset's models, not only those an image uses: shards
    /// of one output must record the same.
    pub fn models_digest(&self) -> Result<String> {
        let mut lines = String::new();
        for &id in self.models_info.keys() {
            let path = self.model_path(id);
            let digest = match std::fs::File::open(&path) {
                Ok(f) => crate::stable::db::sha256_hex_reader(f).map_err(|e| Error::io(&path, e))?,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => "-".into(),
                Err(e) => return Err(Error::io(&path, e)),
            };
            lines += &format!("{id} {digest}\n");
        }
        crate::stable::db::sha256_hex_reader(lines.as_bytes()).map_err(|e| Error::io(&self.models_dir, e))
    }

    /// An object's model as a mesh in metres ([`model_points`](Self::model_points),
    /// checked the same way).
    pub fn model_mesh(&self, obj_id: u32) -> Result<crate::mesh::Mesh> {
        let (pts, tris) = self.model_points(obj_id)?;
        let metres: Vec<DVec3> = pts.iter().map(|v| *v * 1e-3).collect();
        Ok(crate::mesh::Mesh::from_raw(&self.model_path(obj_id), metres, tris)?.0)
    }

    /// Folder of a scene of the split.
    pub fn scene_dir(&self, scene_id: u32) -> PathBuf {
        self.root.join(&self.split).join(format!("{scene_id:06}"))
    }

    /// Scene ids of the split (numeric folder names), ascending.
    pub fn scene_ids(&self) -> Result<Vec<u32>> {
        let dir = self.root.join(&self.split);
        let mut ids: Vec<u32> = std::fs::read_dir(&dir)
            .map_err(|e| Error::io(&dir, e))?
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_dir())
            .filter_map(|e| e.file_name().to_str().and_then(|s| s.parse().ok()))
            .collect();
        ids.sort_unstable();
        Ok(ids)
    }

    /// Reads a scene's annotations.
    pub fn scene(&self, scene_id: u32) -> Result<Scene> {
        let dir = self.scene_dir(scene_id);
        if !dir.is_dir() {
            return Err(Error::InvalidInput(format!("{}: scene {scene_id} is not in the dataset", dir.display())));
        }
        let suffix = self.suffix(scene_id)?;
        let file = |stem: &str| dir.join(format!("{stem}{suffix}.json"));
        if !file("scene_gt").is_file() {
            return Err(self.missing_annotations(&dir, &file("scene_gt")));
        }
        let gt = read_scene_gt(&file("scene_gt"))?;
        let camera = read_scene_camera(&file("scene_camera"))?;
        let info_path = file("scene_gt_info");
        let gt_info = if info_path.is_file() { Some(read_scene_gt_info(&info_path, &gt)?) } else { None };
        for (im, insts) in &gt {
            for g in insts {
                if !self.models_info.contains_key(&g.obj_id) {
                    return Err(Error::BadJson {
                        path: file("scene_gt"),
                        reason: format!("image {im}: object {} is not in models_info.json", g.obj_id),
                    });
                }
            }
        }
        Ok(Scene { id: scene_id, dir, gt, camera, gt_info, image_size: self.image_size, first_size: Default::default(), suffix })
    }

    /// The error for a scene without `want`: naming the sensors whose
    /// annotations the scene does have (a split annotated per sensor).
    fn missing_annotations(&self, dir: &Path, want: &Path) -> Error {
        let sensors = sensors_in(dir);
        if sensors.is_empty() {
            return Error::NotFound { path: want.to_path_buf() };
        }
        let which = match (&self.sensor, self.sensor_rule) {
            (Some(s), _) => format!("there is no sensor '{s}'"),
            (None, Some(rule)) => format!("the rule per scene ({}) names one the scene lacks", rule.describe()),
            (None, None) => "choose one".into(),
        };
        Error::InvalidInput(format!(
            "{}: the split is annotated per sensor ({}): {which} (the BOP toolkit evaluates photoneo for ipd, xyz for xyzibd, 3dlong for itoddmv, rgb or gray1 by scene for hot3d)",
            dir.display(),
            sensors.join(", ")
        ))
        .about(Input::Sensor)
    }

    /// The sensors a split is annotated for, when it is annotated per sensor
    /// (its first scene has `scene_gt_{sensor}.json` files and no
    /// `scene_gt.json`); empty for the classic layout.
    pub fn sensors(&self) -> Result<Vec<String>> {
        let Some(&first) = self.scene_ids()?.first() else { return Ok(Vec::new()) };
        let dir = self.scene_dir(first);
        Ok(if dir.join("scene_gt.json").is_file() { Vec::new() } else { sensors_in(&dir) })
    }

    /// The evaluation targets: `file` (or `test_targets_bop19.json` in the
    /// dataset when `file` is `None` and it exists), else every annotated
    /// instance. The second value says which.
    pub fn targets(&self, file: Option<&Path>) -> Result<(Vec<Target>, TargetSource)> {
        let default = self.default_targets();
        let path = match file {
            Some(f) => Some(f.to_path_buf()),
            None if default.is_file() => Some(default),
            None => None,
        };
        match path {
            Some(p) => {
                let (targets, images_only) = read_targets_file(&p, self)?;
                Ok((targets, if images_only { TargetSource::ImageList(p) } else { TargetSource::File(p) }))
            }
            None => {
                let mut out = Vec::new();
                for scene_id in self.scene_ids()? {
                    let scene = self.scene(scene_id)?;
                    for (&im_id, insts) in &scene.gt {
                        out.extend(instance_targets(scene_id, im_id, insts));
                    }
                }
                Ok((out, TargetSource::AllInstances))
            }
        }
    }
}

/// The sensors of a scene folder's `scene_gt_{sensor}.json` files, sorted.
fn sensors_in(dir: &Path) -> Vec<String> {
    let mut sensors: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().to_str().and_then(|n| n.strip_prefix("scene_gt_")?.strip_suffix(".json").map(str::to_string)))
        .filter(|s| !s.starts_with("info") && !s.starts_with("coco"))
        .collect();
    sensors.sort();
    sensors
}

/// Where the targets came from.
#[derive(Clone, Debug, PartialEq)]
pub enum TargetSource {
    File(PathBuf),
    /// A file naming images only (BOP'24's `{scene_id, im_id}`): every
    /// annotated instance of those images is a target.
    ImageList(PathBuf),
    /// No targets file: every annotated instance is a target.
    AllInstances,
}

/// One scene's annotations.
#[derive(Clone, Debug)]
pub struct Scene {
    pub id: u32,
    pub dir: PathBuf,
    /// Per image, the annotated instances in file order (the index is the
    /// BOP `gt_id`).
    pub gt: BTreeMap<u32, Vec<GtInstance>>,
    pub camera: BTreeMap<u32, FrameCamera>,
    /// Per image and instance, the visible fraction (`scene_gt_info.json`),
    /// `None` when the file is missing.
    pub gt_info: Option<BTreeMap<u32, Vec<f64>>>,
    image_size: Option<(u32, u32)>,
    /// Without a camera.json, the size of the scene's first depth image by
    /// id: the others must match it (BOP images of a dataset share one size, and
    /// MSPD is scaled by it).
    first_size: std::sync::OnceLock<(PathBuf, u32, u32)>,
    /// `_{sensor}` for a split annotated per sensor, else empty.
    suffix: String,
}

impl Scene {
    /// One of the scene's annotation files (`scene_gt`, `scene_camera`,
    /// `scene_gt_info`), for the dataset's sensor.
    pub fn file(&self, stem: &str) -> PathBuf {
        self.dir.join(format!("{stem}{}.json", self.suffix))
    }

    /// The full-mask folder (`mask`, `mask_{sensor}`): the silhouettes
    /// including occluded parts.
    pub fn mask_dir(&self) -> PathBuf {
        self.dir.join(format!("mask{}", self.suffix))
    }

    /// The visible-mask folder (`mask_visib`, `mask_visib_{sensor}`).
    pub fn mask_visib_dir(&self) -> PathBuf {
        self.dir.join(format!("mask_visib{}", self.suffix))
    }

    /// The depth image of an image: `depth/{im_id:06}.png`, or `.tif` where
    /// the dataset has TIFF depth (ITODD) and no PNG (`depth_{sensor}/` for
    /// a split annotated per sensor).
    pub fn depth_path(&self, im_id: u32) -> PathBuf {
        let dir = self.dir.join(format!("depth{}", self.suffix));
        let png = dir.join(format!("{im_id:06}.png"));
        let tif = dir.join(format!("{im_id:06}.tif"));
        if !png.exists() && tif.exists() { tif } else { png }
    }

    /// An image's camera, or an error naming the scene file.
    pub fn frame_camera(&self, im_id: u32) -> Result<&FrameCamera> {
        self.camera
            .get(&im_id)
            .ok_or_else(|| Error::BadJson { path: self.file("scene_camera"), reason: format!("no entry for image {im_id}") })
    }

    /// Intrinsics of an image of `width × height`, checked against its
    /// size ([`Intrinsics::check_against_image`]): a K with the principal
    /// point far outside the image or a focal length of a pixel gave every
    /// estimate metres away and every score 0 without a word.
    pub fn intrinsics(&self, im_id: u32, width: u32, height: u32) -> Result<Intrinsics> {
        Ok(self.pinhole(im_id, width, height)?.0)
    }

    /// [`Self::intrinsics`] with the row-major K they came from (the
    /// toolkit's VSD uses K as given). A lens camera with distortion is an
    /// error naming what needs a pinhole.
    pub fn pinhole(&self, im_id: u32, width: u32, height: u32) -> Result<(Intrinsics, [f64; 9])> {
        let k = self.pinhole_k(im_id)?;
        let bad = |reason: String| Error::BadJson { path: self.file("scene_camera"), reason: format!("image {im_id}: {reason}") };
        let i = Intrinsics::from_k(&k, width, height).map_err(|e| bad(e.to_string()))?;
        i.check_against_image().map_err(bad)?;
        Ok((i, k))
    }

    /// An image's pinhole K (row-major): `cam_K` or a `PinholePlane`
    /// `cam_model`'s. A lens with distortion is an error naming what needs
    /// a pinhole (checked before depth is read: HOT3D has none).
    pub fn pinhole_k(&self, im_id: u32) -> Result<[f64; 9]> {
        match self.frame_camera(im_id)?.projection {
            Projection::Pinhole(k) => Ok(k),
            Projection::Lens(l) => l.pinhole_k().ok_or_else(|| Error::BadJson {
                path: self.file("scene_camera"),
                reason: format!(
                    "image {im_id}: its camera is a {} lens model (cam_model); rendering, depth and VSD need a pinhole camera (cam_K or a PinholePlane cam_model; the BOP toolkit computes VSD for cam_K alone), MSSD and MSPD take any lens",
                    l.kind.name()
                ),
            }),
        }
    }

    /// The size of an image: its `cam_model`'s (checked against the
    /// dataset's `camera.json` where it has one), else `camera.json`'s, else
    /// the depth PNG's header.
    pub fn image_size(&self, im_id: u32) -> Result<(u32, u32)> {
        if let Some((w, h)) = self.frame_camera(im_id)?.projection.image_size() {
            return match self.image_size {
                Some((cw, ch)) if (cw, ch) != (w, h) => Err(Error::BadJson {
                    path: self.file("scene_camera"),
                    reason: format!("image {im_id}: cam_model is {w}x{h} but the dataset's camera file says {cw}x{ch}"),
                }),
                _ => Ok((w, h)),
            };
        }
        if let Some(s) = self.image_size {
            return Ok(s);
        }
        let path = self.depth_path(im_id);
        if !path.exists() {
            // Say why depth was looked for (an RGB-only split with cam_K).
            return Err(Error::BadJson {
                path: self.file("scene_camera"),
                reason: format!(
                    "image {im_id}: its size is unknown: its camera is a cam_K (no size), the dataset has no camera file and there is no depth image {}",
                    path.display()
                ),
            });
        }
        let (w, h) = depth_size(&path)?;
        self.check_size(&path, w, h)?;
        Ok((w, h))
    }

    /// Checks an image's size against the dataset's camera.json, or without
    /// one against the scene's first image by id (the same one whichever
    /// image is read first: images are read in parallel).
    fn check_size(&self, path: &Path, w: u32, h: u32) -> Result<()> {
        let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
        match self.image_size {
            Some((cw, ch)) if (w, h) != (cw, ch) => Err(bad(format!("depth is {w}x{h} but the dataset's camera.json says {cw}x{ch}"))),
            Some(_) => Ok(()),
            None => {
                let (first, fw, fh) = self.first_size.get_or_init(|| {
                    let first = self.gt.keys().next().map(|&im| self.depth_path(im)).filter(|p| p.is_file()).unwrap_or_else(|| path.to_path_buf());
                    let (fw, fh) = if first == path { (w, h) } else { depth_size(&first).unwrap_or((w, h)) };
                    (first, fw, fh)
                });
                if (w, h) != (*fw, *fh) {
                    return Err(bad(format!(
                        "depth is {w}x{h} but {} is {fw}x{fh}: the images of a dataset share one size (the dataset has no camera.json to say which is right)",
                        first.display()
                    )));
                }
                Ok(())
            }
        }
    }

    /// Reads an image's depth as the BOP toolkit does (value × depth_scale,
    /// f32 mm). The PNG header is checked against the dataset's image size
    /// before anything is decoded.
    pub fn read_depth(&self, im_id: u32) -> Result<DepthMm> {
        let path = self.depth_path(im_id);
        let cam = self.frame_camera(im_id)?;
        let bad = |reason: String| Error::BadImage { path: path.clone(), reason };
        let (w, h) = depth_size(&path)?;
        self.check_size(&path, w, h)?;
        if let Some((cw, ch)) = cam.projection.image_size().filter(|&s| s != (w, h)) {
            return Err(bad(format!("depth is {w}x{h} but the image's cam_model in {} says {cw}x{ch}", self.file("scene_camera").display())));
        }
        let s = cam.depth_scale.ok_or_else(|| Error::BadJson {
            path: self.file("scene_camera"),
            reason: format!("image {im_id} has no depth_scale (PNG value × depth_scale = mm), needed to read its depth"),
        })?;
        let mm: Vec<f32> = if is_tiff(&path) {
            let (_, _, v) = read_tiff_depth(&path)?;
            v.into_iter().map(|v| v * s as f32).collect()
        } else {
            let img = image::open(&path).map_err(|e| bad(e.to_string()))?;
            let image::DynamicImage::ImageLuma16(img) = img else {
                return Err(bad(format!("depth must be a 16-bit single-channel PNG (BOP convention; TIFF for ITODD and float sensors), got {:?}", img.color())));
            };
            img.as_raw().iter().map(|&v| v as f32 * s as f32).collect()
        };
        crate::observation::check_depth_scale(&mm, 1e-3, s).map_err(bad)?;
        Ok(DepthMm { width: w, height: h, mm })
    }
}

fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    read_json_capped(path, MAX_JSON_BYTES)
}

fn read_json_capped<T: DeserializeOwned>(path: &Path, cap: u64) -> Result<T> {
    let text = crate::io::read_to_string_capped(path, cap, "dataset JSON file")?;
    serde_json::from_str(&text).map_err(|e| Error::BadJson { path: path.to_path_buf(), reason: e.to_string() })
}

/// Largest dataset JSON file read (scene_gt.json, ...): the largest BOP
/// scene files are tens of MB; the cap stops an endless stream.
const MAX_JSON_BYTES: u64 = 2 << 30;

/// Largest targets file read: BOP's hold a few thousand entries of about
/// 60 bytes; a smaller cap than scene files' ends `--targets /dev/zero`
/// sooner (it read 2 GiB).
const MAX_TARGETS_BYTES: u64 = 256 << 20;

fn parse_id(path: &Path, key: &str, what: &str) -> Result<u32> {
    key.parse()
        .map_err(|_| Error::BadJson { path: path.to_path_buf(), reason: format!("'{key}' is not an id of {what} (expected an integer)") })
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawContinuous {
    axis: Vec<f64>,
    offset: Vec<f64>,
}

#[derive(Deserialize)]
struct RawModelInfo {
    diameter: f64,
    #[serde(default)]
    symmetries_discrete: Vec<Vec<f64>>,
    #[serde(default)]
    symmetries_continuous: Vec<RawContinuous>,
}

/// The largest and smallest ratio of an object's `models_info.json`
/// diameter to its model's bounding-box diagonal that are taken to be in
/// the same units. The diameter of points in a box of diagonal d lies in
/// [d/√3, d]; the slack covers a diameter computed on another resampling
/// of the model (`models_eval/` against `models/`). A model in metres,
/// centimetres or inches against a diameter in mm is off by 1000, 10 or
/// 25.4, and every error of its estimates with it: MSSD, ADD and the
/// visual score are in the model's units, their thresholds in the
/// diameter's.
pub const MODEL_DIAMETER_RATIO: std::ops::RangeInclusive<f64> = 0.4..=2.5;

/// Refuses a model whose vertices do not span about its `diameter` (mm).
pub fn check_model_size(path: &Path, obj_id: u32, pts: &[DVec3], diameter: f64) -> Result<()> {
    let (lo, hi) = crate::mesh::bounds_of(pts);
    let diagonal = (hi - lo).length();
    if pts.is_empty() || MODEL_DIAMETER_RATIO.contains(&(diameter / diagonal)) {
        return Ok(());
    }
    let num = |x: f64| if (1e-3..1e9).contains(&x) { format!("{x:.4}") } else { format!("{x:.3e}") };
    Err(Error::MalformedMesh {
        path: path.to_path_buf(),
        reason: format!(
            "object {obj_id}: its vertices span {} units (bounding-box diagonal) but models_info.json gives it a diameter of {} mm; BOP models are in millimetres: is the model (or the diameter) in other units?",
            num(diagonal),
            num(diameter)
        ),
    })
}

/// Reads `models_info.json`.
pub fn read_models_info(path: &Path) -> Result<BTreeMap<u32, ModelInfo>> {
    let raw: BTreeMap<String, RawModelInfo> = read_json(path)?;
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let mut out = BTreeMap::new();
    for (key, m) in raw {
        let id = parse_id(path, &key, "an object")?;
        if !(m.diameter.is_finite() && m.diameter > 0.0) {
            return Err(bad(format!("object {id}: diameter must be a positive number of mm, got {}", m.diameter)));
        }
        let mut disc = Vec::new();
        for (i, s) in m.symmetries_discrete.iter().enumerate() {
            let arr: [f64; 16] = s
                .as_slice()
                .try_into()
                .map_err(|_| bad(format!("object {id}: symmetries_discrete[{i}] has {} numbers, expected 16 (4x4 row-major)", s.len())))?;
            if arr.iter().any(|v| !v.is_finite()) || arr[12..] != [0.0, 0.0, 0.0, 1.0] {
                return Err(bad(format!("object {id}: symmetries_discrete[{i}] is not a rigid 4x4 transform")));
            }
            let r = DMat3::from_cols_array(&[arr[0], arr[4], arr[8], arr[1], arr[5], arr[9], arr[2], arr[6], arr[10]]);
            let err = (r.transpose() * r - DMat3::IDENTITY).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
            if err > BOP_ORTHONORMAL_TOL {
                return Err(bad(format!("object {id}: symmetries_discrete[{i}] is not a rotation (|RᵀR − I| up to {err:.2e})")));
            }
            if r.determinant() < 0.0 {
                return Err(bad(format!("object {id}: symmetries_discrete[{i}] is a reflection (determinant −1), not a rotation")));
            }
            disc.push(arr);
        }
        let mut cont = Vec::new();
        for (i, s) in m.symmetries_continuous.iter().enumerate() {
            let ok = s.axis.len() == 3 && s.offset.len() == 3 && s.axis.iter().chain(&s.offset).all(|v| v.is_finite());
            let axis = if ok { DVec3::from_slice(&s.axis) } else { DVec3::ZERO };
            if !ok || axis.length() < 1e-9 {
                return Err(bad(format!("object {id}: symmetries_continuous[{i}] needs a non-zero 'axis' and an 'offset' of 3 numbers")));
            }
            cont.push(ContinuousSymmetry { axis, offset: DVec3::from_slice(&s.offset) });
        }
        out.insert(id, ModelInfo { diameter: m.diameter, symmetries_discrete: disc, symmetries_continuous: cont });
    }
    if out.is_empty() {
        return Err(bad("lists no object".into()));
    }
    Ok(out)
}

#[derive(Deserialize)]
struct RawSize {
    width: u32,
    height: u32,
}

fn read_image_size(path: &Path) -> Result<Option<(u32, u32)>> {
    if !path.is_file() {
        return Ok(None);
    }
    let raw: RawSize = read_json(path)?;
    if raw.width == 0 || raw.height == 0 || raw.width > MAX_IMAGE_SIDE || raw.height > MAX_IMAGE_SIDE {
        return Err(Error::BadJson {
            path: path.to_path_buf(),
            reason: format!("image size {}x{} is not between 1 and {MAX_IMAGE_SIDE} pixels a side", raw.width, raw.height),
        });
    }
    Ok(Some((raw.width, raw.height)))
}

#[derive(Deserialize)]
struct RawGt {
    #[serde(rename = "cam_R_m2c")]
    r: Vec<f64>,
    #[serde(rename = "cam_t_m2c")]
    t: Vec<f64>,
    obj_id: u32,
}

/// Reads `scene_gt.json`.
pub fn read_scene_gt(path: &Path) -> Result<BTreeMap<u32, Vec<GtInstance>>> {
    let raw: BTreeMap<String, Vec<RawGt>> = read_json(path)?;
    let mut out = BTreeMap::new();
    for (key, list) in raw {
        let im = parse_id(path, &key, "an image")?;
        let mut insts = Vec::with_capacity(list.len());
        for (i, g) in list.iter().enumerate() {
            let pose = PoseMm::from_row_major(&g.r, &g.t)
                .map_err(|reason| Error::BadJson { path: path.to_path_buf(), reason: format!("image {im}, instance {i}: {reason}") })?;
            insts.push(GtInstance { obj_id: g.obj_id, pose });
        }
        out.insert(im, insts);
    }
    Ok(out)
}

#[derive(Deserialize)]
struct RawCamera {
    #[serde(rename = "cam_K")]
    k: Option<Vec<f64>>,
    cam_model: Option<RawCamModel>,
    depth_scale: Option<f64>,
}

/// BOP-H3's `cam_model` (the Hand Tracking Toolkit's calibration fields).
#[derive(Deserialize)]
struct RawCamModel {
    projection_model_type: String,
    projection_params: Vec<f64>,
    image_width: f64,
    image_height: f64,
}

/// Reads `scene_camera.json`; a `depth_scale` given must be plausible
/// (its absence is an error only where depth is read).
pub fn read_scene_camera(path: &Path) -> Result<BTreeMap<u32, FrameCamera>> {
    let raw: BTreeMap<String, RawCamera> = read_json(path)?;
    let mut out = BTreeMap::new();
    for (key, c) in raw {
        let im = parse_id(path, &key, "an image")?;
        let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason: format!("image {im}: {reason}") };
        let projection = match (c.k, c.cam_model) {
            (Some(k), None) => {
                let k: [f64; 9] = k.as_slice().try_into().map_err(|_| bad(format!("cam_K has {} numbers, expected 9", k.len())))?;
                Intrinsics::from_k(&k, 1, 1).map_err(|e| bad(e.to_string()))?;
                Projection::Pinhole(k)
            }
            (None, Some(m)) => Projection::Lens(
                LensCamera::from_bop(&m.projection_model_type, m.image_width, m.image_height, &m.projection_params)
                    .map_err(|e| bad(e.to_string()))?,
            ),
            (Some(_), Some(_)) => return Err(bad("both cam_K and cam_model: a camera is one or the other".into())),
            (None, None) => return Err(bad("neither cam_K nor cam_model".into())),
        };
        if let Some(d) = c.depth_scale {
            if !(d.is_finite() && d > 1e-6 && d < 1e3) {
                return Err(bad(format!("depth_scale {d} is not a plausible scale to millimetres")));
            }
        }
        out.insert(im, FrameCamera { projection, depth_scale: c.depth_scale });
    }
    Ok(out)
}

#[derive(Deserialize)]
struct RawGtInfo {
    visib_fract: f64,
}

/// Reads the visible fractions of `scene_gt_info.json`, checked against
/// the scene's annotations (same images, same instance counts).
pub fn read_scene_gt_info(path: &Path, gt: &BTreeMap<u32, Vec<GtInstance>>) -> Result<BTreeMap<u32, Vec<f64>>> {
    let raw: BTreeMap<String, Vec<RawGtInfo>> = read_json(path)?;
    let mut out = BTreeMap::new();
    for (key, list) in raw {
        let im = parse_id(path, &key, "an image")?;
        let fr: Vec<f64> = list.iter().map(|i| i.visib_fract).collect();
        if let Some(v) = fr.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(Error::BadJson { path: path.to_path_buf(), reason: format!("image {im}: visib_fract {v} is not a fraction in [0, 1]") });
        }
        if let Some(g) = gt.get(&im) {
            if g.len() != fr.len() {
                return Err(Error::BadJson {
                    path: path.to_path_buf(),
                    reason: format!("image {im} has {} entries but scene_gt.json annotates {} instances", fr.len(), g.len()),
                });
            }
        }
        out.insert(im, fr);
    }
    Ok(out)
}

#[derive(Deserialize)]
struct RawTarget {
    scene_id: u32,
    im_id: u32,
    obj_id: Option<u32>,
    inst_count: Option<u32>,
}

/// Every annotated instance of an image as targets: per object, its
/// instance count.
fn instance_targets(scene_id: u32, im_id: u32, insts: &[GtInstance]) -> Vec<Target> {
    let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
    for g in insts {
        *counts.entry(g.obj_id).or_default() += 1;
    }
    counts.into_iter().map(|(obj_id, inst_count)| Target { scene_id, im_id, obj_id, inst_count }).collect()
}

/// The targets of a file that names images only (BOP'24's
/// `test_targets_bop24.json`: `{scene_id, im_id}`): every annotated
/// instance of those images, as without a targets file.
fn image_targets(path: &Path, ds: &Dataset, raw: &[RawTarget]) -> Result<Vec<Target>> {
    let mut scenes: BTreeMap<u32, Scene> = BTreeMap::new();
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for (i, t) in raw.iter().enumerate() {
        let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason: format!("entry {i}: {reason}") }.about(Input::Targets);
        if !seen.insert((t.scene_id, t.im_id)) {
            return Err(bad(format!("scene {}, image {} is listed twice", t.scene_id, t.im_id)));
        }
        let scene = match scenes.entry(t.scene_id) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => e.insert(ds.scene(t.scene_id)?),
        };
        let insts = scene.gt.get(&t.im_id).ok_or_else(|| bad(format!("image {} of scene {} is not annotated", t.im_id, t.scene_id)))?;
        out.extend(instance_targets(t.scene_id, t.im_id, insts));
    }
    Ok(out)
}

/// Reads a BOP targets file (`test_targets_bop19.json`): a list of
/// `{scene_id, im_id, obj_id, inst_count}`. Objects must be in the dataset.
/// A list of `{scene_id, im_id}` alone (BOP'24's `test_targets_bop24.json`)
/// makes every annotated instance of those images a target.
pub fn read_targets(path: &Path, ds: &Dataset) -> Result<Vec<Target>> {
    Ok(read_targets_file(path, ds)?.0)
}

/// [`read_targets`], and whether the file names images only.
fn read_targets_file(path: &Path, ds: &Dataset) -> Result<(Vec<Target>, bool)> {
    let raw: Vec<RawTarget> = read_json_capped(path, MAX_TARGETS_BYTES).map_err(|e| e.about(Input::Targets))?;
    if !raw.is_empty() && raw.iter().all(|t| t.obj_id.is_none()) {
        return Ok((image_targets(path, ds, &raw)?, true));
    }
    let mut seen = std::collections::HashMap::new();
    let mut out = Vec::with_capacity(raw.len());
    for (i, t) in raw.iter().enumerate() {
        let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason: format!("entry {i}: {reason}") }.about(Input::Targets);
        let obj_id = t.obj_id.ok_or_else(|| bad("no obj_id (other entries have one)".into()))?;
        let inst_count = t.inst_count.ok_or_else(|| bad("no inst_count (needed by the BOP'19 protocol)".into()))?;
        if inst_count == 0 {
            return Err(bad("inst_count is 0".into()));
        }
        if !ds.models_info.contains_key(&obj_id) {
            return Err(bad(format!("object {obj_id} is not in models_info.json")));
        }
        if let Some(j) = seen.insert((t.scene_id, t.im_id, obj_id), i) {
            return Err(bad(format!("scene {}, image {}, object {obj_id} is already entry {j}", t.scene_id, t.im_id)));
        }
        out.push(Target { scene_id: t.scene_id, im_id: t.im_id, obj_id, inst_count });
    }
    Ok((out, false))
}
