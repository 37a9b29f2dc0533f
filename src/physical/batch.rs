//! Physical terms for a batch of camera-frame pose hypotheses of one object
//! resting on a support plane given in the camera frame: the entry point for
//! ranking hypotheses by physical plausibility beside the visual score.
//!
//! Ranking rule ([`physics_rank`]): plausible hypotheses first, then
//! unstable ones (feasible: touching, not intersecting), then floating, then
//! intersecting; within a group by the visual score, best first.

use glam::DVec3;

use super::contacts::{evaluate_batch, Body, Environment, Evaluation, Verdict};
use super::gpu::GpuContacts;
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
    /// `plane` in the camera frame, metres. With `ctx`, evaluations run on
    /// the GPU (records finished on the CPU); without, on the CPU twin.
    pub fn new(
        mesh: &Mesh,
        plane: &Plane,
        ctx: Option<&Context>,
        samples: usize,
        seed: u64,
    ) -> Result<PlanePhysics> {
        let to_plane = camera_to_plane_frame(plane);
        let body = Body::new(mesh, samples, seed, None)?;
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
