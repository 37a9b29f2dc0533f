//! Triangulating one polygon face of a mesh file (PLY faces with more than
//! three corners, OBJ faces).
//!
//! Fanning a polygon from its first corner is only right when the polygon
//! is convex: the fan of an L-shaped face covers its notch. So concave
//! polygons are ear-clipped in the plane of their Newell normal. Convex
//! polygons keep the fan `(v0, vk, vk+1)`, exactly the triangles the loaders
//! made before: any triangulation of a convex polygon covers the same
//! surface, and keeping this one keeps existing meshes (and every result
//! computed from them) unchanged, triangle for triangle.
//!
//! Ear clipping costs O(n²) and more per polygon, so it is only tried up to
//! [`MAX_EAR_CLIP`] corners; bigger polygons, and polygons it cannot clip
//! (self-intersecting, or without area), are fanned as before. The work per
//! polygon is therefore linear in its corners beyond that bound.

use glam::{DVec2, DVec3};

/// Most corners a polygon may have to be ear-clipped; larger ones are fanned.
pub(super) const MAX_EAR_CLIP: usize = 256;

/// Ear-clipping work one file may spend, in corners² of its concave
/// polygons (about 30 ns each, so 2 s in all): a file of the same concave
/// 256-gon repeated costs 2 ms per 258 bytes, 8 s per megabyte. Past it
/// the remaining concave polygons are fanned.
pub(super) struct EarClipBudget(u64);

impl Default for EarClipBudget {
    fn default() -> Self {
        EarClipBudget(1 << 26)
    }
}

/// Appends the triangles of the polygon `face` (indices into `vertices`,
/// in winding order) to `out`: `face.len() - 2` of them for a polygon of
/// three corners or more, none for fewer. Indices that are not in
/// `vertices` make the fan (the caller reports them).
pub(super) fn triangulate(vertices: &[DVec3], face: &[u64], out: &mut Vec<[u64; 3]>, budget: &mut EarClipBudget) {
    if face.len() < 3 {
        return;
    }
    if face.len() > 3 && face.len() <= MAX_EAR_CLIP {
        if let Some(tris) = planar(vertices, face).and_then(|p| clip_concave(&p, budget)) {
            out.extend(tris.into_iter().map(|t| t.map(|k| face[k])));
            return;
        }
    }
    fan(face, out);
}

/// The fan from the first corner.
fn fan(face: &[u64], out: &mut Vec<[u64; 3]>) {
    out.extend((1..face.len() - 1).map(|k| [face[0], face[k], face[k + 1]]));
}

/// The corners in 2-D coordinates of the plane of the polygon's Newell
/// normal, relative to the first corner (so far-off meshes keep their
/// precision), oriented so the polygon winds counter-clockwise. `None` when
/// an index is out of range, a corner is not finite, or the polygon has no
/// normal (no area).
fn planar(vertices: &[DVec3], face: &[u64]) -> Option<Vec<DVec2>> {
    let pts: Vec<DVec3> = face.iter().map(|&i| vertices.get(usize::try_from(i).ok()?).copied()).collect::<Option<_>>()?;
    let o = pts[0];
    let newell = (0..pts.len()).fold(DVec3::ZERO, |n, k| n + (pts[k] - o).cross(pts[(k + 1) % pts.len()] - o));
    let n = newell.try_normalize()?;
    let u = n.any_orthonormal_vector();
    let v = n.cross(u);
    let p: Vec<DVec2> = pts.iter().map(|&q| DVec2::new((q - o).dot(u), (q - o).dot(v))).collect();
    p.iter().all(|q| q.is_finite()).then_some(p)
}

