//! The stable-pose database (SQLite, one file).
//!
//! Schema (documented for users in `docs/stable-poses.md`):
//! - `meshes`: one row per mesh geometry, keyed by the SHA-256 of the loaded
//!   geometry in metres; source path, units, sizes, mass properties.
//! - `runs`: one row per (mesh, drop-test parameters) pair; the parameters
//!   (as canonical JSON) and their hash without the drop count form the key,
//!   so re-running the same inputs finds the same run and continues it, and
//!   asking for more drops extends it.
//! - `drops`: one row per finished drop, primary key `(run_id, drop_index)`:
//!   a drop is written at most once, so a killed run that restarts loses only
//!   uncommitted drops (which it simulates again, bit-identically) and never
//!   duplicates one.
//! - `clusters`, `analytic`: derived tables, recomputed from the drops (and
//!   the mesh) after every run and merge, so they never disagree with them.
//!
//! All floating-point values are stored as SQLite REALs (IEEE doubles), which
//! round-trip exactly: a merged database has bit-identical drops.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use rusqlite::{params, Connection, OptionalExtension};

use super::analytic::AnalyticPose;
use super::cluster::{cluster_about, Cluster, ClusterKind, ClusterParams};
use super::drop::DropResult;
use crate::error::{Error, Result};

const SCHEMA: &str = r#"
CREATE TABLE IF NOT EXISTS meshes (
    sha256          TEXT PRIMARY KEY,
    source          TEXT NOT NULL,
    units           TEXT NOT NULL,
    scale_to_metres REAL NOT NULL,
    vertices        INTEGER NOT NULL,
    triangles       INTEGER NOT NULL,
    closed          INTEGER NOT NULL,
    volume          REAL NOT NULL,
    com_x REAL NOT NULL, com_y REAL NOT NULL, com_z REAL NOT NULL,
    inertia         TEXT NOT NULL,
    mass_source     TEXT NOT NULL,
    warnings        TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS runs (
    id              INTEGER PRIMARY KEY,
    mesh_sha256     TEXT NOT NULL REFERENCES meshes(sha256),
    params_key      TEXT NOT NULL,
    params          TEXT NOT NULL,
    seed            INTEGER NOT NULL,
    drops           INTEGER NOT NULL,
    collider        TEXT NOT NULL,
    crate_version   TEXT NOT NULL,
    cluster_params  TEXT NOT NULL,
    analytic_notes  TEXT NOT NULL DEFAULT '[]',
    UNIQUE (mesh_sha256, params_key)
);
CREATE TABLE IF NOT EXISTS drops (
    run_id      INTEGER NOT NULL REFERENCES runs(id),
    drop_index  INTEGER NOT NULL,
    settled     INTEGER NOT NULL,
    steps       INTEGER NOT NULL,
    qw REAL NOT NULL, qx REAL NOT NULL, qy REAL NOT NULL, qz REAL NOT NULL,
    height      REAL NOT NULL,
    gx REAL NOT NULL, gy REAL NOT NULL, gz REAL NOT NULL,
    PRIMARY KEY (run_id, drop_index)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS clusters (
    run_id          INTEGER NOT NULL REFERENCES runs(id),
    rank            INTEGER NOT NULL,
    kind            TEXT NOT NULL,
    axis            TEXT,
    count           INTEGER NOT NULL,
    probability     REAL NOT NULL,
    ci_lo REAL NOT NULL, ci_hi REAL NOT NULL,
    gx REAL NOT NULL, gy REAL NOT NULL, gz REAL NOT NULL,
    r_model_to_plane TEXT NOT NULL,
    height          REAL NOT NULL,
    representatives TEXT NOT NULL,
    PRIMARY KEY (run_id, rank)
);
CREATE TABLE IF NOT EXISTS analytic (
    run_id      INTEGER NOT NULL REFERENCES runs(id),
    rank        INTEGER NOT NULL,
    probability REAL NOT NULL,
    gx REAL NOT NULL, gy REAL NOT NULL, gz REAL NOT NULL,
    height      REAL NOT NULL,
    margin      REAL NOT NULL,
    area        REAL NOT NULL,
    PRIMARY KEY (run_id, rank)
);
"#;

/// A mesh as stored in the `meshes` table.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshRecord {
    pub sha256: String,
    pub source: String,
    pub units: String,
    pub scale_to_metres: f64,
    pub vertices: u64,
    pub triangles: u64,
    pub closed: bool,
    pub volume: f64,
    pub com: [f64; 3],
    pub inertia: [f64; 9],
    pub mass_source: String,
    pub warnings: Vec<String>,
}

/// A run as stored in the `runs` table.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRecord {
    pub id: i64,
    pub mesh_sha256: String,
    pub params_key: String,
    pub params: String,
    pub seed: u64,
    pub drops: u64,
    pub collider: String,
    pub crate_version: String,
    pub cluster_params: ClusterParams,
    pub analytic_notes: Vec<String>,
}

