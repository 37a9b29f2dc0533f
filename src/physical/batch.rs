//! Physical terms for a batch of camera-frame pose hypotheses of one object
//! resting on a support plane given in the camera frame: the entry point for
//! ranking hypotheses by physical plausibility beside the visual score.
//!
//! Ranking rule ([`physics_rank`]): plausible hypotheses first, then
//! unstable ones (feasible: touching, not intersecting), then floating, then
//! intersecting; within a group by the visual score, best first.

use glam::DVec3;

use super::contacts::{evaluate_batch, evaluate_detailed, Body, Detail, Environment, Evaluation, Verdict};
use super::explain::{draw_views, Drawn};
use super::gpu::{finish_from_bits, ContactRecord, GpuContacts};
use crate::kernels::plane_contacts::PlaneParams;
use super::scene::{camera_to_plane_frame, Plane};
use crate::error::Result;
use crate::gpu::Context;
use crate::mesh::Mesh;
use crate::pose::Pose;


/// Hypotheses of one object against one support plane (camera frame).
pub struct PlanePhysics {
    to_plane: Pose,
    body: Body,
    env: Environment,
    gpu: Option<GpuContacts>,
}

impl PlanePhysics {
    /// `plane` in the camera frame, metres; `samples` surface samples drawn
    /// with `seed`; ε from `epsilon` or the default for the sample spacing.
    /// With `ctx`, [`evaluate`](Self::evaluate) runs the contacts kernel on
    /// the GPU (records finished on the CPU); without, the CPU twin. (The
    /// fused score kernel takes the plane through
    /// [`kernel_params`](Self::kernel_params) and needs no `ctx` here.)
    pub fn new(
        mesh: &Mesh,
        plane: &Plane,
        ctx: Option<&Context>,
        samples: usize,
        seed: u64,
        epsilon: Option<f64>,
    ) -> Result<PlanePhysics> {
        let to_plane = camera_to_plane_frame(plane);
        let body = Body::new(mesh, samples, seed, epsilon)?;
        let env = Environment {
            planes: vec![Plane {
                point: DVec3::ZERO,
                normal: DVec3::Z,
            }],
            obstacles: Vec::new(),
            gravity: DVec3::new(0.0, 0.0, -9.81),
        };
        let gpu = match ctx {
            Some(c) => Some(GpuContacts::new(c, &body, &env, 4096, false)?),
            None => None,
        };
        Ok(PlanePhysics {
            to_plane,
            body,
            env,
            gpu,
        })
    }

    /// The object's surface samples, centre of mass and ε.
    pub fn body(&self) -> &Body {
        &self.body
    }

    /// Parameters of the plane stage fused into the score kernel
    /// ([`crate::kernels::score::GpuScorer::with_plane_physics`]).
    /// A GPU scorer of `mesh` against `target` whose dispatch also computes
    /// these physical terms (the score kernel's fused plane stage).
    pub fn gpu_scorer(
        &self,
        ctx: &crate::gpu::Context,
        mesh: &crate::kernels::RenderMesh,
        target: &crate::observation::ScoreTarget,
        params: crate::kernels::score::ScoreParams,
        n_hint: usize,
    ) -> Result<crate::kernels::score::GpuScorer> {
        crate::kernels::score::GpuScorer::with_plane_stage(ctx, mesh, target, params, n_hint, &self.kernel_params(), &self.kernel_samples())
    }

    pub fn kernel_params(&self) -> PlaneParams {
        // The plane frame's z coordinate of a camera point x is row 2 of
        // the camera-to-plane rotation dotted with x, plus t.z: that row is
        // the plane normal in the camera frame and −t.z its offset.
        let n = self.to_plane.r.row(2);
        let w = -self.to_plane.t.z;
        PlaneParams {
            plane: [n.x as f32, n.y as f32, n.z as f32, w as f32],
            n_samples: self.body.samples.len() as u32,
            words: self.body.samples.len().div_ceil(32) as u32,
            eps: self.body.epsilon as f32,
            pad: 0,
        }
    }

    /// The surface samples as the GPU takes them (model frame, xyz + 0).
    pub fn kernel_samples(&self) -> Vec<[f32; 4]> {
        self.body.samples.iter().map(|s| [s.x as f32, s.y as f32, s.z as f32, 0.0]).collect()
    }

    /// Evaluations from the fused kernel's output: one record and
    /// [`PlaneParams::words`] supported-sample words per hypothesis.
    /// The support polygon and the margin are finished here (f64), from the
    /// GPU's classification.
    pub fn finish_fused(&self, cam_poses: &[Pose], records: &[ContactRecord], bits: &[u32]) -> Vec<Evaluation> {
        let world: Vec<Pose> = cam_poses.iter().map(|p| self.to_plane.compose(p)).collect();
        let words = self.body.samples.len().div_ceil(32);
        finish_from_bits(&self.body, &self.env, &world, records, bits, words, false)
    }

    /// The CPU twin's evaluation of every camera-frame hypothesis (exact,
    /// f64), whether or not this was made with a GPU context.
    pub fn evaluate_cpu(&self, cam_poses: &[Pose]) -> Vec<Evaluation> {
        let world: Vec<Pose> = cam_poses.iter().map(|p| self.to_plane.compose(p)).collect();
        evaluate_batch(&self.body, &world, &self.env)
    }

    /// The CPU twin's evaluation of one camera-frame hypothesis with its
    /// per-sample detail (plane frame), for pictures.
    pub fn evaluate_detailed(&self, cam_pose: &Pose) -> (Evaluation, Detail) {
        evaluate_detailed(&self.body, &self.to_plane.compose(cam_pose), &self.env)
    }

    /// Top and side views of one hypothesis on the plane (1024 wide, with
    /// captions and the key of the colours, see [`super::explain`]), with the CPU twin's evaluation
    /// they show (which can differ from the GPU's for samples within
    /// rounding of ±ε).
    pub fn explain(&self, cam_pose: &Pose) -> (image::RgbImage, Evaluation) {
        let (e, detail) = self.evaluate_detailed(cam_pose);
        let drawn = Drawn { detail: &detail, is_static: false, stable: e.stable, label: None };
        (draw_views(&self.env.planes, self.env.gravity, &[drawn]), e)
    }

    /// The physical evaluation of every camera-frame hypothesis.
    pub fn evaluate(&self, cam_poses: &[Pose]) -> Result<Vec<Evaluation>> {
        let world: Vec<Pose> = cam_poses.iter().map(|p| self.to_plane.compose(p)).collect();
        match &self.gpu {
            Some(g) => g.evaluate(&world),
            None => Ok(evaluate_batch(&self.body, &world, &self.env)),
        }
    }
}

/// Group of a verdict in the ranking (lower ranks first).
pub fn physics_rank(v: Verdict) -> u8 {
    match v {
        Verdict::Plausible => 0,
        Verdict::Unstable => 1,
        Verdict::Floating => 2,
        Verdict::Intersecting => 3,
    }
}

/// Indices of hypotheses in ranking order: by [`physics_rank`], then by the
/// visual score (descending; NaN last).
pub fn rank(verdicts: &[Verdict], visual: &[f64]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..verdicts.len().min(visual.len())).collect();
    idx.sort_by(|&a, &b| {
        physics_rank(verdicts[a])
            .cmp(&physics_rank(verdicts[b]))
            .then(
                visual[b]
                    .partial_cmp(&visual[a])
                    .unwrap_or_else(|| visual[a].is_nan().cmp(&visual[b].is_nan())),
            )
    });
    idx
}
