//! The COCO ground truth of a scene's target images: the dataset's own
//! `scene_gt_coco.json` (`scene_gt_coco_modal.json` for modal boxes) when
//! it has one, as `eval_bop22_coco.py` reads it; otherwise built from the
//! masks exactly as the toolkit's `calc_gt_coco.py` builds that file (the
//! visible mask's RLE and pixel count, the box of the full mask (amodal)
//! or of the visible mask (modal), instances under 10 % visible marked
//! ignored, empty masks left out).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Deserialize;

use super::rle::Rle;
use super::results::MaybeSegm;
use super::BoxKind;
use crate::bop::Scene;
use crate::error::{Error, Result};
use crate::observation::read_mask_png;

/// BOP marks instances visible less than this fraction as ignored.
pub const IGNORE_VISIB_BELOW: f64 = 0.1;

/// One ground-truth instance.
#[derive(Clone, Debug)]
pub struct GtAnn {
    pub id: i64,
    pub category_id: u32,
    pub area: f64,
    pub bbox: [f64; 4],
    pub crowd: bool,
    pub ignore: bool,
    /// The visible mask (decoded only when masks are evaluated).
    pub mask: Option<Rle>,
}

/// One target image's ground truth.
#[derive(Clone, Debug)]
pub struct GtImage {
    pub im_id: u32,
    pub width: u32,
    pub height: u32,
    pub anns: Vec<GtAnn>,
}

/// Where a scene's ground truth came from.
#[derive(Clone, Debug, PartialEq)]
pub enum GtSource {
    /// The file, with the category ids it lists (COCOeval scores those).
    File { path: PathBuf, categories: Option<Vec<u32>> },
    /// The masks; `full`: boxes (and the check for empty silhouettes) from
    /// the full masks (`mask/`) too.
    Masks { full: bool },
}

/// The scene's COCO ground-truth file for these boxes.
pub fn gt_file(scene: &Scene, boxes: BoxKind) -> PathBuf {
    scene.file(match boxes {
        BoxKind::Amodal => "scene_gt_coco",
        BoxKind::Modal => "scene_gt_coco_modal",
    })
}

/// The ground truth of `images` (ascending) of a scene; masks decoded when
/// `masks`.
pub fn scene_gt(scene: &Scene, images: &BTreeSet<u32>, boxes: BoxKind, masks: bool) -> Result<(Vec<GtImage>, GtSource)> {
    let file = gt_file(scene, boxes);
    if file.is_file() {
        let (gt, categories) = from_file(&file, images, masks)?;
        return Ok((gt, GtSource::File { path: file, categories }));
    }
    let full = boxes == BoxKind::Amodal && (!masks || scene.mask_dir().is_dir());
    Ok((from_masks(scene, images, full, masks)?, GtSource::Masks { full }))
}

#[derive(Deserialize)]
struct FileImage {
    id: u32,
    width: u32,
    height: u32,
}

#[derive(Deserialize)]
struct FileAnn {
    id: i64,
    image_id: u32,
    category_id: u32,
    #[serde(default)]
    iscrowd: serde_json::Value,
    #[serde(default)]
    ignore: serde_json::Value,
    area: f64,
    bbox: [f64; 4],
    #[serde(default)]
    segmentation: MaybeSegm,
}

#[derive(Deserialize)]
struct FileCategory {
    id: u32,
}

#[derive(Deserialize)]
struct FileGt {
    images: Vec<FileImage>,
    annotations: Vec<FileAnn>,
    #[serde(default)]
    categories: Option<Vec<FileCategory>>,
}

/// Python truthiness of a JSON flag (absent, false, 0 and null are false).
fn truthy(v: &serde_json::Value) -> bool {
    match v {
        serde_json::Value::Null => false,
        serde_json::Value::Bool(b) => *b,
        serde_json::Value::Number(n) => n.as_f64().is_some_and(|x| x != 0.0),
        serde_json::Value::String(s) => !s.is_empty(),
        serde_json::Value::Array(a) => !a.is_empty(),
        serde_json::Value::Object(o) => !o.is_empty(),
    }
}

