//! The `contacts` kernel ([`crate::kernels::contacts`]) on a physical
//! scene: N poses of one body × its M samples × the environment (planes and
//! grids), one 16-byte record and M bits per pose read back. The support
//! polygon is finished on the CPU from the supported-sample bits (a hull of a
//! few hundred 2D points per pose, in parallel): exact for the GPU's
//! classification, and cheaper than shipping the points back.
//!
//! The GPU uses the trilinear grid values, so δ of a sample near another
//! object differs from the exact value by at most the grid's error bound
//! ([`super::sdf::SdfGrid::error_bound`]); plane distances agree to f32
//! rounding. Samples whose class those values cannot decide (a grid value
//! within the bound of ±ε, or a grid contact near an edge of the other
//! object, where interpolated normals blend faces) are flagged by the kernel
//! and refined exactly on the CPU in [`GpuContacts::finish`], so the
//! verdicts match the exact evaluation's ([`super::contacts`]).

use std::sync::Arc;

use rayon::prelude::*;

use super::contacts::{classify, finish, Body, Environment, Evaluation, Tally, SUPPORT_COS};
use crate::error::Result;
use crate::gpu::Context;
use crate::kernels::contacts::{ContactScene, ContactsKernel};
use crate::kernels::GpuPose;
use crate::pose::Pose;

pub use crate::kernels::contacts::{contacts_source, words_per_dispatch, ContactOutput, ContactParams, GpuGrid, CONTACTS_WGSL, MAX_GRIDS, MAX_PLANES};
pub use crate::kernels::ContactRecord;

/// The contacts kernel for one body against one environment; reuse it for
/// many batches of poses.
pub struct GpuContacts {
    body: Body,
    env: Environment,
    kernel: ContactsKernel,
}

impl GpuContacts {
    /// Uploads the body's samples and the environment. At most `max_chunk`
    /// poses go in one dispatch (fewer where the adapter's limits say so);
    /// `with_deltas` also returns δ of every sample (for tests: N·M floats).
    pub fn new(ctx: &Context, body: &Body, env: &Environment, max_chunk: usize, with_deltas: bool) -> Result<Self> {
        env.check_epsilon(body.epsilon)?;
        let kernel = ContactsKernel::new(ctx, &contact_scene(body, env), max_chunk, with_deltas)?;
        Ok(GpuContacts { body: body.clone(), env: env.clone(), kernel })
    }

    /// Poses per dispatch.
    pub fn chunk_size(&self) -> usize {
        self.kernel.chunk_size()
    }

    /// Classifies every sample of every pose; returns the raw records, bits
    /// (and δ when enabled).
    pub fn run(&self, poses: &[Pose]) -> Result<ContactOutput> {
        let gp: Vec<GpuPose> = poses.iter().map(GpuPose::from).collect();
        self.kernel.run(&gp)
    }

    /// Evaluations of `poses`: the GPU's classification, the support
    /// polygon finished on the CPU.
    pub fn evaluate(&self, poses: &[Pose]) -> Result<Vec<Evaluation>> {
        let out = self.run(poses)?;
        Ok(self.finish(poses, &out))
    }

    /// Completes evaluations from a run's output: refines the flagged
    /// samples exactly and builds the support polygons.
    pub fn finish(&self, poses: &[Pose], out: &ContactOutput) -> Vec<Evaluation> {
        finish_from_bits(&self.body, &self.env, poses, &out.records, &out.bits, self.kernel.words(), true)
    }

    /// Samples flagged for refinement in a run's output (for statistics).
    pub fn refined_count(&self, out: &ContactOutput) -> usize {
        out.refined_count(self.kernel.words())
    }
}

