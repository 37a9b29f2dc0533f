//! Stable resting poses of an object on a plane, and the database that holds
//! them (see `docs/stable-poses.md` for the user documentation).
//!
//! Pipeline: [`prepare`] a mesh (hash, mass properties from the mesh, the
//! collider, the quasi-static [`analytic`] estimate), run seeded
//! [`drop`] tests in parallel ([`run_drops`], or [`run_into_db`] which skips
//! finished drops and commits as it goes), then [`cluster`] the settled drops
//! modulo rotation about gravity. Every drop's randomness comes from (mesh
//! hash, seed, drop index) and every drop runs in its own world, so results
//! are independent of thread count, sharding and interruption.

pub mod analytic;
pub mod cluster;
pub mod db;
pub mod drop;
pub mod export;
pub mod hull;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;

use glam::{DVec3, Vec3};
use rapier3d::prelude::SharedShape;
use rapier3d::parry::shape::ConvexPolyhedron;

use self::analytic::{Analytic, AnalyticParams};
use self::cluster::{Cluster, ClusterParams};
use self::db::{sha256_hex, Db, MeshRecord};
use self::drop::{DropBody, DropResult, SimParams};
use self::hull::Hull;
use crate::error::{Error, Result};
use crate::mesh::mass::MassProperties;
use crate::mesh::Mesh;

/// Collision shape used for the dropped object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColliderKind {
    /// One convex hull, simplified (fast; exact for convex objects).
    Hull,
    /// Several convex parts: the mesh's connected components when it has
    /// more than one (files that already are a convex decomposition), else
    /// parry's VHACD decomposition of the mesh.
    Decomposition,
}

impl std::str::FromStr for ColliderKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "hull" => Ok(ColliderKind::Hull),
            "decomposition" | "decomp" => Ok(ColliderKind::Decomposition),
            _ => Err(format!(
                "unknown collider '{s}' (expected hull or decomposition)"
            )),
        }
    }
}

impl ColliderKind {
    pub fn as_str(self) -> &'static str {
        match self {
            ColliderKind::Hull => "hull",
            ColliderKind::Decomposition => "decomposition",
        }
    }
}

/// Everything that determines the drops of a run. Its canonical JSON (field
/// order as declared) is hashed into the run key of the database.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunParams {
    /// Number of drops (indices 0..drops).
    pub drops: u64,
    pub seed: u64,
    pub collider: ColliderKind,
    /// Vertex budget of each simplified hull (rapier jitters on hulls with
    /// hundreds of tiny facets).
    pub hull_max_points: usize,
    /// Stop simplifying once every hull vertex is within this many bounding
    /// diagonals of the simplified hull.
    pub hull_tolerance_diag: f64,
    pub sim: SimParams,
}

impl Default for RunParams {
    fn default() -> Self {
        RunParams {
            drops: 1000,
            seed: 0,
            collider: ColliderKind::Hull,
            hull_max_points: 96,
            hull_tolerance_diag: 5e-3,
            sim: SimParams::default(),
        }
    }
}

/// How drops are made from the same parameters: the collider
/// ([`collider_shapes`]) and the worlds they share
/// ([`drop::DROPS_PER_WORLD`]). It is part of the run key, so a database
/// never resumes a run with drops made another way. 1: one support
/// tetrahedron per corner of every face with more than four, one drop per
/// world; 2: support pyramids of four corners (same support polygons, fewer
/// pieces); 3: 32 drops per world; 4: a support piece takes part in
/// collisions only while it is near the ground (`drop::update_pieces`); 5:
/// the collider is simplified from the exact convex hull
/// ([`crate::mesh::mass::convex_hull`]) instead of parry's `f32` one, and
/// objects smaller than 0.15 m are time-scaled
/// ([`drop::SimParams::for_size`]); 6: the body's principal axes of inertia
/// are computed in f64 ([`crate::mesh::mass::principal_axes`]), not by
/// parry's eigensolver, which gave light bodies (under about 1e-5 kg·m²)
/// wrong axes, and objects larger than 0.15 m are time-scaled too; 7: the
/// collider and the body are built about the centre of mass, offset taken
/// off in f64 ([`drop::DropBody`]), so meshes far from their model origin
/// drop as they do at it.
pub const DROP_REVISION: u32 = 7;

