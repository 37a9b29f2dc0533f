//! Quasi-static stable poses (Goldberg et al. 1999, "Part pose statistics"):
//! the object rests on a facet of its convex hull when the centre of mass
//! projects strictly inside that facet; otherwise it topples over the facet
//! edge nearest to the projection onto the neighbouring facet. Each hull
//! triangle's share of directions is its solid angle seen from the centre of
//! mass (a uniformly random orientation makes gravity pass through it with
//! that probability); the shares flow along the topple graph to the stable
//! facets.
//!
//! Unlike trimesh's `compute_stable_poses` this terminates on every input: a
//! centre of mass outside the hull is an error, facets are merged by region
//! growing from the largest triangle (no chaining along curved surfaces),
//! degenerate triangles carry their (zero) solid angle, and a topple chain
//! that cycles because of rounding ends at the cycle's lowest facet, with a
//! note.

use std::collections::HashMap;

use glam::DVec3;

use super::hull::Hull;
use crate::error::{Error, Result};

/// One analytic resting pose: the hull facet the object lies on.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AnalyticPose {
    /// Probability of ending on this facet (shares of solid angle).
    pub probability: f64,
    /// Gravity direction in the model frame (the facet's outward normal).
    pub gravity_in_model: [f64; 3],
    /// Height of the model origin above the plane when resting here.
    pub height: f64,
    /// Distance from the projected centre of mass to the facet boundary (m):
    /// how far the object can be pushed before it tips.
    pub margin: f64,
    /// Area of the facet (m²).
    pub area: f64,
}

/// The result of the quasi-static analysis.
#[derive(Clone, Debug, Default)]
pub struct Analytic {
    /// Stable facets, most probable first.
    pub poses: Vec<AnalyticPose>,
    /// Things the user should know (cycles broken, solid angles off 4π).
    pub notes: Vec<String>,
}

/// Parameters of the facet merge.
#[derive(Clone, Copy, Debug)]
pub struct AnalyticParams {
    /// Adjacent hull triangles whose normals are within this angle of the
    /// facet's seed triangle and whose corners lie within `plane_tol_rel` ×
    /// diagonal of its plane form one facet.
    pub merge_deg: f64,
    pub plane_tol_rel: f64,
}

impl Default for AnalyticParams {
    fn default() -> Self {
        AnalyticParams {
            merge_deg: 2.0,
            plane_tol_rel: 2e-3,
        }
    }
}

struct Facet {
    normal: DVec3,
    offset: f64,
    area: f64,
    /// Boundary edges (a, b) counter-clockwise seen from outside, with the
    /// facet on the other side of each edge (None if the hull is broken there).
    boundary: Vec<(DVec3, DVec3, Option<usize>)>,
}

/// Runs the analysis on `hull` with the centre of mass `com`.
pub fn stable_poses(hull: &Hull, com: DVec3, params: AnalyticParams) -> Result<Analytic> {
    let diag = hull.diagonal();
    if !diag.is_finite() || diag <= 0.0 || !com.is_finite() {
        return Err(Error::InvalidInput(
            "quasi-static analysis: degenerate hull or centre of mass".into(),
        ));
    }
    let outside = hull.outside_distance(com);
    if outside > -1e-9 * diag {
        return Err(Error::InvalidInput(format!(
            "quasi-static analysis: the centre of mass {:?} lies {} the convex hull ({:.3e} m from a facet plane); \
             no resting pose exists. The mesh is probably not a closed solid with outward faces",
            com.to_array(),
            if outside > 0.0 { "outside" } else { "on the surface of" },
            outside.abs()
        )));
    }
    let (facets, facet_of) = merge_facets(hull, params, diag);
    let (next, margins) = topple_targets(&facets, com, diag);
    let mut notes = Vec::new();
    let sink_of = sinks(&facets, next, com, &mut notes);
    let (mass, total) = solid_angles(hull, com, &sink_of, &facet_of, facets.len());
    let four_pi = 4.0 * std::f64::consts::PI;
    if (total / four_pi - 1.0).abs() > 1e-3 {
        notes.push(format!(
            "solid angles sum to {:.4}·4π; probabilities renormalised",
            total / four_pi
        ));
    }
    let mut poses: Vec<AnalyticPose> = (0..facets.len())
        .filter(|&f| sink_of[f] == f && mass[f] > 0.0)
        .map(|f| AnalyticPose {
            probability: mass[f] / total,
            gravity_in_model: facets[f].normal.to_array(),
            height: facets[f].offset,
            margin: margins[f].max(0.0),
            area: facets[f].area,
        })
        .collect();
    poses.sort_by(|a, b| b.probability.total_cmp(&a.probability));
    Ok(Analytic { poses, notes })
}

