//! BOP'22 COCO results files: a JSON list (`.json`, or gzipped `.json.gz`)
//! of `{"scene_id", "image_id", "category_id", "score", "bbox": [x, y, w,
//! h], "segmentation": {"counts", "size": [h, w]}, "time"}`, read as the
//! BOP toolkit's `check_coco_results` checks them (ids integers, score a
//! number), with the masks kept encoded until they are needed.

use std::io::Read;
use std::path::Path;

use serde::de::{self, Deserializer, Error as _, IgnoredAny, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;

use super::rle::Rle;
use crate::error::{Error, Result};

/// A mask of a result as written: compressed string or counts.
#[derive(Clone, Debug)]
pub enum Counts {
    Compressed(String),
    Runs(Vec<u32>),
}

/// A result's `segmentation` as RLE (the BOP format asks for RLE; polygons
/// would need pycocotools' own rasteriser to agree bit for bit).
#[derive(Clone, Debug)]
pub struct Segmentation {
    pub counts: Counts,
    /// `[height, width]`.
    pub size: [u32; 2],
}

impl SegmField {
    /// The mask, or why the field is not one.
    pub fn decode(&self) -> std::result::Result<Rle, String> {
        match self {
            SegmField::Rle(s) => s.decode(),
            SegmField::Bad(why) => Err(why.clone()),
        }
    }
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

/// A result's `segmentation` field: RLE, or why it is not one. A bad one
/// is refused only where masks are evaluated, as the toolkit checks it
/// only there: a box evaluation does not fail on a field it never uses.
#[derive(Clone, Debug)]
pub enum SegmField {
    Rle(Segmentation),
    Bad(String),
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
    /// `None` when absent or empty (Python-false: `{}`, `[]`, `""`, null).
    pub segmentation: Option<SegmField>,
    /// Seconds for the whole image; `None` when absent (or negative: the
    /// toolkit's "unknown").
    pub time: Option<f64>,
}

/// Reads a results file. Every result is checked here, before anything is
/// evaluated: a bad one is refused with its index. The file is parsed as it
/// is read (masks stay encoded; no JSON tree is built), and a gzipped file
/// may hold several gzip members, as Python's gzip reads them.
pub fn read_coco_results(path: &Path) -> Result<Vec<CocoResult>> {
    let bad = |reason: String| Error::BadJson { path: path.to_path_buf(), reason };
    let name = path.to_string_lossy();
    if !(name.ends_with(".json") || name.ends_with(".json.gz")) {
        return Err(bad("a COCO results file ends in .json or .json.gz (BOP's format for 2D detection and segmentation)".into()));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader: Box<dyn Read> = if name.ends_with(".gz") {
        Box::new(std::io::BufReader::with_capacity(1 << 16, flate2::read::MultiGzDecoder::new(std::io::BufReader::new(file))))
    } else {
        Box::new(std::io::BufReader::with_capacity(1 << 16, file))
    };
    let at = std::cell::Cell::new(None);
    let mut de = serde_json::Deserializer::from_reader(reader);
    let parsed = de.deserialize_seq(ResultsVisitor { at: &at }).and_then(|v| de.end().map(|_| v));
    let results = parsed.map_err(|e| match at.get() {
        Some(i) => bad(format!("result {i}: {e}")),
        None => bad(format!("not a JSON list of BOP COCO results: {e}")),
    })?;
    results.into_iter().enumerate().map(|(i, r)| check(r).map_err(|e| bad(format!("result {i}: {e}")))).collect()
}

/// The list, noting which result is being read (for the error message).
struct ResultsVisitor<'a> {
    at: &'a std::cell::Cell<Option<usize>>,
}

impl<'de> Visitor<'de> for ResultsVisitor<'_> {
    type Value = Vec<CocoResult>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON list of results")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Self::Value, A::Error> {
        let mut out = Vec::new();
        loop {
            self.at.set(Some(out.len()));
            match seq.next_element::<ResultEntry>()? {
                Some(r) => out.push(r.0),
                None => break,
            }
        }
        self.at.set(None);
        Ok(out)
    }
}

/// One result: a JSON object (an array is refused, as the toolkit refuses
/// it); unknown keys are skipped.
struct ResultEntry(CocoResult);

impl<'de> Deserialize<'de> for ResultEntry {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_map(ResultVisitor)
    }
}

struct ResultVisitor;

