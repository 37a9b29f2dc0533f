//! The observed frame: depth (BOP 16-bit PNG), the object's mask, camera
//! intrinsics (BOP `scene_camera.json` entry), metric normals from depth, and
//! the region of interest that hypotheses are scored in.

use std::path::Path;

use glam::{DVec3, Vec3};
use serde::Deserialize;

use crate::camera::Intrinsics;
use crate::error::{Error, Input, Result};

/// A depth image in metres (0 = no measurement) with its intrinsics.
#[derive(Clone, Debug)]
pub struct DepthImage {
    pub intrinsics: Intrinsics,
    /// Row-major, `width * height` values, metres.
    pub depth: Vec<f32>,
}

impl DepthImage {
    /// A depth image from values in metres (0 or NaN = no measurement; a
    /// library caller's arrays), checked like a depth file: the size against
    /// `intrinsics`, the intrinsics against the size, no negative or
    /// infinite value, at least one measurement, nothing beyond 100 m.
    pub fn from_metres(intrinsics: Intrinsics, mut depth: Vec<f32>) -> Result<DepthImage> {
        let bad = |reason: String| Error::InvalidInput(format!("depth: {reason}"));
        let (w, h) = (intrinsics.width, intrinsics.height);
        if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
            return Err(bad(format!("{w}x{h} pixels: each side must lie in 1..={MAX_IMAGE_SIDE}")));
        }
        if depth.len() != intrinsics.pixels() {
            return Err(bad(format!("{} values for a {w}x{h} image", depth.len())));
        }
        intrinsics.check_against_image().map_err(|r| Error::BadCamera { what: "K".into(), reason: r })?;
        for (i, d) in depth.iter_mut().enumerate() {
            if d.is_nan() {
                *d = 0.0;
            } else if *d < 0.0 || !d.is_finite() {
                return Err(bad(format!("pixel ({}, {}) is {d}: depth must be 0 (none) or a positive finite distance", i % w as usize, i / w as usize)));
            }
        }
        let dmax = depth.iter().cloned().fold(0.0f32, f32::max);
        if dmax == 0.0 {
            return Err(bad("no valid (non-zero) pixel".into()));
        }
        if dmax > 100.0 {
            return Err(bad(format!("largest depth is {dmax:.0} m: are the values in millimetres? (give units=\"mm\")")));
        }
        let median = median_depth(&depth);
        if median < MIN_MEDIAN_DEPTH_M {
            return Err(bad(format!("median depth is {:.1} mm: no depth camera sees a scene that close; are the values in another unit than metres?", median * 1e3)));
        }
        Ok(DepthImage { intrinsics, depth })
    }
}

/// A median measured depth below this (metres) is no real depth image but
/// one read in the wrong unit or with the wrong depth_scale (depth cameras
/// see from about 10 cm): it would put the support plane and every point
/// 10-1000 times too close, and score every pose zero without a word.
pub const MIN_MEDIAN_DEPTH_M: f32 = 0.05;

/// The colour type in a PNG's header (0 grey, 4 grey with alpha, ...),
/// `None` for a file that is no PNG. The decoder gives a grey PNG with a
/// transparent value (tRNS chunk) an alpha channel too; only the header
/// tells the two apart.
fn png_colour_type(path: &Path) -> Option<u8> {
    use std::io::Read;
    let mut head = [0u8; 26];
    std::fs::File::open(path).ok()?.read_exact(&mut head).ok()?;
    (head[..8] == *b"\x89PNG\r\n\x1a\n" && head[12..16] == *b"IHDR").then_some(head[25])
}

