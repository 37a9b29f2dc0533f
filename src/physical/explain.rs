//! A picture of a scene check a person can read: on the left the scene seen
//! from above (along gravity), on the right seen from the side.
//!
//! Samples are coloured by class: intersecting red, contact green,
//! supported cyan, free light grey. In the top view each dynamic object's
//! support polygon is outlined (dark blue) and its projected centre of mass
//! is a cross: black when the object is stable, red when it is not. In the
//! side view the support planes are dark lines. Captions, scale bars and a
//! key of these marks are drawn in ([`crate::draw`]).

use glam::{DVec2, DVec3};
use image::{Rgb, RgbImage};

use super::check::ObjectCheck;
use super::contacts::{Detail, SampleClass};
use super::scene::{Plane, Scene};
use super::support::support_basis;
use super::Verdict;
use crate::draw::{self, Mark};
use crate::explain::verdict_colour;

const SIZE: u32 = 512;

const PLANE: Rgb<u8> = Rgb([60, 60, 60]);
const POLYGON: Rgb<u8> = Rgb([20, 40, 160]);
const COM_STABLE: Rgb<u8> = Rgb([0, 0, 0]);
const COM_UNSTABLE: Rgb<u8> = Rgb([220, 0, 0]);

fn class_colour(c: SampleClass) -> Rgb<u8> {
    match c {
        SampleClass::Intersecting => Rgb([220, 30, 30]),
        SampleClass::Contact => Rgb([30, 170, 60]),
        SampleClass::Supported => Rgb([0, 190, 210]),
        SampleClass::Free => Rgb([195, 195, 195]),
    }
}

struct View {
    lo: DVec2,
    scale: f64,
    x0: u32,
}

impl View {
    fn px(&self, p: DVec2) -> (i64, i64) {
        let q = (p - self.lo) * self.scale;
        (
            self.x0 as i64 + 16 + q.x as i64,
            SIZE as i64 - 16 - q.y as i64,
        )
    }
}

fn dot(img: &mut RgbImage, (x, y): (i64, i64), r: i64, c: Rgb<u8>) {
    for dy in -r..=r {
        for dx in -r..=r {
            let (a, b) = (x + dx, y + dy);
            if a >= 0 && b >= 0 && (a as u32) < img.width() && (b as u32) < img.height() {
                img.put_pixel(a as u32, b as u32, c);
            }
        }
    }
}

fn line(img: &mut RgbImage, a: (i64, i64), b: (i64, i64), c: Rgb<u8>) {
    let n = (b.0 - a.0).abs().max((b.1 - a.1).abs()).max(1);
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let p = (
            (a.0 as f64 + (b.0 - a.0) as f64 * t).round() as i64,
            (a.1 as f64 + (b.1 - a.1) as f64 * t).round() as i64,
        );
        dot(img, p, 0, c);
    }
}

/// One object to draw: its per-sample detail, whether it is static (no
/// support polygon or centre of mass drawn), whether it is stable, and a
/// label drawn beside its centre of mass in the top view.
pub struct Drawn<'a> {
    pub detail: &'a Detail,
    pub is_static: bool,
    pub stable: bool,
    pub label: Option<&'a str>,
}

