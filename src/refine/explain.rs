//! Pictures and physical verdicts of a refined scene: per object its
//! alignment before and after refinement (each scored in the scene, so what
//! the other objects hide is left grey), and the scene's physical check
//! (top and side views, verdicts) on the support plane.

use image::RgbImage;

use super::dataset::Model;
use crate::error::Result;
use crate::draw;
use crate::explain::{alignment_captions, alignment_key, alignment_panels_bare, depth_bar, depth_range, verdict_colour};
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

/// The picture of a refined frame: the key of the alignment colours on
/// top; a row per object with the alignment panels (observed | rendered |
/// per-pixel alignment, see [`alignment_panels`]) before and after under
/// its name, its verdict after (in the verdict's colour) and the panels'
/// captions, over its depth colour bar; below, the physical check of the
/// scene after (when a plane is given: title, top and side views, key and
/// the objects by number). Each pose is rendered among the other objects
/// at their poses of the same stage, its hidden pixels left out.
///
/// [`alignment_panels`]: crate::explain::alignment_panels
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
        let render = |stage: fn(&Explained) -> Pose| {
            let others: Vec<(&Model, Pose)> = objects.iter().enumerate().filter(|(j, _)| *j != i).map(|(_, x)| (x.model, stage(x))).collect();
            render_in_scene(&target, o.model, stage(o), &others)
        };
        let (before, after) = (render(|x| x.before), render(|x| x.after));
        // One depth range for both stages, so their colours compare.
        let (lo0, hi0) = depth_range(&before.0, &[&before.1]);
        let (lo1, hi1) = depth_range(&after.0, &[&after.1]);
        let range = (lo0.min(lo1), hi0.max(hi1));
        let panels = |(t, r): &(ScoreTarget, RenderImage)| {
            let captions = alignment_captions(t.intrinsics.width, SCALE);
            draw::stack(&[&captions, &alignment_panels_bare(t, r, params, SCALE, range)], 0)
        };
        let (before, after) = (panels(&before), panels(&after));
        let name = o.model.mesh.source.as_ref().and_then(|p| p.file_stem()).map_or_else(|| format!("object {}", i + 1), |s| s.to_string_lossy().into_owned());
        let verdict = checked.as_ref().map(|(_, c)| c[i].evaluation.verdict);
        let left = draw::title_band(before.width(), &format!("{} {name}: before refinement", i + 1), draw::PAPER);
        let right = draw::title_band(
            after.width(),
            &match verdict {
                Some(v) => format!("after refinement: {}", v.as_str()),
                None => "after refinement".to_string(),
            },
            verdict.map_or(draw::PAPER, verdict_colour),
        );
        let head = draw::beside(&[&left, &right], GAP);
        let body = draw::beside(&[&before, &after], GAP);
        let bar = depth_bar(body.width().min(900), range);
        rows.push(draw::stack(&[&head, &body, &bar], 0));
    }
    let views = checked.as_ref().map(|(scene, checks)| crate::physical::explain::explain_image(scene, checks));
    let width = rows.iter().map(|r| r.width()).chain(views.iter().map(|v| v.width())).max().unwrap_or(1);
    let key = alignment_key(width, params);
    let mut parts: Vec<&RgbImage> = vec![&key];
    parts.extend(&rows);
    parts.extend(&views);
    Ok(draw::stack(&parts, 8))
}

/// Scale of the alignment panels in refinement pictures.
const SCALE: u32 = 2;
/// Gap between the before and after panels.
const GAP: u32 = 8;

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
