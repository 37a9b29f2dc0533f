//! `plausible report IN... -o report.html`: one self-contained HTML page
//! from the JSON outputs of `score`, `check`, `stable-poses export` and
//! `eval`, with the PNG pictures they wrote embedded beside their rows.
//! Inputs are recognised by content; the page needs no network.

mod gallery;
mod html;
mod inputs;
mod sections;
mod svg;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};

use inputs::{Input, Kind};
use sections::Picture;

#[derive(clap::Args, Debug)]
pub struct ReportArgs {
    /// Inputs, recognised by their content: `score --out X.json` (or .csv),
    /// `check --json` output, `stable-poses export` JSON, `eval --out` JSON,
    /// PNG pictures, and folders of PNG pictures (e.g. the demo's explain/).
    /// `hypothesis_<index>.png` goes beside that score row, `alignment.png`
    /// into the score section, other pictures into the check section (or a
    /// section of their own when there is no check).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// The HTML file to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Title of the page.
    #[arg(long, default_value = "plausible report")]
    pub title: String,
}

#[tracing::instrument(name = "plausible report", level = "trace", skip_all)]
pub fn run(a: ReportArgs) -> Result<()> {
    check_output(&a.output, &a.inputs)?;
    let inputs = inputs::read_all(&a.inputs)?;
    let page = build(&a.title, &inputs);
    plausible::io::write_atomically(&a.output, |w| std::io::Write::write_all(w, page.as_bytes())).context("--output")?;
    println!("wrote {} ({} KiB): {}", a.output.display(), page.len().div_ceil(1024), summary(&inputs));
    Ok(())
}

/// The output must be an .html file in a writable folder and none of the
/// inputs (checked before any input is read: a typo costs nothing).
fn check_output(out: &Path, ins: &[PathBuf]) -> Result<()> {
    let ext = out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("html" | "htm")) {
        bail!("--output {}: the report is HTML; give a file name ending in .html", out.display());
    }
    plausible::io::check_writable(out).context("--output")?;
    if let Ok(o) = out.canonicalize() {
        if ins.iter().any(|i| i.canonicalize().is_ok_and(|i| i == o)) {
            bail!("--output {} is also an input; it would be overwritten", out.display());
        }
    }
    Ok(())
}

/// "2 score, 1 eval, 3 pictures" for the closing line.
fn summary(inputs: &[Input]) -> String {
    let count = |f: fn(&Kind) -> bool| inputs.iter().filter(|i| f(&i.kind)).count();
    let parts = [
        (count(|k| matches!(k, Kind::Score(_))), "score"),
        (count(|k| matches!(k, Kind::Check(_))), "check"),
        (count(|k| matches!(k, Kind::Stable(_))), "stable-poses"),
        (count(|k| matches!(k, Kind::Eval(_))), "eval"),
        (count(|k| matches!(k, Kind::Png { .. })), "pictures"),
    ];
    parts
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, w)| if *n == 1 && *w == "pictures" { "1 picture".to_string() } else { format!("{n} {w}") })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The page: sections in a fixed order (score, check, stable poses, eval),
/// each input in the order given; pictures go where their names say.
fn build(title: &str, inputs: &[Input]) -> String {
    let pictures: Vec<Picture> = inputs
        .iter()
        .filter_map(|i| match &i.kind {
            Kind::Png { bytes, width, height } => Some(Picture { name: i.file_name(), bytes, width: *width, height: *height }),
            _ => None,
        })
        .collect();
    let (score_pics, rest): (Vec<&Picture>, Vec<&Picture>) =
        pictures.iter().partition(|p| p.hypothesis_index().is_some() || p.is_alignment());
    let has_score = inputs.iter().any(|i| matches!(i.kind, Kind::Score(_)));
    let has_check = inputs.iter().any(|i| matches!(i.kind, Kind::Check(_)));
    let mut body = String::new();
    let mut score_sec = 0;
    for i in inputs {
        if let Kind::Score(rows) = &i.kind {
            body += &sections::score(&i.path, rows, if score_sec == 0 { &score_pics } else { &[] }, score_sec);
            score_sec += 1;
        }
    }
    let mut check_sec = 0;
    for i in inputs {
        if let Kind::Check(c) = &i.kind {
            body += &sections::check(&i.path, c, if check_sec == 0 { &rest } else { &[] });
            check_sec += 1;
        }
    }
    let mut gallery = gallery::Gallery::new(sections::GALLERY_TOTAL);
    for i in inputs {
        if let Kind::Stable(e) = &i.kind {
            body += &sections::stable(&i.path, e, &mut gallery);
        }
    }
    for i in inputs {
        if let Kind::Eval(e) = &i.kind {
            body += &sections::eval(&i.path, e);
        }
    }
    let mut loose: Vec<&Picture> = if has_check { Vec::new() } else { rest };
    if !has_score {
        loose.extend(score_pics);
    }
    body += &sections::other_pictures(&loose);
    let subtitle = format!("plausible {} — {} input(s): {}", env!("CARGO_PKG_VERSION"), inputs.len(), summary(inputs));
    html::page(title, &subtitle, &body)
}
