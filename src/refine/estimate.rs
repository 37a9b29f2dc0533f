//! Pose estimation over BOP images from stable poses (paper section 3.1):
//! per image the support plane is fitted to the depth outside the objects'
//! masks; per object instance the hypotheses are its resting poses × yaw
//! steps, each placed on the plane under the instance's observed points
//! ([`crate::hypotheses::on_plane`]); all are scored by the visual
//! alignment (eq. 3) alone, the best few scored again in the scene (among
//! the other objects' estimates) and refined by RIR (UCB1 over them, ICP
//! steps kept only where the score improves) object after object in
//! support order ([`super::scene`]).

use std::collections::HashMap;
use std::time::Instant;

use rayon::prelude::*;

use super::dataset::{support_plane, Masks, Model};
use super::scene::{refine_scene, SceneObject};
use super::{ObjectView, RefineParams, MIN_OBSERVED_POINTS};
use crate::bop::dataset::{PoseMm, Scene, Target};
use crate::bop::results::Estimate;
use crate::error::{Error, Result};
use crate::hypotheses::on_plane::{on_plane_hypotheses, ExportMatch, OnPlaneParams, RestingPose};
use crate::support_plane::PlaneFitParams;
use crate::visual::Device;

/// Candidates per refined hypothesis that an instance's scoring alone
/// passes on to the scene, where they are scored again among the other
/// objects (occlusion can reorder them) and the best `top` refined.
const CANDIDATES_PER_TOP: usize = 4;

/// Estimation settings.
#[derive(Clone, Debug)]
pub struct EstimateParams {
    pub hypotheses: OnPlaneParams,
    pub plane: PlaneFitParams,
    /// Best-scored hypotheses refined per instance (the paper: 5).
    pub top: usize,
    pub refine: RefineParams,
}

impl Default for EstimateParams {
    fn default() -> Self {
        EstimateParams { hypotheses: OnPlaneParams::default(), plane: PlaneFitParams::default(), top: 5, refine: RefineParams::default() }
    }
}

/// An object for estimation: its refinement model, its mesh (metres) and
/// its resting poses.
pub struct EstimateModel {
    pub model: Model,
    pub rests: Vec<RestingPose>,
}

/// What estimating one image did.
#[derive(Clone, Copy, Debug, Default)]
pub struct EstimateStats {
    pub instances: usize,
    /// Instances without a mask or observed points (no estimate written).
    pub skipped: usize,
    pub hypotheses: usize,
    pub seconds: f64,
    /// Of which: plane fit, hypotheses + scoring alone (summed over the
    /// parallel instances, so it may exceed the wall time), the scene's
    /// ordering, re-scoring and refinement (wall time).
    pub plane_s: f64,
    pub hypotheses_s: f64,
    pub refine_s: f64,
    /// The scene's time by stage (in `refine_s`).
    pub scene: super::RefineTimes,
}

impl std::ops::AddAssign for EstimateStats {
    /// Totals over images.
    fn add_assign(&mut self, o: Self) {
        self.instances += o.instances;
        self.skipped += o.skipped;
        self.hypotheses += o.hypotheses;
        self.seconds += o.seconds;
        self.plane_s += o.plane_s;
        self.hypotheses_s += o.hypotheses_s;
        self.refine_s += o.refine_s;
        self.scene += o.scene;
    }
}

/// One object instance of a frame: its model (with resting poses) and its
/// mask (the depth image's size).
pub struct Instance<'a> {
    pub model: &'a EstimateModel,
    pub mask: &'a [bool],
}

/// A frame's estimates: the scene as refined, and which instance each
/// scene object is.
pub struct FrameEstimate<'a> {
    pub objects: Vec<SceneObject<'a>>,
    pub instance: Vec<usize>,
    pub scene: super::scene::SceneRefined,
}

impl FrameEstimate<'_> {
    /// Instance `k`'s estimate (its best-scored refined hypothesis), `None`
    /// when it had too few observed points.
    pub fn best(&self, k: usize) -> Option<super::Refined> {
        let i = self.instance.iter().position(|&x| x == k)?;
        self.scene.objects[i].as_ref()?.iter().copied().max_by(|a, b| a.score.total_cmp(&b.score))
    }
}

