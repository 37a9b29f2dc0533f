//! A picture of a scene check a person can read: on the left the scene seen
//! from above (along gravity), on the right seen from the side.
//!
//! Samples are coloured by class: intersecting red, contact green,
//! supported cyan, free light grey. In the top view each dynamic object's
//! support polygon is outlined (dark blue) and its projected centre of mass
//! is a cross: black when the object is stable, red when it is not. In the
//! side view the support planes are dark lines.

use glam::{DVec2, DVec3};
use image::{Rgb, RgbImage};

use super::check::ObjectCheck;
use super::contacts::{Detail, SampleClass};
use super::scene::{Plane, Scene};
use super::support::support_basis;

const SIZE: u32 = 512;

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
/// support polygon or centre of mass drawn) and whether it is stable.
pub struct Drawn<'a> {
    pub detail: &'a Detail,
    pub is_static: bool,
    pub stable: bool,
}

/// Draws the top and side views of a checked scene (1024 × 512 pixels).
pub fn explain_image(scene: &Scene, checks: &[ObjectCheck]) -> RgbImage {
    let items: Vec<Drawn> = checks
        .iter()
        .map(|c| Drawn { detail: &c.detail, is_static: c.is_static, stable: c.evaluation.stable })
        .collect();
    draw_views(&scene.planes, scene.gravity, &items)
}

/// Top and side views (1024 × 512 pixels) of `items` over `planes`.
pub fn draw_views(planes: &[Plane], gravity: DVec3, items: &[Drawn]) -> RgbImage {
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
            line(
                &mut img,
                (a.0.max(SIZE as i64 + 1), a.1),
                b,
                Rgb([60, 60, 60]),
            );
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
            line(&mut img, a, b, Rgb([20, 40, 160]));
        }
        let col = if c.stable {
            Rgb([0, 0, 0])
        } else {
            Rgb([220, 0, 0])
        };
        for (view, p) in [(&tv, c.detail.com), (&sv, side(c.detail.com_world))] {
            let (x, y) = view.px(p);
            line(&mut img, (x - 6, y), (x + 6, y), col);
            line(&mut img, (x, y - 6), (x, y + 6), col);
        }
    }
    img
}
