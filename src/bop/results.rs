//! BOP results files: `scene_id,im_id,obj_id,score,R,t,time`, one pose
//! estimate a line, R row-major (9 numbers) and t in mm (3 numbers), each
//! space-separated; the header line is optional; time in seconds (-1 when
//! unknown), the same for every estimate of an image.

use std::collections::HashMap;
use std::io::{BufRead, Read as _, Write};
use std::path::Path;

use super::dataset::PoseMm;
use crate::error::{Error, Result};

/// The header BOP results files start with.
pub const HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time";

/// One pose estimate of a results file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    pub score: f64,
    pub pose: PoseMm,
    /// Seconds spent on the image (-1 = unknown).
    pub time: f64,
    /// 1-based line in the file it came from (0 when made in memory).
    pub line: usize,
}

fn numbers(field: &str, n: usize, what: &str) -> std::result::Result<Vec<f64>, String> {
    let v: Vec<f64> = field
        .split_whitespace()
        .map(|s| s.parse::<f64>().map_err(|_| format!("{what}: '{s}' is not a number")))
        .collect::<std::result::Result<_, _>>()?;
    if v.len() != n {
        return Err(format!("{what} has {} numbers, expected {n} (space-separated)", v.len()));
    }
    Ok(v)
}

/// Parses one line (no header).
pub fn parse_line(line: &str) -> std::result::Result<Estimate, String> {
    let f: Vec<&str> = line.trim_end_matches(['\r', '\n']).split(',').collect();
    if f.len() != 7 {
        return Err(format!("{} comma-separated fields, expected 7 ({HEADER})", f.len()));
    }
    let id = |s: &str, what: &str| s.trim().parse::<u32>().map_err(|_| format!("{what} '{}' is not a non-negative integer", s.trim()));
    let scalar = |s: &str, what: &str| match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{what} '{}' is not a finite number", s.trim())),
    };
    // A score only orders estimates: ±inf orders (the toolkit takes it),
    // NaN does not.
    let score = match f[3].trim().parse::<f64>() {
        Ok(v) if !v.is_nan() => v,
        _ => return Err(format!("score '{}' is not a number (NaN orders nothing)", f[3].trim())),
    };
    let r = numbers(f[4], 9, "R")?;
    let t = numbers(f[5], 3, "t")?;
    Ok(Estimate {
        scene_id: id(f[0], "scene_id")?,
        im_id: id(f[1], "im_id")?,
        obj_id: id(f[2], "obj_id")?,
        score,
        pose: PoseMm::from_row_major(&r, &t)?,
        time: scalar(f[6], "time")?,
        line: 0,
    })
}

