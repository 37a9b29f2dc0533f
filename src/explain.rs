//! Pictures that explain a score: observed depth, a hypothesis' rendered
//! depth, and where the two agree, side by side.

use image::{Rgb, RgbImage};

use crate::draw::{self, Mark};

use crate::kernels::raster::RenderImage;
use crate::kernels::score::ScoreParams;
use crate::observation::ScoreTarget;

/// A perceptually ordered colour map (dark blue → green → yellow), `t` in [0, 1].
pub fn colormap(t: f32) -> Rgb<u8> {
    let stops = [(0.0, [48, 18, 59]), (0.25, [50, 100, 200]), (0.5, [30, 180, 140]), (0.75, [170, 220, 50]), (1.0, [250, 240, 30])];
    let t = t.clamp(0.0, 1.0);
    for w in stops.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let f = (t - t0) / (t1 - t0);
            return Rgb([0, 1, 2].map(|i| (c0[i] as f32 + f * (c1[i] as f32 - c0[i] as f32)) as u8));
        }
    }
    Rgb(stops[4].1)
}

/// Colour of pixels with neither observed nor rendered depth (outside V,
/// or hidden by another object).
pub const BACKGROUND: Rgb<u8> = Rgb([24, 24, 24]);
/// Alignment colour of a pixel rendered where nothing was observed.
pub const RENDERED_ONLY: Rgb<u8> = Rgb([200, 40, 40]);
/// Alignment colour of a pixel observed where nothing is rendered.
pub const OBSERVED_ONLY: Rgb<u8> = Rgb([40, 80, 220]);

/// The depth range (m) of the observed and rendered depths: the range of
/// the depth colour map (near yellow, far dark blue).
pub fn depth_range(target: &ScoreTarget, renders: &[&RenderImage]) -> (f32, f32) {
    let depths = target.depth.iter().chain(renders.iter().flat_map(|r| &r.depth)).filter(|&&d| d > 0.0);
    depths.fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| (lo.min(d), hi.max(d)))
}

/// Colour of depth `d` in `range` (near yellow, far dark blue).
fn depth_colour(d: f32, (lo, hi): (f32, f32)) -> Rgb<u8> {
    colormap(if hi > lo { 1.0 - (d - lo) / (hi - lo) } else { 1.0 })
}

/// The three bare panels of [`alignment_panels`] (no captions, no legend),
/// depths coloured over `range` ([`depth_range`]).
pub fn alignment_panels_bare(target: &ScoreTarget, render: &RenderImage, params: &ScoreParams, scale: u32, range: (f32, f32)) -> RgbImage {
    let (w, h) = (target.intrinsics.width, target.intrinsics.height);
    let gap = panel_gap(scale);
    let mut img = RgbImage::from_pixel(3 * w * scale + 2 * gap, h * scale, Rgb([255, 255, 255]));
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let (od, rd) = (target.depth[i], render.depth[i]);
            let obs_c = if od > 0.0 { depth_colour(od, range) } else { BACKGROUND };
            let ren_c = if rd > 0.0 { depth_colour(rd, range) } else { BACKGROUND };
            let align_c = match (od > 0.0, rd > 0.0) {
                (false, false) => BACKGROUND,
                (false, true) => RENDERED_ONLY,
                (true, false) => OBSERVED_ONLY,
                (true, true) => {
                    let ad = 1.0 - ((rd - od).abs() / params.tau).min(1.0);
                    let n = target.normals[i];
                    let an = if n == glam::Vec3::ZERO {
                        0.0
                    } else {
                        1.0 - ((1.0 - n.dot(render.normals[i]).clamp(0.0, 1.0)) / params.alpha).min(1.0)
                    };
                    colormap(0.5 * (ad + an))
                }
            };
            for (panel, c) in [obs_c, ren_c, align_c].into_iter().enumerate() {
                let ox = panel as u32 * (w * scale + gap);
                for dy in 0..scale {
                    for dx in 0..scale {
                        img.put_pixel(ox + x * scale + dx, y * scale + dy, c);
                    }
                }
            }
        }
    }
    img
}

fn panel_gap(scale: u32) -> u32 {
    4 * scale
}

/// The captions above the three panels of a region `w` pixels wide at
/// `scale` (shorter ones when the panels are narrow).
pub fn alignment_captions(w: u32, scale: u32) -> RgbImage {
    let step = w * scale + panel_gap(scale);
    let long = ["observed depth", "rendered depth", "alignment ½(a_d + a_n)"];
    let fits = long.iter().all(|c| draw::text_width(draw::TEXT_PX, c) + 6 <= step);
    let captions = if fits { long } else { ["observed", "rendered", "alignment"] };
    draw::caption_band(3 * w * scale + 2 * panel_gap(scale), &[(0, captions[0]), (step, captions[1]), (2 * step, captions[2])])
}

