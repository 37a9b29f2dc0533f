//! The support polygon: the convex hull of the supported points projected
//! along gravity, and the signed distance from the projected centre of mass
//! to its boundary (the stability margin).

use glam::{DVec2, DVec3};

/// Two unit vectors spanning the plane orthogonal to `gravity` (the support
/// plane's directions); a right-handed `(u, v, -ĝ)` frame.
pub fn support_basis(gravity: DVec3) -> (DVec3, DVec3) {
    let up = -gravity.normalize();
    let helper = if up.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = (helper - up * helper.dot(up)).normalize();
    let v = up.cross(u);
    (u, v)
}

/// Convex hull (Andrew's monotone chain), counter-clockwise, without
/// collinear points. Fewer than three distinct points give a segment or a
/// point.
pub fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut pts: Vec<DVec2> = points.to_vec();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(pts.len() + 1);
    for pass in 0..2 {
        let start = hull.len();
        let seq: Box<dyn Iterator<Item = &DVec2>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &q in seq {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).length()
}

/// Signed distance from `p` to the boundary of the convex polygon `hull`
/// (counter-clockwise, from [`convex_hull`]): positive inside, negative
/// outside. A degenerate hull (segment or point) has no inside, so the
/// result is minus the distance to it. `None` for an empty hull.
pub fn signed_margin(hull: &[DVec2], p: DVec2) -> Option<f64> {
    match hull.len() {
        0 => None,
        1 => Some(-(p - hull[0]).length()),
        2 => Some(-segment_distance(p, hull[0], hull[1])),
        n => {
            let mut inside = true;
            let mut dist = f64::INFINITY;
            for i in 0..n {
                let (a, b) = (hull[i], hull[(i + 1) % n]);
                if (b - a).perp_dot(p - a) <= 0.0 {
                    inside = false;
                }
                dist = dist.min(segment_distance(p, a, b));
            }
            Some(if inside { dist } else { -dist })
        }
    }
}

/// The support polygon and margin for supported points and a centre of
/// mass (world coordinates), projected along `gravity`.
pub fn stability(
    supported: &[DVec3],
    com: DVec3,
    gravity: DVec3,
) -> (Vec<DVec2>, DVec2, Option<f64>) {
    let (u, v) = support_basis(gravity);
    let proj = |p: DVec3| DVec2::new(p.dot(u), p.dot(v));
    let pts: Vec<DVec2> = supported.iter().map(|&p| proj(p)).collect();
    let hull = convex_hull(&pts);
    let c = proj(com);
    let m = signed_margin(&hull, c);
    (hull, c, m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn margin_inside_outside_and_degenerate() {
        let sq = [
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 1.0),
            DVec2::new(0.5, 0.5),
            DVec2::new(0.5, 0.0),
        ];
        let h = convex_hull(&sq);
        assert_eq!(h.len(), 4);
        assert!((signed_margin(&h, DVec2::new(0.5, 0.5)).unwrap() - 0.5).abs() < 1e-12);
        assert!((signed_margin(&h, DVec2::new(0.9, 0.5)).unwrap() - 0.1).abs() < 1e-12);
        assert!((signed_margin(&h, DVec2::new(1.3, 0.5)).unwrap() + 0.3).abs() < 1e-12);
        assert!((signed_margin(&h, DVec2::new(1.3, 1.4)).unwrap() + 0.5).abs() < 1e-12);
        let seg = convex_hull(&[DVec2::ZERO, DVec2::X, DVec2::new(0.5, 0.0)]);
        assert_eq!(seg.len(), 2);
        assert_eq!(signed_margin(&seg, DVec2::new(0.5, 0.0)), Some(-0.0));
        assert!((signed_margin(&seg, DVec2::new(0.5, 0.2)).unwrap() + 0.2).abs() < 1e-12);
        assert_eq!(signed_margin(&[], DVec2::ZERO), None);
    }

    #[test]
    fn basis_is_orthonormal_and_orthogonal_to_gravity() {
        for g in [
            DVec3::new(0.0, 0.0, -9.81),
            DVec3::new(-9.81, 0.0, 0.0),
            DVec3::new(0.3, -2.0, -5.0),
        ] {
            let (u, v) = support_basis(g);
            assert!(u.dot(g).abs() < 1e-12 && v.dot(g).abs() < 1e-12 && u.dot(v).abs() < 1e-12);
            assert!((u.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12);
        }
        let (u, v) = support_basis(DVec3::new(0.0, 0.0, -9.81));
        assert!((u.cross(v) - DVec3::Z).length() < 1e-12);
    }
}