/// Refuses depth read with a wrong `depth_scale`: a largest depth beyond
/// 100 m or a median under [`MIN_MEDIAN_DEPTH_M`]. `depth` holds values in
/// units of `metres_per_unit` (1 for metres, 1e-3 for millimetres); an image
/// without a measurement passes (its reader decides). Returns the reason.
pub(crate) fn check_depth_scale(depth: &[f32], metres_per_unit: f32, depth_scale: f64) -> std::result::Result<(), String> {
    let dmax = depth.iter().cloned().fold(0.0f32, f32::max) * metres_per_unit;
    if dmax > 100.0 {
        return Err(format!("largest depth is {dmax:.0} m: depth_scale {depth_scale} looks wrong (value x depth_scale must be millimetres)"));
    }
    let median = median_depth(depth) * metres_per_unit;
    if dmax > 0.0 && median < MIN_MEDIAN_DEPTH_M {
        return Err(format!(
            "median depth is {:.1} mm, closer than any depth camera sees a scene: depth_scale {depth_scale} looks wrong (value x depth_scale must be millimetres)",
            median * 1e3
        ));
    }
    Ok(())
}

/// The median of the measured (non-zero) depths, over at most about 16k
/// pixels spread evenly over the image (a plausibility check; reading
/// every image of a dataset should not pay for a full sort); 0 when there
/// is none.
fn median_depth(depth: &[f32]) -> f32 {
    let stride = (depth.len() / 16_384).max(1);
    let mut valid: Vec<f32> = depth.iter().step_by(stride).copied().filter(|&d| d > 0.0).collect();
    if valid.is_empty() {
        valid = depth.iter().copied().filter(|&d| d > 0.0).collect();
    }
    if valid.is_empty() {
        return 0.0;
    }
    let mid = valid.len() / 2;
    *valid.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Checks a mask given as data (not a file) against its depth image: the
/// same size, and at least one object pixel.
pub fn check_mask(mask: &[bool], width: u32, height: u32) -> Result<()> {
    if mask.len() != width as usize * height as usize {
        return Err(Error::InvalidInput(format!("the mask has {} pixels, the depth image {width}x{height}", mask.len())));
    }
    if !mask.iter().any(|&m| m) {
        return Err(Error::InvalidInput("the mask is empty: it marks no pixel of the object".into()));
    }
    Ok(())
}

/// Camera entry in BOP `scene_camera.json` form.
#[derive(Clone, Debug, Deserialize)]
pub struct BopCamera {
    #[serde(rename = "cam_K")]
    pub cam_k: Vec<f64>,
    pub depth_scale: f64,
    /// The image size, where the file states it (a dataset `camera.json`
    /// does): the depth image must have it.
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
}

/// The dataset-level BOP `camera.json`: `fx, fy, cx, cy, width, height,
/// depth_scale`.
#[derive(Deserialize)]
struct DatasetCamera {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    depth_scale: f64,
    #[serde(default)]
    width: Option<u32>,
    #[serde(default)]
    height: Option<u32>,
}

/// Reads a camera JSON: one BOP `scene_camera.json` entry (`{"cam_K":
/// [...], "depth_scale": s}`), a BOP dataset `camera.json` (`fx, fy, cx, cy,
/// width, height, depth_scale`), or a whole `scene_camera.json` from which
/// `frame` picks the entry (optional when it holds one entry; a frame id
/// that the file does not hold is an error, never ignored).
pub fn read_camera(path: &Path, frame: Option<&str>) -> Result<BopCamera> {
    read_camera_file(path, frame).map(|(cam, _)| cam)
}

/// What a camera file holds: one camera, or a `scene_camera.json` of frames.
/// A caller given a frame id for a single camera has nothing to pick, and
/// says so rather than ignoring the id.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraFile {
    /// One BOP camera entry or a dataset `camera.json`.
    Single,
    /// A `scene_camera.json` keyed by frame id.
    Frames,
}

