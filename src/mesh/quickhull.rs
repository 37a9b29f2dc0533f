//! The exact convex hull of a point set in 3D: quickhull in `f64` with
//! Shewchuk's adaptive exact orientation test (the `robust` crate).
//!
//! Why not parry's hull: it runs in `f32` with tolerances, and on point
//! sets with many coplanar or cocircular points (a machined ring, a
//! subdivided mesh) it returns surfaces that are not convex or leave whole
//! regions out (on pybullet's `diff_ring.stl` a point 0.68 of the object's
//! size outside); a jittered retry only moved the problem. Why not qhull:
//! its Rust bindings need bindgen and libclang at build time and report
//! errors through `longjmp`. With exact predicates quickhull is correct by
//! construction: a point is outside a face only when it lies strictly above
//! its plane, so coplanar points never create faces and the visible region
//! of a new point is always a disc whose horizon is one cycle. Coplanar
//! regions come out triangulated (possibly with slivers, which
//! [`super::mass::face_plane`] recognises).
//!
//! Expected O(n log n): each face keeps the points outside it (its
//! conflict list), a face's farthest point is added next, and only the
//! points of the faces it removes are tested again, against the new faces.

use std::collections::HashMap;

use glam::DVec3;
use robust::{orient3d, Coord3D};

/// A face (outward, counter-clockwise seen from outside) under
/// construction: `adj[i]` is the face across the edge `v[i] → v[i+1]`.
struct Face {
    v: [u32; 3],
    adj: [u32; 3],
    /// Points strictly above the face's plane not yet on the hull.
    outside: Vec<u32>,
    alive: bool,
}

fn coord(p: DVec3) -> Coord3D<f64> {
    Coord3D { x: p.x, y: p.y, z: p.z }
}

/// Whether `p` lies strictly above the plane of the counter-clockwise
/// triangle `(a, b, c)` (on the side its right-hand normal points to),
/// decided exactly.
fn above(a: DVec3, b: DVec3, c: DVec3, p: DVec3) -> bool {
    // orient3d is positive when p lies below (a, b, c) counter-clockwise.
    orient3d(coord(a), coord(b), coord(c), coord(p)) < 0.0
}

struct Builder<'a> {
    pts: &'a [DVec3],
    faces: Vec<Face>,
}

impl Builder<'_> {
    fn corners(&self, f: u32) -> [DVec3; 3] {
        self.faces[f as usize].v.map(|i| self.pts[i as usize])
    }

    fn sees(&self, f: u32, p: u32) -> bool {
        let [a, b, c] = self.corners(f);
        above(a, b, c, self.pts[p as usize])
    }

    fn push_face(&mut self, v: [u32; 3]) -> u32 {
        self.faces.push(Face { v, adj: [u32::MAX; 3], outside: Vec::new(), alive: true });
        (self.faces.len() - 1) as u32
    }

    /// Gives each of `candidates` to the first of `faces` it lies above;
    /// points above none are inside the hull and dropped.
    fn assign(&mut self, candidates: &[u32], faces: &[u32]) {
        for &p in candidates {
            if let Some(&f) = faces.iter().find(|&&f| self.sees(f, p)) {
                self.faces[f as usize].outside.push(p);
            }
        }
    }

    /// Adds the farthest outside point of face `start`: removes the faces
    /// it sees (a disc around `start`), closes the hole with a fan of new
    /// faces from its horizon to the point, and hands the removed faces'
    /// outside points to the new faces. Returns the new faces.
    fn add_point(&mut self, start: u32) -> Vec<u32> {
        // The farthest point above the face (by its unnormalised normal:
        // the choice only orders the work, correctness does not depend on it).
        let [a, b, c] = self.corners(start);
        let n = (b - a).cross(c - a);
        let eye = *self.faces[start as usize]
            .outside
            .iter()
            .max_by(|&&p, &&q| n.dot(self.pts[p as usize] - a).total_cmp(&n.dot(self.pts[q as usize] - a)))
            .expect("a face with outside points");
        // The visible faces, by depth-first search from `start`; each edge
        // from a visible face to one that is not is a horizon edge.
        let mut visible = vec![start];
        let mut horizon: Vec<(u32, u32, u32)> = Vec::new(); // (a, b, face beyond)
        let mut seen: HashMap<u32, bool> = HashMap::from([(start, true)]);
        let mut stack = vec![start];
        while let Some(f) = stack.pop() {
            for i in 0..3 {
                let g = self.faces[f as usize].adj[i];
                let vis = *seen.entry(g).or_insert_with(|| {
                    let v = self.sees(g, eye);
                    if v {
                        stack.push(g);
                        visible.push(g);
                    }
                    v
                });
                if !vis {
                    let v = self.faces[f as usize].v;
                    horizon.push((v[i], v[(i + 1) % 3], g));
                }
            }
        }
        // The fan: face (a, b, eye) per horizon edge a → b, linked to the
        // face beyond the edge and to its two fan neighbours (the horizon
        // is one cycle, so each vertex starts exactly one edge).
        let mut fan_from: HashMap<u32, u32> = HashMap::with_capacity(horizon.len());
        let mut fan = Vec::with_capacity(horizon.len());
        for &(a, b, beyond) in &horizon {
            let f = self.push_face([a, b, eye]);
            self.faces[f as usize].adj[0] = beyond;
            let back = &mut self.faces[beyond as usize];
            let slot = (0..3).find(|&j| back.v[j] == b && back.v[(j + 1) % 3] == a).expect("horizon edge shared");
            back.adj[slot] = f;
            fan_from.insert(a, f);
            fan.push(f);
        }
        for &f in &fan {
            let [_, b, _] = self.faces[f as usize].v;
            let next = fan_from[&b];
            self.faces[f as usize].adj[1] = next; // edge b → eye
            self.faces[next as usize].adj[2] = f; // edge eye → b of the next face
        }
        let mut orphans = Vec::new();
        for &f in &visible {
            let face = &mut self.faces[f as usize];
            face.alive = false;
            orphans.extend(face.outside.drain(..).filter(|&p| p != eye));
        }
        self.assign(&orphans, &fan);
        fan
    }
}

