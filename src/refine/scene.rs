//! Refinement of a whole scene (the paper's section 3.2 over a frame): the
//! objects are ordered by support ([`support_order`]: clusters of objects
//! resting on one base that touches the plane, the least occluded base
//! first, each cluster bottom-up), and refined one after another. Each is
//! scored among the others' current estimates (the scene-level score: what
//! they hide does not count against it), and simulated on the plane among
//! the objects already placed, so an object on another comes to rest on its
//! refined pose.

use glam::DVec3;

use super::dataset::{physics_world, Model};
use super::{refine_hypotheses, ObjectView, RefineParams, Refined, MIN_OBSERVED_POINTS};
use crate::error::{Error, Result};
use crate::observation::DepthImage;
use crate::physical::Plane;
use crate::pose::Pose;
use crate::visual::Device;

/// One object of a scene: its model, its mask in the frame and its
/// hypotheses (model → camera, m).
pub struct SceneObject<'a> {
    pub model: &'a Model,
    /// Its pixels in the frame (the depth image's size).
    pub mask: &'a [bool],
    pub hypotheses: Vec<Pose>,
    /// The hypothesis that stands for the object among the others until it
    /// is refined (e.g. the estimator's best-scored one).
    pub lead: usize,
}

/// What rests an object up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Support {
    /// The support plane (the object is a cluster's base).
    Plane,
    /// Another object of the scene (index).
    Object(usize),
}

/// A refined scene.
#[derive(Clone, Debug)]
pub struct SceneRefined {
    /// Per object, per hypothesis (input order): the refined pose and its
    /// scene-level score; `None` for an object without a usable view (no
    /// mask pixel or fewer than [`MIN_OBSERVED_POINTS`] observed points).
    pub objects: Vec<Option<Vec<Refined>>>,
    /// The objects with a view in the order they were refined, and what
    /// supports each (indexed like the objects; `Plane` for those without).
    pub order: Vec<usize>,
    pub support: Vec<Support>,
    /// Where the time went (summed over the objects).
    pub times: super::RefineTimes,
}

