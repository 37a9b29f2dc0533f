//! Text, titles and legends drawn into the pictures, so that a picture
//! explains itself: a title band, captions, a colour bar with its unit and
//! a key of marks with labels.
//!
//! Text is DejaVu Sans (shipped in `assets/fonts`, cut down to Latin, Greek
//! and a few signs; Bitstream Vera licence, see `LICENSE-DejaVu.txt` there),
//! rasterized by `ab_glyph` and alpha-blended over the picture. Everything
//! is clipped at the image border: long text or a small image never panics.

use std::sync::OnceLock;

use ab_glyph::{point, Font, FontRef, GlyphId, PxScale, ScaleFont};
use image::{Rgb, RgbImage};

static FONT_BYTES: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::try_from_slice(FONT_BYTES).expect("the shipped font parses"))
}

/// Size of captions and legends (line height in pixels).
pub const TEXT_PX: f32 = 15.0;
/// Size of titles.
pub const TITLE_PX: f32 = 18.0;
/// Dark text.
pub const INK: Rgb<u8> = Rgb([20, 20, 20]);
/// Picture background.
pub const PAPER: Rgb<u8> = Rgb([255, 255, 255]);
/// Space around text in bands.
pub const PAD: u32 = 6;

/// Calls `f(glyph, caret)` per glyph of `text` laid out on one line at
/// `px`, kerned; returns the advance of the whole line.
fn layout(px: f32, text: &str, mut f: impl FnMut(GlyphId, f32)) -> f32 {
    let sf = font().as_scaled(PxScale::from(px));
    let (mut caret, mut prev) = (0.0f32, None);
    for ch in text.chars().filter(|c| !c.is_control()) {
        let id = font().glyph_id(ch);
        if let Some(p) = prev {
            caret += sf.kern(p, id);
        }
        f(id, caret);
        caret += sf.h_advance(id);
        prev = Some(id);
    }
    caret
}

/// Width in pixels of `text` on one line at size `px`.
pub fn text_width(px: f32, text: &str) -> u32 {
    layout(px, text, |_, _| {}).ceil() as u32
}

/// Height of a line of text at size `px` (ascent to descent).
pub fn line_height(px: f32) -> u32 {
    font().as_scaled(PxScale::from(px)).height().ceil() as u32
}