impl<'de> Visitor<'de> for ResultVisitor {
    type Value = ResultEntry;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a result object {\"scene_id\", \"image_id\", \"category_id\", \"score\", ...}")
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> std::result::Result<Self::Value, A::Error> {
        let (mut scene, mut image, mut cat, mut score) = (None, None, None, None);
        let (mut bbox, mut seg, mut time) = (None, None, None);
        while let Some(key) = map.next_key::<String>()? {
            match key.as_str() {
                "scene_id" => scene = Some(map.next_value::<u32>()?),
                "image_id" => image = Some(map.next_value::<u32>()?),
                "category_id" => cat = Some(map.next_value::<u32>()?),
                "score" => score = Some(map.next_value::<f64>()?),
                "bbox" => bbox = map.next_value::<Option<Vec<f64>>>()?,
                "segmentation" => seg = map.next_value::<MaybeSegm>()?.0,
                "time" => time = map.next_value::<Option<f64>>()?,
                _ => {
                    map.next_value::<IgnoredAny>()?;
                }
            }
        }
        let raw = CocoResult {
            scene_id: scene.ok_or_else(|| A::Error::missing_field("scene_id"))?,
            image_id: image.ok_or_else(|| A::Error::missing_field("image_id"))?,
            category_id: cat.ok_or_else(|| A::Error::missing_field("category_id"))?,
            score: score.ok_or_else(|| A::Error::missing_field("score"))?,
            bbox: None,
            segmentation: seg,
            time,
        };
        // The box is checked after parsing, with the others' checks.
        Ok(ResultEntry(CocoResult { bbox: bbox.map(|b| pack_box(&b)), ..raw }))
    }
}

/// A box as read, kept for [`check`]: 4 numbers, or NaN in the first slot
/// and the count of numbers in the second when there were not 4 (empty:
/// no box).
fn pack_box(b: &[f64]) -> [f64; 4] {
    match b {
        [x, y, w, h] => [*x, *y, *w, *h],
        _ => [f64::NAN, b.len() as f64, 0.0, 0.0],
    }
}

/// The `segmentation` field, read without a JSON tree (a mask's counts can
/// be millions of numbers); `None` when absent or Python-false.
#[derive(Default)]
pub(crate) struct MaybeSegm(pub(crate) Option<SegmField>);

impl<'de> Deserialize<'de> for MaybeSegm {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_any(SegmVisitor)
    }
}

struct SegmVisitor;

fn bad_segm(what: &str) -> MaybeSegm {
    MaybeSegm(Some(SegmField::Bad(format!(
        "segmentation is {what}, not RLE ({{\"counts\": string or run lengths, \"size\": [height, width]}}, as pycocotools.mask.encode writes it; polygons are not read)"
    ))))
}