impl RunRecord {
    /// How its drops were made (see [`super::DROP_REVISION`]); runs stored
    /// before the revision was recorded are revision 1.
    pub fn drop_revision(&self) -> u64 {
        serde_json::from_str::<serde_json::Value>(&self.params)
            .ok()
            .and_then(|v| v.get("drop_revision").and_then(|r| r.as_u64()))
            .unwrap_or(1)
    }
}

/// An open stable-pose database.
pub struct Db {
    conn: Connection,
    path: PathBuf,
}

impl Db {
    /// Opens (creating if needed) the database at `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Db> {
        let path = path.as_ref().to_path_buf();
        // SQLite needs a file beside which it can keep its rollback journal
        // (`DB-journal`): a device or pipe is no database, and a journal
        // would be made beside it (e.g. in /dev).
        if std::fs::metadata(&path).is_ok_and(|m| !m.is_file()) {
            return Err(Error::Database { path, reason: "not a regular file (a database is a file SQLite can write a journal beside)".into() });
        }
        let conn = Connection::open(&path).map_err(|e| err(&path, e))?;
        let db = Db { conn, path };
        db.conn
            .busy_timeout(std::time::Duration::from_secs(30))
            .map_err(|e| db.e(e))?;
        db.check_integrity()?;
        db.conn.execute_batch(SCHEMA).map_err(|e| db.e(e))?;
        Ok(db)
    }

    /// `PRAGMA quick_check`: a corrupted page would otherwise give counts
    /// that disagree between queries and a merge that silently loses drops.
    fn check_integrity(&self) -> Result<()> {
        let mut stmt = self.conn.prepare("PRAGMA quick_check").map_err(|e| self.e(e))?;
        let rows: Vec<String> =
            stmt.query_map([], |r| r.get::<_, String>(0)).map_err(|e| self.e(e))?.collect::<std::result::Result<_, _>>().map_err(|e| self.e(e))?;
        if rows.len() == 1 && rows[0] == "ok" {
            return Ok(());
        }
        Err(Error::Database {
            path: self.path.clone(),
            reason: format!("the file is corrupt (SQLite quick_check: {}); restore it or run the drops again", rows.join("; ")),
        })
    }

    /// Opens an existing database read-only-ish (errors if it does not exist).
    pub fn open_existing(path: impl AsRef<Path>) -> Result<Db> {
        let p = path.as_ref();
        if !p.exists() {
            return Err(Error::NotFound {
                path: p.to_path_buf(),
            });
        }
        Db::open(p)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn e(&self, e: rusqlite::Error) -> Error {
        err(&self.path, e)
    }

    /// Inserts the mesh unless a mesh with the same hash is already stored.
    pub fn upsert_mesh(&self, m: &MeshRecord) -> Result<()> {
        self.conn
            .execute(
                "INSERT OR IGNORE INTO meshes (sha256, source, units, scale_to_metres, vertices, triangles, closed,
                 volume, com_x, com_y, com_z, inertia, mass_source, warnings)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
                params![
                    m.sha256,
                    m.source,
                    m.units,
                    m.scale_to_metres,
                    m.vertices as i64,
                    m.triangles as i64,
                    m.closed,
                    m.volume,
                    m.com[0],
                    m.com[1],
                    m.com[2],
                    json(&m.inertia),
                    m.mass_source,
                    json(&m.warnings)
                ],
            )
            .map_err(|e| self.e(e))?;
        Ok(())
    }

    /// All meshes, ordered by source path then hash.
    pub fn meshes(&self) -> Result<Vec<MeshRecord>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT sha256, source, units, scale_to_metres, vertices, triangles, closed, volume,
                 com_x, com_y, com_z, inertia, mass_source, warnings FROM meshes ORDER BY source, sha256",
            )
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([], |r| {
                Ok(MeshRecord {
                    sha256: r.get(0)?,
                    source: r.get(1)?,
                    units: r.get(2)?,
                    scale_to_metres: r.get(3)?,
                    vertices: r.get::<_, i64>(4)? as u64,
                    triangles: r.get::<_, i64>(5)? as u64,
                    closed: r.get(6)?,
                    volume: r.get(7)?,
                    com: [r.get(8)?, r.get(9)?, r.get(10)?],
                    inertia: json_col(r, 11)?,
                    mass_source: r.get(12)?,
                    warnings: json_col(r, 13)?,
                })
            })
            .map_err(|e| self.e(e))?;
        rows.collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| self.e(e))
    }

    /// Finds the run for (mesh, parameters) or creates it. `params_json` is the
    /// canonical JSON of the drop-test parameters; the hash of all of them but
    /// the drop count is the key ([`params_key`]), so a run asked for more
    /// drops goes on from the ones it has.
    #[allow(clippy::too_many_arguments)]
    pub fn run_id(
        &self,
        mesh_sha256: &str,
        params_json: &str,
        seed: u64,
        drops: u64,
        collider: &str,
        cluster_params: ClusterParams,
    ) -> Result<i64> {
        let key = params_key(params_json)?;
        self.conn
            .execute(
                "INSERT OR IGNORE INTO runs (mesh_sha256, params_key, params, seed, drops, collider, crate_version, cluster_params)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![
                    mesh_sha256,
                    key,
                    params_json,
                    seed as i64,
                    drops as i64,
                    collider,
                    env!("CARGO_PKG_VERSION"),
                    json(&cluster_params)
                ],
            )
            .map_err(|e| self.e(e))?;
        // More drops asked of a run it already holds extend it: drop i is
        // the same whatever the count, so the stored ones are kept, and the
        // stored parameters say the new count (SET reads the old row).
        self.conn
            .execute(
                "UPDATE runs SET cluster_params = ?1, drops = MAX(drops, ?4),
                     params = CASE WHEN ?4 > drops THEN ?5 ELSE params END
                 WHERE mesh_sha256 = ?2 AND params_key = ?3",
                params![json(&cluster_params), mesh_sha256, key, drops as i64, params_json],
            )
            .map_err(|e| self.e(e))?;
        self.conn
            .query_row(
                "SELECT id FROM runs WHERE mesh_sha256 = ?1 AND params_key = ?2",
                params![mesh_sha256, key],
                |r| r.get(0),
            )
            .map_err(|e| self.e(e))
    }

    /// All runs, ordered by the mesh's source path then id.
    pub fn runs(&self) -> Result<Vec<RunRecord>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT r.id, r.mesh_sha256, r.params_key, r.params, r.seed, r.drops, r.collider, r.crate_version,
                 r.cluster_params, r.analytic_notes FROM runs r LEFT JOIN meshes m ON m.sha256 = r.mesh_sha256
                 ORDER BY m.source, r.id",
            )
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([], |r| {
                Ok(RunRecord {
                    id: r.get(0)?,
                    mesh_sha256: r.get(1)?,
                    params_key: r.get(2)?,
                    params: r.get(3)?,
                    seed: r.get::<_, i64>(4)? as u64,
                    drops: r.get::<_, i64>(5)? as u64,
                    collider: r.get(6)?,
                    crate_version: r.get(7)?,
                    cluster_params: json_col(r, 8)?,
                    analytic_notes: json_col(r, 9)?,
                })
            })
            .map_err(|e| self.e(e))?;
        rows.collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| self.e(e))
    }

    /// Indices of the drops already stored for a run.
    pub fn finished_drops(&self, run_id: i64) -> Result<HashSet<u64>> {
        let mut st = self
            .conn
            .prepare("SELECT drop_index FROM drops WHERE run_id = ?1")
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([run_id], |r| r.get::<_, i64>(0))
            .map_err(|e| self.e(e))?;
        let mut out = HashSet::new();
        for r in rows {
            out.insert(r.map_err(|e| self.e(e))? as u64);
        }
        Ok(out)
    }

    /// Stores finished drops in one transaction. A drop already present is
    /// left alone (it is bit-identical by construction).
    pub fn insert_drops(&mut self, run_id: i64, drops: &[DropResult]) -> Result<()> {
        let path = self.path.clone();
        let tx = self.conn.transaction().map_err(|e| err(&path, e))?;
        {
            let mut st = tx
                .prepare_cached(
                    "INSERT OR IGNORE INTO drops (run_id, drop_index, settled, steps, qw, qx, qy, qz, height, gx, gy, gz)
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12)",
                )
                .map_err(|e| err(&path, e))?;
            for d in drops {
                let q = d.rotation;
                let g = d.gravity_in_model;
                st.execute(params![
                    run_id,
                    d.index as i64,
                    d.settled,
                    d.steps as i64,
                    q.w,
                    q.x,
                    q.y,
                    q.z,
                    d.height,
                    g.x,
                    g.y,
                    g.z
                ])
                .map_err(|e| err(&path, e))?;
            }
        }
        tx.commit().map_err(|e| err(&path, e))
    }

    /// All stored drops of a run, by index.
    pub fn drops(&self, run_id: i64) -> Result<Vec<DropResult>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT drop_index, settled, steps, qw, qx, qy, qz, height, gx, gy, gz FROM drops
                 WHERE run_id = ?1 ORDER BY drop_index",
            )
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([run_id], |r| {
                Ok(DropResult {
                    index: r.get::<_, i64>(0)? as u64,
                    settled: r.get(1)?,
                    steps: r.get::<_, i64>(2)? as u32,
                    rotation: DQuat::from_xyzw(r.get(4)?, r.get(5)?, r.get(6)?, r.get(3)?),
                    height: r.get(7)?,
                    gravity_in_model: DVec3::new(r.get(8)?, r.get(9)?, r.get(10)?),
                })
            })
            .map_err(|e| self.e(e))?;
        rows.collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| self.e(e))
    }

    /// Replaces the analytic poses of a run.
    pub fn set_analytic(
        &mut self,
        run_id: i64,
        poses: &[AnalyticPose],
        notes: &[String],
    ) -> Result<()> {
        let path = self.path.clone();
        let tx = self.conn.transaction().map_err(|e| err(&path, e))?;
        tx.execute("DELETE FROM analytic WHERE run_id = ?1", [run_id])
            .map_err(|e| err(&path, e))?;
        for (rank, p) in poses.iter().enumerate() {
            let g = p.gravity_in_model;
            tx.execute(
                "INSERT INTO analytic (run_id, rank, probability, gx, gy, gz, height, margin, area)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
                params![
                    run_id,
                    rank as i64,
                    p.probability,
                    g[0],
                    g[1],
                    g[2],
                    p.height,
                    p.margin,
                    p.area
                ],
            )
            .map_err(|e| err(&path, e))?;
        }
        tx.execute(
            "UPDATE runs SET analytic_notes = ?1 WHERE id = ?2",
            params![json(&notes), run_id],
        )
        .map_err(|e| err(&path, e))?;
        tx.commit().map_err(|e| err(&path, e))
    }

    /// The analytic poses of a run, most probable first.
    pub fn analytic(&self, run_id: i64) -> Result<Vec<AnalyticPose>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT probability, gx, gy, gz, height, margin, area FROM analytic WHERE run_id = ?1 ORDER BY rank",
            )
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([run_id], |r| {
                Ok(AnalyticPose {
                    probability: r.get(0)?,
                    gravity_in_model: [r.get(1)?, r.get(2)?, r.get(3)?],
                    height: r.get(4)?,
                    margin: r.get(5)?,
                    area: r.get(6)?,
                })
            })
            .map_err(|e| self.e(e))?;
        rows.collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| self.e(e))
    }

    /// Re-clusters a run's stored drops and replaces its `clusters` rows.
    pub fn recompute_clusters(
        &mut self,
        run_id: i64,
        params: ClusterParams,
    ) -> Result<Vec<Cluster>> {
        let drops = self.drops(run_id)?;
        // The mesh's centre of mass, for the clusters' heights (see
        // `cluster_about`); a run without its mesh record clusters about
        // the origin.
        let com = self
            .conn
            .query_row(
                "SELECT m.com_x, m.com_y, m.com_z FROM runs r JOIN meshes m ON m.sha256 = r.mesh_sha256 WHERE r.id = ?1",
                [run_id],
                |r| Ok(DVec3::new(r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()
            .map_err(|e| err(&self.path, e))?
            .filter(|c| c.is_finite())
            .unwrap_or(DVec3::ZERO);
        let clusters = cluster_about(&drops, params, com);
        let path = self.path.clone();
        let tx = self.conn.transaction().map_err(|e| err(&path, e))?;
        tx.execute("DELETE FROM clusters WHERE run_id = ?1", [run_id])
            .map_err(|e| err(&path, e))?;
        for (rank, c) in clusters.iter().enumerate() {
            let (kind, axis) = match &c.kind {
                ClusterKind::Pose => ("pose", None),
                ClusterKind::Circle { axis } => ("circle", Some(json(axis))),
                ClusterKind::Scattered => ("scattered", None),
            };
            let g = c.gravity_in_model;
            tx.execute(
                "INSERT INTO clusters (run_id, rank, kind, axis, count, probability, ci_lo, ci_hi, gx, gy, gz,
                 r_model_to_plane, height, representatives) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
                params![
                    run_id,
                    rank as i64,
                    kind,
                    axis,
                    c.count as i64,
                    c.probability,
                    c.ci95[0],
                    c.ci95[1],
                    g[0],
                    g[1],
                    g[2],
                    json(&c.r_model_to_plane),
                    c.height,
                    json(&c.representatives)
                ],
            )
            .map_err(|e| err(&path, e))?;
        }
        tx.execute(
            "UPDATE runs SET cluster_params = ?1 WHERE id = ?2",
            params![json(&params), run_id],
        )
        .map_err(|e| err(&path, e))?;
        tx.commit().map_err(|e| err(&path, e))?;
        Ok(clusters)
    }

    /// The stored clusters of a run, in rank order.
    pub fn clusters(&self, run_id: i64) -> Result<Vec<Cluster>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT kind, axis, count, probability, ci_lo, ci_hi, gx, gy, gz, r_model_to_plane, height, representatives
                 FROM clusters WHERE run_id = ?1 ORDER BY rank",
            )
            .map_err(|e| self.e(e))?;
        let rows = st
            .query_map([run_id], |r| {
                let kind: String = r.get(0)?;
                let axis: Option<String> = r.get(1)?;
                let kind = match kind.as_str() {
                    "circle" => ClusterKind::Circle {
                        axis: serde_json::from_str(&axis.unwrap_or_default()).map_err(|e| corrupt(1, e))?,
                    },
                    "scattered" => ClusterKind::Scattered,
                    "pose" => ClusterKind::Pose,
                    other => return Err(corrupt(0, format!("unknown cluster kind '{other}'"))),
                };
                Ok(Cluster {
                    kind,
                    count: r.get::<_, i64>(2)? as u64,
                    probability: r.get(3)?,
                    ci95: [r.get(4)?, r.get(5)?],
                    gravity_in_model: [r.get(6)?, r.get(7)?, r.get(8)?],
                    r_model_to_plane: json_col(r, 9)?,
                    height: r.get(10)?,
                    representatives: json_col(r, 11)?,
                })
            })
            .map_err(|e| self.e(e))?;
        rows.collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| self.e(e))
    }

    /// Merges another database into this one: meshes and runs are matched by
    /// their keys (mesh hash, parameter hash), drops by `(run, index)`. A drop
    /// present in both must be identical; otherwise the merge fails (the
    /// inputs were made by builds that simulate differently). Clusters of the
    /// touched runs are recomputed. Returns the number of new drops.
    pub fn merge_from(&mut self, other: &Path) -> Result<u64> {
        let src = Db::open_existing(other)?;
        for m in src.meshes()? {
            self.upsert_mesh(&m)?;
        }
        let mut added = 0;
        for run in src.runs()? {
            let id = self.run_id(
                &run.mesh_sha256,
                &run.params,
                run.seed,
                run.drops,
                &run.collider,
                run.cluster_params,
            )?;
            if self.analytic(id)?.is_empty() {
                self.set_analytic(id, &src.analytic(run.id)?, &run.analytic_notes)?;
            }
            let have: std::collections::HashMap<u64, DropResult> =
                self.drops(id)?.into_iter().map(|d| (d.index, d)).collect();
            let mut new = Vec::new();
            for d in src.drops(run.id)? {
                match have.get(&d.index) {
                    Some(h) if !same_drop(h, &d) => {
                        return Err(Error::Database {
                            path: self.path.clone(),
                            reason: format!(
                                "drop {} of run {} differs between {} and this database; they were made by builds \
                                 that simulate differently and cannot be merged",
                                d.index,
                                run.params_key,
                                other.display()
                            ),
                        })
                    }
                    Some(_) => {}
                    None => new.push(d),
                }
            }
            added += new.len() as u64;
            self.insert_drops(id, &new)?;
            self.recompute_clusters(id, run.cluster_params)?;
        }
        Ok(added)
    }

    /// A canonical text dump of every table (rows in key order, floats as
    /// bit patterns), for comparing databases in tests and audits.
    pub fn contents(&self) -> Result<String> {
        let mut out = String::new();
        for (table, order) in [
            ("meshes", "sha256"),
            ("runs", "mesh_sha256, params_key"),
            ("drops", "run_id, drop_index"),
            ("clusters", "run_id, rank"),
            ("analytic", "run_id, rank"),
        ] {
            let mut st = self
                .conn
                .prepare(&format!("SELECT * FROM {table} ORDER BY {order}"))
                .map_err(|e| self.e(e))?;
            let names: Vec<String> = st.column_names().iter().map(|s| s.to_string()).collect();
            let mut rows = st.query([]).map_err(|e| self.e(e))?;
            out.push_str(&format!("[{table}]\n"));
            while let Some(r) = rows.next().map_err(|e| self.e(e))? {
                for (c, name) in names.iter().enumerate() {
                    // Run ids are local row ids; runs are identified by their keys.
                    if name == "id" || name == "run_id" {
                        continue;
                    }
                    let v: rusqlite::types::Value = r.get(c).map_err(|e| self.e(e))?;
                    let s = match v {
                        rusqlite::types::Value::Real(f) => format!("{:016x}", f.to_bits()),
                        other => format!("{other:?}"),
                    };
                    out.push_str(&s);
                    out.push('|');
                }
                out.push('\n');
            }
        }
        Ok(out)
    }

    /// Whether the database holds a run for this mesh hash (any parameters).
    pub fn has_mesh(&self, sha256: &str) -> Result<bool> {
        self.conn
            .query_row("SELECT 1 FROM meshes WHERE sha256 = ?1", [sha256], |_| {
                Ok(())
            })
            .optional()
            .map(|o| o.is_some())
            .map_err(|e| self.e(e))
    }
}

