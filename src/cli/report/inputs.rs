//! Reading the report's inputs: each file's kind is told from its content
//! (a PNG signature, a JSON list of score records, a JSON object with the
//! keys of `check`, `stable-poses export` or `eval`), never from its name, so
//! a renamed file still lands in the right section and a wrong file is
//! refused with its name rather than drawn as garbage.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use serde::Deserialize;

/// Largest JSON or CSV input read (a million score records with physics
/// are about 450 MB); beyond it the file is refused before it is read.
pub const MAX_DATA_BYTES: u64 = 1 << 30;
/// Largest PNG embedded: the report carries it as base64, and a browser
/// page of hundreds of megabytes is no longer a report.
pub const MAX_PNG_BYTES: u64 = 32 << 20;
/// Most PNG files taken from one folder, and most pictures in one report.
pub const MAX_FOLDER_PNGS: usize = 200;
/// Most bytes of pictures one report embeds (a third more as base64):
/// without it one 9.7 MB PNG given 64 times had made an 830 MB page and
/// taken 2.25 GB.
pub const MAX_EMBEDDED_BYTES: u64 = 256 << 20;

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
/// Header of `plausible score --out X.csv`.
const SCORE_CSV_HEADER: &str = "index,rank,score,a_d,a_n,valid,rendered,observed";

/// One record of `plausible score --out X.json` (the physics fields are
/// present with `--physics`). Scores are optional: NaN is written as null.
#[derive(Deserialize, Debug, Clone)]
pub struct ScoreRow {
    pub index: u64,
    pub rank: u64,
    pub score: Option<f64>,
    pub a_d: Option<f64>,
    pub a_n: Option<f64>,
    pub valid: u64,
    pub rendered: u64,
    pub observed: u64,
    pub verdict: Option<String>,
    pub intersecting: Option<u64>,
    pub contact: Option<u64>,
    pub supported: Option<u64>,
    pub min_distance: Option<f64>,
    pub stability_margin: Option<f64>,
}