/// [`read_camera`], also saying which kind of file it read.
pub fn read_camera_file(path: &Path, frame: Option<&str>) -> Result<(BopCamera, CameraFile)> {
    let text = crate::io::read_to_string_capped(path, MAX_CAMERA_FILE_BYTES, "camera file")?;
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
    // A bare camera has no frames: a frame id (which may pick poses from a
    // scene_gt.json) does not concern it. In a scene_camera.json the id
    // must exist, even when the file holds one frame.
    let single = v.get("cam_K").is_some() || v.get("fx").is_some();
    if v.get("cam_K").is_some() && v.get("fx").is_some() {
        return Err(bad("holds both cam_K and fx, fy, cx, cy: which camera is meant? Keep one".into()));
    }
    let cam = if v.get("fx").is_some() {
        let c: DatasetCamera = serde_json::from_value(v)
            .map_err(|e| bad(format!("{e}; a BOP camera.json has fx, fy, cx, cy, width, height and depth_scale")))?;
        BopCamera { cam_k: vec![c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0], depth_scale: c.depth_scale, width: c.width, height: c.height }
    } else {
        let entry = if single {
            v
        } else if let Some(map) = v.as_object() {
            match frame {
                Some(f) => map.get(f).cloned().ok_or_else(|| bad(format!("no frame '{f}' in the file")).about(Input::Selection))?,
                None if map.len() == 1 => map.values().next().cloned().unwrap(),
                None => {
                    return Err(bad(format!(
                        "holds {} frames; pick one by its id (e.g. {})",
                        map.len(),
                        map.keys().next().map(String::as_str).unwrap_or("0")
                    ))
                    .about(Input::Selection))
                }
            }
        } else {
            return Err(bad("expected a BOP camera entry {\"cam_K\": [9 numbers], \"depth_scale\": s}".into()));
        };
        serde_json::from_value(entry)
            .map_err(|e| bad(format!("{e}; expected {{\"cam_K\": [9 numbers], \"depth_scale\": s}} (depth_scale: PNG value x depth_scale = mm)")))?
    };
    if !(cam.depth_scale.is_finite() && cam.depth_scale > 0.0) {
        return Err(bad(format!("depth_scale must be positive, got {}", cam.depth_scale)));
    }
    if !(MIN_DEPTH_SCALE..=MAX_DEPTH_SCALE).contains(&cam.depth_scale) {
        return Err(bad(format!(
            "depth_scale {} is not a plausible scale from PNG values to millimetres (expected {MIN_DEPTH_SCALE} to {MAX_DEPTH_SCALE}, usually 0.1 or 1)",
            cam.depth_scale
        )));
    }
    // K on its own (its fit to the image size is checked with the depth).
    Intrinsics::from_k(&cam.cam_k, 1, 1).map_err(|e| bad(e.to_string()))?;
    Ok((cam, if single { CameraFile::Single } else { CameraFile::Frames }))
}

/// Largest camera file read (256 MiB): a `scene_camera.json` of a hundred
/// thousand frames is about 30 MB.
pub const MAX_CAMERA_FILE_BYTES: u64 = 256 << 20;

/// Plausible `depth_scale` range (PNG value × scale = mm).
pub const MIN_DEPTH_SCALE: f64 = 1e-3;
pub const MAX_DEPTH_SCALE: f64 = 100.0;

/// Size of a PNG from its header, refusing images above [`MAX_IMAGE_SIDE`]
/// before anything is decoded.
pub fn png_size(path: &Path) -> Result<(u32, u32)> {
    let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
    // A PNG is opened twice (header, then pixels), which a pipe cannot
    // serve, and a FIFO without a writer blocks the open for ever.
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(bad("not a regular file (an image is read from a file, not a pipe or device)".into()));
    }
    let reader = image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    let (w, h) = reader.into_dimensions().map_err(|e| bad(e.to_string()))?;
    if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(bad(format!("image is {w}x{h}; 1 to {MAX_IMAGE_SIDE} pixels a side are read")));
    }
    Ok((w, h))
}