impl<'de> Visitor<'de> for SegmVisitor {
    type Value = MaybeSegm;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an RLE mask")
    }
    fn visit_unit<E: de::Error>(self) -> std::result::Result<Self::Value, E> {
        Ok(MaybeSegm(None))
    }
    fn visit_none<E: de::Error>(self) -> std::result::Result<Self::Value, E> {
        Ok(MaybeSegm(None))
    }
    fn visit_bool<E: de::Error>(self, v: bool) -> std::result::Result<Self::Value, E> {
        Ok(if v { bad_segm("true") } else { MaybeSegm(None) })
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<Self::Value, E> {
        Ok(if v != 0 { bad_segm("a number") } else { MaybeSegm(None) })
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<Self::Value, E> {
        Ok(if v != 0 { bad_segm("a number") } else { MaybeSegm(None) })
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<Self::Value, E> {
        Ok(if v != 0.0 { bad_segm("a number") } else { MaybeSegm(None) })
    }
    fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<Self::Value, E> {
        Ok(if v.is_empty() { MaybeSegm(None) } else { bad_segm("a string") })
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Self::Value, A::Error> {
        let mut n = 0;
        while seq.next_element::<IgnoredAny>()?.is_some() {
            n += 1;
        }
        Ok(if n == 0 { MaybeSegm(None) } else { bad_segm("a list (polygons?)") })
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> std::result::Result<Self::Value, A::Error> {
        let (mut counts, mut size, mut keys) = (None, None, 0);
        while let Some(key) = map.next_key::<String>()? {
            keys += 1;
            match key.as_str() {
                "counts" => counts = Some(map.next_value::<CountsField>()?.0),
                "size" => size = Some(map.next_value::<Vec<IgnoredOrU32>>()?),
                _ => {
                    map.next_value::<IgnoredAny>()?;
                }
            }
        }
        if keys == 0 {
            return Ok(MaybeSegm(None));
        }
        let size = match size.as_deref() {
            Some([IgnoredOrU32(Some(h)), IgnoredOrU32(Some(w))]) if *h > 0 && *w > 0 => [*h, *w],
            Some(s) => {
                return Ok(MaybeSegm(Some(SegmField::Bad(format!(
                    "segmentation size has {} entries, not [height, width] of whole numbers above 0",
                    s.len()
                )))))
            }
            None => return Ok(bad_segm("without \"size\"")),
        };
        Ok(match counts {
            Some(Ok(counts)) => MaybeSegm(Some(SegmField::Rle(Segmentation { counts, size }))),
            Some(Err(why)) => MaybeSegm(Some(SegmField::Bad(format!("segmentation counts: {why}")))),
            None => bad_segm("without \"counts\""),
        })
    }
}

/// A size entry: a whole number that fits, or anything else (`None`).
struct IgnoredOrU32(Option<u32>);

impl<'de> Deserialize<'de> for IgnoredOrU32 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let v = serde_json::Value::deserialize(d)?;
        Ok(IgnoredOrU32(v.as_u64().and_then(|x| u32::try_from(x).ok())))
    }
}

/// `counts`: a compressed string or a list of run lengths (whole numbers
/// under 2^32), or why not.
struct CountsField(std::result::Result<Counts, String>);

impl<'de> Deserialize<'de> for CountsField {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_any(CountsVisitor)
    }
}

struct CountsVisitor;

impl<'de> Visitor<'de> for CountsVisitor {
    type Value = CountsField;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("RLE counts")
    }
    fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Ok(Counts::Compressed(v.to_string()))))
    }
    fn visit_string<E: de::Error>(self, v: String) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Ok(Counts::Compressed(v))))
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Self::Value, A::Error> {
        let mut runs = Vec::new();
        let mut bad = None;
        while let Some(IgnoredOrU32(v)) = seq.next_element::<IgnoredOrU32>()? {
            match v {
                Some(c) => runs.push(c),
                None => {
                    bad.get_or_insert(runs.len());
                    runs.push(0);
                }
            }
        }
        Ok(CountsField(match bad {
            Some(i) => Err(format!("run length {i} is not a whole number from 0 to 2^32 - 1")),
            None => Ok(Counts::Runs(runs)),
        }))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> std::result::Result<Self::Value, A::Error> {
        while map.next_entry::<IgnoredAny, IgnoredAny>()?.is_some() {}
        Ok(CountsField(Err("an object, not a string or a list".into())))
    }
    fn visit_unit<E: de::Error>(self) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Err("null".into())))
    }
    fn visit_bool<E: de::Error>(self, _: bool) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Err("a boolean".into())))
    }
    fn visit_i64<E: de::Error>(self, _: i64) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Err("a number, not a string or a list".into())))
    }
    fn visit_u64<E: de::Error>(self, _: u64) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Err("a number, not a string or a list".into())))
    }
    fn visit_f64<E: de::Error>(self, _: f64) -> std::result::Result<Self::Value, E> {
        Ok(CountsField(Err("a number, not a string or a list".into())))
    }
}

/// The checks that need the whole result.
fn check(r: CocoResult) -> std::result::Result<CocoResult, String> {
    if !r.score.is_finite() {
        return Err(format!("score {} is not a finite number", r.score));
    }
    let bbox = match r.bbox {
        Some([x, n, ..]) if x.is_nan() && n == 0.0 => None,
        Some([x, n, ..]) if x.is_nan() => return Err(format!("bbox has {n} numbers, not 4 ([x, y, width, height])")),
        b => b,
    };
    let time = match r.time {
        Some(t) if !t.is_finite() => return Err(format!("time {t} is not finite")),
        Some(t) if t >= 0.0 => Some(t),
        _ => None,
    };
    Ok(CocoResult { bbox, time, ..r })
}

/// Writes results as the BOP toolkit reads them (a JSON list; masks as
/// compressed RLE strings or run lengths as they are held).
pub fn write_coco_results(path: &Path, results: &[CocoResult]) -> Result<()> {
    let list: Vec<serde_json::Value> = results
        .iter()
        .map(|r| {
            let mut v = serde_json::json!({"scene_id": r.scene_id, "image_id": r.image_id, "category_id": r.category_id, "score": r.score});
            if let Some(b) = r.bbox {
                v["bbox"] = serde_json::json!(b);
            }
            if let Some(SegmField::Rle(s)) = &r.segmentation {
                let counts = match &s.counts {
                    Counts::Compressed(c) => serde_json::json!(c),
                    Counts::Runs(c) => serde_json::json!(c),
                };
                v["segmentation"] = serde_json::json!({"counts": counts, "size": s.size});
            }
            if let Some(t) = r.time {
                v["time"] = serde_json::json!(t);
            }
            v
        })
        .collect();
    crate::io::write_atomically(path, |w| {
        serde_json::to_writer(&mut *w, &list)?;
        std::io::Write::write_all(w, b"\n")
    })
}