fn same_drop(a: &DropResult, b: &DropResult) -> bool {
    a.settled == b.settled
        && a.steps == b.steps
        && a.height.to_bits() == b.height.to_bits()
        && a.rotation.to_array().map(f64::to_bits) == b.rotation.to_array().map(f64::to_bits)
}

fn err(path: &Path, e: rusqlite::Error) -> Error {
    Error::Database {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

fn json<T: serde::Serialize + ?Sized>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "null".into())
}

/// Lower-case hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    hex(&Sha256::digest(bytes))
}

/// Lower-case hex SHA-256 of everything `reader` yields, read in pieces
/// (a file of any size in bounded memory).
pub fn sha256_hex_reader(mut reader: impl std::io::Read) -> std::io::Result<String> {
    use sha2::{Digest, Sha256};
    let mut hash = Sha256::new();
    std::io::copy(&mut reader, &mut hash)?;
    Ok(hex(&hash.finalize()))
}

/// Lower-case hex of a digest's bytes.
pub fn hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// A column that does not hold what this version wrote there: an error
/// (the database is corrupt or from another tool), never a silent default.
fn corrupt(col: usize, e: impl std::fmt::Display) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(col, rusqlite::types::Type::Text, format!("corrupt column {col}: {e}").into())
}

/// Parses the JSON stored in column `col`.
fn json_col<T: serde::de::DeserializeOwned>(r: &rusqlite::Row, col: usize) -> rusqlite::Result<T> {
    let text: String = r.get(col)?;
    serde_json::from_str(&text).map_err(|e| corrupt(col, e))
}

/// The run key of a parameter JSON: SHA-256 of the parameters without
/// `drops` (keys sorted). Drop i depends on the seed, the index and the
/// other parameters, never on how many drops were asked for.
fn params_key(params_json: &str) -> Result<String> {
    let mut v: serde_json::Value = serde_json::from_str(params_json)
        .map_err(|e| Error::InvalidInput(format!("run parameters are not JSON: {e}")))?;
    if let Some(o) = v.as_object_mut() {
        o.remove("drops");
    }
    Ok(sha256_hex(v.to_string().as_bytes()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_regular_file_is_a_database() {
        let d = tempfile::tempdir().unwrap();
        let folder = d.path().join("db");
        std::fs::create_dir(&folder).unwrap();
        let e = Db::open(&folder).err().expect("a folder is no database").to_string();
        assert!(e.contains("not a regular file"), "{e}");
        assert!(!d.path().join("db-journal").exists());
    }
}