/// The depth colour bar, `width` wide, in mm over `range` (m).
pub fn depth_bar(width: u32, range: (f32, f32)) -> RgbImage {
    let (lo, hi) = if range.1 >= range.0 { range } else { (0.0, 0.0) };
    draw::colour_bar(width, "depth", &|t| colormap(1.0 - t), lo as f64 * 1e3, hi as f64 * 1e3, "mm")
}

/// What the alignment colours mean, `width` wide: τ and α, and the colours
/// of pixels outside V.
fn alignment_notes(width: u32, params: &ScoreParams) -> RgbImage {
    let angle = (1.0 - params.alpha.min(2.0)).acos().to_degrees();
    let meaning = format!(
        "alignment 1 = aligned; 0 = depth off by ≥ τ = {} mm and normals ≥ {:.0}° apart (α = {})",
        draw::short_number(params.tau as f64 * 1e3),
        angle,
        draw::short_number(params.alpha as f64)
    );
    let key = draw::key(
        width,
        &[
            (Mark::Fill(RENDERED_ONLY), "rendered, not observed"),
            (Mark::Fill(OBSERVED_ONLY), "observed, not rendered"),
            (Mark::Fill(BACKGROUND), "neither (outside V or hidden)"),
        ],
    );
    draw::stack(&[&draw::text_lines(width, &[&meaning]), &key], 0)
}

/// The key of the alignment colours alone, `width` wide: the colour bar
/// from 0 to 1 and what 0, 1 and the other colours mean.
pub fn alignment_key(width: u32, params: &ScoreParams) -> RgbImage {
    let bar = draw::colour_bar(width.min(700), "alignment", &colormap, 0.0, 1.0, "");
    draw::stack(&[&bar, &alignment_notes(width, params)], 0)
}

/// The legend of the alignment panels, `width` wide: the depth colour bar
/// (mm, over `range`), the alignment colour bar (0 to 1) with τ and α, and
/// the colours of pixels outside V.
pub fn alignment_legend(width: u32, range: (f32, f32), params: &ScoreParams) -> RgbImage {
    let half = width >= 760;
    let bar_w = if half { width / 2 } else { width };
    let depth = depth_bar(bar_w, range);
    let align = draw::colour_bar(bar_w, "alignment", &colormap, 0.0, 1.0, "");
    let bars = if half { draw::beside(&[&depth, &align], 0) } else { draw::stack(&[&depth, &align], 0) };
    draw::stack(&[&bars, &alignment_notes(width, params)], 0)
}

/// Three panels, each `scale` times the region's size: observed depth,
/// rendered depth (same colour range), and the per-pixel alignment
/// ½(a_d + a_n) over V (dark grey where the pixel is outside V; red where
/// only the rendering covers it, blue where only the observation does),
/// under their captions and over their legend ([`alignment_legend`]).
pub fn alignment_panels(target: &ScoreTarget, render: &RenderImage, params: &ScoreParams, scale: u32) -> RgbImage {
    let range = depth_range(target, &[render]);
    let panels = alignment_panels_bare(target, render, params, scale, range);
    let captions = alignment_captions(target.intrinsics.width, scale);
    let legend = alignment_legend(panels.width(), range, params);
    draw::stack(&[&captions, &panels, &legend], 4)
}

/// Colour of a physical verdict in pictures: plausible green, unstable
/// orange, floating violet, intersecting red.
pub fn verdict_colour(v: crate::physical::Verdict) -> Rgb<u8> {
    use crate::physical::Verdict;
    match v {
        Verdict::Plausible => Rgb([40, 160, 70]),
        Verdict::Unstable => Rgb([240, 150, 20]),
        Verdict::Floating => Rgb([140, 80, 200]),
        Verdict::Intersecting => Rgb([220, 30, 30]),
    }
}

/// One picture of one hypothesis: a title band (`title`, in the verdict's
/// colour ([`verdict_colour`]) when physics is given), the alignment panels
/// with their legend ([`alignment_panels`]) and, when given, the physical
/// top and side views (with their key) below.
pub fn hypothesis_picture(
    target: &ScoreTarget,
    render: &RenderImage,
    params: &ScoreParams,
    physics: Option<(&RgbImage, crate::physical::Verdict)>,
    title: &str,
) -> RgbImage {
    let panels = alignment_panels(target, render, params, 3);
    let width = panels.width().max(physics.map_or(0, |(v, _)| v.width()));
    let band = draw::title_band(width, title, physics.map_or(Rgb([225, 225, 225]), |(_, v)| verdict_colour(v)));
    match physics {
        Some((views, _)) => draw::stack(&[&band, &panels, views], 8),
        None => draw::stack(&[&band, &panels], 8),
    }
}
