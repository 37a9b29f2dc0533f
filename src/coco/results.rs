//! BOP'22 COCO results files: a JSON list (`.json`, or gzipped `.json.gz`)
//! of `{"scene_id", "image_id", "category_id", "score", "bbox": [x, y, w,
//! h], "segmentation": {"counts", "size": [h, w]}, "time"}`, read as the
//! BOP toolkit's `check_coco_results` checks them (ids integers, score a
//! number), with the masks kept encoded until they are needed.

use std::io::Read;
use std::path::Path;

use serde::Deserialize;

use super::rle::Rle;
use crate::error::{Error, Result};

/// A mask of a result as written: compressed string or counts.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum Counts {
    Compressed(String),
    Runs(Vec<u32>),
}

/// A result's `segmentation` (RLE only: the BOP format asks for RLE and
/// polygons would need pycocotools' own rasteriser to agree bit for bit).
#[derive(Clone, Debug, Deserialize)]
pub struct Segmentation {
    pub counts: Counts,
    /// `[height, width]`.
    pub size: [u32; 2],
}

impl Segmentation {
    pub fn decode(&self) -> std::result::Result<Rle, String> {
        let [h, w] = self.size;
        match &self.counts {
            Counts::Compressed(s) => Rle::from_compressed(s, h, w),
            Counts::Runs(c) => Rle::from_counts(c.clone(), h, w),
        }
    }
}

/// One 2D detection or segmentation.
#[derive(Clone, Debug)]
pub struct CocoResult {
    pub scene_id: u32,
    pub image_id: u32,
    pub category_id: u32,
    pub score: f64,
    /// `[x, y, w, h]` in pixels, `None` when absent or empty.
    pub bbox: Option<[f64; 4]>,
    pub segmentation: Option<Segmentation>,
    /// Seconds for the whole image; `None` when absent (or negative: the
    /// toolkit's "unknown").
    pub time: Option<f64>,
}

#[derive(Deserialize)]
struct Raw {
    scene_id: u32,
    image_id: u32,
    category_id: u32,
    score: f64,
    #[serde(default)]
    bbox: Option<Vec<f64>>,
    #[serde(default)]
    segmentation: Option<serde_json::Value>,
    #[serde(default)]
    time: Option<f64>,
}

/// Reads a results file. Every result is checked here, before anything is
/// evaluated: a bad one is refused with its index.
pub fn read_coco_results(path: &Path) -> Result<Vec<CocoResult>> {
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let name = path.to_string_lossy();
    if !(name.ends_with(".json") || name.ends_with(".json.gz")) {
        return Err(bad("a COCO results file ends in .json or .json.gz (BOP's format for 2D detection and segmentation)".into()));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader: Box<dyn Read> = if name.ends_with(".gz") {
        Box::new(flate2::read::GzDecoder::new(std::io::BufReader::new(file)))
    } else {
        Box::new(std::io::BufReader::new(file))
    };
    let raw: Vec<Raw> = serde_json::from_reader(reader).map_err(|e| bad(format!("not a list of BOP COCO results: {e}")))?;
    raw.into_iter().enumerate().map(|(i, r)| convert(r).map_err(|e| bad(format!("result {i}: {e}")))).collect()
}

fn convert(r: Raw) -> std::result::Result<CocoResult, String> {
    if !r.score.is_finite() {
        return Err(format!("score {} is not a finite number", r.score));
    }
    let bbox = match r.bbox {
        None => None,
        Some(b) if b.is_empty() => None,
        Some(b) => {
            let b: [f64; 4] = b.as_slice().try_into().map_err(|_| format!("bbox has {} numbers, not 4 ([x, y, width, height])", b.len()))?;
            if b.iter().any(|v| !v.is_finite()) {
                return Err(format!("bbox {b:?} is not finite"));
            }
            Some(b)
        }
    };
    let segmentation = match r.segmentation {
        None | Some(serde_json::Value::Null) => None,
        Some(serde_json::Value::Object(o)) if o.is_empty() => None,
        Some(serde_json::Value::Array(_)) => {
            return Err("segmentation is a polygon list; BOP results hold masks as RLE ({\"counts\", \"size\"}, e.g. pycocotools.mask.encode)".into())
        }
        Some(v) => {
            let s: Segmentation = serde_json::from_value(v).map_err(|e| format!("segmentation is not RLE ({{\"counts\", \"size\": [h, w]}}): {e}"))?;
            if s.size[0] == 0 || s.size[1] == 0 {
                return Err(format!("segmentation size {:?} is empty", s.size));
            }
            Some(s)
        }
    };
    let time = match r.time {
        Some(t) if !t.is_finite() => return Err(format!("time {t} is not finite")),
        Some(t) if t >= 0.0 => Some(t),
        _ => None,
    };
    Ok(CocoResult { scene_id: r.scene_id, image_id: r.image_id, category_id: r.category_id, score: r.score, bbox, segmentation, time })
}