/// `plausible check --json`.
#[derive(Deserialize, Debug, Clone)]
pub struct CheckReport {
    pub scene: String,
    pub samples: Option<u64>,
    pub friction: Option<f64>,
    pub objects: Vec<CheckObject>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct CheckObject {
    pub name: String,
    pub verdict: String,
    #[serde(rename = "static", default)]
    pub is_static: bool,
    pub intersecting: u64,
    pub contact: u64,
    pub supported: u64,
    pub min_distance: Option<f64>,
    pub stability_margin: Option<f64>,
    pub friction_equilibrium: Option<bool>,
    #[serde(default)]
    pub methods_disagree: bool,
    pub displacement: Option<CheckDisplacement>,
    pub epsilon: Option<f64>,
    pub mass_kg: Option<f64>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct CheckDisplacement {
    pub translation: Option<f64>,
    pub rotation_deg: Option<f64>,
}

/// `plausible stable-poses export` (format `plausible-stable-poses/1`).
#[derive(Deserialize, Debug, Clone)]
pub struct StableExport {
    pub format: String,
    pub meshes: Vec<StableMesh>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct StableMesh {
    pub mesh: String,
    pub sha256: String,
    pub drops: u64,
    pub settled: u64,
    #[serde(default)]
    pub collider: String,
    pub clusters: Vec<StableCluster>,
    #[serde(default)]
    pub families: Vec<StableFamily>,
    #[serde(default)]
    pub analytic: Vec<StableAnalytic>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct StableCluster {
    pub probability: f64,
    pub ci95: [f64; 2],
    pub count: u64,
    pub gravity_in_model: [f64; 3],
    #[serde(rename = "R_model_to_plane")]
    pub r_model_to_plane: [f64; 9],
    pub height: f64,
}

#[derive(Deserialize, Debug, Clone)]
pub struct StableFamily {
    pub kind: String,
    pub axis: Option<[f64; 3]>,
    pub probability: f64,
    pub ci95: [f64; 2],
    pub count: u64,
}

#[derive(Deserialize, Debug, Clone)]
pub struct StableAnalytic {
    pub probability: f64,
    pub gravity_in_model: [f64; 3],
    pub margin: f64,
}

/// `plausible eval --out X.json`.
#[derive(Deserialize, Debug, Clone)]
pub struct EvalReport {
    pub ar: Option<f64>,
    pub ar_vsd: Option<f64>,
    pub ar_mssd: Option<f64>,
    pub ar_mspd: Option<f64>,
    pub recall_ad: Option<f64>,
    pub recall_add: Option<f64>,
    pub recall_adi: Option<f64>,
    pub add_threshold: Option<f64>,
    pub per_object: BTreeMap<String, EvalObject>,
    pub per_threshold: BTreeMap<String, Vec<EvalThreshold>>,
    pub n_estimates: Option<u64>,
    pub n_targets: Option<u64>,
    pub n_images: Option<u64>,
    pub device: Option<String>,
    pub dataset: Option<String>,
    pub results: Option<String>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct EvalObject {
    pub targets: u64,
    pub ar: Option<f64>,
    pub by_error: BTreeMap<String, Option<f64>>,
}

#[derive(Deserialize, Debug, Clone)]
pub struct EvalThreshold {
    pub threshold: f64,
    pub tau: Option<f64>,
    pub recall: Option<f64>,
}

/// What one input file turned out to be.
#[derive(Debug, Clone)]
pub enum Kind {
    Score(Vec<ScoreRow>),
    Check(CheckReport),
    Stable(StableExport),
    Eval(Box<EvalReport>),
    Png { bytes: Vec<u8>, width: u32, height: u32 },
}

/// One input: where it came from and what it holds.
#[derive(Debug, Clone)]
pub struct Input {
    pub path: PathBuf,
    pub kind: Kind,
}

impl Input {
    /// The file name, for captions and the matching of pictures.
    pub fn file_name(&self) -> String {
        self.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| self.path.display().to_string())
    }
}

/// Reads every argument: files by content, folders as their PNG files
/// (sorted by name; other files in a folder are left alone, since an
/// output folder such as the demo's holds inputs of its own).
/// A file given twice (or as itself and inside a folder given) is read
/// once. The pictures are counted and their sizes added up before any
/// file is read whole or decoded.
pub fn read_all(paths: &[PathBuf]) -> Result<Vec<Input>> {
    let mut files = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for p in paths {
        let found = if p.is_dir() { folder_pngs(p)? } else { vec![p.clone()] };
        for f in found {
            if seen.insert(f.canonicalize().unwrap_or_else(|_| f.clone())) {
                files.push(f);
            }
        }
    }
    check_pictures(&files)?;
    let (mut pictures, mut embedded) = (0usize, 0u64);
    let mut out = Vec::new();
    for f in &files {
        let input = read_one(f)?;
        if let Kind::Png { bytes, .. } = &input.kind {
            // Again as read: a pipe's size is only known now.
            pictures += 1;
            embedded += bytes.len() as u64;
            if pictures > MAX_FOLDER_PNGS || embedded > MAX_EMBEDDED_BYTES {
                bail!("{}: with it the pictures pass the {MAX_FOLDER_PNGS} pictures or {} MiB a report embeds; pass fewer", f.display(), MAX_EMBEDDED_BYTES >> 20);
            }
        }
        out.push(input);
    }
    Ok(out)
}

/// Refuses more pictures, or more bytes of them, than a report embeds,
/// telling PNG files by their signature and size (a file that is not a
/// regular one is counted when it is read).
fn check_pictures(files: &[PathBuf]) -> Result<()> {
    let mut pngs: Vec<(u64, &PathBuf)> = Vec::new();
    for f in files {
        let Ok(meta) = std::fs::metadata(f) else { continue };
        let mut head = [0u8; 8];
        let is_png = meta.is_file() && std::fs::File::open(f).and_then(|mut r| std::io::Read::read_exact(&mut r, &mut head)).is_ok() && head == PNG_SIGNATURE;
        if is_png {
            pngs.push((meta.len(), f));
        }
    }
    if pngs.len() > MAX_FOLDER_PNGS {
        bail!("{} pictures, more than the {MAX_FOLDER_PNGS} a report embeds; pass the ones you want", pngs.len());
    }
    let total: u64 = pngs.iter().map(|(n, _)| n).sum();
    if total > MAX_EMBEDDED_BYTES {
        pngs.sort_by_key(|p| std::cmp::Reverse(p.0));
        let largest: Vec<String> = pngs.iter().take(5).map(|(n, f)| format!("{} ({:.1} MiB)", f.display(), *n as f64 / 1048576.0)).collect();
        bail!(
            "the {} pictures add up to {} MiB, more than the {} MiB a report embeds; pass fewer or smaller ones (largest: {})",
            pngs.len(),
            total >> 20,
            MAX_EMBEDDED_BYTES >> 20,
            largest.join(", ")
        );
    }
    Ok(())
}

/// The PNG files directly inside `dir` (by name; read by content later).
fn folder_pngs(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).with_context(|| format!("cannot read the folder {}", dir.display()))?;
    let mut pngs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    if pngs.is_empty() {
        bail!("{}: a folder without PNG files (a folder input is a folder of pictures, e.g. the demo's explain/)", dir.display());
    }
    if pngs.len() > MAX_FOLDER_PNGS {
        bail!("{}: {} PNG files, more than the {MAX_FOLDER_PNGS} a report embeds; pass the ones you want", dir.display(), pngs.len());
    }
    pngs.sort();
    Ok(pngs)
}

/// Reads one file and tells its kind from its content.
pub fn read_one(path: &Path) -> Result<Input> {
    let bytes = read_capped(path)?;
    let kind = classify(&bytes).with_context(|| format!("{}", path.display()))?;
    Ok(Input { path: path.to_path_buf(), kind })
}

/// Reads a file through the library's capped reader (a regular file
/// larger than any input could sensibly be is refused before it is read,
/// a stream once past the cap); a PNG is held to the smaller embedding cap.
fn read_capped(path: &Path) -> Result<Vec<u8>> {
    let bytes = plausible::io::read_capped(path, MAX_DATA_BYTES, "report input")?;
    if bytes.starts_with(PNG_SIGNATURE) && bytes.len() as u64 > MAX_PNG_BYTES {
        bail!("{}: a PNG of {} MiB, larger than the {} MiB a report embeds", path.display(), bytes.len() >> 20, MAX_PNG_BYTES >> 20);
    }
    Ok(bytes)
}

/// The kind of a file's content, or why it is none of the known kinds.
pub fn classify(bytes: &[u8]) -> Result<Kind> {
    if bytes.starts_with(PNG_SIGNATURE) {
        return png(bytes);
    }
    let Ok(text) = std::str::from_utf8(bytes) else {
        bail!("neither a PNG nor text: not an output of plausible (score, check, stable-poses export, eval JSON, or a PNG picture)");
    };
    let text = text.trim_start_matches('\u{feff}').trim_start();
    match text.as_bytes().first() {
        None => bail!("the file is empty"),
        Some(b'[') => score_json(text),
        Some(b'{') => object_json(text),
        _ if text.starts_with(SCORE_CSV_HEADER) => score_csv(text),
        _ => bail!("not an output of plausible: expected a JSON (score, check, stable-poses export, eval), a score CSV or a PNG picture"),
    }
}

/// A PNG: its size from the header, checked to decode that far.
fn png(bytes: &[u8]) -> Result<Kind> {
    let reader = image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
    let (width, height) = reader.into_dimensions().context("a broken PNG")?;
    if width == 0 || height == 0 {
        bail!("a PNG of {width}x{height} pixels");
    }
    // Decoded whole, once: a truncated file has a valid header, and a
    // browser would show it as a broken picture. (The header check above
    // bounds the decode's memory first.)
    if (width as u64) * (height as u64) > 64 << 20 {
        bail!("a PNG of {width}x{height} pixels, more than a report shows");
    }
    image::load_from_memory_with_format(bytes, image::ImageFormat::Png).context("a broken PNG (truncated?)")?;
    Ok(Kind::Png { bytes: bytes.to_vec(), width, height })
}

/// A JSON list: the records of `plausible score --out X.json`.
fn score_json(text: &str) -> Result<Kind> {
    let rows: Vec<ScoreRow> = serde_json::from_str(text).context("a JSON list, but not the records of `plausible score --out X.json`")?;
    if rows.is_empty() {
        bail!("a score file with no records");
    }
    for (i, r) in rows.iter().enumerate() {
        check_score_row(r).with_context(|| format!("record {i} (index {})", r.index))?;
    }
    Ok(Kind::Score(rows))
}

/// A JSON object: a check report, a stable-pose export or an eval report,
/// told apart by their distinctive keys.
fn object_json(text: &str) -> Result<Kind> {
    let v: serde_json::Value = serde_json::from_str(text).context("not valid JSON")?;
    let Some(obj) = v.as_object() else { bail!("not a JSON object") };
    if let Some(format) = obj.get("format").and_then(|f| f.as_str()).filter(|f| f.starts_with("plausible-stable-poses/")) {
        if format != plausible::stable::export::FORMAT {
            bail!(
                "a stable-pose export of format '{format}', which this version does not read (it reads {})",
                plausible::stable::export::FORMAT
            );
        }
        let e: StableExport = serde_json::from_value(v).context("a stable-pose export with missing or malformed fields")?;
        check_stable(&e)?;
        return Ok(Kind::Stable(e));
    }
    if obj.contains_key("objects") && obj.contains_key("scene") {
        let c: CheckReport = serde_json::from_value(v).context("a `plausible check --json` report with missing or malformed fields")?;
        for o in &c.objects {
            check_verdict(&o.verdict).with_context(|| format!("object {}", o.name))?;
        }
        return Ok(Kind::Check(c));
    }
    if obj.contains_key("per_object") && obj.contains_key("per_threshold") {
        let e: EvalReport = serde_json::from_value(v).context("a `plausible eval --out` report with missing or malformed fields")?;
        return Ok(Kind::Eval(Box::new(e)));
    }
    let keys: Vec<&str> = obj.keys().take(8).map(String::as_str).collect();
    bail!(
        "a JSON object that is no output plausible reports on (keys: {}); expected `check --json`, `stable-poses export` or `eval --out`",
        keys.join(", ")
    )
}

/// The verdicts `score --physics` and `check` write.
const VERDICTS: [&str; 4] = ["plausible", "unstable", "floating", "intersecting"];

fn check_verdict(v: &str) -> Result<()> {
    if !VERDICTS.contains(&v) {
        bail!("verdict '{v}' is none of {}", VERDICTS.join(", "));
    }
    Ok(())
}

/// A record as `score` writes it: scores in [0, 1] (or missing, NaN's
/// `null`), finite physics, a known verdict. A report drew -7 as a score
/// and "banana" as a verdict.
fn check_score_row(r: &ScoreRow) -> Result<()> {
    for (k, v) in [("score", r.score), ("a_d", r.a_d), ("a_n", r.a_n)] {
        if let Some(v) = v.filter(|v| !(0.0..=1.0).contains(v)) {
            bail!("{k} {v} is not in [0, 1]");
        }
    }
    for (k, v) in [("min_distance", r.min_distance), ("stability_margin", r.stability_margin)] {
        if let Some(v) = v.filter(|v| !v.is_finite()) {
            bail!("{k} {v} is not a finite number");
        }
    }
    if r.rank == 0 {
        bail!("rank 0 (ranks start at 1)");
    }
    r.verdict.as_deref().map_or(Ok(()), check_verdict)
}

/// An export as `stable-poses export` writes it: at least one mesh, and
/// per mesh probabilities and intervals in [0, 1] that sum to at most 1,
/// counts within the drops. A report drew "p = -500.0 %" and clusters
/// summing to 20000 %.
fn check_stable(e: &StableExport) -> Result<()> {
    if e.meshes.is_empty() {
        bail!("a stable-pose export with no mesh");
    }
    for m in &e.meshes {
        let bad = |what: String| anyhow::anyhow!("stable-pose export, mesh {}: {what}", m.mesh);
        if m.settled > m.drops {
            return Err(bad(format!("{} settled of {} drops", m.settled, m.drops)));
        }
        let groups = m.clusters.iter().map(|c| (c.probability, c.ci95, c.count)).chain(m.families.iter().map(|f| (f.probability, f.ci95, f.count)));
        let mut sum = 0.0;
        for (i, (p, [lo, hi], count)) in groups.enumerate() {
            if !(0.0..=1.0).contains(&p) || !(0.0..=1.0).contains(&lo) || !(0.0..=1.0).contains(&hi) || lo > hi {
                return Err(bad(format!("cluster {i}: probability {p} or interval [{lo}, {hi}] is not within [0, 1]")));
            }
            if count > m.drops {
                return Err(bad(format!("cluster {i}: {count} drops of {}", m.drops)));
            }
            sum += p;
        }
        if sum > 1.0 + 1e-6 {
            return Err(bad(format!("the probabilities sum to {sum:.3}, more than 1")));
        }
        if let Some(a) = m.analytic.iter().find(|a| !(0.0..=1.0).contains(&a.probability)) {
            return Err(bad(format!("analytic pose probability {} is not in [0, 1]", a.probability)));
        }
    }
    Ok(())
}

/// `plausible score --out X.csv`: the same records as the JSON.
fn score_csv(text: &str) -> Result<Kind> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let mut rows = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let row = csv_row(&header, line).and_then(|r| check_score_row(&r).map(|()| r));
        rows.push(row.with_context(|| format!("score CSV line {}", n + 2))?);
    }
    if rows.is_empty() {
        bail!("a score file with no records");
    }
    Ok(Kind::Score(rows))
}

/// One CSV line as a record (empty cells are missing values).
fn csv_row(header: &[&str], line: &str) -> Result<ScoreRow> {
    let cells: Vec<&str> = line.split(',').collect();
    if cells.len() != header.len() {
        bail!("{} cells, the header has {}", cells.len(), header.len());
    }
    let get = |k: &str| header.iter().position(|h| *h == k).map(|i| cells[i].trim()).filter(|c| !c.is_empty());
    let num = |k: &str| -> Result<Option<f64>> {
        get(k).map(|c| c.parse::<f64>().with_context(|| format!("{k} '{c}' is not a number"))).transpose()
    };
    let int = |k: &str| -> Result<Option<u64>> {
        get(k).map(|c| c.parse::<u64>().with_context(|| format!("{k} '{c}' is not a count"))).transpose()
    };
    let need = |k: &str, v: Option<u64>| v.with_context(|| format!("no {k}"));
    Ok(ScoreRow {
        index: need("index", int("index")?)?,
        rank: need("rank", int("rank")?)?,
        score: num("score")?,
        a_d: num("a_d")?,
        a_n: num("a_n")?,
        valid: need("valid", int("valid")?)?,
        rendered: need("rendered", int("rendered")?)?,
        observed: need("observed", int("observed")?)?,
        verdict: get("verdict").map(str::to_string),
        intersecting: int("intersecting")?,
        contact: int("contact")?,
        supported: int("supported")?,
        min_distance: num("min_distance")?,
        stability_margin: num("stability_margin")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_binary_and_foreign_json_are_refused() {
        assert!(classify(b"").is_err());
        assert!(classify(b"   \n").is_err());
        assert!(classify(&[0xff, 0xfe, 0x00, 0x01]).is_err());
        assert!(classify(b"[]").is_err());
        assert!(classify(br#"[{"cam_R_m2c": [1,0,0,0,1,0,0,0,1], "cam_t_m2c": [0,0,500]}]"#).is_err());
        assert!(classify(br#"{"point": [0,0,1], "normal": [0,0,1]}"#).is_err());
        assert!(classify(br#"{"format": "plausible-stable-poses/9", "meshes": []}"#).is_err());
        assert!(classify(b"\x89PNG\r\n\x1a\nnot really").is_err());
    }

    #[test]
    fn score_csv_reads_like_the_json() {
        let csv = "index,rank,score,a_d,a_n,valid,rendered,observed\n0,2,0.5,0.4,0.6,10,11,12\n1,1,,0.1,0.2,1,2,3\n";
        let Kind::Score(rows) = classify(csv.as_bytes()).unwrap() else { panic!("not a score") };
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].score, None);
        assert!(classify(b"index,rank,score,a_d,a_n,valid,rendered,observed\n0,x\n").is_err());
    }

    #[test]
    fn values_no_command_writes_are_refused() {
        let row = |score: &str, verdict: &str| format!(r#"[{{"index": 0, "rank": 1, "score": {score}, "a_d": 0.5, "a_n": 0.5, "valid": 1, "rendered": 1, "observed": 1, "verdict": "{verdict}"}}]"#);
        assert!(classify(row("0.5", "plausible").as_bytes()).is_ok());
        assert!(classify(row("null", "floating").as_bytes()).is_ok());
        let e = format!("{:#}", classify(row("-7", "plausible").as_bytes()).unwrap_err());
        assert!(e.contains("score -7"), "{e}");
        let e = format!("{:#}", classify(row("0.5", "banana").as_bytes()).unwrap_err());
        assert!(e.contains("banana"), "{e}");
        assert!(classify(b"index,rank,score,a_d,a_n,valid,rendered,observed\n0,1,NaN,0.1,0.2,1,2,3\n").is_err());
        let export = |p: f64| {
            format!(
                r#"{{"format": "{}", "meshes": [{{"mesh": "m.obj", "sha256": "x", "drops": 10, "settled": 10, "clusters": [{{"probability": {p}, "ci95": [0.1, 0.9], "count": 5, "gravity_in_model": [0,0,-1], "R_model_to_plane": [1,0,0,0,1,0,0,0,1], "height": 0.01}}]}}]}}"#,
                plausible::stable::export::FORMAT
            )
        };
        assert!(classify(export(0.5).as_bytes()).is_ok());
        let e = format!("{:#}", classify(export(-5.0).as_bytes()).unwrap_err());
        assert!(e.contains("probability -5"), "{e}");
        let none = format!(r#"{{"format": "{}", "meshes": []}}"#, plausible::stable::export::FORMAT);
        assert!(classify(none.as_bytes()).is_err());
    }
}
