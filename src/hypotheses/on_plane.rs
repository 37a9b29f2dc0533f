//! Hypotheses of an object resting on a support plane (paper section 3.1):
//! each stable resting pose × yaw steps about the plane normal × an in-plane
//! position found from the segmented depth.
//!
//! The resting poses come from the stable-pose database (`plausible
//! stable-poses export`) or, without one, from the quasi-static analysis of
//! the mesh's convex hull. For each (resting pose, yaw) the object is put on
//! the plane (its lowest vertex touching it) with its centre of mass over
//! the centroid of the observed object points, then moved along the plane
//! by the offset between the observed and the rendered visible centroids
//! (the camera sees one side of the object, so the centroid of what it sees
//! is not over the centre of mass); that alignment is repeated a few times.
//! An optional grid of in-plane offsets around the aligned position adds
//! the neighbours.

use glam::{DMat3, DVec2, DVec3};
use rayon::prelude::*;

use crate::error::{Error, Input, Result};
use crate::kernels::raster::{render_ids, resolve};
use crate::kernels::{GpuPose, RenderMesh};
use crate::mesh::mass::MassProperties;
use crate::mesh::Mesh;
use crate::observation::DepthImage;
use crate::physical::scene::camera_to_plane_frame;
use crate::physical::Plane;
use crate::pose::{axis_angle, Pose};

/// A resting pose up to rotation about the plane normal.
#[derive(Clone, Debug, PartialEq)]
pub struct RestingPose {
    /// Rotation from the model frame to the plane frame (z up).
    pub r_model_to_plane: DMat3,
    /// How often the object ends up resting like this.
    pub probability: f64,
    /// The probability of the cluster or the whole rolling family this pose
    /// stands for (a family's roll angles share its probability);
    /// [`OnPlaneParams::min_probability`] filters on this.
    pub group_probability: f64,
}

/// What [`resting_poses_from_export`] reads of the export (the reading
/// side of `stable::export`; unknown fields are ignored, missing ones are
/// errors that name them).
#[derive(serde::Deserialize)]
struct ExportIn {
    format: String,
    meshes: Vec<MeshIn>,
}

#[derive(serde::Deserialize)]
struct MeshIn {
    mesh: String,
    sha256: String,
    /// Settled drops of the run (several runs of one mesh: the largest
    /// clustered one is taken, its probabilities the most precise).
    #[serde(default)]
    settled: u64,
    /// Drops stored and asked for: with no clusters, fewer stored than
    /// asked (or settled drops) mean a run stopped before clustering.
    #[serde(default)]
    drops: u64,
    #[serde(default)]
    drops_requested: u64,
    clusters: Vec<ClusterIn>,
    #[serde(default)]
    families: Vec<FamilyIn>,
}

#[derive(serde::Deserialize)]
struct ClusterIn {
    probability: f64,
    #[serde(rename = "R_model_to_plane")]
    r_model_to_plane: [f64; 9],
}

#[derive(serde::Deserialize)]
struct FamilyIn {
    kind: String,
    axis: Option<[f64; 3]>,
    probability: f64,
}

/// How [`resting_poses_from_export`] found the mesh's entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportMatch {
    /// By the geometry hash: the same mesh in the same units.
    Hash,
    /// By the file name: probably the same object, other units or edits.
    Name,
    /// Neither, but the export holds a single mesh: the caller should warn.
    OnlyEntry,
}

/// Parameters of the generator.
#[derive(Clone, Copy, Debug)]
pub struct OnPlaneParams {
    /// Yaw angles per resting pose, evenly spaced over 360°.
    pub yaw_steps: usize,
    /// Resting poses whose cluster or rolling family is less probable than
    /// this are left out.
    pub min_probability: f64,
    /// Observed-versus-rendered centroid alignments per hypothesis.
    pub align_iterations: usize,
    /// In-plane grid around each aligned position: (2r + 1)² offsets...
    pub grid_radius: usize,
    /// ... spaced this far apart (m).
    pub grid_step: f64,
}

