//! Visual plausibility as a library API: score many pose hypotheses of one
//! mesh against one observation, on the GPU or with the CPU twin, and rank
//! them.

use crate::error::Result;
use crate::kernels::score::{score_cpu, GpuScorer, ScoreParams, ScoreRecord, StageTimes};
use crate::kernels::RenderMesh;
use crate::observation::ScoreTarget;
use crate::physical::batch::PlanePhysics;
use crate::physical::Evaluation;
use crate::pose::Pose;

pub use crate::gpu::Device;
pub use crate::mesh::lod::LodChoice;

/// The mesh the visual score renders, and why it was chosen.
#[derive(Clone, Debug)]
pub struct ScoringMesh {
    pub mesh: crate::mesh::Mesh,
    /// Its geometric error against the full mesh (metres).
    pub error_m: f64,
    /// The size of a pixel (metres) at the observed object, for `auto`.
    pub pixel_m: Option<f64>,
    /// Triangles of the full mesh.
    pub full_triangles: usize,
}

impl ScoringMesh {
    /// One line for the user: which mesh scores, and why.
    pub fn describe(&self) -> String {
        let n = self.mesh.triangles.len();
        if n == self.full_triangles {
            return format!("scoring mesh: the full {n} triangles");
        }
        let why = match self.pixel_m {
            Some(p) => format!(" ≤ {} of a {:.2} mm pixel at the object", crate::mesh::lod::AUTO_PIXEL_FRACTION, p * 1e3),
            None => String::new(),
        };
        format!("scoring mesh: {n} of {} triangles (level of detail, geometric error {:.3} mm{why})", self.full_triangles, self.error_m * 1e3)
    }
}

/// The mesh to score `target` with: the full mesh (`Off`), a simplification
/// to about N triangles (`Faces`), or (`Auto`) the coarsest level of detail
/// whose geometric error stays within a quarter of a pixel of the scoring region at
/// the near side of the observed object. The physical terms and evaluation
/// always use the full mesh.
pub fn scoring_mesh(mesh: &crate::mesh::Mesh, choice: LodChoice, target: &ScoreTarget) -> Result<ScoringMesh> {
    use crate::mesh::lod::{with_faces, within_error, LodLevel, AUTO_PIXEL_FRACTION};
    let full_triangles = mesh.triangles.len();
    let pixel_m = match choice {
        LodChoice::Auto => auto_pixel(target),
        _ => None,
    };
    let level = match (choice, pixel_m) {
        (LodChoice::Faces(n), _) => with_faces(mesh, n)?,
        (LodChoice::Auto, Some(pixel)) => within_error(mesh, AUTO_PIXEL_FRACTION * pixel)?,
        _ => LodLevel::full(mesh),
    };
    Ok(ScoringMesh { mesh: level.mesh, error_m: level.error_m, pixel_m, full_triangles })
}

/// The size (metres) of a pixel of `target` at the near side of the
/// observed object: what `auto` bounds the geometric error by.
fn auto_pixel(target: &ScoreTarget) -> Option<f64> {
    target.near_depth().map(|z| crate::mesh::lod::pixel_size(&target.intrinsics, z))
}

/// `auto` levels of detail of one mesh, kept per error bound: refinement
/// and estimation score many views of each model, at pixel sizes that
/// differ by little, and simplifying for every view cost more than the
/// smaller mesh saved (RIR on LM-O: 42 s with `auto` against 32 s with the
/// full models). Bounds are rounded *down* to quarter octaves (the mesh is
/// never coarser than `auto` asks), so a model is simplified a few times per
/// dataset, not once per view.
#[derive(Debug, Default)]
pub struct AutoLodCache {
    levels: std::sync::Mutex<std::collections::HashMap<i32, std::sync::Arc<RenderMesh>>>,
}