/// The run parameters as stored and hashed into the run key.
#[derive(serde::Serialize)]
struct KeyedParams<'a> {
    drop_revision: u32,
    /// The drop body's scale when it is not 1 ([`drop::simulation_scale`]):
    /// revision 7 simulated such objects at their own size, most drops
    /// unsettled, and those runs are not resumed.
    #[serde(skip_serializing_if = "Option::is_none")]
    simulation_scale: Option<f64>,
    #[serde(flatten)]
    params: &'a RunParams,
}

/// Drop indices made at a time by [`run_into_db`] (8 MB).
const PENDING_CHUNK: usize = 1 << 20;

/// A subset of the drop indices: `--shard k/n` runs the worlds (groups of
/// [`drop::DROPS_PER_WORLD`] consecutive drops, simulated together) with
/// `world % n == k - 1`, so every world runs whole in one shard.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 1-based shard number.
    pub k: u64,
    pub n: u64,
}

impl Shard {
    pub fn contains(&self, index: u64) -> bool {
        (index / drop::DROPS_PER_WORLD) % self.n == self.k - 1
    }

    /// This shard's drops of a run of `drops`, in order.
    pub fn indices(self, drops: u64) -> impl Iterator<Item = u64> {
        let per = drop::DROPS_PER_WORLD;
        let n = usize::try_from(self.n).unwrap_or(usize::MAX);
        (self.k - 1..drops.div_ceil(per))
            .step_by(n)
            .flat_map(move |w| w * per..(w * per).saturating_add(per).min(drops))
    }

    /// How many drops of a run of `drops` this shard holds.
    pub fn count(&self, drops: u64) -> u64 {
        let per = drop::DROPS_PER_WORLD;
        let worlds = drops.div_ceil(per);
        if worlds < self.k {
            return 0;
        }
        let mine = (worlds - self.k) / self.n + 1;
        let last = worlds - 1;
        let short = if last % self.n == self.k - 1 { last * per + per - drops } else { 0 };
        mine.saturating_mul(per) - short
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || format!("bad shard '{s}': expected k/n with 1 <= k <= n (e.g. 3/8)");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k: u64 = k.trim().parse().map_err(|_| bad())?;
        let n: u64 = n.trim().parse().map_err(|_| bad())?;
        if n == 0 || k == 0 || k > n {
            return Err(bad());
        }
        Ok(Shard { k, n })
    }
}

/// A mesh ready for drop tests.
#[derive(Clone)]
pub struct PreparedMesh {
    /// Name shown to users (the source path).
    pub name: String,
    /// SHA-256 of the geometry in metres (see [`mesh_sha256`]).
    pub sha256: String,
    pub mesh: Mesh,
    pub mass: MassProperties,
    pub body: DropBody,
    /// Convex parts of the collider and their total vertex count.
    pub collider_parts: usize,
    pub collider_points: usize,
    pub analytic: Analytic,
    /// Warnings to show the user (open mesh, fallbacks).
    pub warnings: Vec<String>,
}

