//! Visual plausibility as a library API: score many pose hypotheses of one
//! mesh against one observation, on the GPU or with the CPU twin, and rank
//! them.

use crate::error::Result;
use crate::gpu::Context;
use crate::kernels::score::{score_cpu, GpuScorer, ScoreParams, ScoreRecord, StageTimes};
use crate::kernels::RenderMesh;
use crate::observation::ScoreTarget;
use crate::pose::Pose;

/// Where the kernels run.
#[derive(Clone, Debug)]
pub enum Device {
    Gpu(Context),
    /// The CPU twins, multi-threaded with rayon.
    Cpu,
}

impl Device {
    pub fn describe(&self) -> String {
        match self {
            Device::Gpu(c) => c.describe(),
            Device::Cpu => format!("CPU twin ({} threads)", rayon::current_num_threads()),
        }
    }
}

/// Scores `poses` on `device`; records come back in input order.
pub fn score_poses(
    device: &Device,
    mesh: &RenderMesh,
    target: &ScoreTarget,
    poses: &[Pose],
    params: ScoreParams,
) -> Result<(Vec<ScoreRecord>, StageTimes)> {
    match device {
        Device::Gpu(ctx) => GpuScorer::new(ctx, mesh, target, params, poses.len())?.score(poses),
        Device::Cpu => {
            let t = std::time::Instant::now();
            let r = score_cpu(mesh, target, poses, &params);
            Ok((r, StageTimes { compute: t.elapsed(), ..Default::default() }))
        }
    }
}

/// Rank of each record (1 = best): by score, descending; ties keep input
/// order, so ranking is deterministic.
pub fn ranks(records: &[ScoreRecord]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..records.len()).collect();
    order.sort_by(|&a, &b| records[b].score.total_cmp(&records[a].score).then(a.cmp(&b)));
    let mut rank = vec![0; records.len()];
    for (r, &i) in order.iter().enumerate() {
        rank[i] = r + 1;
    }
    rank
}