/// Indices of four points spanning a tetrahedron of nonzero volume (decided
/// exactly), or `None` when all points are coplanar.
fn initial_simplex(pts: &[DVec3]) -> Option<[u32; 4]> {
    let extreme = |key: &dyn Fn(DVec3) -> f64| -> (usize, usize) {
        let (mut lo, mut hi) = (0, 0);
        for (i, p) in pts.iter().enumerate() {
            if key(*p) < key(pts[lo]) {
                lo = i;
            }
            if key(*p) > key(pts[hi]) {
                hi = i;
            }
        }
        (lo, hi)
    };
    let axes = [extreme(&|p| p.x), extreme(&|p| p.y), extreme(&|p| p.z)];
    let (a, b) = axes.into_iter().max_by(|x, y| pts[x.1].distance(pts[x.0]).total_cmp(&pts[y.1].distance(pts[y.0])))?;
    let (pa, pb) = (pts[a], pts[b]);
    let c = (0..pts.len()).max_by(|&i, &j| (pts[i] - pa).cross(pb - pa).length_squared().total_cmp(&(pts[j] - pa).cross(pb - pa).length_squared()))?;
    let n = (pb - pa).cross(pts[c] - pa);
    let d = (0..pts.len()).max_by(|&i, &j| n.dot(pts[i] - pa).abs().total_cmp(&n.dot(pts[j] - pa).abs()))?;
    // Nearly collinear a, b, c with an exact nonzero volume still make a
    // valid start; only an exact zero means the set is flat.
    (orient3d(coord(pa), coord(pb), coord(pts[c]), coord(pts[d])) != 0.0).then_some([a as u32, b as u32, c as u32, d as u32])
}

/// The convex hull of `pts` (finite, at least four, not all coplanar:
/// `None` otherwise): its vertices (a subset of `pts`, in input order) and
/// outward counter-clockwise triangles indexing them.
pub fn exact_hull(pts: &[DVec3]) -> Option<(Vec<DVec3>, Vec<[u32; 3]>)> {
    if pts.len() < 4 || pts.iter().any(|p| !p.is_finite()) {
        return None;
    }
    let [a, mut b, mut c, d] = initial_simplex(pts)?;
    let mut h = Builder { pts, faces: Vec::new() };
    // d must lie below (a, b, c): otherwise swap b and c.
    if above(pts[a as usize], pts[b as usize], pts[c as usize], pts[d as usize]) {
        std::mem::swap(&mut b, &mut c);
    }
    for v in [[a, b, c], [a, d, b], [b, d, c], [c, d, a]] {
        h.push_face(v);
    }
    link_initial(&mut h.faces);
    let rest: Vec<u32> = (0..pts.len() as u32).filter(|i| ![a, b, c, d].contains(i)).collect();
    h.assign(&rest, &[0, 1, 2, 3]);
    let mut pending: Vec<u32> = (0..4).collect();
    while let Some(f) = pending.pop() {
        let face = &h.faces[f as usize];
        if face.alive && !face.outside.is_empty() {
            pending.extend(h.add_point(f));
        }
    }
    Some(compact(pts, &h.faces))
}

/// Links the four faces of the starting tetrahedron across their edges.
fn link_initial(faces: &mut [Face]) {
    for f in 0..faces.len() {
        for i in 0..3 {
            let (a, b) = (faces[f].v[i], faces[f].v[(i + 1) % 3]);
            let g = (0..faces.len()).find(|&g| (0..3).any(|j| faces[g].v[j] == b && faces[g].v[(j + 1) % 3] == a));
            faces[f].adj[i] = g.expect("closed tetrahedron") as u32;
        }
    }
}