/// Merges the hull's triangles into facets by region growing from the
/// largest triangles (normals within `merge_deg`, vertices within the plane
/// tolerance); returns the facets and each triangle's facet.
fn merge_facets(hull: &Hull, params: AnalyticParams, diag: f64) -> (Vec<Facet>, Vec<usize>) {
    let ntri = hull.triangles.len();
    let planes = hull.planes();
    let areas: Vec<f64> = hull
        .triangles
        .iter()
        .map(|t| {
            let v = |k: usize| hull.vertices[t[k] as usize];
            0.5 * (v(1) - v(0)).cross(v(2) - v(0)).length()
        })
        .collect();
    // Directed edge -> triangle, to find neighbours.
    let mut edge_owner: HashMap<(u32, u32), usize> = HashMap::with_capacity(ntri * 3);
    for (i, t) in hull.triangles.iter().enumerate() {
        for k in 0..3 {
            edge_owner.insert((t[k], t[(k + 1) % 3]), i);
        }
    }
    let neighbour = |i: usize, k: usize| -> Option<usize> {
        let t = hull.triangles[i];
        edge_owner.get(&(t[(k + 1) % 3], t[k])).copied()
    };

    // Region growing from the largest triangles.
    let mut order: Vec<usize> = (0..ntri).collect();
    order.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]).then(a.cmp(&b)));
    let cos_merge = params.merge_deg.to_radians().cos();
    let plane_tol = params.plane_tol_rel * diag;
    let mut facet_of = vec![usize::MAX; ntri];
    let mut members: Vec<Vec<usize>> = Vec::new();
    for &seed in &order {
        if facet_of[seed] != usize::MAX {
            continue;
        }
        let f = members.len();
        let (n0, d0) = planes[seed];
        facet_of[seed] = f;
        let mut group = vec![seed];
        let mut stack = vec![seed];
        while let Some(i) = stack.pop() {
            for k in 0..3 {
                let Some(j) = neighbour(i, k) else { continue };
                if facet_of[j] != usize::MAX {
                    continue;
                }
                let (nj, _) = planes[j];
                let flat = hull.triangles[j]
                    .iter()
                    .all(|&v| (n0.dot(hull.vertices[v as usize]) - d0).abs() <= plane_tol);
                // Degenerate (zero-normal) slivers join any neighbouring facet.
                if (nj == DVec3::ZERO || nj.dot(n0) >= cos_merge) && flat && n0 != DVec3::ZERO {
                    facet_of[j] = f;
                    group.push(j);
                    stack.push(j);
                }
            }
        }
        members.push(group);
    }
    let mut facets: Vec<Facet> = Vec::with_capacity(members.len());
    for group in &members {
        let mut n = DVec3::ZERO;
        let mut area = 0.0;
        for &i in group {
            n += planes[i].0 * areas[i];
            area += areas[i];
        }
        let n = if n.length() > 0.0 {
            n.normalize()
        } else {
            planes[group[0]].0
        };
        let offset = group
            .iter()
            .flat_map(|&i| {
                hull.triangles[i]
                    .iter()
                    .map(|&v| n.dot(hull.vertices[v as usize]))
            })
            .fold(f64::NEG_INFINITY, f64::max);
        let mut boundary = Vec::new();
        for &i in group {
            let t = hull.triangles[i];
            for k in 0..3 {
                let other = neighbour(i, k).map(|j| facet_of[j]);
                if other == Some(facet_of[i]) {
                    continue;
                }
                boundary.push((
                    hull.vertices[t[k] as usize],
                    hull.vertices[t[(k + 1) % 3] as usize],
                    other,
                ));
            }
        }
        facets.push(Facet {
            normal: n,
            offset,
            area,
            boundary,
        });
    }

    (facets, facet_of)
}