impl AutoLodCache {
    /// The render mesh `auto` scores `target` with (the full `render` mesh
    /// when the view has no depth to size pixels by).
    pub fn render_mesh(&self, mesh: &crate::mesh::Mesh, render: &RenderMesh, target: &ScoreTarget) -> Result<std::sync::Arc<RenderMesh>> {
        use crate::mesh::lod::{within_error, AUTO_PIXEL_FRACTION};
        let bound = auto_pixel(target).map(|pixel| AUTO_PIXEL_FRACTION * pixel);
        // i32::MIN: no bound, the full mesh.
        let bucket = bound.filter(|b| b.is_finite() && *b > 0.0).map_or(i32::MIN, |b| (b.log2() * 4.0).floor() as i32);
        let poisoned = |_| crate::error::Error::InvalidInput("the level-of-detail cache was poisoned by a panic".into());
        if let Some(level) = self.levels.lock().map_err(poisoned)?.get(&bucket) {
            return Ok(level.clone());
        }
        let level = std::sync::Arc::new(match bucket {
            i32::MIN => render.clone(),
            b => RenderMesh::new(&within_error(mesh, (b as f64 / 4.0).exp2())?.mesh)?,
        });
        self.levels.lock().map_err(poisoned)?.insert(bucket, level.clone());
        Ok(level)
    }
}

/// A scorer for one mesh and one observation, built once and called many
/// times: on the GPU the pipeline, the mesh and the observation stay
/// uploaded between calls; on the CPU it runs the twin. The one scoring API
/// of the library (the CLI, evaluation and bindings all call it).
pub struct Scorer {
    inner: ScorerImpl,
}

enum ScorerImpl {
    Gpu(Box<GpuScorer>),
    Cpu { mesh: RenderMesh, target: ScoreTarget, params: ScoreParams },
}

/// Hypotheses the CPU twin scores between progress reports.
const CPU_PROGRESS_CHUNK: usize = 1024;

impl Scorer {
    /// Prepares scoring of `mesh` against `target` on `device`; `n_hint`
    /// sizes the GPU buffers (larger batches are split). On the GPU the
    /// mesh and observation are uploaded and the score kernel compiled
    /// (or a [`precompile`](Self::precompile) of it waited for) here, on
    /// lavapipe with one hypothesis scored to make its machine code
    /// ([`GpuScorer::compile`]), so [`score`](Self::score) only scores.
    pub fn new(device: &Device, mesh: &RenderMesh, target: &ScoreTarget, params: ScoreParams, n_hint: usize) -> Result<Scorer> {
        let inner = match device {
            Device::Gpu(ctx) => {
                let scorer = GpuScorer::new(ctx, mesh, target, params, n_hint)?;
                scorer.compile()?;
                ScorerImpl::Gpu(Box::new(scorer))
            }
            Device::Cpu => ScorerImpl::Cpu { mesh: mesh.clone(), target: target.clone(), params },
        };
        Ok(Scorer { inner })
    }

    /// Starts compiling the GPU score kernel a scorer on `device` will most
    /// likely use, on a thread of its own, and returns at once (nothing to
    /// do on the CPU). Call it as soon as the device is open, before
    /// preparing the mesh and observation: the compile then overlaps that
    /// work instead of delaying the first scores
    /// ([`GpuScorer::precompile`]). Keep the handle while preparing:
    /// dropping it waits for the compile.
    pub fn precompile(device: &Device) -> crate::gpu::Compiling {
        match device {
            Device::Gpu(ctx) => GpuScorer::precompile(ctx),
            Device::Cpu => crate::gpu::Compiling::none(),
        }
    }

    /// Replaces the observation with `target`'s (the same region and
    /// observed pixels, other occluders: see
    /// [`GpuScorer::set_observation`]); nothing is rebuilt.
    pub fn set_observation(&mut self, target: &ScoreTarget) -> Result<()> {
        match &mut self.inner {
            ScorerImpl::Gpu(g) => g.set_observation(target),
            ScorerImpl::Cpu { target: t, .. } => {
                if target.intrinsics != t.intrinsics || target.observed_pixels() != t.observed_pixels() {
                    return Err(crate::error::Error::InvalidInput(
                        "a scorer's observation can only change its occluders, not its region or observed pixels".into(),
                    ));
                }
                *t = target.clone();
                Ok(())
            }
        }
    }

