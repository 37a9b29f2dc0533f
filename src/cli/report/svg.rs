//! Inline SVG charts of the eval section, drawn here rather than by a
//! plotting library so the report stays one file without scripts from
//! elsewhere: recall against threshold, and grouped bars per object.

use std::fmt::Write as _;

use super::html::esc;

/// One line of a line chart.
pub struct Series {
    pub name: String,
    pub colour: &'static str,
    pub points: Vec<(f64, f64)>,
    /// Thin lines (e.g. VSD per τ) behind the thick mean.
    pub thin: bool,
}

const W: f64 = 380.0;
const H: f64 = 250.0;
const LEFT: f64 = 48.0;
const RIGHT: f64 = 12.0;
const TOP: f64 = 28.0;
const BOTTOM: f64 = 40.0;

/// Colour of an error type, the same in every chart.
pub fn error_colour(name: &str) -> &'static str {
    match name {
        "vsd" => "#1f77b4",
        "mssd" => "#ff7f0e",
        "mspd" => "#2ca02c",
        "ad" => "#9467bd",
        "add" => "#8c564b",
        "adi" => "#e377c2",
        "ar" => "#444444",
        _ => "#7f7f7f",
    }
}

/// Horizontal grid lines and labels of recall 0-1 on a chart `h` high.
fn recall_axis(s: &mut String, w: f64, h: f64) {
    for i in 0..=4 {
        let v = i as f64 / 4.0;
        let y = TOP + (1.0 - v) * (h - TOP - BOTTOM);
        let _ = write!(
            s,
            r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{:.1}" y="{:.1}" font-size="11" text-anchor="end">{v:.2}</text>"##,
            w - RIGHT,
            LEFT - 4.0,
            y + 4.0
        );
    }
}

/// Recall (0-1) against threshold, one line per series; the x range is the
/// thresholds' own (each error type has its unit), labelled `x_label`.
pub fn recall_chart(title: &str, x_label: &str, series: &[Series]) -> String {
    let xs = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).filter(|x| x.is_finite());
    let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    let (lo, hi) = if lo.is_finite() && hi > lo {
        (lo, hi)
    } else if lo.is_finite() {
        (lo - 1.0, lo + 1.0)
    } else {
        (0.0, 1.0)
    };
    let px = |x: f64| LEFT + (x - lo) / (hi - lo) * (W - LEFT - RIGHT);
    let py = |y: f64| TOP + (1.0 - y.clamp(0.0, 1.0)) * (H - TOP - BOTTOM);
    let mut s = format!(r#"<svg class="chart" width="{W}" height="{H}" viewBox="0 0 {W} {H}">"#);
    let _ = write!(s, r#"<text x="{:.1}" y="16" font-size="13" text-anchor="middle" font-weight="bold">{}</text>"#, W / 2.0, esc(title));
    recall_axis(&mut s, W, H);
    for x in [lo, (lo + hi) / 2.0, hi] {
        let _ = write!(s, r#"<text x="{:.1}" y="{:.1}" font-size="11" text-anchor="middle">{}</text>"#, px(x), H - BOTTOM + 14.0, short(x));
    }
    let _ = write!(
        s,
        r#"<text x="{:.1}" y="{:.1}" font-size="11" text-anchor="middle">{}</text>"#,
        (LEFT + W - RIGHT) / 2.0,
        H - 8.0,
        esc(x_label)
    );
    for ser in series.iter().filter(|s| s.thin).chain(series.iter().filter(|s| !s.thin)) {
        let pts: Vec<String> =
            ser.points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()).map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y))).collect();
        let (width, opacity) = if ser.thin { (1.0, 0.35) } else { (2.5, 1.0) };
        let _ = write!(
            s,
            r#"<polyline fill="none" stroke="{}" stroke-width="{width}" stroke-opacity="{opacity}" points="{}"><title>{}</title></polyline>"#,
            ser.colour,
            pts.join(" "),
            esc(&ser.name)
        );
        if !ser.thin {
            for p in &pts {
                let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
                let _ = write!(s, r#"<circle cx="{x}" cy="{y}" r="2.5" fill="{}"/>"#, ser.colour);
            }
        }
    }
    s.push_str("</svg>");
    s
}

/// One group of bars: its label and (error name, value) per bar.
pub type BarGroup = (String, Vec<(String, Option<f64>)>);

/// Grouped bars: one group per label, one bar per (name, value) in it,
/// values 0-1, with a legend of the names.
pub fn bar_chart(title: &str, groups: &[BarGroup]) -> String {
    let per_group = groups.iter().map(|g| g.1.len()).max().unwrap_or(1).max(1) as f64;
    let bar = 12.0;
    let group_w = per_group * bar + 14.0;
    let w = (LEFT + RIGHT + group_w * groups.len() as f64).max(300.0);
    let h = H + 18.0;
    let py = |y: f64| TOP + (1.0 - y.clamp(0.0, 1.0)) * (h - TOP - BOTTOM - 18.0);
    let mut s = format!(r#"<svg class="chart" width="{w:.0}" height="{h}" viewBox="0 0 {w:.0} {h}">"#);
    let _ = write!(s, r#"<text x="{:.1}" y="16" font-size="13" text-anchor="middle" font-weight="bold">{}</text>"#, w / 2.0, esc(title));
    recall_axis(&mut s, w, h - 18.0);
    for (gi, (label, bars)) in groups.iter().enumerate() {
        let x0 = LEFT + 7.0 + gi as f64 * group_w;
        for (bi, (name, v)) in bars.iter().enumerate() {
            let Some(v) = v.filter(|v| v.is_finite()) else { continue };
            let x = x0 + bi as f64 * bar;
            let y = py(v);
            let _ = write!(
                s,
                r#"<rect x="{x:.1}" y="{y:.1}" width="{:.1}" height="{:.1}" fill="{}"><title>{} {}: {v:.4}</title></rect>"#,
                bar - 1.0,
                py(0.0) - y,
                error_colour(name),
                esc(label),
                esc(&name.to_uppercase())
            );
        }
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" font-size="11" text-anchor="middle">{}</text>"#,
            x0 + per_group * bar / 2.0,
            py(0.0) + 14.0,
            esc(label)
        );
    }
    let names: Vec<&String> = groups.first().map(|g| g.1.iter().map(|b| &b.0).collect()).unwrap_or_default();
    for (i, name) in names.iter().enumerate() {
        let x = LEFT + i as f64 * 70.0;
        let _ = write!(
            s,
            r#"<rect x="{x:.1}" y="{:.1}" width="10" height="10" fill="{}"/><text x="{:.1}" y="{:.1}" font-size="11">{}</text>"#,
            h - 14.0,
            error_colour(name),
            x + 14.0,
            h - 5.0,
            esc(&name.to_uppercase())
        );
    }
    s.push_str("</svg>");
    s
}

/// A tick label: few digits, no trailing zeros.
fn short(x: f64) -> String {
    let s = format!("{x:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}