/// The live faces, re-indexed to the points they use (in input order).
fn compact(pts: &[DVec3], faces: &[Face]) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let live: Vec<[u32; 3]> = faces.iter().filter(|f| f.alive).map(|f| f.v).collect();
    let mut used: Vec<u32> = live.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    let index: HashMap<u32, u32> = used.iter().enumerate().map(|(k, &i)| (i, k as u32)).collect();
    let vertices = used.iter().map(|&i| pts[i as usize]).collect();
    (vertices, live.iter().map(|t| t.map(|i| index[&i])).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point on or inside every face's plane, decided exactly, and
    /// every edge shared by exactly two faces in opposite directions.
    fn assert_hull(pts: &[DVec3], hv: &[DVec3], ht: &[[u32; 3]]) {
        for t in ht {
            let [a, b, c] = t.map(|i| hv[i as usize]);
            for p in pts {
                assert!(!above(a, b, c, *p), "point {p} above face {t:?}");
            }
        }
        let mut edges: HashMap<(u32, u32), usize> = HashMap::new();
        for t in ht {
            for i in 0..3 {
                *edges.entry((t[i], t[(i + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}->{b} has no twin");
        }
        assert_eq!(hv.len() + ht.len(), edges.len() / 2 + 2, "Euler characteristic of a sphere");
    }

    fn volume(hv: &[DVec3], ht: &[[u32; 3]]) -> f64 {
        ht.iter().map(|t| hv[t[0] as usize].dot(hv[t[1] as usize].cross(hv[t[2] as usize]))).sum::<f64>() / 6.0
    }

    #[test]
    fn orientation_sign() {
        assert!(above(DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z));
        assert!(!above(DVec3::ZERO, DVec3::X, DVec3::Y, -DVec3::Z));
        assert!(!above(DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(3.0, 4.0, 0.0)));
    }

    /// A grid of points on and inside a box: every face coplanar with
    /// others, most points on the surface. The hull is the box, exactly.
    #[test]
    fn box_grid_with_coplanar_points() {
        let mut pts = Vec::new();
        for i in 0..7 {
            for j in 0..5 {
                for k in 0..4 {
                    pts.push(DVec3::new(i as f64 * 0.1, j as f64 * 0.07, k as f64 * 0.3));
                }
            }
        }
        let (hv, ht) = exact_hull(&pts).unwrap();
        assert_hull(&pts, &hv, &ht);
        assert!((volume(&hv, &ht) - 0.6 * 0.28 * 0.9).abs() < 1e-12);
    }

    /// A ring with many points on circles at a few heights (cocircular and
    /// coplanar, as on a machined part): a closed convex hull holding all.
    #[test]
    fn cocircular_ring() {
        let mut pts = Vec::new();
        for (z, r) in [(0.0, 1.0), (0.0, 0.7), (0.2, 1.0), (0.2, 0.7), (0.1, 1.02)] {
            for k in 0..360 {
                let a = k as f64 * std::f64::consts::TAU / 360.0;
                pts.push(DVec3::new(r * a.cos(), r * a.sin(), z));
            }
        }
        let (hv, ht) = exact_hull(&pts).unwrap();
        assert_hull(&pts, &hv, &ht);
        // Two frusta of regular 360-gons, radius 1 -> 1.02 -> 1 over 0.1 each.
        let area = |r: f64| 180.0 * r * r * (std::f64::consts::TAU / 360.0).sin();
        let frustum = 0.1 / 3.0 * (area(1.0) + area(1.02) + (area(1.0) * area(1.02)).sqrt());
        assert!((volume(&hv, &ht) - 2.0 * frustum).abs() < 1e-12, "{} vs {}", volume(&hv, &ht), 2.0 * frustum);
    }

    #[test]
    fn flat_and_short_inputs_have_no_hull() {
        let flat: Vec<DVec3> = (0..20).map(|i| DVec3::new(i as f64, (i * i) as f64, 0.0)).collect();
        assert!(exact_hull(&flat).is_none());
        assert!(exact_hull(&flat[..3]).is_none());
        let mut bad = flat.clone();
        bad.push(DVec3::new(0.0, 0.0, f64::NAN));
        assert!(exact_hull(&bad).is_none());
    }

    /// Random points in a ball, seeded: the hull holds them all.
    #[test]
    fn random_ball() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let pts: Vec<DVec3> = (0..5000)
            .map(|_| DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)))
            .filter(|p| p.length() <= 1.0)
            .collect();
        let (hv, ht) = exact_hull(&pts).unwrap();
        assert_hull(&pts, &hv, &ht);
        assert!(volume(&hv, &ht) > 0.9 * 4.0 / 3.0 * std::f64::consts::PI);
    }
}