impl Default for OnPlaneParams {
    fn default() -> Self {
        // 15° yaw steps and a 5 mm grid are the reference grids of the
        // authors' code; the grid is off by default (the alignment already
        // centres each hypothesis).
        OnPlaneParams { yaw_steps: 24, min_probability: 0.01, align_iterations: 3, grid_radius: 0, grid_step: 0.005 }
    }
}

/// One generated hypothesis and where it came from.
#[derive(Clone, Debug)]
pub struct OnPlaneHypothesis {
    /// Model to camera.
    pub pose: Pose,
    /// Index into the resting poses given.
    pub rest: usize,
    /// Yaw about the plane normal (radians).
    pub yaw: f64,
    /// In-plane offset from the aligned position (m, plane frame).
    pub offset: DVec2,
}

/// The quasi-static resting poses of `mesh` (stable facets of its convex
/// hull, most probable first): the prior when no drop-test database exists.
pub fn analytic_resting_poses(mesh: &Mesh) -> Result<Vec<RestingPose>> {
    let (hull, _) = crate::stable::hull::Hull::of_mesh_vertices("object", &mesh.vertices)?;
    let (mass, _) = MassProperties::of_mesh(mesh)?;
    let a = crate::stable::analytic::stable_poses(&hull, mass.com, Default::default())?;
    Ok(a.poses
        .iter()
        .map(|p| RestingPose {
            r_model_to_plane: rows(&crate::stable::cluster::canonical_rotation(DVec3::from_array(p.gravity_in_model))),
            probability: p.probability,
            group_probability: p.probability,
        })
        .collect())
}

/// The resting poses of `mesh`: from a stable-pose export's JSON text when
/// given (see [`resting_poses_from_export`]; `name` is the mesh file's name,
/// and how the entry was found comes back for the caller's policy), else the
/// quasi-static analysis of its convex hull.
pub fn resting_poses(mesh: &Mesh, export: Option<&str>, name: &str) -> Result<(Vec<RestingPose>, Option<ExportMatch>)> {
    match export {
        Some(text) => resting_poses_from_export(text, &crate::stable::mesh_sha256(mesh), name).map(|(r, how)| (r, Some(how))),
        None => Ok((analytic_resting_poses(mesh)?, None)),
    }
}

