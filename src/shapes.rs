//! Analytic test shapes (box, sphere, cylinder) with outward, counter-clockwise
//! faces. They are the ground truth of the tests: their depth images, stable
//! faces and mass properties are known in closed form.

use glam::DVec3;

use crate::mesh::Mesh;

/// An axis-aligned box centred at the origin with the given half extents.
pub fn cuboid(half: DVec3) -> Mesh {
    let mut vertices = Vec::with_capacity(8);
    for i in 0..8 {
        let s = DVec3::new(
            if i & 1 == 0 { -1.0 } else { 1.0 },
            if i & 2 == 0 { -1.0 } else { 1.0 },
            if i & 4 == 0 { -1.0 } else { 1.0 },
        );
        vertices.push(s * half);
    }
    // Quads as (a, b, c, d) counter-clockwise seen from outside.
    let quads = [
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
    ];
    let mut triangles = Vec::with_capacity(12);
    for q in quads {
        triangles.push([q[0], q[1], q[2]]);
        triangles.push([q[0], q[2], q[3]]);
    }
    Mesh { vertices, triangles, source: None }
}

/// A geodesic sphere of the given radius: an icosahedron subdivided
/// `subdivisions` times (20 * 4^s faces), vertices projected onto the sphere.
pub fn icosphere(radius: f64, subdivisions: u32) -> Mesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<DVec3> = [
        [-1.0, p, 0.0], [1.0, p, 0.0], [-1.0, -p, 0.0], [1.0, -p, 0.0],
        [0.0, -1.0, p], [0.0, 1.0, p], [0.0, -1.0, -p], [0.0, 1.0, -p],
        [p, 0.0, -1.0], [p, 0.0, 1.0], [-p, 0.0, -1.0], [-p, 0.0, 1.0],
    ]
    .iter()
    .map(|a| DVec3::from_array(*a).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(triangles.len() * 4);
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                (v.len() - 1) as u32
            })
        };
        for [a, b, c] in triangles {
            let ab = midpoint(a, b, &mut vertices);
            let bc = midpoint(b, c, &mut vertices);
            let ca = midpoint(c, a, &mut vertices);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    for v in &mut vertices {
        *v *= radius;
    }
    Mesh { vertices, triangles, source: None }
}

/// A closed cylinder along z, centred at the origin, with `segments` sides.
pub fn cylinder(radius: f64, height: f64, segments: u32) -> Mesh {
    let h = height / 2.0;
    let mut vertices = vec![DVec3::new(0.0, 0.0, -h), DVec3::new(0.0, 0.0, h)];
    for i in 0..segments {
        let a = std::f64::consts::TAU * i as f64 / segments as f64;
        let (s, c) = a.sin_cos();
        vertices.push(DVec3::new(radius * c, radius * s, -h));
        vertices.push(DVec3::new(radius * c, radius * s, h));
    }
    let mut triangles = Vec::new();
    for i in 0..segments {
        let j = (i + 1) % segments;
        let (b0, t0, b1, t1) = (2 + 2 * i, 3 + 2 * i, 2 + 2 * j, 3 + 2 * j);
        triangles.push([0, b1, b0]);
        triangles.push([1, t0, t1]);
        triangles.push([b0, b1, t1]);
        triangles.push([b0, t1, t0]);
    }
    Mesh { vertices, triangles, source: None }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_are_closed_and_outward() {
        for m in [cuboid(DVec3::new(0.1, 0.2, 0.3)), icosphere(0.1, 2), cylinder(0.05, 0.2, 32)] {
            assert!(m.is_closed());
            // Outward winding: the signed volume is positive.
            let vol: f64 = (0..m.triangles.len())
                .map(|i| {
                    let [a, b, c] = m.corners(i);
                    a.dot(b.cross(c)) / 6.0
                })
                .sum();
            assert!(vol > 0.0);
        }
    }
}