/// Reads a results file, streaming it line by line. Malformed lines and
/// duplicated estimates (the same object, image and pose twice, but for
/// placeholders at t = 0) are errors naming the line.
pub fn read_results(path: &Path) -> Result<Vec<Estimate>> {
    if path.is_dir() {
        return Err(Error::InvalidInput(format!("{}: is a folder; a results file is a CSV", path.display())));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let mut out = Vec::new();
    let mut seen: HashMap<(u32, u32, u32, [u64; 12]), usize> = HashMap::new();
    let mut n = 0;
    while let Some(line) = next_line(&mut reader).map_err(|reason| Error::BadLine { path: path.to_path_buf(), line: n + 1, reason })? {
        n += 1;
        // A byte-order mark from a spreadsheet export is no field.
        let line = if n == 1 { line.strip_prefix('\u{feff}').map(str::to_owned).unwrap_or(line) } else { line };
        if line.trim().is_empty() || (n == 1 && line.contains(HEADER)) {
            continue;
        }
        let mut e = parse_line(&line).map_err(|reason| Error::BadLine { path: path.to_path_buf(), line: n, reason })?;
        e.line = n;
        // Placeholders (t = 0, an object the method did not find) may repeat.
        let placeholder = e.pose.t == glam::DVec3::ZERO;
        if let Some(first) = seen.insert((e.scene_id, e.im_id, e.obj_id, pose_bits(&e)), n).filter(|_| !placeholder) {
            return Err(Error::BadLine {
                path: path.to_path_buf(),
                line: n,
                reason: format!("duplicates line {first} (same scene, image, object and pose)"),
            });
        }
        out.push(e);
    }
    check_millimetres(path, &out)?;
    Ok(out)
}

/// Longest line read from a results file: a line is about 200 bytes, and
/// without a bound a stream without newlines (`/dev/zero`) would be read
/// as one line until memory runs out.
const MAX_LINE_BYTES: u64 = 64 << 10;

/// The next line without its line end (`\n` or `\r\n`), `None` at the end.
fn next_line(reader: &mut impl BufRead) -> std::result::Result<Option<String>, String> {
    let mut line = String::new();
    let got = reader.by_ref().take(MAX_LINE_BYTES + 1).read_line(&mut line).map_err(|e| e.to_string())?;
    if got == 0 {
        return Ok(None);
    }
    if got as u64 > MAX_LINE_BYTES && !line.ends_with('\n') {
        return Err(format!("a line longer than {} KiB: not a BOP results CSV", MAX_LINE_BYTES >> 10));
    }
    let end = line.trim_end_matches('\n').trim_end_matches('\r').len();
    line.truncate(end);
    Ok(Some(line))
}

/// BOP results are in millimetres: a median camera distance under 2 cm is
/// a file written in metres, which would evaluate every estimate as a miss.
/// Rows with t = 0 are left out of the median: they are a method's
/// placeholders for objects it did not find (misses in any unit).
fn check_millimetres(path: &Path, estimates: &[Estimate]) -> Result<()> {
    let distances = estimates.iter().map(|e| e.pose.t.length()).filter(|&d| d > 0.0).collect();
    let Some(median) = crate::pose::median(distances) else { return Ok(()) };
    if median < 20.0 {
        return Err(Error::InvalidInput(format!(
            "{}: the estimates' median camera distance is {median:.2} mm: t looks like metres, but BOP results are in millimetres",
            path.display()
        )));
    }
    Ok(())
}

/// The bits of an estimate's pose: two estimates are the same pose exactly
/// when these are equal (what [`read_results`] refuses twice).
fn pose_bits(e: &Estimate) -> [u64; 12] {
    let mut key = [0u64; 12];
    for (k, v) in key.iter_mut().zip(e.pose.r_row_major().iter().chain(e.pose.t.to_array().iter())) {
        *k = v.to_bits();
    }
    key
}

/// Keeps one of the estimates that give the same object in the same image
/// the same pose (the best scored, in the place of the first): refinement
/// can bring two hypotheses to one pose, and a results file must not hold
/// it twice (the BOP toolkit would count the copy as a false positive, and
/// [`read_results`] refuses it as a likely concatenation mistake).
pub fn drop_repeated_poses(estimates: &mut Vec<Estimate>) {
    let mut first: HashMap<(u32, u32, u32, [u64; 12]), usize> = HashMap::new();
    let mut keep = vec![true; estimates.len()];
    for i in 0..estimates.len() {
        let e = &estimates[i];
        match first.entry((e.scene_id, e.im_id, e.obj_id, pose_bits(e))) {
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(i);
            }
            std::collections::hash_map::Entry::Occupied(o) => {
                let j = *o.get();
                estimates[j].score = estimates[j].score.max(estimates[i].score);
                keep[i] = false;
            }
        }
    }
    let mut k = keep.iter();
    estimates.retain(|_| *k.next().unwrap());
}

/// Formats one estimate as a results line (shortest round-trip floats).
pub fn format_line(e: &Estimate) -> String {
    let join = |v: &[f64]| v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(" ");
    format!(
        "{},{},{},{:?},{},{},{:?}",
        e.scene_id,
        e.im_id,
        e.obj_id,
        e.score,
        join(&e.pose.r_row_major()),
        join(&e.pose.t.to_array()),
        e.time
    )
}

/// Writes a results file (header first). The file is written beside the
/// target and renamed into place, so a failure never leaves half a file.
pub fn write_results(path: &Path, estimates: &[Estimate]) -> Result<()> {
    crate::io::write_atomically(path, |w| {
        writeln!(w, "{HEADER}")?;
        for e in estimates {
            writeln!(w, "{}", format_line(e))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::parse_line;

    const POSE: &str = "1 0 0 0 1 0 0 0 1,0 0 500";

    #[test]
    fn scores_order_so_infinities_are_taken_and_nan_is_not() {
        assert_eq!(parse_line(&format!("2,3,1,inf,{POSE},-1")).unwrap().score, f64::INFINITY);
        assert_eq!(parse_line(&format!("2,3,1,-inf,{POSE},-1")).unwrap().score, f64::NEG_INFINITY);
        assert!(parse_line(&format!("2,3,1,nan,{POSE},-1")).unwrap_err().contains("score 'nan'"));
        assert!(parse_line(&format!("2,3,1,1,{POSE},inf")).unwrap_err().contains("time 'inf'"));
    }
}
