//! Pictures and physical verdicts of a refined scene: per object its
//! alignment before and after refinement (each scored in the scene, so what
//! the other objects hide is left grey), and the scene's physical check
//! (top and side views, verdicts) on the support plane.

use image::{Rgb, RgbImage};

use super::dataset::Model;
use crate::error::Result;
use crate::explain::{alignment_panels, verdict_colour};
use crate::kernels::render::{render_cpu, RenderImage};
use crate::kernels::score::ScoreParams;
use crate::observation::{DepthImage, RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use crate::physical::check::{check_scene, CheckOptions, ObjectCheck};
use crate::physical::scene::{camera_to_plane_frame, Scene, SceneObject, DEFAULT_DENSITY};
use crate::physical::Plane;
use crate::pose::Pose;

/// Checks the objects at `poses` (camera frame) as resting on `plane`:
/// the scene in the plane's frame (gravity −z) and each object's check
/// (its verdict: plausible, unstable, floating, intersecting).
pub fn scene_check(plane: &Plane, objects: &[(&Model, Pose)]) -> Result<(Scene, Vec<ObjectCheck>)> {
    let to_plane = camera_to_plane_frame(plane);
    let scene = Scene {
        gravity: glam::DVec3::new(0.0, 0.0, -9.81),
        planes: vec![Plane { point: glam::DVec3::ZERO, normal: glam::DVec3::Z }],
        objects: objects
            .iter()
            .enumerate()
            .map(|(i, (m, pose))| SceneObject {
                name: m.mesh.source.as_ref().and_then(|p| p.file_stem()).map_or_else(|| format!("object {i}"), |s| s.to_string_lossy().into_owned()),
                mesh: m.mesh.clone(),
                mesh_path: m.mesh.source.clone().unwrap_or_default(),
                units: crate::mesh::MeshUnits::Metres,
                pose: to_plane.compose(pose),
                is_static: false,
                density: DEFAULT_DENSITY,
            })
            .collect(),
    };
    let checks = check_scene(&scene, &CheckOptions::default())?;
    Ok((scene, checks))
}

/// One object of a refinement picture: its model, mask, and pose before
/// and after.
pub struct Explained<'a> {
    pub model: &'a Model,
    pub mask: &'a [bool],
    pub before: Pose,
    pub after: Pose,
}

/// The picture of a refined frame: a row per object with the alignment
/// panels (observed | rendered | per-pixel alignment, see
/// [`alignment_panels`]) before and after, a band in the colour of its
/// verdict after; below, the physical views of the scene after (when a
/// plane is given). Each pose is rendered among the other objects at their
/// poses of the same stage, its hidden pixels left out.
pub fn refinement_picture(depth: &DepthImage, objects: &[Explained], plane: Option<&Plane>, params: &ScoreParams, res: u32) -> Result<RgbImage> {
    let checked = match plane {
        Some(pl) if !objects.is_empty() => {
            let placed: Vec<(&Model, Pose)> = objects.iter().map(|o| (o.model, o.after)).collect();
            Some(scene_check(pl, &placed)?)
        }
        _ => None,
    };
    let mut rows = Vec::new();
    for (i, o) in objects.iter().enumerate() {
        let target = ScoreTarget::new(depth, Some(o.mask), RoiSampling::Square(res), DEFAULT_ROI_MARGIN)?;
        let panels = |stage: fn(&Explained) -> Pose| {
            let others: Vec<(&Model, Pose)> = objects.iter().enumerate().filter(|(j, _)| *j != i).map(|(_, x)| (x.model, stage(x))).collect();
            let render = render_in_scene(&target, o.model, stage(o), &others);
            alignment_panels(&render.0, &render.1, params, 2)
        };
        let (before, after) = (panels(|x| x.before), panels(|x| x.after));
        let band = checked.as_ref().map(|(_, c)| verdict_colour(c[i].evaluation.verdict)).unwrap_or(Rgb([255, 255, 255]));
        let mut row = RgbImage::from_pixel(before.width() + 8 + after.width(), before.height() + 6, Rgb([255, 255, 255]));
        for x in before.width() + 8..row.width() {
            for y in 0..4 {
                row.put_pixel(x, y, band);
            }
        }
        image::imageops::overlay(&mut row, &before, 0, 6);
        image::imageops::overlay(&mut row, &after, (before.width() + 8) as i64, 6);
        rows.push(row);
    }
    let views = checked.as_ref().map(|(scene, checks)| crate::physical::explain::explain_image(scene, checks));
    let width = rows.iter().map(|r| r.width()).chain(views.iter().map(|v| v.width())).max().unwrap_or(1);
    let height = rows.iter().map(|r| r.height() + 4).sum::<u32>() + views.as_ref().map_or(0, |v| v.height());
    let mut img = RgbImage::from_pixel(width, height.max(1), Rgb([255, 255, 255]));
    let mut y = 0;
    for r in &rows {
        image::imageops::overlay(&mut img, r, 0, y as i64);
        y += r.height() + 4;
    }
    if let Some(v) = &views {
        image::imageops::overlay(&mut img, v, 0, y as i64);
    }
    Ok(img)
}

/// The target with the other objects as occluders, and the pose's
/// rendering with its hidden pixels removed.
fn render_in_scene(target: &ScoreTarget, model: &Model, pose: Pose, others: &[(&Model, Pose)]) -> (ScoreTarget, RenderImage) {
    let k = target.intrinsics;
    let meshes: Vec<(&crate::kernels::RenderMesh, Pose)> = others.iter().map(|(m, p)| (&m.render, *p)).collect();
    let occ = super::scene_depth(&k, &meshes);
    let mut t = target.clone();
    t.set_occluders(occ).expect("one finite depth per region pixel");
    let mut r = render_cpu(&model.render, &pose, &k);
    for i in 0..r.depth.len() {
        if r.depth[i] > 0.0 && t.hidden(i, r.depth[i]) {
            r.depth[i] = 0.0;
        }
    }
    (t, r)
}

/// The picture of a refined scene: each object with a view from its lead
/// hypothesis (before) to its best refined one (after).
pub fn scene_picture(
    depth: &DepthImage,
    objects: &[super::scene::SceneObject],
    refined: &super::scene::SceneRefined,
    plane: Option<&Plane>,
    p: &super::RefineParams,
) -> Result<RgbImage> {
    let explained: Vec<Explained> = objects
        .iter()
        .zip(&refined.objects)
        .filter_map(|(o, r)| {
            let best = r.as_ref()?.iter().max_by(|a, b| a.score.total_cmp(&b.score))?;
            Some(Explained { model: o.model, mask: o.mask, before: *o.hypotheses.get(o.lead)?, after: best.pose })
        })
        .collect();
    refinement_picture(depth, &explained, plane, &p.score, p.res)
}