/// The resting poses of one mesh in a `plausible stable-poses export` JSON:
/// the entry whose `sha256` matches `sha256`, else the one whose file name
/// stem is that of `name` (the mesh's file name; reported as
/// [`ExportMatch::Name`]: BOP datasets all name their models
/// obj_0000NN.ply, so the caller should warn that the geometry differs),
/// else the only entry (reported as [`ExportMatch::OnlyEntry`] so the caller
/// can warn). Of several runs of one mesh the clustered one with the most
/// settled drops is taken. Clusters give one resting pose each, rolling
/// families [`ROLL_STEPS`] (their probability split evenly).
pub fn resting_poses_from_export(text: &str, sha256: &str, name: &str) -> Result<(Vec<RestingPose>, ExportMatch)> {
    let bad = |reason: String| Error::InvalidInput(format!("the stable poses (a `stable-poses export`): {reason}")).about(Input::StablePoses);
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
    if value.get("format").and_then(|f| f.as_str()).is_none() {
        return Err(bad(format!("not a `stable-poses export` file (it has no \"format\": \"{}\")", crate::stable::export::FORMAT)));
    }
    let v: ExportIn = serde_json::from_value(value).map_err(|e| bad(e.to_string()))?;
    if v.format != crate::stable::export::FORMAT {
        return Err(bad(format!("format '{}' is not '{}' (made by another tool or version?)", v.format, crate::stable::export::FORMAT)));
    }
    let meshes = &v.meshes;
    let stem = |m: &MeshIn| std::path::Path::new(&m.mesh).file_stem().map(|s| s.to_string_lossy().into_owned());
    let name = std::path::Path::new(name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    // A run stopped before clustering has no clusters: a finished run of
    // the same mesh is preferred to it whatever their sizes.
    let best = |m: &&MeshIn| (!(m.clusters.is_empty() && m.families.is_empty()), m.settled);
    // The entries of this mesh by hash, else by name, else the only one:
    // the best of them is taken.
    let by_hash: Vec<&MeshIn> = meshes.iter().filter(|m| m.sha256 == sha256).collect();
    let by_name: Vec<&MeshIn> = meshes.iter().filter(|m| stem(m).as_deref() == Some(name.as_str())).collect();
    let (group, how) = if !by_hash.is_empty() {
        (by_hash, ExportMatch::Hash)
    } else if !by_name.is_empty() {
        (by_name, ExportMatch::Name)
    } else {
        (meshes.iter().filter(|_| meshes.len() == 1).collect(), ExportMatch::OnlyEntry)
    };
    let entry = group
        .iter()
        .copied()
        .max_by_key(best)
        .ok_or_else(|| {
            let names: Vec<String> = meshes.iter().filter_map(stem).collect();
            bad(format!(
                "no entry for this mesh (by geometry hash or the name '{name}'); it has {}",
                if names.is_empty() { "no meshes".to_string() } else { names.join(", ") }
            ))
        })?;
    let label = if entry.mesh.is_empty() { format!("sha256 {}", entry.sha256.chars().take(12).collect::<String>()) } else { entry.mesh.clone() };
    if entry.drops < entry.drops_requested && !entry.clusters.is_empty() {
        tracing::warn!(
            "the stable poses of {label} come from {} of its {} drops (a shard not merged, or a run not finished): their probabilities are less precise than asked for",
            entry.drops,
            entry.drops_requested
        );
    }
    if group.len() > 1 {
        tracing::warn!("the stable poses hold {} entries for {label} (runs with other seeds or settings?): using the one with clusters and the most settled drops ({})", group.len(), entry.settled);
    }
    let out = entry_resting_poses(entry).map_err(|reason| bad(format!("the entry of {label}: {reason}")))?;
    Ok((out, how))
}

/// The resting poses of one export entry; `Err` says what is wrong with it.
fn entry_resting_poses(entry: &MeshIn) -> std::result::Result<Vec<RestingPose>, String> {
    let mut out = Vec::new();
    for (i, c) in entry.clusters.iter().enumerate() {
        let r = rows(&c.r_model_to_plane);
        if ((r.transpose() * r) - DMat3::IDENTITY).to_cols_array().iter().any(|x| !(x.abs() <= 1e-6)) || r.determinant() < 0.0 {
            return Err(format!("cluster {i}: R_model_to_plane is not a rotation (scaled, sheared or a reflection)"));
        }
        if !(0.0..=1.0).contains(&c.probability) {
            return Err(format!("cluster {i}: probability {} is not in [0, 1]", crate::error::compact(c.probability, 3)));
        }
        out.push(RestingPose { r_model_to_plane: r, probability: c.probability, group_probability: c.probability });
    }
    // Rolling families (a cylinder on its side): gravity anywhere on the
    // great circle normal to the axis, sampled at ROLL_STEPS angles that
    // share the family's probability. Scattered (ball-like) families have no
    // resting orientation to offer and are left out.
    for (i, f) in entry.families.iter().enumerate() {
        if f.kind != "circle" {
            continue;
        }
        let (Some(axis), p) = (f.axis, f.probability) else {
            return Err(format!("family {i} (a rolling family) needs an axis"));
        };
        let axis = DVec3::from_array(axis).normalize();
        if !axis.is_finite() || !(0.0..=1.0).contains(&p) {
            return Err(format!("family {i} has a zero axis or no probability in [0, 1]"));
        }
        let start = axis.any_orthonormal_vector();
        for k in 0..ROLL_STEPS {
            let g = axis_angle(axis, std::f64::consts::TAU * k as f64 / ROLL_STEPS as f64) * start;
            out.push(RestingPose {
                r_model_to_plane: rows(&crate::stable::cluster::canonical_rotation(g)),
                probability: p / ROLL_STEPS as f64,
                group_probability: p,
            });
        }
    }
    check_entry_probabilities(entry)?;
    if out.is_empty() {
        return Err(no_resting_poses(entry));
    }
    Ok(out)
}

/// Refuses cluster and family probabilities that sum to more than 1 (by
/// more than rounding): each is a share of the same settled drops, so such
/// an entry was edited or made by another tool, and its poses would be
/// weighted wrongly without a word.
fn check_entry_probabilities(entry: &MeshIn) -> std::result::Result<(), String> {
    let sum: f64 = entry.clusters.iter().map(|c| c.probability).chain(entry.families.iter().map(|f| f.probability)).sum();
    if sum > 1.01 {
        return Err(format!(
            "its {} cluster and {} family probabilities sum to {}, more than 1 (each is a share of the same settled drops): edited or made by another tool?",
            entry.clusters.len(),
            entry.families.len(),
            crate::error::compact(sum, 3)
        ));
    }
    Ok(())
}

/// Why an entry gives no resting pose: a run stopped before clustering
/// (drops stored but no clusters; `stable-poses run` resumes it), drops that
/// never settled, or only ball-like families (no resting orientation).
fn no_resting_poses(entry: &MeshIn) -> String {
    let (stored, asked, settled) = (entry.drops, entry.drops_requested, entry.settled);
    if entry.clusters.is_empty() && entry.families.is_empty() && (settled > 0 || stored < asked) {
        format!(
            "no clusters: its drop test is unfinished ({stored} of {asked} drops stored, {settled} settled, not yet clustered); \
             resume it by running `plausible stable-poses run` again with the same arguments"
        )
    } else if !entry.families.is_empty() {
        "its drops settled only in ball-like (scattered) families, which have no resting orientation".to_string()
    } else if stored == 0 {
        "no resting poses: it lists no clusters and no drops (an empty list?)".to_string()
    } else {
        format!("no clusters: none of its {stored} drops settled")
    }
}

/// Largest in-plane grid radius: (2·20 + 1)² = 1681 offsets per (resting
/// pose, yaw) already make hundreds of thousands of hypotheses.
pub const MAX_GRID_RADIUS: usize = 20;

/// Most yaw steps per resting pose (0.1° apart).
pub const MAX_YAW_STEPS: usize = 3600;

/// Most hypotheses generated in one call: a million poses are about 500 MB
/// of pose JSON and minutes of scoring; each flag alone stays within its
/// range, their product must too.
pub const MAX_HYPOTHESES: usize = 1_000_000;

/// Roll angles a rolling family is sampled at (30° apart).
pub const ROLL_STEPS: usize = 12;

/// `mesh` in the plane frame, rotated by `r`, with its lowest vertex on the
/// plane z = 0 and its model origin over `xy`.
pub fn rest_on_plane(mesh: &Mesh, r: DMat3, xy: DVec2) -> Pose {
    let low = mesh.vertices.iter().map(|&v| (r * v).z).fold(f64::INFINITY, f64::min);
    Pose::new(r, xy.extend(-low))
}

fn rows(r: &[f64; 9]) -> DMat3 {
    DMat3::from_cols_array(r).transpose()
}

/// The observed object's points (camera frame): masked pixels with depth.
fn observed_points(obs: &DepthImage, mask: &[bool]) -> Vec<DVec3> {
    (0..obs.depth.len())
        .filter(|&i| mask[i] && obs.depth[i] > 0.0)
        .map(|i| obs.intrinsics.pixel_point(i, obs.depth[i] as f64))
        .collect()
}

/// The centroid (plane frame, in-plane part) of the surface points `pose`
/// shows the camera, `None` when it shows none. Only the drawn rectangle of
/// the z-buffer is visited (`zbuf` and `ids` are `k.pixels()` scratch): an
/// object covers a few percent of a frame, and a full-frame render per
/// alignment was most of `estimate`'s time.
fn visible_centroid(mesh: &RenderMesh, pose: &Pose, k: &crate::camera::Intrinsics, to_plane: &Pose, zbuf: &mut [f32], ids: &mut [u32]) -> Option<DVec2> {
    let gp = GpuPose::from(pose);
    let [x0, y0, x1, y1] = render_ids(mesh, &gp, k, zbuf, ids)?;
    let du = gp.dual();
    let w = k.width as usize;
    let (mut sum, mut count) = (DVec3::ZERO, 0usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let id = ids[y * w + x];
            if id != u32::MAX {
                let (z, _) = resolve(&mesh.triangles[id as usize], &gp, &du, mesh.radius, k, x as f32, y as f32);
                if z > 0.0 {
                    sum += to_plane.transform_point(k.pixel_point(y * w + x, z as f64));
                    count += 1;
                }
            }
        }
    }
    (count > 0).then(|| sum.truncate() / count as f64)
}