/// For each facet, where it topples to (`None`: it is stable; `usize::MAX`:
/// across an open hull edge) and its stability margin.
fn topple_targets(facets: &[Facet], com: DVec3, diag: f64) -> (Vec<Option<usize>>, Vec<f64>) {
    // Where each facet sends its probability: itself when stable.
    let margin_tol = 1e-6 * diag;
    let mut next: Vec<Option<usize>> = Vec::with_capacity(facets.len());
    let mut margins = Vec::with_capacity(facets.len());
    for f in facets {
        let n = f.normal;
        let p = com - n * (n.dot(com) - f.offset);
        let mut inside = true;
        let mut margin = f64::INFINITY;
        // (distance to the edge segment, signed distance to the edge line, target)
        let mut exit: Option<(f64, f64, Option<usize>)> = None;
        for &(a, b, other) in &f.boundary {
            let e = b - a;
            let len = e.length();
            if len <= 0.0 {
                continue;
            }
            // Positive when p is on the facet's side (left of a->b seen from outside).
            let signed = n.dot(e.cross(p - a)) / len;
            let tpar = ((p - a).dot(e) / (len * len)).clamp(0.0, 1.0);
            let seg = (a + e * tpar - p).length();
            margin = margin.min(signed);
            if signed <= margin_tol {
                inside = false;
                let better = match exit {
                    None => true,
                    Some((s, l, _)) => {
                        seg < s - 1e-12 * diag || (seg <= s + 1e-12 * diag && signed < l)
                    }
                };
                if better {
                    exit = Some((seg, signed, other));
                }
            }
        }
        margins.push(margin);
        if inside {
            next.push(None);
        } else {
            next.push(Some(exit.and_then(|e| e.2).unwrap_or(usize::MAX)));
        }
    }

    (next, margins)
}

/// The resting facet each facet ends on, following the topple targets
/// (cycles from rounding end at their lowest facet; noted).
fn sinks(facets: &[Facet], mut next: Vec<Option<usize>>, com: DVec3, notes: &mut Vec<String>) -> Vec<usize> {
    let mut sink_of = vec![usize::MAX; facets.len()];
    for start in 0..facets.len() {
        let mut path = vec![start];
        let mut cur = start;
        let sink = loop {
            if sink_of[cur] != usize::MAX {
                break sink_of[cur];
            }
            match next[cur] {
                None => break cur,
                Some(usize::MAX) => {
                    notes.push(format!(
                        "facet {cur}: open hull edge; treated as a resting facet"
                    ));
                    break cur;
                }
                Some(nx) => {
                    if let Some(pos) = path.iter().position(|&q| q == nx) {
                        // Rounding produced a cycle: end at its lowest facet
                        // (smallest centre-of-mass height = least potential energy).
                        let cycle = &path[pos..];
                        let low = cycle
                            .iter()
                            .copied()
                            .min_by(|&a, &b| {
                                let ha = facets[a].offset - facets[a].normal.dot(com);
                                let hb = facets[b].offset - facets[b].normal.dot(com);
                                ha.total_cmp(&hb).then(a.cmp(&b))
                            })
                            .unwrap_or(nx);
                        notes.push(format!(
                            "topple cycle among facets {cycle:?} (rounding); ended at facet {low}"
                        ));
                        next[low] = None;
                        break low;
                    }
                    path.push(nx);
                    cur = nx;
                }
            }
        };
        for q in path {
            if sink_of[q] == usize::MAX {
                sink_of[q] = sink;
            }
        }
    }

    sink_of
}

