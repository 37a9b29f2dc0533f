//! Refinement of pose estimates against a depth observation (VeREFINE,
//! paper section 3.2): REF (robust point-to-plane ICP, [`icp`]), PIR (ICP
//! after a round of rigid-body simulation on the support plane among the
//! other objects, [`crate::physical::simulate::SimWorld`]), SIR (the
//! simulated and the refined pose are scored and the better one kept only
//! if the visual-alignment score of eq. 3 improves, so the score also
//! verifies the final pose) and RIR (a budget of SIR steps spread over an
//! object's hypotheses by UCB1 on the score, [`bandit`]). [`dataset`] runs
//! them over the images of a BOP dataset, [`estimate`] makes the
//! hypotheses from resting poses.

pub mod bandit;
pub mod dataset;
pub mod estimate;
pub mod explain;
pub mod icp;
pub mod scene;

use glam::DVec3;

use crate::error::{Error, Result};
use crate::kernels::score::ScoreParams;
use crate::kernels::RenderMesh;
use crate::observation::{DepthImage, RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use crate::physical::simulate::SimWorld;
use crate::pose::Pose;
use crate::visual::{Device, Scorer};
use bandit::Ucb;
use icp::{icp, IcpParams, ModelSurface};

/// Which refinement (the paper's names).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// ICP steps, no verification.
    Ref,
    /// ICP steps, each after a short simulation of the object on the
    /// support plane among the other objects (velocities reset), no
    /// verification.
    Pir,
    /// ICP steps kept only where the score improves.
    Sir,
    /// SIR steps allocated over the hypotheses by UCB1.
    Rir,
}

impl Method {
    /// Parses `ref`, `pir`, `sir` or `rir`.
    pub fn parse(s: &str) -> Option<Method> {
        match s {
            "ref" => Some(Method::Ref),
            "pir" => Some(Method::Pir),
            "sir" => Some(Method::Sir),
            "rir" => Some(Method::Rir),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Method::Ref => "ref",
            Method::Pir => "pir",
            Method::Sir => "sir",
            Method::Rir => "rir",
        }
    }
}

/// Refinement settings.
#[derive(Clone, Debug)]
pub struct RefineParams {
    pub method: Method,
    /// Refinement steps per hypothesis (RIR: the budget is this times the
    /// number of hypotheses, spread by UCB1, unless `budget` says).
    pub steps: usize,
    /// RIR: refinement steps per object, spread over its hypotheses by UCB1
    /// (default: `steps` × hypotheses).
    pub budget: Option<usize>,
    pub icp: IcpParams,
    /// UCB exploration constant (the paper: 0.1).
    pub exploration: f64,
    /// UCB discount γ (1 = UCB1; the paper uses 0.99 for scenes).
    pub gamma: f64,
    pub score: ScoreParams,
    /// Scoring region resolution (pixels a side).
    pub res: u32,
    /// Model surface samples for ICP, and their seed.
    pub samples: usize,
    pub seed: u64,
    /// The simulation interleaved with ICP (PIR; SIR and RIR too unless
    /// `physics` is false): rounds per step and their settings.
    pub physics: bool,
    pub sim: crate::physical::simulate::SimSettings,
    /// Level of detail of the mesh the visual score renders (per object
    /// view; `Off` by default here: the published numbers were measured
    /// with the full meshes). ICP, the simulation and the pictures keep the
    /// full mesh.
    pub lod: crate::mesh::lod::LodChoice,
    /// Checked before every refinement step: set from another thread, the
    /// refinement returns [`Error::Stopped`] (see [`crate::stop`]).
    pub stop: crate::stop::Stop,
}

impl Method {
    /// Whether the method simulates between ICP steps (given `physics`).
    pub fn simulates(self, physics: bool) -> bool {
        match self {
            Method::Ref => false,
            Method::Pir => true,
            Method::Sir | Method::Rir => physics,
        }
    }
}

impl Default for RefineParams {
    fn default() -> Self {
        RefineParams {
            method: Method::Rir,
            steps: 2,
            budget: None,
            icp: IcpParams::default(),
            exploration: 0.1,
            gamma: 1.0,
            score: ScoreParams::default(),
            res: 128,
            samples: 3000,
            seed: 0,
            physics: true,
            // VeREFINE's settings: dt 1/60 s, 3 steps, one round per step.
            sim: crate::physical::simulate::SimSettings { rounds: 1, ..Default::default() },
            lod: crate::mesh::lod::LodChoice::Off,
            stop: Default::default(),
        }
    }
}