/// Refuses a plane the observed object does not stand on: the median
/// height of its points above the plane must lie within one object size of
/// the plane (a plane in the wrong units, or fitted to another surface,
/// would otherwise place every hypothesis far from the object while the
/// output says they are centred on it).
fn check_object_on_plane(points: &[DVec3], to_plane: &Pose, diagonal: f64) -> Result<()> {
    let mut heights: Vec<f64> = points.iter().map(|&x| to_plane.transform_point(x).z).collect();
    heights.sort_by(f64::total_cmp);
    let median = heights[heights.len() / 2];
    if median < -0.5 * diagonal - 0.01 || median > 1.5 * diagonal + 0.01 {
        return Err(Error::InvalidInput(format!(
            "the object's observed points lie {} m {} the support plane, and the object is {} m across: \
             is the plane in other units (\"units\": \"mm\" or \"m\"), or fitted to another surface?",
            crate::error::compact(median.abs(), 3),
            if median < 0.0 { "below" } else { "above" },
            crate::error::compact(diagonal, 3)
        ))
        .about(Input::SupportPlane));
    }
    Ok(())
}

/// The mesh may be smaller than the observed object's robust extent times
/// this (by the diagonal of its bounding box) and no less: the visible part
/// of an object cannot be larger than the object. The lmo-synth masks (5
/// to 100 % visible) give 1.25-3.4 and the demo's duck 1.36; a mesh in
/// centimetres read as millimetres gives 0.13-0.34, one in metres 0.03.
pub const MIN_MESH_TO_OBSERVED: f64 = 0.5;