/// Refines every object of a frame in support order (see the module doc).
/// `plane` enables the simulation (PIR, and SIR/RIR with physics); `top`
/// keeps, per object, only its best `top` hypotheses by the scene-level
/// score for refinement (the others come back scored, unrefined).
pub fn refine_scene(
    device: &Device,
    depth: &DepthImage,
    plane: Option<&Plane>,
    objects: &[SceneObject],
    top: usize,
    p: &RefineParams,
) -> Result<SceneRefined> {
    let n = objects.len();
    if let Some((i, o)) = objects.iter().enumerate().find(|(_, o)| !o.hypotheses.is_empty() && o.lead >= o.hypotheses.len()) {
        return Err(Error::InvalidInput(format!("object {i}: lead hypothesis {} of {}", o.lead, o.hypotheses.len())));
    }
    let mut views: Vec<Option<ObjectView>> = objects
        .iter()
        .map(|o| {
            let observed = o.mask.iter().zip(&depth.depth).filter(|(m, d)| **m && **d > 0.0).count();
            if observed < MIN_OBSERVED_POINTS || o.hypotheses.is_empty() {
                return Ok(None);
            }
            ObjectView::new(device, o.model, depth, o.mask, p).map(Some)
        })
        .collect::<Result<_>>()?;
    let mut current: Vec<Pose> = objects.iter().map(|o| o.hypotheses.get(o.lead).copied().unwrap_or(Pose::IDENTITY)).collect();
    let active: Vec<usize> = (0..n).filter(|&i| views[i].is_some()).collect();
    // Visible fraction of each lead estimate: its mask pixels over the
    // pixels it renders (an occluded object renders more than it shows).
    let mut visible = vec![0.0; n];
    for &i in &active {
        let rec = views[i].as_mut().expect("active").records(&[current[i]])?[0];
        visible[i] = (rec.observed as f64 / rec.rendered.max(1) as f64).min(1.0);
    }
    let t_order = std::time::Instant::now();
    let placed_in: Vec<(&[DVec3], Pose)> = active.iter().map(|&i| (objects[i].model.surface.points.as_slice(), current[i])).collect();
    let (local_order, local_support) = match plane {
        Some(pl) => support_order(pl, &placed_in, &active.iter().map(|&i| visible[i]).collect::<Vec<_>>()),
        None => {
            let mut o: Vec<usize> = (0..active.len()).collect();
            o.sort_by(|&a, &b| visible[active[b]].total_cmp(&visible[active[a]]).then(a.cmp(&b)));
            (o, vec![Support::Plane; active.len()])
        }
    };
    let order: Vec<usize> = local_order.iter().map(|&k| active[k]).collect();
    let mut support = vec![Support::Plane; n];
    for (k, s) in local_support.iter().enumerate() {
        support[active[k]] = match s {
            Support::Object(j) => Support::Object(active[*j]),
            Support::Plane => Support::Plane,
        };
    }
    let mut times = super::RefineTimes { scene: t_order.elapsed().as_secs_f64(), ..Default::default() };
    let mut out: Vec<Option<Vec<Refined>>> = vec![None; n];
    let mut placed: Vec<usize> = Vec::new();
    for &i in &order {
        let o = &objects[i];
        let view = views[i].as_mut().expect("ordered objects have a view");
        let others: Vec<(&crate::kernels::RenderMesh, Pose)> =
            active.iter().filter(|&&j| j != i).map(|&j| (&objects[j].model.render, current[j])).collect();
        view.set_occluders(&others)?;
        if let Some(pl) = plane.filter(|_| p.method.simulates(p.physics)) {
            let t = std::time::Instant::now();
            let below: Vec<(&Model, Pose)> = placed.iter().map(|&j| (objects[j].model, current[j])).collect();
            view.sim = physics_world(pl, o.model, &below, p).ok();
            view.times.simulate += t.elapsed().as_secs_f64();
        }
        let scores = view.score_many(&o.hypotheses)?;
        let mut rank: Vec<usize> = (0..o.hypotheses.len()).collect();
        rank.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
        rank.truncate(top.max(1));
        let chosen: Vec<Pose> = rank.iter().map(|&h| o.hypotheses[h]).collect();
        let refined = refine_hypotheses(&o.model.surface, view, &chosen, p)?;
        let mut all: Vec<Refined> = o.hypotheses.iter().zip(&scores).map(|(&pose, &score)| Refined { pose, score, steps: 0, kept: 0 }).collect();
        for (&h, r) in rank.iter().zip(refined) {
            all[h] = r;
        }
        let best = all.iter().max_by(|a, b| a.score.total_cmp(&b.score)).expect("hypotheses");
        current[i] = best.pose;
        placed.push(i);
        out[i] = Some(all);
        times += view.times;
        views[i] = None; // its scorer and simulation are done with
    }
    Ok(SceneRefined { objects: out, order, support, times })
}

/// Points within this height of an object's lowest point are where it can
/// rest on something (m).
const CONTACT_BAND: f64 = 0.005;
/// The plane is preferred over an object as support unless the object is
/// closer by more than this (m): two objects side by side on the table both
/// rest on the table.
const PLANE_PREFERENCE: f64 = 0.002;
/// Farthest gap (m) across which an object can be found resting on
/// another (an estimate may float above its support by this much).
const SUPPORT_REACH: f64 = 0.05;
/// Points compared per object when looking for supports (a stride over the
/// surface samples keeps the pairwise search to ~10⁵ distances a pair).
const SUPPORT_POINTS: usize = 400;