/// The kernel's plain-data view of a body in an environment.
pub fn contact_scene(body: &Body, env: &Environment) -> ContactScene {
    let g = env.gravity.normalize();
    let (nodes, grids) = grid_block(env);
    ContactScene {
        samples: body.samples.iter().map(|s| [s.x as f32, s.y as f32, s.z as f32, 0.0]).collect(),
        planes: env.planes.iter().map(|p| [p.normal.x as f32, p.normal.y as f32, p.normal.z as f32, p.normal.dot(p.point) as f32]).collect(),
        grids,
        nodes,
        gravity: [g.x as f32, g.y as f32, g.z as f32],
        error_bound: env.error_bound() as f32,
        eps: body.epsilon as f32,
        support_cos: SUPPORT_COS as f32,
    }
}

/// Completes the evaluations of `poses` (world frame) from a kernel's
/// per-pose records and sample bits: `words` u32 of supported bits per pose,
/// followed, when `with_refine`, by `words` u32 of samples left to the CPU,
/// which are classified here exactly. The support polygons are built from
/// the supported samples, in parallel over poses.
pub(crate) fn finish_from_bits(
    body: &Body,
    env: &Environment,
    poses: &[Pose],
    records: &[ContactRecord],
    bits: &[u32],
    words: usize,
    with_refine: bool,
) -> Vec<Evaluation> {
    let stride = words * if with_refine { 2 } else { 1 };
    let g = env.gravity.normalize();
    let eps = body.epsilon;
    poses
        .par_iter()
        .enumerate()
        .map(|(i, pose)| {
            let r = records[i];
            let supported = &bits[i * stride..i * stride + words];
            let refine = with_refine.then(|| &bits[i * stride + words..(i + 1) * stride]);
            let mut tally = Tally { intersecting: r.intersecting, contact: r.contact, supported: Vec::new() };
            let mut min = r.min_delta as f64;
            for (j, s) in body.samples.iter().enumerate() {
                let (w, b) = (j / 32, j % 32);
                if supported[w] >> b & 1 == 1 {
                    tally.supported.push(pose.transform_point(*s));
                } else if refine.is_some_and(|r| r[w] >> b & 1 == 1) {
                    let x = pose.transform_point(*s);
                    let d = env.refined_distance(x, eps);
                    min = min.min(d.delta);
                    tally.add(classify(d.delta, d.normal, eps, g), x);
                }
            }
            finish(tally.intersecting, tally.contact, min, &tally.supported, pose.transform_point(body.com), env.gravity).0
        })
        .collect()
}

/// Each distinct grid's nodes once, and one descriptor per placed
/// obstacle (the kernel checks them against its and the adapter's limits).
fn grid_block(env: &Environment) -> (Vec<f32>, Vec<GpuGrid>) {
    // Grids: each distinct grid's nodes once, one descriptor per placement.
    let mut node_data: Vec<f32> = Vec::new();
    let mut offsets: Vec<(*const super::sdf::SdfGrid, u32)> = Vec::new();
    let mut descs = Vec::new();
    for o in &env.obstacles {
        let key = Arc::as_ptr(&o.sdf);
        let offset = match offsets.iter().find(|(k, _)| *k == key) {
            Some((_, off)) => *off,
            None => {
                let off = node_data.len() as u32;
                node_data.extend(o.sdf.nodes.iter().map(|n| n[3]));
                offsets.push((key, off));
                off
            }
        };
        let inv = o.pose.inverse();
        let gp = GpuPose::from(&inv);
        let s = &o.sdf;
        let up = s.upper();
        descs.push(GpuGrid {
            inv: gp.rows,
            origin: [
                s.origin.x as f32,
                s.origin.y as f32,
                s.origin.z as f32,
                (1.0 / s.h) as f32,
            ],
            upper: [up.x as f32, up.y as f32, up.z as f32, s.margin as f32],
            dims: [s.dims[0] as u32, s.dims[1] as u32, s.dims[2] as u32, offset],
        });
    }
    (node_data, descs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every specialised source still validates.
    #[test]
    fn specialised_sources_validate() {
        for (planes, grids) in [(0, 0), (1, 0), (1, 1), (4, 16)] {
            let src = contacts_source(planes, grids);
            assert!(src.contains(&format!("const GRID_SLOTS: u32 = {}u;", grids.max(1))));
            crate::kernels::wgsl_layout::module("contacts", &src);
        }
    }
}