/// Reads a BOP depth PNG (16-bit, `value * depth_scale` = millimetres). The
/// intrinsics are checked against the image size: a principal point far
/// outside the image or an absurd focal length means the camera belongs to
/// another image.
pub fn read_depth_png(path: &Path, cam: &BopCamera) -> Result<DepthImage> {
    let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
    if !path.exists() {
        return Err(Error::NotFound { path: path.to_path_buf() });
    }
    let (w, h) = png_size(path)?;
    for (what, stated, got) in [("width", cam.width, w), ("height", cam.height, h)] {
        if stated.is_some_and(|s| s != got) {
            return Err(bad(format!("the depth image's {what} is {got} px, but the camera states {} px: is the camera for another image?", stated.unwrap_or(0))));
        }
    }
    let intrinsics = Intrinsics::from_k(&cam.cam_k, w, h)?;
    intrinsics.check_against_image().map_err(bad)?;
    let img = image::open(path).map_err(|e| bad(e.to_string()))?;
    let img = match img {
        image::DynamicImage::ImageLuma16(i) => i,
        // A grey PNG with a tRNS chunk (one depth value marked
        // transparent) comes out of the decoder with an alpha channel;
        // the grey values are the depth, unchanged.
        image::DynamicImage::ImageLumaA16(i) if png_colour_type(path) == Some(0) => {
            let luma: Vec<u16> = i.as_raw().chunks_exact(2).map(|p| p[0]).collect();
            image::ImageBuffer::from_raw(i.width(), i.height(), luma).ok_or_else(|| bad("depth image buffer of the wrong size".into()))?
        }
        other => {
            return Err(bad(format!(
                "depth must be a 16-bit single-channel PNG (BOP convention), got {:?}{}",
                other.color(),
                if other.color() == image::ColorType::La16 { " (an alpha channel, which a depth image has no use for)" } else { "" }
            )))
        }
    };
    let s = (cam.depth_scale * 1e-3) as f32;
    let depth: Vec<f32> = img.as_raw().iter().map(|&v| v as f32 * s).collect();
    if depth.iter().all(|&d| d == 0.0) {
        return Err(bad("depth image has no valid (non-zero) pixel".into()));
    }
    check_depth_scale(&depth, 1.0, cam.depth_scale).map_err(bad)?;
    Ok(DepthImage { intrinsics, depth })
}

/// Reads an 8-bit mask PNG (non-zero = object) of the given size.
pub fn read_mask_png(path: &Path, width: u32, height: u32) -> Result<Vec<bool>> {
    let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
    if !path.exists() {
        return Err(Error::NotFound { path: path.to_path_buf() });
    }
    let (mw, mh) = png_size(path)?;
    if (mw, mh) != (width, height) {
        return Err(bad(format!("mask is {mw}x{mh} but the image is {width}x{height}")));
    }
    let img = image::open(path).map_err(|e| bad(e.to_string()))?;
    // A 16-bit or float PNG is a depth image, not a mask (BOP masks are
    // 8-bit, 0 or 255): thresholding it at zero would take every pixel
    // with depth as the object.
    if img.color().bytes_per_pixel() > img.color().channel_count() {
        return Err(bad(format!("a mask is an 8-bit PNG (0 = background), this one has {} bits a channel: a depth image?", 8 * img.color().bytes_per_pixel() / img.color().channel_count())));
    }
    // BOP's masks are 8-bit grey: no conversion.
    if let Some(g) = img.as_luma8().filter(|g| g.dimensions() == (width, height)) {
        return Ok(g.as_raw().iter().map(|&v| v != 0).collect());
    }
    // Any colour channel non-zero is the object: the luma of a colour mask
    // rounds dark colours such as (0, 0, 3) to 0. Alpha is not the mask.
    let img = img.to_rgb8();
    if img.dimensions() != (width, height) {
        return Err(bad(format!(
            "mask is {}x{} but the image is {width}x{height}",
            img.width(),
            img.height()
        )));
    }
    Ok(img.pixels().map(|p| p.0 != [0, 0, 0]).collect())
}