/// A mesh larger than the observed extent times this is warned about, not
/// refused: occlusion can hide most of an object (5 % visible gives 3.4 on
/// lmo-synth), but a mesh in mm read as m is a thousand times too large.
pub const MAX_MESH_TO_OBSERVED: f64 = 10.0;

/// The observed object's robust size (m): the diagonal of the spans, along
/// the points' principal axes, from the 5th to the 95th percentile (mask
/// edges that catch the background and depth noise fall outside it).
fn observed_extent(points: &[DVec3]) -> f64 {
    let (mean, scatter) = crate::mesh::mass::scatter_about_mean(points);
    let (_, axes) = crate::mesh::mass::principal_axes(&scatter);
    let axes = DMat3::from_quat(axes);
    let span = |axis: DVec3| {
        let mut s: Vec<f64> = points.iter().map(|&x| (x - mean).dot(axis)).collect();
        s.sort_by(f64::total_cmp);
        let at = |q: f64| s[((q * s.len() as f64) as usize).min(s.len() - 1)];
        at(0.95) - at(0.05)
    };
    DVec3::new(span(axes.x_axis), span(axes.y_axis), span(axes.z_axis)).length()
}

/// Compares a mesh `diagonal` (m) with the extent of the observed points:
/// an error when the mesh is smaller than what the mask sees (a mesh in
/// other units: the hypotheses would be centred on the object yet far from
/// it), a warning when it is far larger. Too few points to judge pass.
fn mesh_size_verdict(diagonal: f64, points: &[DVec3]) -> Result<Option<String>> {
    if points.len() < 10 {
        return Ok(None);
    }
    let seen = observed_extent(points);
    let sizes = format!(
        "the mesh is {} m across (its bounding-box diagonal) and the masked depth shows {} m of the object",
        crate::error::compact(diagonal, 3),
        crate::error::compact(seen, 3)
    );
    if diagonal < MIN_MESH_TO_OBSERVED * seen {
        return Err(Error::InvalidInput(format!(
            "{sizes}, but the visible part cannot be larger than the object: is the mesh in other units (a mesh in metres or centimetres read as millimetres?), or does the mask cover other surfaces (a loose mask, or one of several objects)?"
        )));
    }
    Ok((diagonal > MAX_MESH_TO_OBSERVED * seen).then(|| {
        format!("{sizes}, {:.0} times smaller: is the mesh in other units (millimetres read as centimetres or metres?), or is the object almost all hidden?", diagonal / seen)
    }))
}