/// The picture of a checked scene: a title with the verdicts, the top and
/// side views with their key ([`draw_views`]), and the objects by number
/// (beside their centres of mass) with their verdicts, in the verdict's
/// colour (1024 pixels wide).
pub fn explain_image(scene: &Scene, checks: &[ObjectCheck]) -> RgbImage {
    let numbers: Vec<String> = (1..=checks.len()).map(|k| k.to_string()).collect();
    let items: Vec<Drawn> = checks
        .iter()
        .zip(&numbers)
        .map(|(c, n)| Drawn {
            detail: &c.detail,
            is_static: c.is_static,
            stable: c.evaluation.stable,
            label: (!c.is_static).then_some(n.as_str()),
        })
        .collect();
    let views = draw_views(&scene.planes, scene.gravity, &items);
    let dynamic: Vec<&ObjectCheck> = checks.iter().filter(|c| !c.is_static).collect();
    let counts: Vec<String> = [Verdict::Plausible, Verdict::Unstable, Verdict::Floating, Verdict::Intersecting]
        .iter()
        .map(|v| (v, dynamic.iter().filter(|c| c.evaluation.verdict == *v).count()))
        .filter(|(_, n)| *n > 0)
        .map(|(v, n)| format!("{n} {}", v.as_str()))
        .collect();
    let statics = checks.len() - dynamic.len();
    let title = format!(
        "physical check: {} objects{}: {}",
        checks.len(),
        if statics > 0 { format!(" ({statics} static)") } else { String::new() },
        if counts.is_empty() { "none dynamic".to_string() } else { counts.join(", ") }
    );
    let entries: Vec<(Mark, String)> = checks
        .iter()
        .enumerate()
        .map(|(k, c)| {
            if c.is_static {
                (Mark::Fill(Rgb([195, 195, 195])), format!("{} {}: static", k + 1, c.name))
            } else {
                let margin = c.evaluation.stability_margin.map_or(String::new(), |m| format!(", margin {:.1} mm", m * 1e3));
                (
                    Mark::Fill(verdict_colour(c.evaluation.verdict)),
                    format!("{} {}: {}{margin}", k + 1, c.name, c.evaluation.verdict.as_str()),
                )
            }
        })
        .collect();
    let entries: Vec<(Mark, &str)> = entries.iter().map(|(m, s)| (*m, s.as_str())).collect();
    let objects = draw::key(views.width(), &entries);
    let band = draw::title_band(views.width(), &title, Rgb([225, 225, 225]));
    draw::stack(&[&band, &views, &objects], 0)
}

/// A round length of about `m` metres (1, 2 or 5 times a power of ten, at
/// most `m`) and its label.
fn scale_length(m: f64) -> (f64, String) {
    let p = 10f64.powf(m.max(1e-9).log10().floor());
    let l = [5.0, 2.0, 1.0].into_iter().map(|k| k * p).find(|&l| l <= m).unwrap_or(p);
    let s = if l >= 1.0 {
        format!("{} m", draw::short_number(l))
    } else if l >= 0.01 {
        format!("{} cm", draw::short_number(l * 1e2))
    } else {
        format!("{} mm", draw::short_number(l * 1e3))
    };
    (l, s)
}

/// The caption band of the views: each view's name and a scale bar.
fn caption_band(views: [(&View, &str); 2]) -> RgbImage {
    let mut band = draw::caption_band(2 * SIZE, &[]);
    let h = band.height() as i64;
    for (view, name) in views {
        draw::draw_text(&mut band, view.x0 as i64 + draw::PAD as i64, (draw::PAD / 2) as i64, draw::TEXT_PX, draw::INK, name);
        let (l, label) = scale_length(0.2 * (SIZE - 32) as f64 / view.scale);
        let len = (l * view.scale).round() as i64;
        let right = (view.x0 + SIZE) as i64 - 16;
        let x0 = right - text_width(&label) as i64 - 6 - len;
        draw::fill_rect(&mut band, x0, h / 2, len as u32, 2, draw::INK);
        draw::fill_rect(&mut band, x0, h / 2 - 4, 1, 10, draw::INK);
        draw::fill_rect(&mut band, x0 + len - 1, h / 2 - 4, 1, 10, draw::INK);
        draw::draw_text(&mut band, right - text_width(&label) as i64, (draw::PAD / 2) as i64, draw::TEXT_PX, draw::INK, &label);
    }
    band
}

fn text_width(s: &str) -> u32 {
    draw::text_width(draw::TEXT_PX, s)
}

/// The key of the views' marks.
fn views_key(width: u32) -> RgbImage {
    draw::key(
        width,
        &[
            (Mark::Dot(class_colour(SampleClass::Intersecting)), "intersecting (δ < −ε)"),
            (Mark::Dot(class_colour(SampleClass::Contact)), "contact (|δ| ≤ ε)"),
            (Mark::Dot(class_colour(SampleClass::Supported)), "supported"),
            (Mark::Dot(class_colour(SampleClass::Free)), "free"),
            (Mark::Line(POLYGON), "support polygon"),
            (Mark::Cross(COM_STABLE), "centre of mass: stable"),
            (Mark::Cross(COM_UNSTABLE), "not stable"),
            (Mark::Line(PLANE), "plane"),
        ],
    )
}