/// Largest margin of the region around the mask (fraction of its size).
pub const MAX_ROI_MARGIN: f64 = 10.0;
/// Largest resampled region side (pixels): 4096² pixels hold 1.3 GB of
/// per-pixel data per visibility slot and image.
pub const MAX_ROI_SIDE: u32 = 4096;
/// Largest depth or mask image side read (pixels), checked from the PNG
/// header before decoding: a 4096² frame holds about 1 GB of depth,
/// normals and masks; an 8000² one took 3.3 GB.
pub const MAX_IMAGE_SIDE: u32 = 4096;

/// Depth jump (metres) between neighbours above which they are taken to lie
/// on different surfaces, so no normal is estimated across them.
pub const NORMAL_JUMP_M: f32 = 0.02;

/// Camera-frame unit normals of a depth image, from back-projected 3D points
/// (metric and focal-length aware, unlike pixel gradients of raw depth).
///
/// Each tangent is a Sobel-weighted sum (rows 1-2-1) of central differences
/// of 3D points; where a neighbour is missing or lies across a depth jump of
/// more than [`NORMAL_JUMP_M`], the one-sided difference is used, and a pixel
/// without any usable pair gets no normal (zero vector). Normals face the
/// camera.
pub fn normals_from_depth(img: &DepthImage) -> Vec<Vec3> {
    let k = &img.intrinsics;
    let (w, h) = (k.width as i64, k.height as i64);
    let z = |x: i64, y: i64| -> f32 {
        if x < 0 || y < 0 || x >= w || y >= h {
            0.0
        } else {
            img.depth[(y * w + x) as usize]
        }
    };
    let point = |x: i64, y: i64| -> DVec3 { k.ray(x as f64, y as f64) * z(x, y) as f64 };
    let mut out = vec![Vec3::ZERO; img.depth.len()];
    for y in 0..h {
        for x in 0..w {
            let zc = z(x, y);
            if zc <= 0.0 {
                continue;
            }
            let ok = |xx: i64, yy: i64| {
                let d = z(xx, yy);
                d > 0.0 && (d - zc).abs() < NORMAL_JUMP_M
            };
            // Difference along (dx, dy) at offset (ox, oy) across the stencil.
            let diff = |ox: i64, oy: i64, dx: i64, dy: i64| -> Option<DVec3> {
                let (cx, cy) = (x + ox, y + oy);
                if !ok(cx, cy) {
                    return None;
                }
                let (f, b) = ((cx + dx, cy + dy), (cx - dx, cy - dy));
                match (ok(f.0, f.1), ok(b.0, b.1)) {
                    (true, true) => Some((point(f.0, f.1) - point(b.0, b.1)) * 0.5),
                    (true, false) => Some(point(f.0, f.1) - point(cx, cy)),
                    (false, true) => Some(point(cx, cy) - point(b.0, b.1)),
                    _ => None,
                }
            };
            let mut tx = DVec3::ZERO;
            let mut ty = DVec3::ZERO;
            let mut nx = 0;
            let mut ny = 0;
            for (o, wgt) in [(-1i64, 1.0), (0, 2.0), (1, 1.0)] {
                if let Some(d) = diff(0, o, 1, 0) {
                    tx += d * wgt;
                    nx += 1;
                }
                if let Some(d) = diff(o, 0, 0, 1) {
                    ty += d * wgt;
                    ny += 1;
                }
            }
            if nx == 0 || ny == 0 {
                continue;
            }
            // x right, y down: tx × ty points away from the camera for a
            // surface facing it; flip so normals face the camera (n·z < 0).
            let mut n = tx.cross(ty);
            if n.length_squared() == 0.0 {
                continue;
            }
            n = n.normalize();
            if n.dot(point(x, y)) > 0.0 {
                n = -n;
            }
            out[(y * w + x) as usize] = n.as_vec3();
        }
    }
    out
}