/// Estimates the poses of object instances in one frame (any depth image,
/// support plane in the camera frame, metres): per instance (in parallel)
/// its resting poses × yaws on the plane, scored alone, the best
/// [`CANDIDATES_PER_TOP`] × `top` passed on; then the scene: candidates
/// re-scored among the other objects' estimates and the best `top` refined
/// in support order ([`refine_scene`]; `steps` 0: none refined). Adds its
/// counts and times to `stats`.
pub fn estimate_frame<'a>(
    device: &Device,
    depth: &crate::observation::DepthImage,
    plane: &crate::physical::Plane,
    instances: &'a [Instance<'a>],
    p: &EstimateParams,
    stats: &mut EstimateStats,
) -> Result<FrameEstimate<'a>> {
    let per: Vec<Option<(Vec<crate::pose::Pose>, usize, f64)>> = instances
        .par_iter()
        .map(|inst| {
            p.refine.stop.check()?;
            let (m, mask) = (inst.model, inst.mask);
            if mask.len() != depth.depth.len() {
                return Err(Error::InvalidInput(format!("a mask has {} pixels, the depth image {}", mask.len(), depth.depth.len())));
            }
            if mask.iter().zip(&depth.depth).filter(|(m, d)| **m && **d > 0.0).count() < MIN_OBSERVED_POINTS {
                return Ok(None);
            }
            let th = Instant::now();
            let hyps = on_plane_hypotheses(&m.model.mesh, &m.rests, plane, depth, mask, &p.hypotheses)?;
            let mut view = ObjectView::new(device, &m.model, depth, mask, &p.refine)?;
            let poses: Vec<_> = hyps.iter().map(|h| h.pose).collect();
            let scores = view.score_many(&poses)?;
            let mut order: Vec<usize> = (0..poses.len()).collect();
            order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
            let kept = order.iter().take(CANDIDATES_PER_TOP * p.top.max(1)).map(|&i| poses[i]).collect();
            Ok(Some((kept, poses.len(), th.elapsed().as_secs_f64())))
        })
        .collect::<Result<_>>()?;
    let tr = Instant::now();
    let mut instance = Vec::new();
    let mut objects = Vec::new();
    for (k, (inst, r)) in instances.iter().zip(per).enumerate() {
        let Some((hypotheses, n, hs)) = r else {
            stats.skipped += 1;
            continue;
        };
        stats.hypotheses += n;
        stats.hypotheses_s += hs;
        instance.push(k);
        objects.push(SceneObject { model: &inst.model.model, mask: inst.mask, hypotheses, lead: 0 });
    }
    let simulate = p.refine.method.simulates(p.refine.physics);
    let scene = refine_scene(device, depth, simulate.then_some(plane), &objects, p.top.max(1), &p.refine)?;
    stats.refine_s += tr.elapsed().as_secs_f64();
    stats.scene += scene.times;
    stats.skipped += scene.objects.iter().filter(|o| o.is_none()).count();
    Ok(FrameEstimate { objects, instance, scene })
}

/// Estimates every target object of one image (`targets` of this image):
/// one estimate per mask instance, scored by the visual alignment.
pub fn estimate_image(
    scene: &Scene,
    im_id: u32,
    targets: &[Target],
    models: &HashMap<u32, EstimateModel>,
    device: &Device,
    masks: &Masks,
    p: &EstimateParams,
    explain: bool,
) -> Result<super::dataset::ImageResult<EstimateStats>> {
    let t0 = Instant::now();
    let depth = super::dataset::depth_image(scene, im_id)?;
    let (w, h) = (depth.intrinsics.width, depth.intrinsics.height);
    // Every instance mask of the image's target objects.
    let mut instances: Vec<(u32, Vec<bool>)> = Vec::new();
    for t in targets {
        for m in masks.instances(scene, im_id, t.obj_id, w, h)? {
            instances.push((t.obj_id, m));
        }
    }
    let mut stats = EstimateStats { instances: instances.len(), ..Default::default() };
    let tp = Instant::now();
    let plane = support_plane(&depth, instances.iter().map(|(_, m)| m.as_slice()), &p.plane)
        .map_err(|e| Error::InvalidInput(format!("image {im_id}: support plane: {e}")))?;
    stats.plane_s = tp.elapsed().as_secs_f64();
    let inst: Vec<Instance> = instances
        .iter()
        .map(|(obj, mask)| {
            let model = models.get(obj).ok_or_else(|| Error::InvalidInput(format!("object {obj} has no model")))?;
            Ok(Instance { model, mask })
        })
        .collect::<Result<_>>()?;
    let frame = estimate_frame(device, &depth, &plane, &inst, p, &mut stats)?;
    let mut out = Vec::new();
    for (k, (obj, _)) in instances.iter().enumerate() {
        let Some(top) = frame.best(k) else { continue };
        out.push(Estimate {
            scene_id: scene.id,
            im_id,
            obj_id: *obj,
            score: top.score,
            pose: PoseMm { r: top.pose.r, t: top.pose.t * 1e3 },
            time: 0.0,
            line: 0,
        });
    }
    stats.seconds = t0.elapsed().as_secs_f64();
    out.iter_mut().for_each(|e| e.time = stats.seconds);
    // Two instances refined to the very same pose are one estimate.
    crate::bop::results::drop_repeated_poses(&mut out);
    // Drawn after the clock stops: pictures are not the method's time.
    let picture = explain.then(|| super::explain::scene_picture(&depth, &frame.objects, &frame.scene, Some(&plane), &p.refine)).transpose()?;
    Ok(super::dataset::ImageResult { estimates: out, stats, picture })
}

/// Loads the objects for estimation: meshes (BOP models are millimetres),
/// refinement models and resting poses, from a stable-pose export
/// (`stable-poses export` JSON) when given, else from the quasi-static
/// analysis of each convex hull.
pub fn load_estimate_models(ds: &crate::bop::Dataset, obj_ids: &[u32], p: &RefineParams, stable: Option<&str>) -> Result<HashMap<u32, EstimateModel>> {
    obj_ids
        .par_iter()
        .map(|&id| {
            let path = ds.model_path(id);
            let mesh = ds.model_mesh(id)?;
            // Matched by its stem when the hash differs (a database of
            // models/ serves models_eval/).
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let (rests, how) = crate::hypotheses::on_plane::resting_poses(&mesh, stable, &name)?;
            match how {
                Some(ExportMatch::OnlyEntry) => {
                    return Err(Error::InvalidInput(format!("the stable poses given (a database or its export) have no entry for {name} (object {id}): drop-test that model too"))
                        .about(crate::error::Input::StablePoses));
                }
                // Every BOP dataset names its models obj_0000NN.ply: a
                // database of another dataset matches by name alone.
                Some(ExportMatch::Name) => tracing::warn!(
                    "the stable poses given match {name} (object {id}) by file name only, not by geometry (another dataset's object of the same name, other units or an edited model?); using them anyway"
                ),
                Some(ExportMatch::Hash) | None => {}
            }
            Ok((id, EstimateModel { model: Model::new(mesh, p)?, rests }))
        })
        .collect()
}