/// Blends `c` over the pixel at (x, y) with coverage `a` in [0, 1];
/// nothing outside the image.
fn blend(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>, a: f32) {
    if x < 0 || y < 0 || x >= img.width() as i64 || y >= img.height() as i64 || a <= 0.0 {
        return;
    }
    let a = a.min(1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for i in 0..3 {
        p.0[i] = (p.0[i] as f32 + (c.0[i] as f32 - p.0[i] as f32) * a).round() as u8;
    }
}

/// Draws `text` on one line with its box's top-left corner at (x, y) (the
/// box is [`text_width`] × [`line_height`]); returns its width. Clipped at
/// the image border.
pub fn draw_text(img: &mut RgbImage, x: i64, y: i64, px: f32, colour: Rgb<u8>, text: &str) -> u32 {
    let scale = PxScale::from(px);
    let baseline = y as f32 + font().as_scaled(scale).ascent();
    let w = layout(px, text, |id, caret| {
        let g = id.with_scale_and_position(scale, point(x as f32 + caret, baseline));
        if let Some(o) = font().outline_glyph(g) {
            let b = o.px_bounds();
            o.draw(|gx, gy, a| blend(img, b.min.x as i64 + gx as i64, b.min.y as i64 + gy as i64, colour, a));
        }
    });
    w.ceil() as u32
}

/// Fills the rectangle at (x, y) of size w × h, clipped.
pub fn fill_rect(img: &mut RgbImage, x: i64, y: i64, w: u32, h: u32, c: Rgb<u8>) {
    let (x0, y0) = (x.max(0), y.max(0));
    let x1 = (x + w as i64).min(img.width() as i64);
    let y1 = (y + h as i64).min(img.height() as i64);
    for yy in y0..y1 {
        for xx in x0..x1 {
            img.put_pixel(xx as u32, yy as u32, c);
        }
    }
}

/// Dark or white text, whichever reads better on `bg`.
pub fn ink_on(bg: Rgb<u8>) -> Rgb<u8> {
    let [r, g, b] = bg.0.map(f32::from);
    if 0.299 * r + 0.587 * g + 0.114 * b > 140.0 {
        INK
    } else {
        PAPER
    }
}

/// `text` broken at spaces into lines at most `width` pixels wide at size
/// `px` (a word longer than that stays whole on its line, to be clipped).
pub fn wrap(px: f32, text: &str, width: u32) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in text.split(' ') {
        match lines.last_mut() {
            Some(l) if text_width(px, &format!("{l} {word}")) <= width => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// A band `width` wide in `background` with `title`, on as many lines as
/// it needs.
pub fn title_band(width: u32, title: &str, background: Rgb<u8>) -> RgbImage {
    let lines = wrap(TITLE_PX, title, width.saturating_sub(4 * PAD));
    let lh = line_height(TITLE_PX);
    let mut band = RgbImage::from_pixel(width.max(1), lines.len() as u32 * lh + 2 * PAD, background);
    for (i, l) in lines.iter().enumerate() {
        draw_text(&mut band, 2 * PAD as i64, (PAD + i as u32 * lh) as i64, TITLE_PX, ink_on(background), l);
    }
    band
}

/// A white band `width` wide with one caption per (x, text).
pub fn caption_band(width: u32, captions: &[(u32, &str)]) -> RgbImage {
    let mut band = RgbImage::from_pixel(width.max(1), line_height(TEXT_PX) + PAD, PAPER);
    for &(x, text) in captions {
        draw_text(&mut band, x as i64, (PAD / 2) as i64, TEXT_PX, INK, text);
    }
    band
}

/// The parts one below the other, left-aligned, `gap` pixels apart, on
/// white.
pub fn stack(parts: &[&RgbImage], gap: u32) -> RgbImage {
    let width = parts.iter().map(|p| p.width()).max().unwrap_or(1).max(1);
    let height = parts.iter().map(|p| p.height()).sum::<u32>() + gap * parts.len().saturating_sub(1) as u32;
    let mut img = RgbImage::from_pixel(width, height.max(1), PAPER);
    let mut y = 0;
    for p in parts {
        image::imageops::replace(&mut img, *p, 0, y as i64);
        y += p.height() + gap;
    }
    img
}

/// The parts side by side, top-aligned, `gap` pixels apart, on white.
pub fn beside(parts: &[&RgbImage], gap: u32) -> RgbImage {
    let height = parts.iter().map(|p| p.height()).max().unwrap_or(1).max(1);
    let width = parts.iter().map(|p| p.width()).sum::<u32>() + gap * parts.len().saturating_sub(1) as u32;
    let mut img = RgbImage::from_pixel(width.max(1), height, PAPER);
    let mut x = 0;
    for p in parts {
        image::imageops::replace(&mut img, *p, x as i64, 0);
        x += p.width() + gap;
    }
    img
}

/// `img` under a [`title_band`] as wide as it.
pub fn with_title(img: &RgbImage, title: &str, background: Rgb<u8>) -> RgbImage {
    stack(&[&title_band(img.width(), title, background), img], 0)
}

/// A value on a scale, short: 3 significant digits, no trailing zeros.
pub fn short_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A horizontal colour bar `width` wide: `label` on the left, the bar with
/// `map(t)` from t = 0 (value `lo`) to t = 1 (`hi`), and ticks below it at
/// both ends and between, labelled with the value and `unit` at the ends.
pub fn colour_bar(width: u32, label: &str, map: &dyn Fn(f32) -> Rgb<u8>, lo: f64, hi: f64, unit: &str) -> RgbImage {
    let lh = line_height(TEXT_PX);
    let bar_h = 12;
    let mut img = RgbImage::from_pixel(width.max(1), PAD + bar_h + 4 + lh + PAD, PAPER);
    let label_w = draw_text(&mut img, PAD as i64, (PAD + bar_h / 2) as i64 - lh as i64 / 2, TEXT_PX, INK, label);
    // The end labels hang half out of the bar's ends.
    let end = |v: f64| format!("{} {unit}", short_number(v)).trim_end().to_string();
    let (lo_s, hi_s) = (end(lo), end(hi));
    let x0 = (PAD + label_w + 12 + text_width(TEXT_PX, &lo_s) / 2) as i64;
    let x1 = width as i64 - (2 * PAD + text_width(TEXT_PX, &hi_s) / 2) as i64;
    let len = x1 - x0;
    if len < 8 {
        return img;
    }
    for x in x0..=x1 {
        let c = map((x - x0) as f32 / len as f32);
        fill_rect(&mut img, x, PAD as i64, 1, bar_h, c);
    }
    let ty = (PAD + bar_h) as i64;
    let n = if len > 300 { 4 } else { 2 };
    for k in 0..=n {
        let x = x0 + len * k / n;
        fill_rect(&mut img, x, ty, 1, 4, INK);
        let v = lo + (hi - lo) * k as f64 / n as f64;
        let s = if k == 0 {
            lo_s.clone()
        } else if k == n {
            hi_s.clone()
        } else {
            short_number(v)
        };
        draw_text(&mut img, x - text_width(TEXT_PX, &s) as i64 / 2, ty + 4, TEXT_PX, INK, &s);
    }
    img
}

/// A mark in a [`key`].
#[derive(Clone, Copy, Debug)]
pub enum Mark {
    /// A filled square (a colour of a colour map or an area).
    Fill(Rgb<u8>),
    /// A small dot (a sample).
    Dot(Rgb<u8>),
    /// A line (an outline or a trace).
    Line(Rgb<u8>),
    /// A cross (a point such as a centre of mass).
    Cross(Rgb<u8>),
}

/// Draws `mark` in the `s` × `s` square at (x, y).
pub fn draw_mark(img: &mut RgbImage, x: i64, y: i64, s: u32, mark: Mark) {
    let c = s as i64 / 2;
    match mark {
        Mark::Fill(col) => {
            fill_rect(img, x, y, s, s, Rgb([90, 90, 90]));
            fill_rect(img, x + 1, y + 1, s.saturating_sub(2), s.saturating_sub(2), col);
        }
        Mark::Dot(col) => fill_rect(img, x + c - 2, y + c - 2, 5, 5, col),
        Mark::Line(col) => fill_rect(img, x, y + c - 1, s, 2, col),
        Mark::Cross(col) => {
            fill_rect(img, x, y + c, s, 1, col);
            fill_rect(img, x + c, y, 1, s, col);
        }
    }
}

/// A key `width` wide: each mark followed by its label, flowing left to
/// right and onto further lines when the width is used up.
pub fn key(width: u32, items: &[(Mark, &str)]) -> RgbImage {
    let lh = line_height(TEXT_PX);
    let s = 13;
    let mut places = Vec::new();
    let (mut x, mut line) = (PAD, 0u32);
    for (mark, label) in items {
        let w = s + 5 + text_width(TEXT_PX, label);
        if x > PAD && x + w + PAD > width {
            x = PAD;
            line += 1;
        }
        places.push((x, line, *mark, *label));
        x += w + 18;
    }
    let lines = places.last().map_or(0, |p| p.1 + 1);
    let mut img = RgbImage::from_pixel(width.max(1), lines * (lh + 4) + PAD, PAPER);
    for (x, line, mark, label) in places {
        let y = (PAD / 2 + line * (lh + 4)) as i64;
        draw_mark(&mut img, x as i64, y + (lh as i64 - s as i64) / 2, s, mark);
        draw_text(&mut img, (x + s + 5) as i64, y, TEXT_PX, INK, label);
    }
    img
}

/// Lines of plain text `width` wide, each wrapped at spaces to fit.
pub fn text_lines(width: u32, lines: &[&str]) -> RgbImage {
    let lines: Vec<String> = lines.iter().flat_map(|l| wrap(TEXT_PX, l, width.saturating_sub(2 * PAD))).collect();
    let lh = line_height(TEXT_PX);
    let mut img = RgbImage::from_pixel(width.max(1), lines.len() as u32 * (lh + 2) + PAD, PAPER);
    for (i, l) in lines.iter().enumerate() {
        draw_text(&mut img, PAD as i64, (PAD / 2 + i as u32 * (lh + 2)) as i64, TEXT_PX, INK, l);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn changed(img: &RgbImage, bg: Rgb<u8>) -> Vec<(u32, u32)> {
        img.enumerate_pixels().filter(|(_, _, p)| **p != bg).map(|(x, y, _)| (x, y)).collect()
    }

    #[test]
    fn text_draws_inside_its_box_only() {
        let mut img = RgbImage::from_pixel(400, 60, PAPER);
        let text = "hypothesis 17: τ = 20 mm, α ½ (a_d + a_n) — Ågj";
        let w = draw_text(&mut img, 10, 12, TEXT_PX, INK, text);
        assert_eq!(w, text_width(TEXT_PX, text));
        let px = changed(&img, PAPER);
        assert!(px.len() > 200, "the text is drawn: {} pixels", px.len());
        let h = line_height(TEXT_PX);
        assert!(h >= 11 && TEXT_PX >= 11.0);
        for (x, y) in px {
            assert!((9..=10 + w + 1).contains(&x) && (12..12 + h).contains(&y), "pixel ({x}, {y}) outside the box");
        }
    }

    #[test]
    fn width_grows_with_text_and_empty_text_draws_nothing() {
        assert_eq!(text_width(TEXT_PX, ""), 0);
        assert!(text_width(TEXT_PX, "ab") > text_width(TEXT_PX, "a"));
        assert!(text_width(TITLE_PX, "depth") > text_width(TEXT_PX, "depth"));
        let mut img = RgbImage::from_pixel(50, 30, PAPER);
        assert_eq!(draw_text(&mut img, 5, 5, TEXT_PX, INK, ""), 0);
        assert!(changed(&img, PAPER).is_empty());
    }

    #[test]
    fn text_is_clipped_at_the_border() {
        // Longer than the image, partly above and left of it, and on a 1x1 image.
        let mut img = RgbImage::from_pixel(40, 10, PAPER);
        draw_text(&mut img, -7, -5, TITLE_PX, INK, &"long text ".repeat(50));
        assert!(!changed(&img, PAPER).is_empty());
        let mut tiny = RgbImage::from_pixel(1, 1, PAPER);
        draw_text(&mut tiny, 0, 0, TEXT_PX, INK, "W");
        draw_text(&mut tiny, 5000, -5000, TEXT_PX, INK, "W");
        let mut far = RgbImage::from_pixel(20, 20, PAPER);
        draw_text(&mut far, 30, 30, TEXT_PX, INK, "outside");
        assert!(changed(&far, PAPER).is_empty());
    }

    #[test]
    fn blending_keeps_the_colour_between_ink_and_paper() {
        let mut img = RgbImage::from_pixel(200, 30, Rgb([0, 0, 255]));
        draw_text(&mut img, 2, 2, TEXT_PX, Rgb([255, 0, 0]), "mixed");
        assert!(img.pixels().all(|p| p.0[1] == 0));
        assert!(img.pixels().any(|p| p.0[0] > 0 && p.0[0] < 255), "anti-aliased edges");
    }

    #[test]
    fn bands_bars_and_keys_have_their_width_and_never_panic_small() {
        let bar = colour_bar(500, "depth", &|t| Rgb([(t * 255.0) as u8, 0, 0]), 512.0, 688.5, "mm");
        assert_eq!(bar.width(), 500);
        // The bar runs from dark to red, left to right.
        let row = PAD + 6;
        let reds: Vec<u8> = (0..500).map(|x| bar.get_pixel(x, row).0[0]).filter(|&r| r != 255).collect();
        assert!(reds.first() < reds.last());
        let items = [(Mark::Fill(Rgb([200, 40, 40])), "rendered only"), (Mark::Cross(INK), "centre of mass"), (Mark::Dot(INK), "x")];
        let one = key(800, &items);
        let wrapped = key(120, &items);
        assert!(wrapped.height() > one.height(), "a narrow key wraps");
        for w in [0, 1, 5] {
            colour_bar(w, "a long label", &|_| INK, 0.0, 1.0, "");
            key(w, &items);
            title_band(w, "title", INK);
            caption_band(w, &[(0, "caption")]);
            text_lines(w, &["a", "b"]);
        }
        let t = with_title(&RgbImage::new(30, 20), "a title far longer than thirty pixels", Rgb([40, 160, 70]));
        assert_eq!(t.width(), 30);
        assert_eq!(t.get_pixel(1, 1).0, [40, 160, 70]);
    }

    #[test]
    fn long_titles_and_notes_wrap_to_the_width() {
        let text = "hypothesis 17 (rank 1 of 4096): score 0.912 (a_d 0.950, a_n 0.870), plausible";
        let lines = wrap(TITLE_PX, text, 200);
        assert!(lines.len() > 1 && lines.iter().all(|l| text_width(TITLE_PX, l) <= 200), "{lines:?}");
        assert_eq!(lines.join(" "), text);
        assert_eq!(wrap(TITLE_PX, text, 5000), [text]);
        assert!(title_band(200, text, INK).height() > title_band(2000, text, INK).height());
        assert!(text_lines(200, &[text]).height() > text_lines(2000, &[text]).height());
    }

    #[test]
    fn short_numbers() {
        assert_eq!(short_number(512.34), "512");
        assert_eq!(short_number(0.25), "0.25");
        assert_eq!(short_number(1.0), "1");
        assert_eq!(short_number(0.0), "0");
        assert_eq!(short_number(12.5), "12.5");
    }
}