/// How the scored region is sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RoiSampling {
    /// Resample the square around the mask to `res x res` pixels by scaling
    /// the intrinsics, clipped to the image (fewer pixels of that size where
    /// the square reaches past the border).
    Square(u32),
    /// Native pixels of the region.
    Native,
    /// The whole frame at native resolution.
    FullFrame,
}

/// The region of interest that hypotheses are rendered and scored in: its
/// intrinsics (a crop of the camera's) and the observed depth and normals
/// at its pixels, masked to the object.
#[derive(Clone, Debug)]
pub struct ScoreTarget {
    pub intrinsics: Intrinsics,
    /// Observed depth (m), 0 outside the mask or where not measured.
    pub depth: Vec<f32>,
    /// Observed unit normals, zero where unknown.
    pub normals: Vec<Vec3>,
    /// The crop in the original image: `(x0, y0, w, h)` in pixel-edge units.
    pub crop: (f64, f64, f64, f64),
    /// Depth (m) of the other objects' nearest surface per pixel, 0 where
    /// none; empty when the object is scored alone. A hypothesis pixel
    /// outside the mask that lies behind it is hidden by another object: it
    /// is not in V (the scene-level score, [`ScoreTarget::set_occluders`]).
    pub occluder: Vec<f32>,
}

/// Fraction by which the mask's bounding box is grown on each side.
pub const DEFAULT_ROI_MARGIN: f64 = 0.25;

impl ScoreTarget {
    /// Says when the poses' median distance along the optical axis and
    /// the observed depth of the scored region differ more than fourfold:
    /// one of them is in the wrong unit or scale (a `depth_scale` 10× too
    /// small, poses of another camera), and every hypothesis would score
    /// zero. A warning, not a refusal: the region may hold background.
    pub fn distance_mismatch(&self, poses: &[crate::pose::Pose]) -> Option<String> {
        let observed = median_depth(&self.depth);
        let posed = crate::pose::median(poses.iter().map(|p| p.t.z).collect())?;
        if observed <= 0.0 {
            return None;
        }
        let ratio = posed / observed as f64;
        (!(0.25..=4.0).contains(&ratio)).then(|| {
            format!(
                "the poses lie a median {:.0} mm from the camera, the observed depth of the object's region {:.0} mm: is the depth scale (or the poses' unit) right? Poses this far off the depth all score zero",
                posed * 1e3,
                observed * 1e3
            )
        })
    }