    /// Scores `poses` (records in input order), calling `done(n)` as
    /// hypotheses finish.
    pub fn score(&self, poses: &[Pose], done: &mut dyn FnMut(usize)) -> Result<(Vec<ScoreRecord>, StageTimes)> {
        crate::pose::check_pose_count(poses.len())?;
        match &self.inner {
            ScorerImpl::Gpu(g) => g.score_with_progress(poses, done),
            ScorerImpl::Cpu { mesh, target, params } => {
                let _span = tracing::trace_span!("cpu_twin", hypotheses = poses.len()).entered();
                let t = std::time::Instant::now();
                let mut out = Vec::with_capacity(poses.len());
                for chunk in poses.chunks(CPU_PROGRESS_CHUNK) {
                    out.extend(score_cpu(mesh, target, chunk, params));
                    done(out.len());
                }
                Ok((out, StageTimes { compute: t.elapsed(), ..Default::default() }))
            }
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
    Scorer::new(device, mesh, target, params, poses.len())?.score(poses, &mut |_| {})
}

/// Scores `poses` on `device` and computes their physical terms against
/// `physics`' support plane: on the GPU in the same dispatch as the visual
/// score (the support polygons are finished on the CPU from the GPU's
/// supported-sample bits), on the CPU with the twins. `done(n)` reports
/// progress. Records and evaluations come back in input order.
pub fn score_poses_with_physics(
    device: &Device,
    mesh: &RenderMesh,
    target: &ScoreTarget,
    poses: &[Pose],
    params: ScoreParams,
    physics: &PlanePhysics,
    mut done: impl FnMut(usize),
) -> Result<(Vec<ScoreRecord>, Vec<Evaluation>, StageTimes)> {
    match device {
        // A mesh past the rasterizer's budget is ray-cast on the GPU, which
        // has no fused physical stage: the physical terms come from the
        // CPU twins beside it.
        Device::Gpu(ctx) if mesh.gpu_renderer() == crate::kernels::CpuRenderer::RayCast => {
            let (records, times) = GpuScorer::new(ctx, mesh, target, params, poses.len())?.score_with_progress(poses, done)?;
            let evals = tracing::trace_span!("cpu_twin", hypotheses = poses.len()).in_scope(|| physics.evaluate_cpu(poses));
            Ok((records, evals, times))
        }
        Device::Gpu(ctx) => {
            let scorer = physics.gpu_scorer(ctx, mesh, target, params, poses.len())?;
            let (records, contacts, times) = scorer.score_with_physics(poses, done)?;
            let evals = tracing::trace_span!("finish").in_scope(|| physics.finish_fused(poses, &contacts.records, &contacts.bits));
            Ok((records, evals, times))
        }
        Device::Cpu => {
            let _span = tracing::trace_span!("cpu_twin", hypotheses = poses.len()).entered();
            let t = std::time::Instant::now();
            let mut records = Vec::with_capacity(poses.len());
            let mut evals = Vec::with_capacity(poses.len());
            for chunk in poses.chunks(1024) {
                records.extend(score_cpu(mesh, target, chunk, &params));
                evals.extend(physics.evaluate_cpu(chunk));
                done(records.len());
            }
            Ok((records, evals, StageTimes { compute: t.elapsed(), ..Default::default() }))
        }
    }
}

/// Rank of each hypothesis (1 = best) by the physics-first rule of
/// [`crate::physical::batch::rank`]: plausible, then unstable, floating,
/// intersecting; within a group by visual score; ties keep input order.
pub fn ranks_with_physics(records: &[ScoreRecord], evals: &[Evaluation]) -> Vec<usize> {
    let verdicts: Vec<_> = evals.iter().map(|e| e.verdict).collect();
    let scores: Vec<f64> = records.iter().map(|r| r.score as f64).collect();
    let mut rank = vec![0; records.len()];
    for (r, i) in crate::physical::batch::rank(&verdicts, &scores).into_iter().enumerate() {
        rank[i] = r + 1;
    }
    rank
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