/// Checks the size of `mesh` against the object the mask sees (see
/// `mesh_size_verdict`): an error for a mesh smaller than its visible
/// part, and a warning to show the user for one far larger. For callers
/// whose mesh units come from the user (`hypotheses`; Python's `estimate`
/// shows both outcomes as warnings); not made by
/// [`on_plane_hypotheses`] itself, since `estimate` knows its models'
/// units and a loose detector mask, or one shared by two instances, must
/// not end a dataset run.
pub fn check_mesh_size(mesh: &Mesh, obs: &DepthImage, mask: &[bool]) -> Result<Option<String>> {
    if mask.len() != obs.depth.len() {
        return Err(Error::InvalidInput(format!("the mask has {} pixels, the depth {}", mask.len(), obs.depth.len())).about(Input::Mask));
    }
    mesh_size_verdict(mesh.diagonal(), &observed_points(obs, mask))
}

/// Refuses a camera-frame plane the observed object does not stand on, as
/// hypotheses do (see `check_object_on_plane`), for scoring given poses
/// with physics: the object's masked points, or without a mask every
/// point of the frame, must lie within one object size of the plane. Too
/// few points to judge pass.
pub fn check_plane_under_observation(plane: &Plane, obs: &DepthImage, mask: Option<&[bool]>, diagonal: f64) -> Result<()> {
    let all;
    let mask = match mask {
        Some(m) => m,
        None => {
            all = vec![true; obs.depth.len()];
            &all
        }
    };
    let points = observed_points(obs, mask);
    if points.len() < 10 {
        return Ok(());
    }
    check_object_on_plane(&points, &camera_to_plane_frame(plane), diagonal)
}