/// The support order of objects on a plane: `objects` are surface points
/// (model frame, m) with their poses (model → camera), `visible` each one's
/// visible fraction. Each object rests on the plane or on the object whose
/// surface is nearest below its lowest points (one whose own lowest point is
/// lower); following supports down gives each object its cluster's base.
/// Clusters come least occluded base first; within a cluster, objects come
/// bottom-up (supports before what they carry), the more visible first.
/// Returns the order and each object's support.
pub fn support_order(plane: &Plane, objects: &[(&[DVec3], Pose)], visible: &[f64]) -> (Vec<usize>, Vec<Support>) {
    let n = objects.len();
    let world: Vec<Vec<DVec3>> = objects
        .iter()
        .map(|(pts, pose)| {
            let stride = pts.len().div_ceil(SUPPORT_POINTS).max(1);
            pts.iter().step_by(stride).map(|v| pose.transform_point(*v)).collect()
        })
        .collect();
    let low: Vec<f64> = world.iter().map(|w| w.iter().map(|q| plane.distance(*q)).fold(f64::INFINITY, f64::min)).collect();
    // Bounding spheres: objects whose spheres are apart cannot support
    // each other (keeps many-object scenes from the all-pairs search).
    let spheres: Vec<(DVec3, f64)> = world
        .iter()
        .map(|w| {
            let c = w.iter().sum::<DVec3>() / w.len().max(1) as f64;
            (c, w.iter().map(|q| q.distance(c)).fold(0.0, f64::max))
        })
        .collect();
    let near = |i: usize, j: usize| spheres[i].0.distance(spheres[j].0) <= spheres[i].1 + spheres[j].1 + SUPPORT_REACH;
    let support: Vec<Support> = (0..n)
        .map(|i| {
            let feet: Vec<DVec3> = world[i].iter().copied().filter(|q| plane.distance(*q) <= low[i] + CONTACT_BAND).collect();
            let plane_gap = low[i].max(0.0);
            let mut best: Option<(f64, usize)> = None;
            for j in (0..n).filter(|&j| j != i && low[j] < low[i] && near(i, j)) {
                let gap = feet
                    .iter()
                    .flat_map(|f| world[j].iter().map(move |q| f.distance_squared(*q)))
                    .fold(f64::INFINITY, f64::min)
                    .sqrt();
                if best.is_none_or(|(g, _)| gap < g) {
                    best = Some((gap, j));
                }
            }
            match best {
                Some((gap, j)) if gap + PLANE_PREFERENCE < plane_gap => Support::Object(j),
                _ => Support::Plane,
            }
        })
        .collect();
    // Base and level (steps down to the plane) of each object; supports
    // are strictly lower, so the chains end.
    let base_level = |mut i: usize| {
        let mut level = 0;
        while let Support::Object(j) = support[i] {
            i = j;
            level += 1;
        }
        (i, level)
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        let ((ba, la), (bb, lb)) = (base_level(a), base_level(b));
        visible[bb]
            .total_cmp(&visible[ba])
            .then(ba.cmp(&bb))
            .then(la.cmp(&lb))
            .then(visible[b].total_cmp(&visible[a]))
            .then(a.cmp(&b))
    });
    (order, support)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;

    fn box_points(half: DVec3) -> Vec<DVec3> {
        let mesh = crate::shapes::cuboid(half);
        super::super::icp::ModelSurface::sample(&mesh, 2000, 1).unwrap().points
    }

    /// A slab on the table with a cube on it, a cube on that cube, and a
    /// lone cylinder-like box beside: two clusters; the tower comes
    /// bottom-up, the clusters by their base's visibility.
    #[test]
    fn a_stacked_scene_is_ordered_bottom_up_by_cluster() {
        let plane = Plane { point: DVec3::ZERO, normal: DVec3::Z };
        let slab = box_points(DVec3::new(0.06, 0.06, 0.01));
        let cube = box_points(DVec3::splat(0.02));
        let at = |x: f64, y: f64, z: f64| Pose::new(DMat3::IDENTITY, DVec3::new(x, y, z));
        // Input order scrambled: top cube, lone box, slab, middle cube.
        let objects = [
            (cube.as_slice(), at(0.01, 0.0, 0.0 + 0.02 + 0.04 + 0.02 + 0.001)),
            (cube.as_slice(), at(0.2, 0.0, 0.02)),
            (slab.as_slice(), at(0.0, 0.0, 0.01)),
            (cube.as_slice(), at(0.0, 0.0, 0.04 + 0.0005)),
        ];
        let (order, support) = support_order(&plane, &objects, &[0.3, 0.5, 0.9, 0.6]);
        assert_eq!(support, vec![Support::Object(3), Support::Plane, Support::Plane, Support::Object(2)]);
        // The slab's cluster first (visible 0.9 > 0.5), bottom-up.
        assert_eq!(order, vec![2, 3, 0, 1]);
        // The lone box more visible than the slab: its cluster first.
        let (order, _) = support_order(&plane, &objects, &[0.3, 0.95, 0.9, 0.6]);
        assert_eq!(order, vec![1, 2, 3, 0]);
        // Two cubes side by side on the table both rest on the table.
        let side = [(cube.as_slice(), at(0.0, 0.0, 0.02)), (cube.as_slice(), at(0.0401, 0.0, 0.0201))];
        assert_eq!(support_order(&plane, &side, &[0.5, 0.5]).1, vec![Support::Plane, Support::Plane]);
    }
}