/// Top and side views of `items` over `planes`: captions with scale bars
/// (22 pixels), the views (1024 × 512) and the key of their marks below
/// (about 40 pixels).
pub fn draw_views(planes: &[Plane], gravity: DVec3, items: &[Drawn]) -> RgbImage {
    let (canvas, tv, sv) = draw_canvas(planes, gravity, items);
    let captions = caption_band([(&tv, "top view (along gravity)"), (&sv, "side view")]);
    draw::stack(&[&captions, &canvas, &views_key(canvas.width())], 0)
}

/// The two views alone (1024 × 512: top | side), without captions or key,
/// for thumbnails that carry their own words (the report's gallery).
pub fn draw_views_bare(planes: &[Plane], gravity: DVec3, items: &[Drawn]) -> RgbImage {
    draw_canvas(planes, gravity, items).0
}

/// The bare views (1024 × 512) and their projections.
fn draw_canvas(planes: &[Plane], gravity: DVec3, items: &[Drawn]) -> (RgbImage, View, View) {
    let mut img = RgbImage::from_pixel(2 * SIZE, SIZE, Rgb([255, 255, 255]));
    let (u, v) = support_basis(gravity);
    let up = -gravity.normalize();
    let top = |p: DVec3| DVec2::new(p.dot(u), p.dot(v));
    let side = |p: DVec3| DVec2::new(p.dot(u), p.dot(up));
    let all: Vec<DVec3> = items
        .iter()
        .flat_map(|c| c.detail.world.iter().copied())
        .collect();
    let fit = |f: &dyn Fn(DVec3) -> DVec2, x0: u32| {
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in &all {
            lo = lo.min(f(*p));
            hi = hi.max(f(*p));
        }
        let span = (hi - lo).max_element().max(1e-6);
        let pad = 0.05 * span;
        View {
            lo: lo - DVec2::splat(pad) - (DVec2::splat(span) - (hi - lo)) * 0.5,
            scale: (SIZE - 32) as f64 / (span + 2.0 * pad),
            x0,
        }
    };
    let tv = fit(&top, 0);
    let sv = fit(&side, SIZE);
    // Separator and planes (side view: the plane's trace).
    line(
        &mut img,
        (SIZE as i64, 0),
        (SIZE as i64, SIZE as i64 - 1),
        Rgb([120, 120, 120]),
    );
    for p in planes {
        let h = p.point.dot(up);
        if p.normal.dot(up) > 0.99 {
            let a = sv.px(DVec2::new(sv.lo.x, h));
            let b = sv.px(DVec2::new(sv.lo.x + (SIZE - 32) as f64 / sv.scale, h));
            line(&mut img, (a.0.max(SIZE as i64 + 1), a.1), b, PLANE);
        }
    }
    // Free samples first, then the classes on top.
    for pass in 0..2 {
        for c in items {
            for (p, cls) in c.detail.world.iter().zip(&c.detail.classes) {
                if (*cls == SampleClass::Free) == (pass == 0) {
                    let col = class_colour(*cls);
                    dot(&mut img, tv.px(top(*p)), 1, col);
                    dot(&mut img, sv.px(side(*p)), 1, col);
                }
            }
        }
    }
    for c in items.iter().filter(|c| !c.is_static) {
        let hull = &c.detail.hull;
        for i in 0..hull.len() {
            let a = tv.px(hull[i]);
            let b = tv.px(hull[(i + 1) % hull.len()]);
            line(&mut img, a, b, POLYGON);
        }
        let col = if c.stable { COM_STABLE } else { COM_UNSTABLE };
        for (view, p) in [(&tv, c.detail.com), (&sv, side(c.detail.com_world))] {
            let (x, y) = view.px(p);
            line(&mut img, (x - 6, y), (x + 6, y), col);
            line(&mut img, (x, y - 6), (x, y + 6), col);
        }
        if let Some(label) = c.label {
            // Beside the top view's cross, on a white patch so it reads over samples.
            let (x, y) = tv.px(c.detail.com);
            let (w, h) = (text_width(label), draw::line_height(draw::TEXT_PX));
            let (lx, ly) = (x + 8, y - 8 - h as i64);
            draw::fill_rect(&mut img, lx - 2, ly, w + 4, h, Rgb([255, 255, 255]));
            draw::draw_text(&mut img, lx, ly, draw::TEXT_PX, col, label);
        }
    }
    (img, tv, sv)
}