/// SHA-256 over the geometry in metres: vertex count, triangle count, the
/// vertices as little-endian f64 triples, then the triangles as u32 triples.
/// Independent of file format and path; changes when units change.
pub fn mesh_sha256(mesh: &Mesh) -> String {
    let mut bytes = Vec::with_capacity(16 + mesh.vertices.len() * 24 + mesh.triangles.len() * 12);
    bytes.extend((mesh.vertices.len() as u64).to_le_bytes());
    bytes.extend((mesh.triangles.len() as u64).to_le_bytes());
    for v in &mesh.vertices {
        for c in v.to_array() {
            bytes.extend(c.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for i in t {
            bytes.extend(i.to_le_bytes());
        }
    }
    sha256_hex(&bytes)
}

/// Computes mass properties, the collider and the analytic estimate.
pub fn prepare(mesh: Mesh, name: &str, params: &RunParams) -> Result<PreparedMesh> {
    let _span = tracing::trace_span!("prepare", mesh = name).entered();
    let sha256 = mesh_sha256(&mesh);
    let (mass, mut warnings) = MassProperties::of_mesh(&mesh)?;
    let diagonal = mesh.diagonal();
    let tol = params.hull_tolerance_diag * diagonal;
    let (full, note) = Hull::of_mesh_vertices(name, &mesh.vertices)?;
    warnings.extend(note);
    let analytic = analytic::stable_poses(&full, mass.com, AnalyticParams::default())
        .map_err(|e| Error::InvalidInput(format!("{name}: {e}")))?;
    // The collider and the body are built about the centre of mass (see
    // `DropBody`): the offset is taken off in f64, before rapier's f32; and
    // scaled there when the object is outside the sizes rapier is run at.
    let scale = drop::simulation_scale(diagonal);
    let origin = mass.com;
    let parts: Vec<Hull> = match params.collider {
        ColliderKind::Hull => {
            let h = full.simplified(params.hull_max_points, tol)?;
            vec![Hull { vertices: h.vertices.iter().map(|v| *v - origin).collect(), triangles: h.triangles }]
        }
        ColliderKind::Decomposition => {
            decomposition(&mesh, name, origin, params.hull_max_points, tol, &mut warnings)?
        }
    };
    let parts: Vec<Hull> = parts
        .into_iter()
        .map(|h| Hull { vertices: h.vertices.iter().map(|v| *v * scale).collect(), triangles: h.triangles })
        .collect();
    let mut support = Vec::new();
    for p in &parts {
        support.extend(p.vertices.iter().copied());
    }
    let (shapes, is_piece): (Vec<SharedShape>, Vec<bool>) = collider_shapes(name, &parts)?.into_iter().unzip();
    let collider_points = support.len();
    let body_mass = MassProperties {
        com: DVec3::ZERO,
        volume: mass.volume * scale.powi(3),
        inertia_unit_density: mass.inertia_unit_density * scale.powi(5),
        ..mass.clone()
    };
    Ok(PreparedMesh {
        name: name.to_string(),
        sha256,
        mesh,
        body: DropBody {
            shapes,
            is_piece,
            support,
            mass: body_mass,
            diagonal: diagonal * scale,
            origin: origin * scale,
            scale,
        },
        mass,
        collider_parts: parts.len(),
        collider_points,
        analytic,
        warnings,
    })
}

/// Builds the rapier collider of convex parts (body frame: the parts'
/// vertices are already about the centre of mass, so their f32 rounding is
/// relative to the object's size, wherever the model origin is).
///
/// parry's polyhedron-vs-plane contact uses at most four vertices of the
/// touching face (its `local_support_feature` takes the face's first four
/// vertices). A body resting on a face with more corners (a cylinder's end, a
/// box scan's merged side) would then be supported by a sliver of that face
/// and topple. So the corners the hull leaves out (the fifth on) are given to
/// [`support_pieces`]: thin pyramids inside the hull whose base faces have at
/// most four corners, all on the face. Hull and pieces together touch the
/// plane at every corner, so the support polygon is the whole face, and the
/// shape is unchanged. Four corners per piece keeps the pieces few: every
/// piece touching the plane is one more collider pair and contact
/// constraint at every step (one thin tetrahedron per corner, drop
/// [`DROP_REVISION`] 1, made steps 1.3-3.4× dearer), and pieces take part
/// only near the ground (`drop::update_pieces`). The pieces are separate
/// colliders on the body (not one compound shape: rapier's
/// compound-vs-half-space path let a cylinder on its side sink and roll
/// forever in our tests).
fn collider_shapes(name: &str, parts: &[Hull]) -> Result<Vec<(SharedShape, bool)>> {
    let mut shapes = Vec::new();
    for part in parts {
        let pts: Vec<Vec3> = part.vertices.iter().map(|v| v.as_vec3()).collect();
        let hull = SharedShape::convex_hull(&pts).ok_or_else(|| {
            Error::InvalidInput(format!("{name}: rapier could not build a convex collider"))
        })?;
        let pieces = hull.as_convex_polyhedron().map(support_pieces).unwrap_or_default();
        shapes.push((hull, false));
        shapes.extend(pieces.into_iter().map(|p| (p, true)));
    }
    if shapes.is_empty() {
        return Err(Error::InvalidInput(format!("{name}: empty collider")));
    }
    Ok(shapes)
}

/// The pieces that make every corner of every face of `poly` a contact
/// point (see [`collider_shapes`]): per face with more than four corners,
/// its corners past the fourth in groups of four, each group the base of a
/// pyramid whose apex lies halfway from the face's centre to the hull's.
fn support_pieces(poly: &ConvexPolyhedron) -> Vec<SharedShape> {
    let points = poly.points();
    let inside = points.iter().copied().sum::<Vec3>() / points.len().max(1) as f32;
    let adj = poly.vertices_adj_to_face();
    let mut pieces = Vec::new();
    for face in poly.faces() {
        let (first, n) = (face.first_vertex_or_edge as usize, face.num_vertices_or_edges as usize);
        if n <= 4 || first + n > adj.len() {
            continue;
        }
        let corners: Vec<Vec3> = adj[first..first + n].iter().map(|&v| points[v as usize]).collect();
        let centre = corners.iter().copied().sum::<Vec3>() / n as f32;
        let apex = centre + (inside - centre) * 0.5;
        for group in corners[4..].chunks(4) {
            pieces.extend(pyramid(group, &corners, face.normal, apex));
        }
    }
    pieces
}

/// Pyramids over `group` (1 to 4 corners of a convex face, in order) with
/// apex `apex`: one whose base face is the group when parry keeps the base
/// as one face of four corners, else two tetrahedra. A group of one or two
/// corners is completed with corners the hull already touches with (the
/// face's first and third), so the base is a proper triangle.
fn pyramid(group: &[Vec3], corners: &[Vec3], normal: Vec3, apex: Vec3) -> Vec<SharedShape> {
    let mut base = group.to_vec();
    for extra in [corners[0], corners[2]] {
        if base.len() < 3 {
            base.push(extra);
        }
    }
    let with_apex = |b: &[Vec3]| SharedShape::convex_hull(&[b, &[apex]].concat());
    let whole = with_apex(&base).filter(|s| base.len() == 3 || base_kept(s, normal));
    match (whole, base.as_slice()) {
        (Some(s), _) => vec![s],
        (None, &[a, b, c, d]) => [[a, b, c], [a, c, d]].iter().filter_map(|t| with_apex(t)).collect(),
        (None, _) => Vec::new(),
    }
}

/// Whether the piece's face along `normal` kept four corners (parry merges
/// coplanar triangles into one face only within its tolerance).
fn base_kept(piece: &SharedShape, normal: Vec3) -> bool {
    piece.as_convex_polyhedron().is_some_and(|p| {
        p.faces()
            .iter()
            .max_by(|a, b| a.normal.dot(normal).total_cmp(&b.normal.dot(normal)))
            .is_some_and(|f| f.num_vertices_or_edges == 4)
    })
}

/// Convex parts: connected components when there are several, else VHACD;
/// in the body frame (model frame less `origin`, the centre of mass).
fn decomposition(
    mesh: &Mesh,
    name: &str,
    origin: DVec3,
    max_points: usize,
    tol: f64,
    warnings: &mut Vec<String>,
) -> Result<Vec<Hull>> {
    let mut welded = mesh.clone();
    welded.weld();
    for v in &mut welded.vertices {
        *v -= origin;
    }
    let comps = components(&welded);
    let mut parts = Vec::new();
    if comps.len() > 1 {
        for c in comps {
            let pts: Vec<DVec3> = c.iter().map(|&v| welded.vertices[v as usize]).collect();
            // Tiny or flat components (slivers) carry no volume: skip them.
            match Hull::of_points(name, &pts) {
                Ok(h) if h.volume() > 1e-9 * mesh.diagonal().powi(3) => {
                    parts.push(h.simplified(max_points, tol)?)
                }
                _ => {}
            }
        }
    } else {
        warnings.push(format!(
            "{name}: one connected component; computing a VHACD convex decomposition (slow for large meshes)"
        ));
        let verts: Vec<Vec3> = welded.vertices.iter().map(|v| v.as_vec3()).collect();
        let decomp = rapier3d::parry::transformation::vhacd::VHACD::decompose(
            &rapier3d::parry::transformation::vhacd::VHACDParameters::default(),
            &verts,
            &welded.triangles,
            true,
        );
        for (pts, _) in decomp.compute_exact_convex_hulls(&verts, &welded.triangles) {
            let pts: Vec<DVec3> = pts.iter().map(|p| p.as_dvec3()).collect();
            if let Ok(h) = Hull::of_points(name, &pts) {
                parts.push(h.simplified(max_points, tol)?);
            }
        }
    }
    if parts.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{name}: the convex decomposition produced no solid part"
        )));
    }
    Ok(parts)
}