    /// Builds the scoring region from an observation. `mask` (same size as
    /// the depth) selects the object; without it the whole frame counts.
    pub fn new(obs: &DepthImage, mask: Option<&[bool]>, sampling: RoiSampling, margin: f64) -> Result<Self> {
        if !(margin.is_finite() && (0.0..=MAX_ROI_MARGIN).contains(&margin)) {
            return Err(Error::InvalidInput(format!(
                "the region's margin must lie in [0, {MAX_ROI_MARGIN}] (a fraction of the mask's size on each side), got {margin}"
            )));
        }
        if let RoiSampling::Square(n) = sampling {
            if n == 0 || n > MAX_ROI_SIDE {
                return Err(Error::InvalidInput(format!("the region's resolution must be 1 to {MAX_ROI_SIDE} pixels a side, got {n}")));
            }
        }
        let k = obs.intrinsics;
        let (w, h) = (k.width as usize, k.height as usize);
        let masked: Vec<f32> = match mask {
            Some(m) => {
                if m.len() != obs.depth.len() {
                    return Err(Error::InvalidInput("mask and depth differ in size".into()));
                }
                obs.depth.iter().zip(m).map(|(&d, &keep)| if keep { d } else { 0.0 }).collect()
            }
            None => obs.depth.clone(),
        };
        if !masked.iter().any(|&d| d > 0.0) {
            return Err(Error::InvalidInput(
                "the mask covers no pixel with valid depth: nothing to score".into(),
            ));
        }
        // Normals from the masked observation: across the silhouette the
        // neighbours are background, whose depth would tilt them.
        let normals_full = normals_from_depth(&DepthImage { intrinsics: k, depth: masked.clone() });
        // The crop, and for a square region the side of the square before
        // it was clipped to the image.
        let (crop, square_side) = match (sampling, mask) {
            (RoiSampling::FullFrame, _) | (_, None) => ((0.0, 0.0, w as f64, h as f64), None),
            (_, Some(m)) => {
                let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
                for (i, &keep) in m.iter().enumerate() {
                    if keep {
                        let (x, y) = (i % w, i / w);
                        x0 = x0.min(x);
                        y0 = y0.min(y);
                        x1 = x1.max(x + 1);
                        y1 = y1.max(y + 1);
                    }
                }
                let (bw, bh) = ((x1 - x0) as f64, (y1 - y0) as f64);
                let (cx, cy) = (0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64);
                match sampling {
                    RoiSampling::Square(_) => {
                        // Clipped to the image: past its border there is no
                        // sensor, and an object rendered there would count as
                        // rendered but not observed (a truncated object's true
                        // pose scored 0.38 instead of 0.87).
                        let side = bw.max(bh) * (1.0 + 2.0 * margin);
                        let (ax, ay) = ((cx - side / 2.0).max(0.0), (cy - side / 2.0).max(0.0));
                        let (bx, by) = ((cx + side / 2.0).min(w as f64), (cy + side / 2.0).min(h as f64));
                        ((ax, ay, bx - ax, by - ay), Some(side))
                    }
                    _ => {
                        // Native pixels: integer crop, clipped to the image.
                        let gx = (bw * margin).ceil();
                        let gy = (bh * margin).ceil();
                        let ax = (x0 as f64 - gx).max(0.0);
                        let ay = (y0 as f64 - gy).max(0.0);
                        let bx = (x1 as f64 + gx).min(w as f64);
                        let by = (y1 as f64 + gy).min(h as f64);
                        ((ax, ay, bx - ax, by - ay), None)
                    }
                }
            }
        };
        let (out_w, out_h) = match (sampling, square_side) {
            // `r` pixels along the square's side: a square clipped by the
            // image border keeps that pixel size and has fewer pixels.
            (RoiSampling::Square(r), Some(side)) => {
                let px = |len: f64| ((r as f64 * len / side).round() as u32).clamp(1, r);
                (px(crop.2), px(crop.3))
            }
            (RoiSampling::Square(r), None) => (r, r),
            _ => (crop.2 as u32, crop.3 as u32),
        };
        if out_w == 0 || out_h == 0 {
            return Err(Error::InvalidInput("region of interest is empty".into()));
        }
        let intrinsics = k.crop(crop.0, crop.1, crop.2, crop.3, out_w, out_h);
        let n = out_w as usize * out_h as usize;
        let mut depth = vec![0.0f32; n];
        let mut normals = vec![Vec3::ZERO; n];
        let (sx, sy) = (crop.2 / out_w as f64, crop.3 / out_h as f64);
        for v in 0..out_h as usize {
            // Nearest sample: the source pixel containing this pixel's centre.
            let ys = (crop.1 + (v as f64 + 0.5) * sy).floor();
            for u in 0..out_w as usize {
                let xs = (crop.0 + (u as f64 + 0.5) * sx).floor();
                if xs < 0.0 || ys < 0.0 || xs >= w as f64 || ys >= h as f64 {
                    continue;
                }
                let src = ys as usize * w + xs as usize;
                depth[v * out_w as usize + u] = masked[src];
                normals[v * out_w as usize + u] = normals_full[src];
            }
        }
        Ok(ScoreTarget { intrinsics, depth, normals, crop, occluder: Vec::new() })
    }

