//! JSON export of a stable-pose database, in the format other tools parse
//! (documented in `docs/stable-poses.md`):
//!
//! ```text
//! {"meshes": [{"mesh", "sha256", "drops", "settled", "clusters": [...],
//!              "families": [...], "analytic": [...]}]}
//! ```

use serde::Serialize;

use super::analytic::AnalyticPose;
use super::cluster::{Cluster, ClusterKind};
use super::db::Db;
use crate::error::Result;

/// The format tag of the export (checked by readers).
pub const FORMAT: &str = "plausible-stable-poses/1";

/// Largest export read back (hypotheses, estimate): a mesh's clusters take
/// a few kilobytes, so 256 MiB holds tens of thousands of meshes; the cap
/// stops an endless stream such as `/dev/zero`.
pub const MAX_EXPORT_BYTES: u64 = 256 << 20;

#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct Export {
    pub format: &'static str,
    pub meshes: Vec<MeshExport>,
}

#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct MeshExport {
    /// Source path of the mesh.
    pub mesh: String,
    /// SHA-256 of the geometry in metres.
    pub sha256: String,
    /// Drops stored for this run (all shards present).
    pub drops: u64,
    /// Drops requested by the run's parameters.
    pub drops_requested: u64,
    /// Drops that came to rest (the denominator of every probability).
    pub settled: u64,
    pub seed: u64,
    pub collider: String,
    pub crate_version: String,
    /// The run's full parameters.
    pub params: serde_json::Value,
    pub clusters: Vec<ClusterExport>,
    pub families: Vec<FamilyExport>,
    pub analytic: Vec<AnalyticExport>,
}

#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct ClusterExport {
    pub probability: f64,
    pub ci95: [f64; 2],
    pub count: u64,
    pub gravity_in_model: [f64; 3],
    #[serde(rename = "R_model_to_plane")]
    pub r_model_to_plane: [f64; 9],
    pub height: f64,
    pub representatives: Vec<u64>,
}

#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct FamilyExport {
    /// "circle" (rolling about `axis`) or "scattered" (ball-like).
    pub kind: &'static str,
    /// Rolling axis in the model frame (null for scattered families).
    pub axis: Option<[f64; 3]>,
    pub probability: f64,
    pub ci95: [f64; 2],
    pub count: u64,
    pub height: f64,
    pub representatives: Vec<u64>,
}

#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct AnalyticExport {
    pub probability: f64,
    pub gravity_in_model: [f64; 3],
    pub height: f64,
    pub margin: f64,
}

/// Splits clusters into discrete poses and families, keeping their order.
pub fn split(clusters: &[Cluster]) -> (Vec<ClusterExport>, Vec<FamilyExport>) {
    let mut poses = Vec::new();
    let mut families = Vec::new();
    for c in clusters {
        match &c.kind {
            ClusterKind::Pose => poses.push(ClusterExport {
                probability: c.probability,
                ci95: c.ci95,
                count: c.count,
                gravity_in_model: c.gravity_in_model,
                r_model_to_plane: c.r_model_to_plane,
                height: c.height,
                representatives: c.representatives.clone(),
            }),
            kind => families.push(FamilyExport {
                kind: if matches!(kind, ClusterKind::Circle { .. }) {
                    "circle"
                } else {
                    "scattered"
                },
                axis: match kind {
                    ClusterKind::Circle { axis } => Some(*axis),
                    _ => None,
                },
                probability: c.probability,
                ci95: c.ci95,
                count: c.count,
                height: c.height,
                representatives: c.representatives.clone(),
            }),
        }
    }
    (poses, families)
}

fn analytic(poses: &[AnalyticPose]) -> Vec<AnalyticExport> {
    poses
        .iter()
        .map(|a| AnalyticExport {
            probability: a.probability,
            gravity_in_model: a.gravity_in_model,
            height: a.height,
            margin: a.margin,
        })
        .collect()
}

/// Builds the export of every run in the database (optionally only meshes
/// whose source path or hash contains `filter`).
pub fn export(db: &Db, filter: Option<&str>) -> Result<Export> {
    let meshes = db.meshes()?;
    let mut out = Vec::new();
    for run in db.runs()? {
        let source = meshes
            .iter()
            .find(|m| m.sha256 == run.mesh_sha256)
            .map(|m| m.source.clone())
            .unwrap_or_default();
        if let Some(f) = filter {
            if !source.contains(f) && !run.mesh_sha256.starts_with(f) {
                continue;
            }
        }
        let drops = db.drops(run.id)?;
        let clusters = db.clusters(run.id)?;
        let (clusters, families) = split(&clusters);
        out.push(MeshExport {
            mesh: source,
            sha256: run.mesh_sha256.clone(),
            drops: drops.len() as u64,
            drops_requested: run.drops,
            settled: drops.iter().filter(|d| d.settled).count() as u64,
            seed: run.seed,
            collider: run.collider.clone(),
            crate_version: run.crate_version.clone(),
            params: serde_json::from_str(&run.params).unwrap_or(serde_json::Value::Null),
            clusters,
            families,
            analytic: analytic(&db.analytic(run.id)?),
        });
    }
    Ok(Export {
        format: FORMAT,
        meshes: out,
    })
}
