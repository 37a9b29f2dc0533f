//! Convex hulls for the drop tests and the quasi-static analysis.
//!
//! Physics engines jitter on hulls with hundreds of tiny facets (a scanned
//! object's hull never comes to rest in rapier or pybullet), so the collider
//! hull is simplified: starting from a tetrahedron of extreme points, the hull
//! vertex farthest outside the current hull is added until every vertex lies
//! within a tolerance of the simplified hull or a point budget is reached.
//! This keeps the large facets that carry most of the resting probability and
//! drops the slivers between them.

use glam::DVec3;

use crate::error::{Error, Result};
use crate::mesh::mass::{convex_hull, hull_planes, outside_planes};

/// Most mesh vertices [`Hull::of_mesh_vertices`] takes the hull of.
pub const MAX_HULL_POINTS: usize = 250_000;

/// A closed convex polyhedron with outward, counter-clockwise triangles.
#[derive(Clone, Debug)]
pub struct Hull {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Hull {
    /// The convex hull of `points`; `name` is used in error messages.
    pub fn of_points(name: &str, points: &[DVec3]) -> Result<Hull> {
        let (vertices, triangles) = convex_hull(points)
            .map_err(|r| Error::InvalidInput(format!("{name}: convex hull: {r}")))?;
        Ok(Hull {
            vertices,
            triangles,
        })
    }

    /// The convex hull of a mesh's vertices for the stable-pose analysis.
    /// Beyond [`MAX_HULL_POINTS`] vertices (a multi-million-vertex scan,
    /// whose full hull costs gigabytes) the hull is taken of an evenly
    /// strided subset plus the extreme vertices along 128 directions, and a
    /// note says so: the points left out lie within the scan's own
    /// sampling distance of that hull, far below what a resting pose feels.
    pub fn of_mesh_vertices(name: &str, vertices: &[DVec3]) -> Result<(Hull, Option<String>)> {
        if vertices.len() <= MAX_HULL_POINTS {
            return Ok((Hull::of_points(name, vertices)?, None));
        }
        let stride = vertices.len().div_ceil(MAX_HULL_POINTS);
        let mut pts: Vec<DVec3> = vertices.iter().step_by(stride).copied().collect();
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for i in 0..128 {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / 128.0;
            let r = (1.0 - z * z).sqrt();
            let d = DVec3::new(r * (golden * i as f64).cos(), r * (golden * i as f64).sin(), z);
            let best = vertices.iter().copied().fold(vertices[0], |b, v| if v.dot(d) > b.dot(d) { v } else { b });
            pts.push(best);
        }
        let hull = Hull::of_points(name, &pts)?;
        let note = format!(
            "{name}: the convex hull for the stable poses is taken of {} of its {} vertices (every {stride}th and the extremes along 128 directions)",
            pts.len(),
            vertices.len()
        );
        Ok((hull, Some(note)))
    }

    /// Bounding-box diagonal of the hull.
    pub fn diagonal(&self) -> f64 {
        let (lo, hi) = self.vertices.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(l, h), v| (l.min(*v), h.max(*v)),
        );
        (hi - lo).length()
    }

    /// Outward unit normal and plane offset (`n·x = d`) of every triangle;
    /// a zero normal for a sliver, whose normal is rounding noise (see
    /// [`crate::mesh::mass::SLIVER_REL`]), so containment tests skip it.
    pub fn planes(&self) -> Vec<(DVec3, f64)> {
        hull_planes(&self.vertices, &self.triangles)
    }

    /// Largest distance of `p` outside any facet plane (negative inside).
    pub fn outside_distance(&self, p: DVec3) -> f64 {
        outside_planes(&self.planes(), p)
    }

    /// Simplified hull with at most `max_points` vertices (at least 4), by
    /// greedy farthest-point insertion; stops early once every vertex of
    /// `self` lies within `tolerance` metres of the simplified hull.
    /// Deterministic: ties go to the lowest vertex index.
    pub fn simplified(&self, max_points: usize, tolerance: f64) -> Result<Hull> {
        let pts = &self.vertices;
        if pts.len() <= max_points.max(4) {
            return Ok(self.clone());
        }
        let farthest = |from: &dyn Fn(DVec3) -> f64| -> usize {
            let mut best = (0usize, f64::NEG_INFINITY);
            for (i, p) in pts.iter().enumerate() {
                let v = from(*p);
                if v > best.1 {
                    best = (i, v);
                }
            }
            best.0
        };
        let centroid = pts.iter().copied().sum::<DVec3>() / pts.len() as f64;
        let i0 = farthest(&|p| (p - centroid).length_squared());
        let p0 = pts[i0];
        let i1 = farthest(&|p| (p - p0).length_squared());
        let p1 = pts[i1];
        let axis = (p1 - p0).normalize_or_zero();
        let i2 = farthest(&|p| {
            let r = p - p0;
            (r - axis * r.dot(axis)).length_squared()
        });
        let n = (p1 - p0).cross(pts[i2] - p0).normalize_or_zero();
        let i3 = farthest(&|p| (p - p0).dot(n).abs());
        let mut chosen = vec![i0, i1, i2, i3];
        chosen.sort_unstable();
        chosen.dedup();
        let name = "simplified hull";
        loop {
            let sel: Vec<DVec3> = chosen.iter().map(|&i| pts[i]).collect();
            let hull = Hull::of_points(name, &sel)?;
            if chosen.len() >= max_points.max(4) {
                return Ok(hull);
            }
            let planes = hull.planes();
            let mut best = (usize::MAX, tolerance);
            for (i, p) in pts.iter().enumerate() {
                let out = outside_planes(&planes, *p);
                if out > best.1 {
                    best = (i, out);
                }
            }
            if best.0 == usize::MAX || chosen.contains(&best.0) {
                return Ok(hull);
            }
            chosen.push(best.0);
        }
    }

    /// Volume of the hull (positive for outward winding).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let (a, b, c) = (
                    self.vertices[t[0] as usize],
                    self.vertices[t[1] as usize],
                    self.vertices[t[2] as usize],
                );
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn simplification_keeps_box_corners_and_bounds_sphere_error() {
        let b = shapes::cuboid(DVec3::new(0.1, 0.2, 0.3));
        let h = Hull::of_points("box", &b.vertices).unwrap();
        assert!((h.volume() - 0.048).abs() < 1e-6);
        let s = h.simplified(64, 1e-6).unwrap();
        assert_eq!(s.vertices.len(), 8);
        let sphere = shapes::icosphere(0.1, 4);
        let full = Hull::of_points("sphere", &sphere.vertices).unwrap();
        let simple = full.simplified(64, 1e-9).unwrap();
        assert_eq!(simple.vertices.len(), 64);
        // Every original vertex within a few percent of the radius of the simplified hull.
        let worst = full
            .vertices
            .iter()
            .map(|p| simple.outside_distance(*p))
            .fold(0.0, f64::max);
        assert!(worst < 0.1 * 0.12, "{worst}");
        assert!(simple.volume() > 0.8 * full.volume());
    }
}