/// Refuses parameters out of range before anything is allocated: the
/// number of hypotheses is known from the resting poses kept, the yaws and
/// the grid, and 100000 resting poses x 3600 yaws had aborted on a 4 GB
/// allocation of (pose, yaw) jobs before their count was checked.
fn check_params(mesh: &Mesh, rests: &[RestingPose], obs: &DepthImage, mask: &[bool], p: &OnPlaneParams) -> Result<()> {
    if p.yaw_steps == 0 || p.yaw_steps > MAX_YAW_STEPS {
        return Err(Error::InvalidInput(format!(
            "{} yaw steps: between 1 and {MAX_YAW_STEPS} (0.1° apart) are taken",
            p.yaw_steps
        )));
    }
    if mask.len() != obs.depth.len() {
        return Err(Error::InvalidInput(format!("the mask has {} pixels, the depth {}", mask.len(), obs.depth.len())).about(Input::Mask));
    }
    if !(p.grid_step.is_finite() && p.grid_step > 0.0) {
        return Err(Error::InvalidInput(format!("the grid step must be a positive number of metres, got {}", crate::error::compact(p.grid_step, 3))));
    }
    if p.grid_radius > MAX_GRID_RADIUS {
        return Err(Error::InvalidInput(format!(
            "a grid radius of {}: at most {MAX_GRID_RADIUS} is taken ({} offsets per hypothesis)",
            p.grid_radius,
            (2 * MAX_GRID_RADIUS + 1).pow(2)
        )));
    }
    // Without a grid (radius 0) the step is never used.
    if p.grid_radius > 0 && p.grid_step > mesh.diagonal() {
        return Err(Error::InvalidInput(format!(
            "a grid step of {} m is larger than the object ({} m across): the offsets would place hypotheses away from the observed object",
            crate::error::compact(p.grid_step, 3),
            crate::error::compact(mesh.diagonal(), 3)
        )));
    }
    let used = rests.iter().filter(|r| r.group_probability >= p.min_probability).count();
    let offsets = (2 * p.grid_radius + 1).pow(2);
    let total = used.saturating_mul(p.yaw_steps * offsets);
    if total > MAX_HYPOTHESES {
        return Err(Error::InvalidInput(format!(
            "{used} resting poses x {} yaws x {offsets} offsets make {total} hypotheses; at most {MAX_HYPOTHESES} are generated at once (fewer yaws, a smaller grid or a higher minimum probability)",
            p.yaw_steps
        )));
    }
    Ok(())
}

