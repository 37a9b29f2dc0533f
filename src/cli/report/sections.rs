//! The report's sections, one per input kind: HTML strings built from the
//! parsed inputs (every input string escaped on the way in).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use super::gallery::{self, Drawable, Gallery};
use super::html::{esc, num, pct, png_img, sortable_table, verdict_badge, Cell, Row};
use super::inputs::{CheckReport, EvalReport, ScoreRow, StableCluster, StableExport, StableMesh};
use super::svg::{bar_chart, error_colour, recall_chart, BarGroup, Series};

/// Rows of the score table (the best by rank, plus every explained one).
pub const TOP_ROWS: usize = 200;
/// Clusters drawn per mesh; the rest are listed in the table only.
pub const GALLERY_DRAWN: usize = 48;
/// Clusters drawn over all meshes of all exports: a 0.74 MB export of 100
/// meshes had made a 150 MB page of 4800 pictures.
pub const GALLERY_TOTAL: usize = 4 * GALLERY_DRAWN;
/// Rows of any other table.
pub const MAX_TABLE_ROWS: usize = 2000;
/// Objects in the per-object bar chart.
const MAX_BARS_OBJECTS: usize = 60;
/// Points per recall line.
const MAX_CURVE_POINTS: usize = 2000;

/// A picture given as an input, with the name it is matched by.
pub struct Picture<'a> {
    pub name: String,
    pub bytes: &'a [u8],
    pub width: u32,
    pub height: u32,
}