/// Vertex sets of the connected components (by shared vertices), in order
/// of their first triangle.
fn components(mesh: &Mesh) -> Vec<Vec<u32>> {
    let n = mesh.vertices.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for t in &mesh.triangles {
        let a = find(&mut parent, t[0] as usize);
        for &v in &t[1..] {
            let b = find(&mut parent, v as usize);
            if a != b {
                parent[b] = a;
            }
        }
    }
    let mut index_of = std::collections::HashMap::new();
    let mut out: Vec<Vec<u32>> = Vec::new();
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &v in t {
            if used[v as usize] {
                continue;
            }
            used[v as usize] = true;
            let r = find(&mut parent, v as usize);
            let k = *index_of.entry(r).or_insert_with(|| {
                out.push(Vec::new());
                out.len() - 1
            });
            out[k].push(v);
        }
    }
    out
}

/// Runs the drops with the given indices of a run of `params.drops` drops on
/// `threads` workers, calling `on_result` on the calling thread as results
/// arrive (in completion order). Drops run by world
/// ([`drop::world_members`]): a world with any drop asked for is simulated
/// whole and only the drops asked for are reported, so a drop's result never
/// depends on which others were asked for. Stops early when `on_result`
/// errors.
pub fn run_drops(
    prepared: &PreparedMesh,
    params: &RunParams,
    indices: &[u64],
    threads: usize,
    mut on_result: impl FnMut(DropResult) -> Result<()>,
) -> Result<()> {
    let worlds = worlds_of(indices, params.drops);
    let threads = threads.max(1).min(worlds.len().max(1));
    // One span for the batch: a drop is too many to trace one by one.
    let _span = tracing::trace_span!("drop_tests", drops = indices.len(), threads).entered();
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::sync_channel::<DropResult>(256);
    std::thread::scope(|s| {
        for _ in 0..threads {
            let tx = tx.clone();
            let (next, stop, worlds) = (&next, &stop, &worlds);
            s.spawn(move || loop {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some((members, wanted)) = worlds.get(i) else { break };
                let results = drop::simulate_world(
                    &prepared.body,
                    &params.sim,
                    &prepared.sha256,
                    params.seed,
                    members.clone(),
                );
                let mut sent = results.into_iter().filter(|r| wanted.contains(&r.index));
                if sent.try_for_each(|r| tx.send(r)).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        let mut result = Ok(());
        for r in rx.iter() {
            if result.is_ok() {
                result = on_result(r);
                if result.is_err() {
                    stop.store(true, Ordering::Relaxed);
                }
            }
        }
        result
    })
}

/// The worlds holding `indices` (in a run of `drops` drops), each with the
/// indices asked for in it, in order of first appearance.
fn worlds_of(indices: &[u64], drops: u64) -> Vec<(std::ops::Range<u64>, Vec<u64>)> {
    let mut worlds: Vec<(std::ops::Range<u64>, Vec<u64>)> = Vec::new();
    let mut slot_of = std::collections::HashMap::new();
    for &index in indices {
        let members = drop::world_members(index, drops.max(index.saturating_add(1)));
        let k = *slot_of.entry(members.start).or_insert_with(|| {
            worlds.push((members, Vec::new()));
            worlds.len() - 1
        });
        worlds[k].1.push(index);
    }
    worlds
}

/// What a database run did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    pub run_id: i64,
    /// Drops of this run (this shard) that were already in the database.
    pub reused: u64,
    /// Drops simulated now.
    pub simulated: u64,
    /// Drops stored for the run in total (all shards present).
    pub stored: u64,
    pub settled: u64,
    pub clusters: Vec<Cluster>,
    pub seconds: f64,
}

/// Runs the drops of `params` (restricted to `shard`) that the database does
/// not have yet, committing every `commit_every` drops (and at the end), then
/// re-clusters the run. `progress(done, total)` is called after each drop.
#[allow(clippy::too_many_arguments)]
pub fn run_into_db(
    db: &mut Db,
    prepared: &PreparedMesh,
    units: &str,
    scale_to_metres: f64,
    params: &RunParams,
    shard: Option<Shard>,
    threads: usize,
    cluster_params: ClusterParams,
    mut progress: impl FnMut(u64, u64),
) -> Result<RunSummary> {
    let t0 = std::time::Instant::now();
    let record = tracing::trace_span!("record_run").entered();
    let (closed_b, closed_n) = {
        let mut w = prepared.mesh.clone();
        w.weld();
        w.edge_counts()
    };
    let m = &prepared.mass;
    let inertia = m.inertia_unit_density.to_cols_array();
    db.upsert_mesh(&MeshRecord {
        sha256: prepared.sha256.clone(),
        source: prepared.name.clone(),
        units: units.to_string(),
        scale_to_metres,
        vertices: prepared.mesh.vertices.len() as u64,
        triangles: prepared.mesh.triangles.len() as u64,
        closed: closed_b == 0 && closed_n == 0,
        volume: m.volume,
        com: m.com.to_array(),
        inertia,
        mass_source: serde_json::to_value(m.source)
            .ok()
            .and_then(|v| v.as_str().map(String::from))
            .unwrap_or_default(),
        warnings: prepared.warnings.clone(),
    })?;
    let scale = prepared.body.scale;
    let keyed = KeyedParams { drop_revision: DROP_REVISION, simulation_scale: (scale != 1.0).then_some(scale), params };
    let params_json = serde_json::to_string(&keyed)
        .map_err(|e| Error::InvalidInput(format!("cannot serialise run parameters: {e}")))?;
    let run_id = db.run_id(
        &prepared.sha256,
        &params_json,
        params.seed,
        params.drops,
        params.collider.as_str(),
        cluster_params,
    )?;
    db.set_analytic(run_id, &prepared.analytic.poses, &prepared.analytic.notes)?;
    let done = db.finished_drops(run_id)?;
    drop(record);
    let shard = shard.unwrap_or(Shard { k: 1, n: 1 });
    let total = shard.count(params.drops);
    let reused = done.iter().filter(|&&i| i < params.drops && shard.contains(i)).count() as u64;
    let mut finished = reused;
    let mut simulated = 0u64;
    progress(finished, total);
    let mut batch: Vec<DropResult> = Vec::with_capacity(64);
    let mut last_commit = std::time::Instant::now();
    // The pending indices are made a chunk at a time, so memory stays
    // bounded however many drops are asked for.
    let mut todo = shard.indices(params.drops).filter(|i| !done.contains(i)).peekable();
    while todo.peek().is_some() {
        let pending: Vec<u64> = todo.by_ref().take(PENDING_CHUNK).collect();
        simulated += pending.len() as u64;
        run_drops(prepared, params, &pending, threads, |r| {
            batch.push(r);
            finished += 1;
            progress(finished, total);
            if batch.len() >= 64 || last_commit.elapsed().as_secs_f64() > 1.0 {
                db.insert_drops(run_id, &batch)?;
                batch.clear();
                last_commit = std::time::Instant::now();
            }
            Ok(())
        })?;
    }
    tracing::trace_span!("store").in_scope(|| db.insert_drops(run_id, &batch))?;
    let clusters = tracing::trace_span!("cluster").in_scope(|| db.recompute_clusters(run_id, cluster_params))?;
    let stored = db.drops(run_id)?;
    Ok(RunSummary {
        run_id,
        reused,
        simulated,
        stored: stored.len() as u64,
        settled: stored.iter().filter(|d| d.settled).count() as u64,
        clusters,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// For each cluster, the nearest analytic pose: (index, angle in degrees,
/// cluster probability − analytic probability). Families get `None`.
pub fn match_analytic(
    clusters: &[Cluster],
    analytic: &[analytic::AnalyticPose],
) -> Vec<Option<(usize, f64, f64)>> {
    clusters
        .iter()
        .map(|c| {
            if c.kind != cluster::ClusterKind::Pose {
                return None;
            }
            let g = DVec3::from_array(c.gravity_in_model);
            analytic
                .iter()
                .enumerate()
                .map(|(i, a)| {
                    let cos = g
                        .dot(DVec3::from_array(a.gravity_in_model))
                        .clamp(-1.0, 1.0);
                    (i, cos.acos().to_degrees(), c.probability - a.probability)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn shard_parsing_and_membership() {
        let s: Shard = "2/3".parse().unwrap();
        let per = drop::DROPS_PER_WORLD;
        assert!(s.contains(per) && s.contains(2 * per - 1) && s.contains(4 * per) && !s.contains(0) && !s.contains(2 * per));
        // Every drop of a run is in exactly one shard, listed and counted.
        for drops in [0, 1, per - 1, per, per + 1, 5 * per + 3, 7 * per] {
            for n in 1..=4 {
                let mut all = Vec::new();
                for k in 1..=n {
                    let shard = Shard { k, n };
                    let mine: Vec<u64> = shard.indices(drops).collect();
                    assert_eq!(mine.len() as u64, shard.count(drops), "{k}/{n} of {drops}");
                    assert!(mine.iter().all(|&i| shard.contains(i) && i < drops));
                    all.extend(mine);
                }
                all.sort_unstable();
                assert_eq!(all, (0..drops).collect::<Vec<_>>(), "{n} shards of {drops}");
            }
        }
        assert!("0/3".parse::<Shard>().is_err());
        assert!("4/3".parse::<Shard>().is_err());
        assert!("x".parse::<Shard>().is_err());
    }

    #[test]
    fn components_split_separate_boxes() {
        let a = shapes::cuboid(DVec3::splat(0.1));
        let mut b = shapes::cuboid(DVec3::splat(0.1));
        let off = a.vertices.len() as u32;
        let mut m = a.clone();
        m.vertices
            .extend(b.vertices.drain(..).map(|v| v + DVec3::X));
        m.triangles
            .extend(b.triangles.iter().map(|t| t.map(|i| i + off)));
        assert_eq!(components(&m).len(), 2);
    }

    /// Every corner of a face with more than four corners touches the plane
    /// through the hull (its first four) or a piece (the rest), with one
    /// piece per four corners left over, and the pieces lie inside the hull.
    #[test]
    fn support_pieces_cover_every_corner_of_large_faces() {
        for sides in [5usize, 6, 8, 9, 12, 17, 32] {
            let ring = |z: f32| (0..sides).map(move |i| {
                let a = std::f32::consts::TAU * i as f32 / sides as f32;
                Vec3::new(a.cos() * 0.05, a.sin() * 0.05, z)
            });
            let pts: Vec<Vec3> = ring(0.0).chain(ring(0.08)).collect();
            let hull = SharedShape::convex_hull(&pts).unwrap();
            let poly = hull.as_convex_polyhedron().unwrap();
            let pieces = support_pieces(poly);
            assert_eq!(pieces.len(), 2 * (sides - 4).div_ceil(4), "{sides} sides");
            for face in poly.faces().iter().filter(|f| f.num_vertices_or_edges > 4) {
                let first = face.first_vertex_or_edge as usize;
                let corners: Vec<Vec3> = poly.vertices_adj_to_face()[first..first + sides]
                    .iter()
                    .map(|&v| poly.points()[v as usize])
                    .collect();
                // The points each shape touches a plane along `face.normal` with:
                // the (up to) four parry takes of its best-aligned face.
                let touching = |p: &ConvexPolyhedron| -> Vec<Vec3> {
                    let f = p.faces().iter().max_by(|a, b| a.normal.dot(face.normal).total_cmp(&b.normal.dot(face.normal))).unwrap();
                    let i = f.first_vertex_or_edge as usize;
                    let n = (f.num_vertices_or_edges as usize).min(4);
                    p.vertices_adj_to_face()[i..i + n].iter().map(|&v| p.points()[v as usize]).collect()
                };
                let mut touched = touching(poly);
                for piece in &pieces {
                    let p = piece.as_convex_polyhedron().unwrap();
                    if p.faces().iter().any(|f| f.normal.dot(face.normal) > 0.999) {
                        touched.extend(touching(p));
                    }
                    for v in p.points() {
                        let inside = poly.faces().iter().all(|f| {
                            let on = poly.points()[poly.vertices_adj_to_face()[f.first_vertex_or_edge as usize] as usize];
                            f.normal.dot(*v - on) < 1e-5
                        });
                        assert!(inside, "{sides} sides: piece point {v} outside the hull");
                    }
                }
                for c in &corners {
                    assert!(touched.iter().any(|t| t.distance(*c) < 1e-6), "{sides} sides: corner {c} does not touch");
                }
            }
        }
    }

    #[test]
    fn cube_drops_settle_on_faces() {
        let params = RunParams {
            drops: 24,
            ..Default::default()
        };
        let p = prepare(shapes::cuboid(DVec3::splat(0.03)), "cube", &params).unwrap();
        let idx: Vec<u64> = (0..24).collect();
        let mut out = Vec::new();
        run_drops(&p, &params, &idx, 2, |r| {
            out.push(r);
            Ok(())
        })
        .unwrap();
        assert_eq!(out.len(), 24);
        for d in &out {
            assert!(d.settled, "drop {} did not settle", d.index);
            // Gravity along a face normal, origin 3 cm above the plane.
            let g = d.gravity_in_model;
            let m = g.x.abs().max(g.y.abs()).max(g.z.abs());
            assert!(m > 0.999, "{g}");
            assert!((d.height - 0.03).abs() < 1e-3, "{}", d.height);
        }
    }
}