    /// Refuses a region none of whose samples holds an observed pixel:
    /// sparse depth (a few valid pixels far apart) can fall between the
    /// samples of a coarse region, and every hypothesis would score 0. For
    /// callers that score one object (a scene's refinement takes such an
    /// object as unobserved instead).
    pub fn check_observed(&self) -> Result<()> {
        if self.observed_pixels() > 0 {
            return Ok(());
        }
        Err(Error::InvalidInput(format!(
            "the {}x{} region samples none of the pixels with depth in its {:.0}x{:.0} source pixels (sparse depth or mask): score at native resolution or a finer region",
            self.intrinsics.width, self.intrinsics.height, self.crop.2, self.crop.3
        )))
    }

    /// Sets the depth of the other objects in the scene (one value per
    /// region pixel, 0 where none; e.g. their current estimates rendered
    /// with [`crate::kernels::render::render_cpu`] in [`Self::intrinsics`]):
    /// a hypothesis is then scored as part of the whole scene, its pixels
    /// hidden behind another object neither rendered nor in V. Pixels of
    /// the object's own mask are never hidden (the mask says it is in front).
    pub fn set_occluders(&mut self, depth: Vec<f32>) -> Result<()> {
        if depth.len() != self.depth.len() {
            return Err(Error::InvalidInput(format!(
                "the occluders' depth has {} pixels, the region {}",
                depth.len(),
                self.depth.len()
            )));
        }
        if depth.iter().any(|d| !(d.is_finite() && *d >= 0.0)) {
            return Err(Error::InvalidInput("the occluders' depth must be finite and non-negative".into()));
        }
        self.occluder = depth;
        Ok(())
    }

    /// Whether a hypothesis pixel `i` rendered at depth `d` is hidden by
    /// another object (not observed as this object, and behind the
    /// occluder's surface).
    #[inline]
    pub fn hidden(&self, i: usize, d: f32) -> bool {
        self.depth[i] <= 0.0 && self.occluder.get(i).is_some_and(|&o| o > 0.0 && d > o)
    }

    /// The observation as the `score` kernel reads it, one `vec4` per pixel:
    /// the normal in xyz and in w the observed depth, or where there is none
    /// the occluder's depth negated (0: neither).
    pub fn packed(&self) -> Vec<[f32; 4]> {
        (0..self.depth.len())
            .map(|i| {
                let n = self.normals[i];
                let d = self.depth[i];
                let w = if d > 0.0 { d } else { -self.occluder.get(i).copied().unwrap_or(0.0) };
                [n.x, n.y, n.z, w]
            })
            .collect()
    }

    /// Distance (metres) of the near side of the observed object: the 5th
    /// percentile of the region's observed depth (robust to a few stray
    /// pixels); `None` without any observed pixel.
    pub fn near_depth(&self) -> Option<f64> {
        let mut d: Vec<f32> = self.depth.iter().copied().filter(|&d| d > 0.0).collect();
        if d.is_empty() {
            return None;
        }
        let k = d.len() / 20;
        let (_, v, _) = d.select_nth_unstable_by(k, f32::total_cmp);
        Some(*v as f64)
    }

    /// Number of observed (valid, masked) pixels in the region.
    pub fn observed_pixels(&self) -> usize {
        self.depth.iter().filter(|&&d| d > 0.0).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_are_exact() {
        // A plane z = 0.5 + 0.2 x seen by a camera: normals are constant.
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 32.0, cy: 24.0, width: 64, height: 48 };
        let mut depth = vec![0.0f32; 64 * 48];
        for v in 0..48 {
            for u in 0..64 {
                let r = k.ray(u as f64, v as f64);
                // Solve z = 0.5 + 0.2 * x with x = r.x z.
                depth[v * 64 + u] = (0.5 / (1.0 - 0.2 * r.x)) as f32;
            }
        }
        let n = normals_from_depth(&DepthImage { intrinsics: k, depth });
        let expect = Vec3::new(0.2, 0.0, -1.0).normalize();
        for (i, nn) in n.iter().enumerate() {
            assert!(nn.dot(expect) > 0.99999, "pixel {i}: {nn:?}");
        }
    }
}