/// Ear clipping for a counter-clockwise polygon that is not convex: `None`
/// for a convex one (the caller fans it), where clipping gets stuck, and
/// once the file's `budget` is spent.
fn clip_concave(p: &[DVec2], budget: &mut EarClipBudget) -> Option<Vec<[usize; 3]>> {
    let n = p.len();
    let extent = p.iter().fold(0.0f64, |m, q| m.max(q.x.abs()).max(q.y.abs()));
    let eps = 1e-12 * extent * extent;
    let turn = |a: usize, b: usize, c: usize| (p[b] - p[a]).perp_dot(p[c] - p[b]);
    if (0..n).all(|k| turn((k + n - 1) % n, k, (k + 1) % n) >= -eps) {
        return None;
    }
    // Charged whether or not clipping succeeds (a stuck one costs as much).
    let work = (n * n) as u64;
    if budget.0 < work {
        return None;
    }
    budget.0 -= work;
    let mut ring = Ring::new(n);
    let mut out = Vec::with_capacity(n - 2);
    let (mut i, mut misses) = (0, 0);
    while ring.len > 3 {
        let (a, c) = (ring.prev[i], ring.next[i]);
        if turn(a, i, c) > eps && ring.is_empty_triangle(p, a, i, c, eps) {
            out.push([a, i, c]);
            ring.remove(i);
            (i, misses) = (c, 0);
        } else if misses > ring.len {
            // No ear in a whole round: drop a flat corner (a zero-area
            // triangle keeps the edges shared with neighbours), else give up.
            let flat = ring.find(i, |k| turn(ring.prev[k], k, ring.next[k]).abs() <= eps)?;
            out.push([ring.prev[flat], flat, ring.next[flat]]);
            let c = ring.next[flat];
            ring.remove(flat);
            (i, misses) = (c, 0);
        } else {
            (i, misses) = (c, misses + 1);
        }
    }
    out.push([ring.prev[i], i, ring.next[i]]);
    Some(out)
}

/// The corners not yet clipped, as a doubly linked ring.
struct Ring {
    next: Vec<usize>,
    prev: Vec<usize>,
    len: usize,
}

impl Ring {
    fn new(n: usize) -> Ring {
        Ring { next: (0..n).map(|k| (k + 1) % n).collect(), prev: (0..n).map(|k| (k + n - 1) % n).collect(), len: n }
    }

    fn remove(&mut self, k: usize) {
        let (a, c) = (self.prev[k], self.next[k]);
        self.next[a] = c;
        self.prev[c] = a;
        self.len -= 1;
    }

    /// The first corner from `start` round the ring that satisfies `f`.
    fn find(&self, start: usize, f: impl Fn(usize) -> bool) -> Option<usize> {
        let mut k = start;
        for _ in 0..self.len {
            if f(k) {
                return Some(k);
            }
            k = self.next[k];
        }
        None
    }