impl RefineParams {
    /// Refuses settings that cannot work (library terms; the CLI names flags).
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidInput(m));
        if self.steps == 0 || self.steps > 100 {
            return bad(format!("refinement steps per hypothesis must lie in 1..=100, got {}", self.steps));
        }
        if let Some(b) = self.budget.filter(|b| *b == 0 || *b > 10_000) {
            return bad(format!("the refinement budget per object must lie in 1..=10000 steps, got {b}"));
        }
        if self.icp.iterations == 0 || self.icp.iterations > 100 {
            return bad(format!("ICP iterations per step must lie in 1..=100, got {}", self.icp.iterations));
        }
        if !(self.exploration.is_finite() && self.exploration >= 0.0) {
            return bad(format!("the UCB exploration constant must be a non-negative number, got {}", self.exploration));
        }
        if !(self.gamma > 0.0 && self.gamma <= 1.0) {
            return bad(format!("the UCB discount must lie in (0, 1], got {}", self.gamma));
        }
        if !(16..=512).contains(&self.res) {
            return bad(format!("the scoring resolution must lie in 16..=512 pixels, got {}", self.res));
        }
        // Refused rather than ignored: ref never simulates, pir always does.
        if !self.physics && matches!(self.method, Method::Ref | Method::Pir) {
            let why = if self.method == Method::Ref { "ref never simulates" } else { "pir always simulates" };
            return bad(format!("refinement without physics is for sir and rir; {why}"));
        }
        Ok(())
    }
}

/// One object as the observation shows it: its observed points (camera
/// frame, m) and a scorer of poses against its masked depth, alone or among
/// the other objects of the scene ([`ObjectView::set_occluders`]).
pub struct ObjectView {
    pub points: Vec<DVec3>,
    target: ScoreTarget,
    scorer: Scorer,
    /// The object (dynamic, index 0) on the support plane among the other
    /// objects (static), for PIR; `None` without physics.
    pub sim: Option<SimWorld>,
    /// Where its refinement's time went.
    pub times: RefineTimes,
}

/// Seconds spent per stage of refinement.
#[derive(Clone, Copy, Debug, Default)]
pub struct RefineTimes {
    /// Building the views: observed points, scoring region, the other
    /// objects' depth, support order.
    pub scene: f64,
    /// Visual-alignment scoring.
    pub score: f64,
    /// ICP.
    pub icp: f64,
    /// The rigid-body simulation (building worlds and their rounds).
    pub simulate: f64,
}

impl std::ops::AddAssign for RefineTimes {
    fn add_assign(&mut self, o: Self) {
        self.scene += o.scene;
        self.score += o.score;
        self.icp += o.icp;
        self.simulate += o.simulate;
    }
}

impl RefineTimes {
    /// The stages as JSON (seconds, divided by `per`).
    pub fn json(&self, per: f64) -> serde_json::Value {
        serde_json::json!({"scene": self.scene / per, "score": self.score / per, "icp": self.icp / per, "simulate": self.simulate / per})
    }
}

impl ObjectView {
    /// The object's view in `depth` through `mask` (same size), scoring
    /// `model`'s mesh at the level of detail `p.lod` picks for this view.
    pub fn new(device: &Device, model: &dataset::Model, depth: &DepthImage, mask: &[bool], p: &RefineParams) -> Result<ObjectView> {
        if mask.len() != depth.depth.len() {
            return Err(Error::InvalidInput(format!("the mask has {} pixels, the depth image {}", mask.len(), depth.depth.len())));
        }
        let t = std::time::Instant::now();
        let k = depth.intrinsics;
        let points: Vec<DVec3> =
            (0..depth.depth.len()).filter(|&i| mask[i] && depth.depth[i] > 0.0).map(|i| k.pixel_point(i, depth.depth[i] as f64)).collect();
        let target = ScoreTarget::new(depth, Some(mask), RoiSampling::Square(p.res), DEFAULT_ROI_MARGIN)?;
        // A fixed triangle count was simplified once with the model; auto
        // depends on this view's pixel size (levels cached per model).
        let scorer = match (p.lod, &model.scoring) {
            (crate::mesh::lod::LodChoice::Auto, _) => {
                Scorer::new(device, &*model.auto_lod.render_mesh(&model.mesh, &model.render, &target)?, &target, p.score, 8)?
            }
            (_, Some(scoring)) => Scorer::new(device, scoring, &target, p.score, 8)?,
            _ => Scorer::new(device, &model.render, &target, p.score, 8)?,
        };
        let times = RefineTimes { scene: t.elapsed().as_secs_f64(), ..Default::default() };
        Ok(ObjectView { points, target, scorer, sim: None, times })
    }