impl Picture<'_> {
    /// `hypothesis_<index>.png` → the index it explains.
    pub fn hypothesis_index(&self) -> Option<u64> {
        self.name.strip_prefix("hypothesis_")?.strip_suffix(".png")?.parse().ok()
    }

    /// The alignment picture of the best hypothesis (the demo's name).
    pub fn is_alignment(&self) -> bool {
        self.name == "alignment.png"
    }

    fn figure(&self, caption: &str, id: Option<&str>) -> String {
        // Strips (the alignment panels) take the whole width; others half.
        let class = if self.width > 2 * self.height { "big" } else { "half" };
        let id_attr = id.map(|i| format!(r#" id="{}""#, esc(i))).unwrap_or_default();
        format!(
            r#"<figure{id_attr}>{}<figcaption>{}</figcaption></figure>"#,
            png_img(self.bytes, &self.name, class).replacen(
                "<img ",
                &format!(r#"<img width="{}" height="{}" "#, self.width, self.height),
                1
            ),
            caption
        )
    }
}

/// A section heading with the input file it shows.
fn heading(title: &str, file: &Path) -> String {
    format!(r#"<h2>{}</h2><p class="note">from <span class="src">{}</span></p>"#, esc(title), esc(&file.display().to_string()))
}

/// The score section: summary, sortable table, and the pictures of the
/// top and explained hypotheses beside links to their rows.
/// `sec` numbers the score sections: only the first takes the pictures
/// and the row anchors they link to (indices repeat across files).
pub fn score(file: &Path, rows: &[ScoreRow], pictures: &[&Picture], sec: usize) -> String {
    let physics = rows.iter().any(|r| r.verdict.is_some());
    let by_index: BTreeMap<u64, &Picture> = pictures.iter().filter_map(|p| Some((p.hypothesis_index()?, *p))).collect();
    let mut order: Vec<&ScoreRow> = rows.iter().collect();
    order.sort_by_key(|r| (r.rank, r.index));
    let shown: Vec<&ScoreRow> =
        order.iter().enumerate().filter(|(i, r)| *i < TOP_ROWS || by_index.contains_key(&r.index)).map(|(_, r)| *r).collect();
    let mut h = heading("Scored hypotheses", file);
    let _ = write!(
        h,
        r#"<p class="note">{} hypotheses{}; the table shows the best {} by rank{} (click a header to sort).</p>"#,
        rows.len(),
        if physics { format!(", ranked physics first: {}", verdict_counts(rows)) } else { ", ranked by visual score".into() },
        shown.len().min(TOP_ROWS),
        if shown.len() > TOP_ROWS.min(rows.len()) { " and the explained ones beyond them (outlined)" } else { "" }
    );
    h += &score_table(&format!("scores-{sec}"), &shown, physics, &by_index, sec == 0);
    h += &score_pictures(rows, pictures, &by_index);
    h
}

/// "12 plausible, 3 unstable, ..." over the records that have a verdict.
fn verdict_counts(rows: &[ScoreRow]) -> String {
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for r in rows {
        *counts.entry(r.verdict.as_deref().unwrap_or("no verdict")).or_default() += 1;
    }
    let order = ["plausible", "unstable", "floating", "intersecting"];
    let mut keys: Vec<&str> = counts.keys().copied().collect();
    keys.sort_by_key(|k| order.iter().position(|o| o == k).unwrap_or(order.len()));
    keys.iter().map(|k| format!("{} {}", counts[k], esc(k))).collect::<Vec<_>>().join(", ")
}

fn score_table(id: &str, shown: &[&ScoreRow], physics: bool, pics: &BTreeMap<u64, &Picture>, anchors: bool) -> String {
    let mut headers = vec![
        ("rank", "rank (1 = best)"),
        ("index", "hypothesis index in the input"),
        ("score", "visual score (eq. 3)"),
        ("a_d", "mean depth alignment"),
        ("a_n", "mean normal alignment"),
        ("valid", "pixels with a valid pair"),
        ("rendered", "rendered pixels"),
        ("observed", "observed pixels"),
    ];
    if physics {
        headers.extend([
            ("verdict", "physical verdict"),
            ("|I|", "intersecting samples"),
            ("|C|", "contact samples"),
            ("|S|", "supported samples"),
            ("min δ mm", "smallest signed distance to the plane"),
            ("margin mm", "stability margin"),
        ]);
    }
    headers.push(("picture", "explanation picture"));
    let rows: Vec<Row> = shown
        .iter()
        .enumerate()
        .map(|(i, r)| (anchors.then(|| format!("row-{}", r.index)), i >= TOP_ROWS, score_cells(r, physics, pics)))
        .collect();
    format!(r#"<div class="scroll">{}</div>"#, sortable_table(id, &headers, &rows))
}

fn score_cells(r: &ScoreRow, physics: bool, pics: &BTreeMap<u64, &Picture>) -> Vec<Cell> {
    let mut c = vec![
        Cell::int(Some(r.rank)),
        Cell::int(Some(r.index)),
        Cell::num(r.score, 4),
        Cell::num(r.a_d, 4),
        Cell::num(r.a_n, 4),
        Cell::int(Some(r.valid)),
        Cell::int(Some(r.rendered)),
        Cell::int(Some(r.observed)),
    ];
    if physics {
        let v = r.verdict.as_deref().unwrap_or("");
        c.push(Cell::raw(if v.is_empty() { "–".into() } else { verdict_badge(v) }, v));
        c.extend([Cell::int(r.intersecting), Cell::int(r.contact), Cell::int(r.supported)]);
        c.push(Cell::num(r.min_distance.map(|d| d * 1e3), 2));
        c.push(Cell::num(r.stability_margin.map(|m| m * 1e3), 1));
    }
    let link = if pics.contains_key(&r.index) { format!(r##"<a href="#pic-{}">picture</a>"##, r.index) } else { String::new() };
    c.push(Cell::raw(link, if pics.contains_key(&r.index) { "1" } else { "" }));
    c
}

/// The alignment picture and the hypothesis pictures, best rank first,
/// each captioned with its row's numbers and linked back to the row.
fn score_pictures(rows: &[ScoreRow], pictures: &[&Picture], by_index: &BTreeMap<u64, &Picture>) -> String {
    let row_of: BTreeMap<u64, &ScoreRow> = rows.iter().map(|r| (r.index, r)).collect();
    let mut figs = String::new();
    for p in pictures.iter().filter(|p| p.is_alignment()) {
        figs += &p.figure("alignment of the best hypothesis: observed depth | rendered depth | per-pixel alignment (yellow aligned, red rendered only, blue observed only)", None);
    }
    let mut explained: Vec<(&u64, &&Picture)> = by_index.iter().collect();
    explained.sort_by_key(|(i, _)| row_of.get(i).map_or(u64::MAX, |r| r.rank));
    for (i, p) in explained {
        let caption = match row_of.get(i) {
            Some(r) => format!(
                r##"<a href="#row-{i}">hypothesis {i}</a>: rank {}, score {}{}"##,
                r.rank,
                num(r.score, 4),
                r.verdict.as_deref().map(|v| format!(", {}", verdict_badge(v))).unwrap_or_default()
            ),
            None => format!("hypothesis {i} (not in the score file)"),
        };
        figs += &p.figure(&caption, Some(&format!("pic-{i}")));
    }
    if figs.is_empty() {
        return String::new();
    }
    format!(r#"<h3>Pictures</h3><div class="pics">{figs}</div>"#)
}

/// The check section: one row per object, then its pictures.
pub fn check(file: &Path, c: &CheckReport, pictures: &[&Picture]) -> String {
    let mut h = heading("Physical check", file);
    let _ = write!(
        h,
        r#"<p class="note">scene <span class="src">{}</span>: {} objects, {} samples each, friction μ = {}</p>"#,
        esc(&c.scene),
        c.objects.len(),
        c.samples.map_or("?".into(), |s| s.to_string()),
        num(c.friction, 2)
    );
    let headers = [
        ("object", "object name"),
        ("verdict", "physical verdict"),
        ("|I|", "intersecting samples"),
        ("|C|", "contact samples"),
        ("|S|", "supported samples"),
        ("min δ mm", "smallest signed distance"),
        ("margin mm", "stability margin"),
        ("friction", "static equilibrium with friction"),
        ("moved mm", "displacement after the simulation (--sim)"),
        ("turned °", "rotation after the simulation (--sim)"),
        ("ε mm", "contact tolerance"),
        ("mass kg", "mass"),
    ];
    let rows: Vec<Row> = c.objects.iter().take(MAX_TABLE_ROWS).map(|o| (None, false, check_cells(o))).collect();
    h += &sortable_table("check", &headers, &rows);
    if c.objects.len() > MAX_TABLE_ROWS {
        let _ = write!(h, r#"<p class="note">(the first {MAX_TABLE_ROWS} of {} objects)</p>"#, c.objects.len());
    }
    h += &pictures_block(pictures, "explanation: samples by class (red intersecting, green contact, cyan supported, grey free), support polygons and centres of mass from above | side view");
    h
}

fn check_cells(o: &super::inputs::CheckObject) -> Vec<Cell> {
    let verdict = format!("{}{}", verdict_badge(&o.verdict), if o.is_static { " (static)" } else { "" });
    let friction = match o.friction_equilibrium {
        Some(true) => "balanced",
        Some(false) => "not balanced",
        None => "–",
    };
    let friction = if o.methods_disagree { format!("{friction} (disagrees with the support polygon)") } else { friction.to_string() };
    let d = o.displacement.as_ref();
    vec![
        Cell::text(&o.name),
        Cell::raw(verdict, &o.verdict),
        Cell::int(Some(o.intersecting)),
        Cell::int(Some(o.contact)),
        Cell::int(Some(o.supported)),
        Cell::num(o.min_distance.map(|x| x * 1e3), 2),
        Cell::num(o.stability_margin.map(|x| x * 1e3), 2),
        Cell::text(&friction),
        Cell::num(d.and_then(|d| d.translation).map(|x| x * 1e3), 2),
        Cell::num(d.and_then(|d| d.rotation_deg), 2),
        Cell::num(o.epsilon.map(|x| x * 1e3), 2),
        Cell::num(o.mass_kg, 3),
    ]
}

/// Pictures under a section, each captioned with its file name.
fn pictures_block(pictures: &[&Picture], what: &str) -> String {
    if pictures.is_empty() {
        return String::new();
    }
    let figs: String = pictures.iter().map(|p| p.figure(&format!("{}: {}", esc(&p.name), esc(what)), None)).collect();
    format!(r#"<div class="pics">{figs}</div>"#)
}

/// Pictures that belong to no section.
pub fn other_pictures(pictures: &[&Picture]) -> String {
    if pictures.is_empty() {
        return String::new();
    }
    let figs: String = pictures.iter().map(|p| p.figure(&esc(&p.name), None)).collect();
    format!(r#"<h2>Pictures</h2><div class="pics">{figs}</div>"#)
}

/// The stable-pose section: per mesh, the gallery of clusters, then the
/// tables of clusters, families and analytic poses.
pub fn stable(file: &Path, e: &StableExport, gallery: &mut Gallery) -> String {
    let mut h = heading("Stable resting poses", file);
    let _ = write!(h, r#"<p class="note">{} mesh(es), format {}</p>"#, e.meshes.len(), esc(&e.format));
    for (i, m) in e.meshes.iter().enumerate() {
        h += &stable_mesh(file, m, i, gallery);
    }
    h
}

fn stable_mesh(file: &Path, m: &StableMesh, i: usize, gallery: &mut Gallery) -> String {
    let mut h = format!(r#"<h3>{}</h3>"#, esc(if m.mesh.is_empty() { &m.sha256 } else { &m.mesh }));
    let _ = write!(
        h,
        r#"<p class="note">{} drops, {} came to rest (the denominator of every probability); collider {}; sha256 <span class="src">{}</span></p>"#,
        m.drops,
        m.settled,
        esc(&m.collider),
        esc(m.sha256.get(..16).unwrap_or(&m.sha256))
    );
    // Cards left in the report's gallery: a mesh past them is not even loaded.
    let drawn = m.clusters.len().min(GALLERY_DRAWN).min(gallery.left);
    gallery.left -= drawn;
    let none = Drawable::Missing(String::new());
    let drawable = if drawn == 0 { &none } else { gallery.prepare(&m.mesh, &m.sha256, file) };
    match drawable {
        Drawable::Ready { note: Some(n), .. } => {
            let _ = write!(h, r#"<p class="note">note: {}</p>"#, esc(n));
        }
        Drawable::Missing(why) if !why.is_empty() => {
            let _ = write!(h, r#"<p class="note">no pictures: {}; the poses are listed as text.</p>"#, esc(why));
        }
        _ => {}
    }
    h.push_str(r#"<div class="gallery">"#);
    for (k, c) in m.clusters.iter().enumerate().take(drawn) {
        h += &cluster_card(k, c, m.settled, drawable);
    }
    h.push_str("</div>");
    if drawn == 0 && !m.clusters.is_empty() {
        let _ = write!(h, r#"<p class="note">the report's {GALLERY_TOTAL} gallery pictures went to the meshes above; the clusters are in the table below.</p>"#);
    } else if m.clusters.len() > drawn {
        let _ = write!(h, r#"<p class="note">{} more clusters in the table below.</p>"#, m.clusters.len() - drawn);
    }
    h += &cluster_table(&format!("clusters-{i}"), &m.clusters);
    h += &families_table(&format!("families-{i}"), m);
    h += &analytic_table(&format!("analytic-{i}"), m);
    h
}

/// One gallery card: the side view (or a text box), probability and CI.
fn cluster_card(k: usize, c: &StableCluster, settled: u64, drawable: &Drawable) -> String {
    let pic = match drawable {
        Drawable::Ready { body, .. } => gallery::side_view(body, &c.r_model_to_plane, c.height),
        Drawable::Missing(_) => None,
    };
    let g = c.gravity_in_model;
    let visual = match pic {
        Some(bytes) => png_img(&bytes, &format!("cluster {} from the side", k + 1), "pose"),
        None => format!(
            r#"<div class="textpose">resting pose {}<br>gravity in the model frame<br>({:.3}, {:.3}, {:.3})<br>origin {:.1} mm above the plane</div>"#,
            k + 1,
            g[0],
            g[1],
            g[2],
            c.height * 1e3
        ),
    };
    format!(
        r#"<div class="card">{visual}<div class="p">#{} &nbsp; p = {}</div><div>95 % CI {} – {}</div><div>{} of {} drops; g = ({:.2}, {:.2}, {:.2})</div></div>"#,
        k + 1,
        pct(Some(c.probability)),
        pct(Some(c.ci95[0])),
        pct(Some(c.ci95[1])),
        c.count,
        settled,
        g[0],
        g[1],
        g[2]
    )
}

fn cluster_table(id: &str, clusters: &[StableCluster]) -> String {
    if clusters.is_empty() {
        return r#"<p class="note">no discrete resting poses.</p>"#.into();
    }
    let headers = [
        ("#", "cluster"),
        ("p", "probability"),
        ("CI low", "95 % CI lower bound"),
        ("CI high", "95 % CI upper bound"),
        ("count", "drops"),
        ("gravity in model", "unit gravity direction in the model frame"),
        ("height mm", "origin above the plane"),
    ];
    let rows: Vec<Row> = clusters
        .iter()
        .take(MAX_TABLE_ROWS)
        .enumerate()
        .map(|(k, c)| {
            let g = c.gravity_in_model;
            (
                None,
                false,
                vec![
                    Cell::int(Some(k as u64 + 1)),
                    Cell::num(Some(c.probability), 4),
                    Cell::num(Some(c.ci95[0]), 4),
                    Cell::num(Some(c.ci95[1]), 4),
                    Cell::int(Some(c.count)),
                    Cell::text(&format!("({:.3}, {:.3}, {:.3})", g[0], g[1], g[2])),
                    Cell::num(Some(c.height * 1e3), 1),
                ],
            )
        })
        .collect();
    sortable_table(id, &headers, &rows)
}

fn families_table(id: &str, m: &StableMesh) -> String {
    if m.families.is_empty() {
        return String::new();
    }
    let headers = [
        ("kind", "circle: rolls about an axis; scattered: ball-like"),
        ("axis", "rolling axis (model frame)"),
        ("p", "probability"),
        ("CI low", "95 % CI"),
        ("CI high", "95 % CI"),
        ("count", "drops"),
    ];
    let rows: Vec<Row> = m
        .families
        .iter()
        .take(MAX_TABLE_ROWS)
        .map(|f| {
            let axis = f.axis.map_or("–".into(), |a| format!("({:.3}, {:.3}, {:.3})", a[0], a[1], a[2]));
            (
                None,
                false,
                vec![
                    Cell::text(&f.kind),
                    Cell::text(&axis),
                    Cell::num(Some(f.probability), 4),
                    Cell::num(Some(f.ci95[0]), 4),
                    Cell::num(Some(f.ci95[1]), 4),
                    Cell::int(Some(f.count)),
                ],
            )
        })
        .collect();
    format!("<p class=\"note\">families (rolling or ball-like rest, no single pose):</p>{}", sortable_table(id, &headers, &rows))
}

fn analytic_table(id: &str, m: &StableMesh) -> String {
    if m.analytic.is_empty() {
        return String::new();
    }
    let headers = [
        ("p", "quasi-static probability"),
        ("gravity in model", "unit gravity direction in the model frame"),
        ("margin mm", "stability margin"),
    ];
    let rows: Vec<Row> = m
        .analytic
        .iter()
        .take(MAX_TABLE_ROWS)
        .map(|a| {
            let g = a.gravity_in_model;
            (
                None,
                false,
                vec![
                    Cell::num(Some(a.probability), 4),
                    Cell::text(&format!("({:.3}, {:.3}, {:.3})", g[0], g[1], g[2])),
                    Cell::num(Some(a.margin * 1e3), 1),
                ],
            )
        })
        .collect();
    format!("<p class=\"note\">analytic cross-check (convex hull facets):</p>{}", sortable_table(id, &headers, &rows))
}

/// The eval section: totals, recall curves per error type, per-object bars.
pub fn eval(file: &Path, e: &EvalReport) -> String {
    let mut h = heading("BOP evaluation", file);
    h += &eval_summary(e);
    let mut curves: Vec<(&String, &Vec<super::inputs::EvalThreshold>)> = e.per_threshold.iter().collect();
    curves.sort_by_key(|(k, _)| (error_order(k), (*k).clone()));
    let charts: String = curves.iter().map(|(name, pts)| recall_curves(name, pts)).collect();
    if !charts.is_empty() {
        let _ = write!(h, r#"<h3>Recall against threshold</h3><div class="charts">{charts}</div>"#);
    }
    h += &per_object(e);
    h
}

fn eval_summary(e: &EvalReport) -> String {
    let mut rows = vec![("AR", num(e.ar, 4)), ("AR VSD", num(e.ar_vsd, 4)), ("AR MSSD", num(e.ar_mssd, 4)), ("AR MSPD", num(e.ar_mspd, 4))];
    let at = num(e.add_threshold, 2);
    for (name, v) in [("AD", e.recall_ad), ("ADD", e.recall_add), ("ADI", e.recall_adi)] {
        if v.is_some() {
            rows.push((name, format!("{} (recall at {at} × diameter)", num(v, 4))));
        }
    }
    let count = |v: Option<u64>| v.map_or("–".into(), |x| x.to_string());
    rows.push(("targets", count(e.n_targets)));
    rows.push(("estimates", count(e.n_estimates)));
    rows.push(("images", count(e.n_images)));
    let mut h = String::from(r#"<table class="kv">"#);
    for (k, v) in rows {
        let _ = write!(h, "<tr><td>{k}</td><td>{v}</td></tr>");
    }
    for (k, v) in [("dataset", &e.dataset), ("results", &e.results), ("device", &e.device)] {
        if let Some(v) = v {
            let _ = write!(h, "<tr><td>{k}</td><td>{}</td></tr>", esc(v));
        }
    }
    h.push_str("</table>");
    h
}

/// BOP's order of the error types (AR's parts first), unknown ones last.
fn error_order(name: &str) -> usize {
    ["vsd", "mssd", "mspd", "ad", "add", "adi"].iter().position(|o| *o == name).unwrap_or(9)
}

/// The axis label of an error type's thresholds.
fn threshold_label(name: &str) -> &'static str {
    match name {
        "vsd" => "θ: misaligned fraction of visible pixels",
        "mssd" => "threshold × object diameter",
        "mspd" => "threshold (px, × image width / 640)",
        _ => "threshold × object diameter",
    }
}

/// One chart: recall per threshold; VSD (thresholds × τ) as the mean over
/// τ, which is what AR_VSD averages, with one thin line per τ behind it.
fn recall_curves(name: &str, pts: &[super::inputs::EvalThreshold]) -> String {
    let pts = &pts[..pts.len().min(MAX_CURVE_POINTS)];
    let colour = error_colour(name);
    let mut by_tau: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    let mut by_threshold: BTreeMap<u64, (f64, f64, usize)> = BTreeMap::new();
    for p in pts {
        let Some(r) = p.recall.filter(|r| r.is_finite()) else { continue };
        if let Some(t) = p.tau {
            by_tau.entry(format!("τ = {t}")).or_default().push((p.threshold, r));
        }
        let e = by_threshold.entry(p.threshold.to_bits()).or_insert((p.threshold, 0.0, 0));
        e.1 += r;
        e.2 += 1;
    }
    let mut mean: Vec<(f64, f64)> = by_threshold.values().map(|&(t, s, n)| (t, s / n as f64)).collect();
    mean.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut series: Vec<Series> = by_tau
        .into_iter()
        .filter(|_| name == "vsd")
        .map(|(n, mut p)| {
            p.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series { name: n, colour, points: p, thin: true }
        })
        .collect();
    let label = if series.is_empty() { name.to_uppercase() } else { format!("{} (mean over τ)", name.to_uppercase()) };
    series.push(Series { name: label, colour, points: mean, thin: false });
    recall_chart(&format!("{} recall", name.to_uppercase()), threshold_label(name), &series)
}

/// Bars of AR and its parts per object, and the same numbers as a table.
fn per_object(e: &EvalReport) -> String {
    if e.per_object.is_empty() {
        return String::new();
    }
    // Object ids are map keys (strings): order them as numbers.
    let mut objects: Vec<(&String, &super::inputs::EvalObject)> = e.per_object.iter().collect();
    objects.sort_by_key(|(k, _)| (k.parse::<u64>().unwrap_or(u64::MAX), (*k).clone()));
    let mut errors: Vec<&String> = e.per_object.values().flat_map(|o| o.by_error.keys()).collect();
    errors.sort_by_key(|k| (error_order(k), *k));
    errors.dedup();
    let groups: Vec<BarGroup> = objects
        .iter()
        .take(MAX_BARS_OBJECTS)
        .map(|(obj, s)| {
            let mut bars = vec![("ar".to_string(), s.ar)];
            bars.extend(errors.iter().map(|k| ((*k).clone(), s.by_error.get(*k).copied().flatten())));
            (format!("obj {obj}"), bars)
        })
        .collect();
    let mut h = format!(r#"<h3>Per object</h3><div class="charts">{}</div>"#, bar_chart("AR and its parts per object", &groups));
    let mut headers: Vec<(String, String)> =
        vec![("object".into(), "obj_id".into()), ("targets".into(), "targets".into()), ("AR".into(), "average recall".into())];
    headers.extend(errors.iter().map(|k| (k.to_uppercase(), format!("{} recall", k.to_uppercase()))));
    let headers: Vec<(&str, &str)> = headers.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
    let rows: Vec<Row> = objects
        .iter()
        .take(MAX_TABLE_ROWS)
        .map(|(obj, s)| {
            let mut c = vec![Cell::text(obj), Cell::int(Some(s.targets)), Cell::num(s.ar, 4)];
            c.extend(errors.iter().map(|k| Cell::num(s.by_error.get(*k).copied().flatten(), 4)));
            (None, false, c)
        })
        .collect();
    h += &sortable_table("per-object", &headers, &rows);
    h
}