    /// Whether no other remaining corner that is not strictly convex lies in
    /// (or on) the triangle `a b c`: if one did, clipping the triangle would
    /// cut through the polygon. Convex corners cannot be inside an ear
    /// without a reflex one being inside too, so only those are tested.
    /// Corners at the same place as `a`, `b` or `c` (a polygon that visits a
    /// vertex twice) do not count.
    fn is_empty_triangle(&self, p: &[DVec2], a: usize, b: usize, c: usize, eps: f64) -> bool {
        let turn = |x: DVec2, y: DVec2, z: DVec2| (y - x).perp_dot(z - y);
        let mut k = self.next[c];
        while k != a {
            let q = p[k];
            let reflex = turn(p[self.prev[k]], q, p[self.next[k]]) <= eps;
            let corner = q == p[a] || q == p[b] || q == p[c];
            if reflex && !corner && turn(p[a], p[b], q) >= -eps && turn(p[b], p[c], q) >= -eps && turn(p[c], p[a], q) >= -eps {
                return false;
            }
            k = self.next[k];
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(v: &[DVec3], tris: &[[u64; 3]]) -> f64 {
        tris.iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| v[i as usize]);
                0.5 * (b - a).cross(c - a).z
            })
            .sum()
    }

    fn run(v: &[DVec3], face: &[u64]) -> Vec<[u64; 3]> {
        let mut out = Vec::new();
        triangulate(v, face, &mut out, &mut EarClipBudget::default());
        out
    }

    #[test]
    fn convex_polygons_keep_the_fan() {
        let v: Vec<DVec3> = (0..6).map(|k| DVec3::new((k as f64).cos(), (k as f64).sin(), 0.0)).collect();
        let face = [0, 1, 2, 3, 4, 5];
        assert_eq!(run(&v, &face), vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]);
    }

    #[test]
    fn concave_polygon_is_ear_clipped_within_its_outline() {
        // An L, starting next to its reflex corner (1, 1), where the fan
        // would cover the notch.
        let l = [[1.0, 2.0], [0.0, 2.0], [0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0]];
        let flat: Vec<DVec3> = l.iter().map(|&[x, y]| DVec3::new(x, y, 0.0)).collect();
        let face = [0, 1, 2, 3, 4, 5];
        let tris = run(&flat, &face);
        assert_eq!(tris.len(), 4);
        assert!((area(&flat, &tris) - 3.0).abs() < 1e-12, "{tris:?}");
        // Every triangle winds the same way as the polygon (no flipped one).
        for t in &tris {
            assert!(area(&flat, &[*t]) > 0.0, "{tris:?}");
        }
        // Tilted out of every coordinate plane and far off: the same triangles.
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let tilted: Vec<DVec3> = flat.iter().map(|&p| rot * p + DVec3::splat(1e4)).collect();
        assert_eq!(run(&tilted, &face), tris);
        // The fan would not fit: its triangles overlap outside the L.
        let mut fanned = Vec::new();
        fan(&face, &mut fanned);
        assert!(fanned.iter().any(|t| area(&flat, &[*t]) < 0.0));
        // A file whose clipping budget is spent fans the rest, at once.
        let (mut spent, mut out) = (EarClipBudget(35), Vec::new());
        triangulate(&flat, &face, &mut out, &mut spent);
        assert_eq!(out, fanned);
        assert_eq!(spent.0, 35);
    }

    #[test]
    fn stars_of_every_start_and_size_are_tiled_exactly() {
        for n in [8usize, 31, 64, MAX_EAR_CLIP] {
            for start in [0, 1, 5] {
                let v: Vec<DVec3> = (0..n)
                    .map(|k| {
                        let (r, a) = (
                            if k % 2 == 0 { 1.0 } else { 0.4 + 0.1 * (k % 3) as f64 },
                            (k + start) as f64 / n as f64 * std::f64::consts::TAU,
                        );
                        DVec3::new(r * a.cos(), r * a.sin(), 0.0)
                    })
                    .collect();
                let face: Vec<u64> = (0..n as u64).collect();
                let shoelace: f64 = (0..n).map(|k| 0.5 * v[k].truncate().perp_dot(v[(k + 1) % n].truncate())).sum();
                let tris = run(&v, &face);
                assert_eq!(tris.len(), n - 2);
                assert!(tris.iter().all(|t| area(&v, &[*t]) > 0.0), "n {n} start {start}");
                assert!((area(&v, &tris) - shoelace).abs() < 1e-9, "n {n} start {start}");
            }
        }
    }

    #[test]
    fn huge_and_degenerate_polygons_are_fanned() {
        let n = 1_000_000u64;
        let v: Vec<DVec3> = (0..n).map(|k| DVec3::new(k as f64, (k % 2) as f64, 0.0)).collect();
        let face: Vec<u64> = (0..n).collect();
        let t = run(&v, &face);
        assert_eq!(t.len(), n as usize - 2);
        assert_eq!(t[7], [0, 8, 9]);
        // Collinear corners (no normal), an index out of range, a bow tie.
        let line: Vec<DVec3> = (0..5).map(|k| DVec3::new(k as f64, 0.0, 0.0)).collect();
        assert_eq!(run(&line, &[0, 1, 2, 3, 4]).len(), 3);
        assert_eq!(run(&line, &[0, 1, 9, 3]), vec![[0, 1, 9], [0, 9, 3]]);
        let bow = [DVec3::ZERO, DVec3::new(1.0, 1.0, 0.0), DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 1.0, 0.0)];
        assert_eq!(run(&bow, &[0, 1, 2, 3]).len(), 2);
        assert!(run(&bow, &[0, 1]).is_empty());
    }
}
