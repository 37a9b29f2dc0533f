//! Pictures that explain a score: observed depth, a hypothesis' rendered
//! depth, and where the two agree, side by side.

use image::{Rgb, RgbImage};

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

const BACKGROUND: Rgb<u8> = Rgb([24, 24, 24]);

/// Three panels, each `scale` times the region's size: observed depth,
/// rendered depth (same colour range), and the per-pixel alignment
/// ½(a_d + a_n) over V (grey where the pixel is outside V; red where only
/// the rendering covers it, blue where only the observation does).
pub fn alignment_panels(target: &ScoreTarget, render: &RenderImage, params: &ScoreParams, scale: u32) -> RgbImage {
    let (w, h) = (target.intrinsics.width, target.intrinsics.height);
    let depths = target.depth.iter().chain(&render.depth).filter(|&&d| d > 0.0);
    let (lo, hi) = depths.fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| (lo.min(d), hi.max(d)));
    let norm = |d: f32| if hi > lo { 1.0 - (d - lo) / (hi - lo) } else { 1.0 };
    let gap = 4 * scale;
    let mut img = RgbImage::from_pixel(3 * w * scale + 2 * gap, h * scale, Rgb([255, 255, 255]));
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let (od, rd) = (target.depth[i], render.depth[i]);
            let obs_c = if od > 0.0 { colormap(norm(od)) } else { BACKGROUND };
            let ren_c = if rd > 0.0 { colormap(norm(rd)) } else { BACKGROUND };
            let align_c = match (od > 0.0, rd > 0.0) {
                (false, false) => BACKGROUND,
                (false, true) => Rgb([200, 40, 40]),
                (true, false) => Rgb([40, 80, 220]),
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

/// One picture of one hypothesis: the alignment panels on top and, when
/// given, the physical top and side views below, with a band in the
/// verdict's colour ([`verdict_colour`]) across the top.
pub fn hypothesis_picture(
    target: &ScoreTarget,
    render: &RenderImage,
    params: &ScoreParams,
    physics: Option<(&RgbImage, crate::physical::Verdict)>,
) -> RgbImage {
    let panels = alignment_panels(target, render, params, 3);
    let band = if physics.is_some() { 12 } else { 0 };
    let (pw, ph) = physics.map_or((0, 0), |(v, _)| (v.width(), v.height() + 8));
    let width = panels.width().max(pw);
    let mut img = RgbImage::from_pixel(width, band + panels.height() + ph, Rgb([255, 255, 255]));
    if let Some((_, verdict)) = physics {
        for y in 0..band - 4 {
            for x in 0..width {
                img.put_pixel(x, y, verdict_colour(verdict));
            }
        }
    }
    image::imageops::overlay(&mut img, &panels, 0, band as i64);
    if let Some((views, _)) = physics {
        image::imageops::overlay(&mut img, views, 0, (band + panels.height() + 8) as i64);
    }
    img
}