    /// Scores from now on as part of the scene: the other objects
    /// (`occluders`, at their current poses) are rendered into the scoring
    /// region and the pixels they hide leave V (the scene-level score of
    /// [`ScoreTarget::set_occluders`]). The occluders' depth is one small
    /// image per object and round, rendered by the CPU z-buffer (the render
    /// kernel's twin); the scorer keeps its mesh and pipeline and takes the
    /// new observation in one texture write.
    pub fn set_occluders(&mut self, occluders: &[(&RenderMesh, Pose)]) -> Result<()> {
        let t = std::time::Instant::now();
        let depth = scene_depth(&self.target.intrinsics, occluders);
        self.target.set_occluders(depth)?;
        self.scorer.set_observation(&self.target)?;
        self.times.scene += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// The full score records (eq. 3-5 and pixel counts) of many poses.
    pub fn records(&mut self, poses: &[Pose]) -> Result<Vec<crate::kernels::score::ScoreRecord>> {
        let t = std::time::Instant::now();
        let records = self.scorer.score(poses, &mut |_| {})?.0;
        self.times.score += t.elapsed().as_secs_f64();
        Ok(records)
    }

    /// The visual-alignment scores (eq. 3) of many poses, in order.
    pub fn score_many(&mut self, poses: &[Pose]) -> Result<Vec<f64>> {
        Ok(self.records(poses)?.iter().map(|r| r.score as f64).collect())
    }

    /// The visual-alignment score (eq. 3) of one pose.
    pub fn score(&mut self, pose: &Pose) -> Result<f64> {
        Ok(self.score_many(std::slice::from_ref(pose))?[0])
    }
}

/// The nearest surface of several meshes at their poses, per pixel of `k`
/// (0 where none): the other objects' depth for the scene-level score.
pub fn scene_depth(k: &crate::camera::Intrinsics, objects: &[(&RenderMesh, Pose)]) -> Vec<f32> {
    let mut depth = vec![0.0f32; k.pixels()];
    for (m, pose) in objects {
        let img = crate::kernels::render::render_cpu(m, pose, k);
        for (d, o) in depth.iter_mut().zip(&img.depth) {
            if *o > 0.0 && (*d == 0.0 || *o < *d) {
                *d = *o;
            }
        }
    }
    depth
}

/// Fewest observed points (depth pixels in the mask) an object is refined
/// or estimated from.
pub const MIN_OBSERVED_POINTS: usize = 20;

/// One refined hypothesis.
#[derive(Clone, Copy, Debug)]
pub struct Refined {
    pub pose: Pose,
    /// Its visual-alignment score.
    pub score: f64,
    /// Refinement steps spent on it, and how many were kept.
    pub steps: usize,
    pub kept: usize,
}

/// Refines an object's hypotheses (`initial`, model → camera, m) against
/// its view; returns one result per hypothesis, in input order. Fewer than
/// [`MIN_OBSERVED_POINTS`] leave the poses unrefined (scored as they are).
pub fn refine_hypotheses(model: &ModelSurface, view: &mut ObjectView, initial: &[Pose], p: &RefineParams) -> Result<Vec<Refined>> {
    let mut out: Vec<Refined> =
        initial.iter().map(|&pose| Ok(Refined { pose, score: view.score(&pose)?, steps: 0, kept: 0 })).collect::<Result<_>>()?;
    if view.points.len() < MIN_OBSERVED_POINTS || initial.is_empty() {
        return Ok(out);
    }
    match p.method {
        Method::Ref | Method::Pir | Method::Sir => {
            for h in out.iter_mut() {
                for _ in 0..p.steps {
                    step(model, &mut *view, h, p)?;
                }
            }
        }
        Method::Rir => {
            let mut ucb = Ucb::new(out.len(), p.exploration, p.gamma);
            for _ in 0..p.budget.unwrap_or(p.steps * out.len()) {
                let arm = ucb.select();
                step(model, &mut *view, &mut out[arm], p)?;
                ucb.update(arm, out[arm].score);
            }
        }
    }
    Ok(out)
}

/// One refinement step of a hypothesis. PIR: a round of simulation from its
/// pose, then ICP from the simulated pose. SIR and RIR score both the
/// simulated and the refined pose and keep the better one if it beats the
/// hypothesis' score. (VeREFINE keeps only the simulated rotation; keeping
/// the translation too is what brings an estimate floating above its
/// support down when ICP cannot see the gap, e.g. with the top face
/// occluded: see the stacked-cube test.)
fn step(model: &ModelSurface, view: &mut ObjectView, h: &mut Refined, p: &RefineParams) -> Result<()> {
    p.stop.check()?;
    let mut simulated = None;
    let t = std::time::Instant::now();
    if let Some(sim) = view.sim.as_mut().filter(|_| p.method.simulates(p.physics)) {
        sim.set_pose(0, &h.pose);
        for _ in 0..p.sim.rounds {
            sim.round();
        }
        simulated = sim.pose(0);
    }
    view.times.simulate += t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let (refined, _) = icp(model, &view.points, &simulated.unwrap_or(h.pose), &p.icp)?;
    view.times.icp += t.elapsed().as_secs_f64();
    h.steps += 1;
    let refined_score = view.score(&refined)?;
    if matches!(p.method, Method::Ref | Method::Pir) {
        (h.pose, h.score) = (refined, refined_score);
        h.kept += 1;
        return Ok(());
    }
    let mut best = (refined, refined_score);
    if let Some(s) = simulated {
        let score = view.score(&s)?;
        if score > best.1 {
            best = (s, score);
        }
    }
    if best.1 > h.score {
        (h.pose, h.score) = best;
        h.kept += 1;
    }
    Ok(())
}