fn from_file(path: &Path, images: &BTreeSet<u32>, masks: bool) -> Result<(Vec<GtImage>, Option<Vec<u32>>)> {
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let f: FileGt = serde_json::from_str(&text).map_err(|e| bad(format!("not a COCO annotation file: {e}")))?;
    let mut out: Vec<GtImage> = Vec::new();
    for &im in images {
        let Some(i) = f.images.iter().find(|i| i.id == im) else {
            return Err(bad(format!(
                "image {im} of the targets is not in it (made for other targets? delete it and plausible builds the ground truth from the masks)"
            )));
        };
        out.push(GtImage { im_id: im, width: i.width, height: i.height, anns: Vec::new() });
    }
    let mut ids = BTreeSet::new();
    for (n, a) in f.annotations.into_iter().enumerate() {
        let Ok(slot) = out.binary_search_by_key(&a.image_id, |g| g.im_id) else { continue };
        if !ids.insert(a.id) {
            return Err(bad(format!("annotation {n}: id {} is used twice (pycocotools would keep only the last)", a.id)));
        }
        let img = &out[slot];
        let mask = match (&a.segmentation.0, masks) {
            (Some(s), true) => {
                let r = s.decode().map_err(|e| bad(format!("annotation {n}: {e}")))?;
                if (r.h, r.w) != (img.height, img.width) {
                    return Err(bad(format!("annotation {n}: mask is {}x{} but image {} is {}x{}", r.w, r.h, img.im_id, img.width, img.height)));
                }
                Some(r)
            }
            (None, true) => return Err(bad(format!("annotation {n} has no segmentation"))),
            _ => None,
        };
        if !a.area.is_finite() || a.bbox.iter().any(|v| !v.is_finite()) {
            return Err(bad(format!("annotation {n}: area or bbox is not finite")));
        }
        out[slot].anns.push(GtAnn {
            id: a.id,
            category_id: a.category_id,
            area: a.area,
            bbox: a.bbox,
            crowd: truthy(&a.iscrowd),
            ignore: truthy(&a.ignore),
            mask,
        });
    }
    Ok((out, f.categories.map(|c| c.into_iter().map(|c| c.id).collect())))
}

/// `[x, y, w, h]` of the set pixels of a row-major mask, `None` when empty.
fn mask_box(mask: &[bool], w: u32) -> Option<[f64; 4]> {
    let w = w as usize;
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        let (x, y) = (i % w, i / w);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    (x0 != usize::MAX).then(|| [x0 as f64, y0 as f64, (x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64])
}

/// `read_full`: amodal boxes from the full masks, and instances whose full
/// mask is empty left out (the toolkit does this for masks alone too,
/// where it has the full masks).
fn from_masks(scene: &Scene, images: &BTreeSet<u32>, read_full: bool, masks: bool) -> Result<Vec<GtImage>> {
    let info = scene.gt_info.as_ref().ok_or_else(|| Error::NotFound { path: scene.file("scene_gt_info") })?;
    let full_dir = scene.mask_dir();
    let per_image: Vec<Result<GtImage>> = images
        .par_iter()
        .map(|&im| {
            let insts = scene.gt.get(&im).ok_or_else(|| {
                Error::InvalidInput(format!("{}: image {im} of the targets is not annotated", scene.file("scene_gt").display()))
            })?;
            let (width, height) = scene.image_size(im)?;
            let mut anns = Vec::new();
            for (k, inst) in insts.iter().enumerate() {
                let visib = read_mask_png(&scene.mask_visib_dir().join(format!("{im:06}_{k:06}.png")), width, height)?;
                let area = visib.iter().filter(|&&m| m).count();
                if area == 0 {
                    continue;
                }
                let bbox = if read_full {
                    let full = read_mask_png(&full_dir.join(format!("{im:06}_{k:06}.png")), width, height)?;
                    match mask_box(&full, width) {
                        None => continue,
                        Some(b) => b,
                    }
                } else {
                    mask_box(&visib, width).expect("not empty")
                };
                let fract = info.get(&im).and_then(|v| v.get(k)).copied().ok_or_else(|| Error::BadJson {
                    path: scene.file("scene_gt_info"),
                    reason: format!("image {im}: no visib_fract for instance {k}"),
                })?;
                anns.push(GtAnn {
                    id: 0,
                    category_id: inst.obj_id,
                    area: area as f64,
                    bbox,
                    crowd: false,
                    ignore: fract < IGNORE_VISIB_BELOW,
                    mask: masks.then(|| Rle::from_mask(&visib, width, height)),
                });
            }
            Ok(GtImage { im_id: im, width, height, anns })
        })
        .collect();
    let mut out = per_image.into_iter().collect::<Result<Vec<_>>>()?;
    // Ids as calc_gt_coco.py numbers them: from 1, in image order.
    for (a, id) in out.iter_mut().flat_map(|g| g.anns.iter_mut()).zip(1..) {
        a.id = id;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_of_masks() {
        let m = [false, false, false, false, true, true, false, true, false];
        assert_eq!(mask_box(&m, 3), Some([1.0, 1.0, 2.0, 2.0]));
        assert_eq!(mask_box(&[false; 4], 2), None);
    }

    #[test]
    fn python_truthiness() {
        for (v, t) in [("null", false), ("0", false), ("1", true), ("true", true), ("false", false), ("0.0", false), ("\"\"", false)] {
            assert_eq!(truthy(&serde_json::from_str(v).unwrap()), t, "{v}");
        }
    }
}