/// Generates the hypotheses (see the module docs), in order of resting
/// pose, then yaw, then offset.
pub fn on_plane_hypotheses(
    mesh: &Mesh,
    rests: &[RestingPose],
    plane: &Plane,
    obs: &DepthImage,
    mask: &[bool],
    p: &OnPlaneParams,
) -> Result<Vec<OnPlaneHypothesis>> {
    check_params(mesh, rests, obs, mask, p)?;
    let points = observed_points(obs, mask);
    if points.len() < 10 {
        return Err(Error::InvalidInput(format!(
            "only {} masked pixels have depth; hypotheses need the object's observed points",
            points.len()
        ))
        .about(Input::Mask));
    }
    let to_plane = camera_to_plane_frame(plane);
    let from_plane = to_plane.inverse();
    let centroid = |pts: &[DVec3]| pts.iter().map(|&x| to_plane.transform_point(x)).sum::<DVec3>().truncate() / pts.len() as f64;
    let observed = centroid(&points);
    check_object_on_plane(&points, &to_plane, mesh.diagonal())?;
    let (mass, _) = MassProperties::of_mesh(mesh)?;
    let rmesh = RenderMesh::new(mesh)?;
    let k = obs.intrinsics;
    let jobs: Vec<(usize, usize)> = rests
        .iter()
        .enumerate()
        .filter(|(_, r)| r.group_probability >= p.min_probability)
        .flat_map(|(i, _)| (0..p.yaw_steps).map(move |y| (i, y)))
        .collect();
    let n = k.pixels();
    let aligned: Vec<(usize, f64, Pose)> = jobs
        .par_iter()
        .map_init(
            || (vec![f32::INFINITY; n], vec![u32::MAX; n]),
            |(zbuf, ids), &(i, y)| {
                let yaw = std::f64::consts::TAU * y as f64 / p.yaw_steps as f64;
                let r = axis_angle(DVec3::Z, yaw) * rests[i].r_model_to_plane;
                let com = (r * mass.com).truncate();
                let mut t = rest_on_plane(mesh, r, observed - com).t;
                for _ in 0..p.align_iterations {
                    let cam = from_plane.compose(&Pose::new(r, t));
                    // Out of view: keep the centre-of-mass placement.
                    let Some(seen) = visible_centroid(&rmesh, &cam, &k, &to_plane, zbuf, ids) else { break };
                    let shift = observed - seen;
                    t += shift.extend(0.0);
                    if shift.length() < 1e-4 {
                        break;
                    }
                }
                (i, yaw, Pose::new(r, t))
            },
        )
        .collect();
    let g = p.grid_radius as i64;
    let mut out = Vec::with_capacity(aligned.len() * (2 * p.grid_radius + 1).pow(2));
    for (rest, yaw, base) in aligned {
        for dy in -g..=g {
            for dx in -g..=g {
                let offset = DVec2::new(dx as f64, dy as f64) * p.grid_step;
                let moved = Pose::new(base.r, base.t + offset.extend(0.0));
                out.push(OnPlaneHypothesis { pose: from_plane.compose(&moved), rest, yaw, offset });
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The visible face of a 0.1 m box seen from the front, on a grid of
    /// points, with 4 % of them on the background 0.5 m behind (a mask
    /// edge): the robust extent is the face's, not the background's.
    fn visible_face() -> Vec<DVec3> {
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let p = DVec3::new(i as f64 * 0.0025, j as f64 * 0.0025, 0.8);
                points.push(if (i * 40 + j) % 25 == 0 { p + DVec3::Z * 0.5 } else { p });
            }
        }
        points
    }

    #[test]
    fn the_observed_extent_ignores_a_few_background_points() {
        let e = observed_extent(&visible_face());
        // 90 % of the 0.0975 m span on each in-plane axis: 0.124 m across.
        assert!((e - 0.9 * 0.0975 * 2f64.sqrt()).abs() < 0.01, "{e}");
    }

    /// The box's own diagonal (0.17 m) passes; the same box in cm read as
    /// mm is refused, in mm read as m warned about.
    #[test]
    fn a_mesh_smaller_than_its_visible_part_is_refused_and_a_far_larger_one_warned_about() {
        let face = visible_face();
        assert_eq!(mesh_size_verdict(0.17, &face).unwrap(), None);
        let e = mesh_size_verdict(0.017, &face).unwrap_err().to_string();
        assert!(e.contains("the mesh is 0.017 m across") && e.contains("cannot be larger than the object"), "{e}");
        let w = mesh_size_verdict(170.0, &face).unwrap().unwrap();
        assert!(w.contains("times smaller: is the mesh in other units"), "{w}");
        // Too few points to judge: no verdict (the caller refuses them).
        assert_eq!(mesh_size_verdict(1e-6, &face[..5]).unwrap(), None);
    }

    /// The errors of a call given a plane, a mask and a depth say which of
    /// them is wrong (the CLI names its flag by it, not by the words).
    #[test]
    fn errors_say_whether_the_plane_or_the_mask_is_wrong() {
        // The face is 0.8 m from the plane z = 0, the object 0.17 m across.
        let e = check_object_on_plane(&visible_face(), &Pose::IDENTITY, 0.17).unwrap_err();
        assert_eq!(e.input(), Some(Input::SupportPlane), "{e}");
        assert!(e.to_string().contains("support plane"), "{e}");
        let k = crate::camera::Intrinsics::from_k(&[500.0, 0.0, 16.0, 0.0, 500.0, 12.0, 0.0, 0.0, 1.0], 32, 24).unwrap();
        let obs = DepthImage { intrinsics: k, depth: vec![0.8; 32 * 24] };
        let e = check_mesh_size(&crate::shapes::cuboid(DVec3::splat(0.05)), &obs, &[true; 10]).unwrap_err();
        assert_eq!(e.input(), Some(Input::Mask), "{e}");
    }
}