/// Solid angle of every hull triangle seen from the centre of mass (van
/// Oosterom & Strackee), summed per sink; also the total.
fn solid_angles(hull: &Hull, com: DVec3, sink_of: &[usize], facet_of: &[usize], n_facets: usize) -> (Vec<f64>, f64) {
    let mut mass = vec![0.0; n_facets];
    let mut total = 0.0;
    for (i, t) in hull.triangles.iter().enumerate() {
        let a = hull.vertices[t[0] as usize] - com;
        let b = hull.vertices[t[1] as usize] - com;
        let c = hull.vertices[t[2] as usize] - com;
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c));
        let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        let omega = (2.0 * num.atan2(den)).abs();
        if omega.is_finite() {
            mass[sink_of[facet_of[i]]] += omega;
            total += omega;
        }
    }
    (mass, total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    fn run(m: &crate::mesh::Mesh, com: DVec3) -> Result<Analytic> {
        let h = Hull::of_points("t", &m.vertices)?;
        stable_poses(&h, com, AnalyticParams::default())
    }

    #[test]
    fn cube_has_six_equal_faces() {
        let a = run(&shapes::cuboid(DVec3::splat(0.05)), DVec3::ZERO).unwrap();
        assert_eq!(a.poses.len(), 6);
        for p in &a.poses {
            assert!(
                (p.probability - 1.0 / 6.0).abs() < 1e-9,
                "{}",
                p.probability
            );
            assert!((p.height - 0.05).abs() < 1e-6);
        }
    }

    #[test]
    fn box_largest_face_most_likely_and_pairs_equal() {
        let a = run(&shapes::cuboid(DVec3::new(0.02, 0.04, 0.08)), DVec3::ZERO).unwrap();
        assert_eq!(a.poses.len(), 6);
        // Largest faces are ±x (0.08 x 0.16).
        assert!(a.poses[0].gravity_in_model[0].abs() > 0.99);
        assert!((a.poses[0].probability - a.poses[1].probability).abs() < 1e-9);
        assert!(a.poses[2].probability > a.poses[4].probability);
    }

    #[test]
    fn off_centre_mass_topples_and_outside_is_an_error() {
        // A tall thin box whose centre of mass sits near the +z end: both ends
        // stay stable (the mass projects onto their centres), but the +z end
        // subtends a larger solid angle from the centre of mass.
        let m = shapes::cuboid(DVec3::new(0.01, 0.01, 0.1));
        let a = run(&m, DVec3::new(0.0, 0.0, 0.09)).unwrap();
        let top = a
            .poses
            .iter()
            .find(|p| p.gravity_in_model[2] > 0.99)
            .unwrap();
        let bottom = a
            .poses
            .iter()
            .find(|p| p.gravity_in_model[2] < -0.99)
            .unwrap();
        assert!(top.probability > bottom.probability);
        let total: f64 = a.poses.iter().map(|p| p.probability).sum();
        assert!((total - 1.0).abs() < 1e-9);
        let err = run(&m, DVec3::new(0.5, 0.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("outside the convex hull"), "{err}");
    }

    #[test]
    fn leaning_prism_topples_off_both_ends() {
        // A sheared box: bottom square at z = 0, top square shifted 6 cm in x at
        // z = 10 cm. The centre of mass (x = 4 cm) projects outside both the
        // bottom (x in [0, 2] cm) and the top (x in [6, 8] cm) faces, so neither
        // end is a resting pose and their probability flows to the sides.
        let mut v = Vec::new();
        for (z, dx) in [(0.0, 0.0), (0.1, 0.06)] {
            for (x, y) in [(0.0, 0.0), (0.02, 0.0), (0.02, 0.02), (0.0, 0.02)] {
                v.push(DVec3::new(x + dx, y, z));
            }
        }
        let h = Hull::of_points("prism", &v).unwrap();
        let com = DVec3::new(0.04, 0.01, 0.05);
        let a = stable_poses(&h, com, AnalyticParams::default()).unwrap();
        let total: f64 = a.poses.iter().map(|p| p.probability).sum();
        assert!((total - 1.0).abs() < 1e-9);
        assert!(
            a.poses.iter().all(|p| p.gravity_in_model[2].abs() < 0.9),
            "{:?}",
            a.poses
        );
        assert!(a.poses.iter().all(|p| p.margin > 0.0));
    }
}
