//! Triangle meshes: loading (OBJ, PLY, STL, glTF/GLB), validation, units and
//! the derived quantities every kernel needs (face planes, bounds).
//!
//! Meshes are kept in `f64` metres on the CPU; kernels convert to `f32` when
//! they upload. Loading never panics: malformed input becomes an
//! [`Error`](crate::Error), recoverable defects (degenerate faces, open
//! boundaries, a unit guess) are reported in a [`MeshReport`].

mod load;
pub mod lod;
pub mod mass;
mod quickhull;
mod ply;
mod polygon;
mod stl;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::error::{Error, Result};

pub use load::load_positions;

/// Units of the numbers in a mesh file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MeshUnits {
    /// The file is in metres.
    Metres,
    /// The file is in millimetres (BOP models).
    Millimetres,
    /// The file is in centimetres (common in exports from Blender and
    /// game tools; `Auto` would take a 15 cm object as 15 mm).
    Centimetres,
    /// Guess from the bounding-box diagonal: above 5 m the file is taken as
    /// millimetres (and the report says so); below 5 mm a warning is issued.
    #[default]
    Auto,
}

impl std::str::FromStr for MeshUnits {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "m" | "metres" | "meters" => Ok(MeshUnits::Metres),
            "mm" | "millimetres" | "millimeters" => Ok(MeshUnits::Millimetres),
            "cm" | "centimetres" | "centimeters" => Ok(MeshUnits::Centimetres),
            "auto" => Ok(MeshUnits::Auto),
            _ => Err(format!("unknown mesh units '{s}' (expected m, cm, mm or auto)")),
        }
    }
}

/// Largest plausible object diagonal in metres; anything bigger is taken as
/// millimetres by [`MeshUnits::Auto`].
pub const MAX_DIAGONAL_M: f64 = 5.0;
/// Smallest plausible object diagonal in metres; smaller meshes get a warning.
pub const MIN_DIAGONAL_M: f64 = 0.005;

/// What loading found out about a mesh besides its geometry.
#[derive(Clone, Debug, Default)]
pub struct MeshReport {
    /// Faces with (near) zero area that were dropped.
    pub degenerate_faces: usize,
    /// Edges used by exactly one face (0 for a closed mesh).
    pub boundary_edges: usize,
    /// Edges used by more than two faces.
    pub nonmanifold_edges: usize,
    /// Scale applied to the file's numbers to get metres.
    pub scale_to_metres: f64,
    /// Human-readable warnings (units guessed, open boundary, ...).
    pub warnings: Vec<String>,
}

/// A triangle mesh in metres.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Where the mesh came from, for messages and provenance.
    pub source: Option<PathBuf>,
}

impl Mesh {
    /// Builds a mesh from raw positions and triangles, validating them the
    /// same way as a file (`name` is used in error messages).
    pub fn from_raw(
        name: impl Into<PathBuf>,
        vertices: Vec<DVec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<(Mesh, MeshReport)> {
        let path = name.into();
        validate_and_clean(path, vertices, triangles, MeshUnits::Metres)
    }

    /// Loads a mesh file, converts it to metres and validates it.
    pub fn load(path: impl AsRef<Path>, units: MeshUnits) -> Result<(Mesh, MeshReport)> {
        let path = path.as_ref();
        let _span = tracing::trace_span!("mesh", path = %path.display()).entered();
        let (vertices, triangles) = load_positions(path)?;
        validate_and_clean(path.to_path_buf(), vertices, triangles, units)
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        bounds_of(&self.vertices)
    }

    /// Length of the bounding-box diagonal in metres.
    pub fn diagonal(&self) -> f64 {
        let (lo, hi) = self.bounds();
        (hi - lo).length()
    }

    /// Radius of the smallest origin-centred sphere holding the mesh.
    pub fn radius_about_origin(&self) -> f64 {
        self.vertices.iter().map(|v| v.length()).fold(0.0, f64::max)
    }

    /// Uniformly scales the mesh about the origin.
    pub fn scale(&mut self, s: f64) {
        for v in &mut self.vertices {
            *v *= s;
        }
    }

    /// Moves the bounding-box centre to the origin and scales the mesh so its
    /// bounding-box diagonal is `diagonal` metres (used by the demo and the
    /// benchmarks to give meshes of arbitrary units a common size).
    pub fn normalized(mut self, diagonal: f64) -> Mesh {
        let (lo, hi) = self.bounds();
        let c = 0.5 * (lo + hi);
        let s = diagonal / (hi - lo).length();
        for v in &mut self.vertices {
            *v = (*v - c) * s;
        }
        self
    }

    /// Counts edges used by one face (boundary) and by more than two faces.
    pub fn edge_counts(&self) -> (usize, usize) {
        // Sorted undirected edge keys (8 bytes each) rather than a hash map
        // (about twice the memory on multi-million-triangle scans).
        let mut edges: Vec<u64> = self
            .triangles
            .iter()
            .flat_map(|&t| directed_edges(t))
            .map(|(a, b)| edge_key(a, b))
            .collect();
        edges.sort_unstable();
        let (mut boundary, mut nonmanifold) = (0, 0);
        for run in edges.chunk_by(|a, b| a == b) {
            match run.len() {
                1 => boundary += 1,
                2 => {}
                _ => nonmanifold += 1,
            }
        }
        (boundary, nonmanifold)
    }

    /// True when every edge is shared by exactly two faces.
    pub fn is_closed(&self) -> bool {
        self.edge_counts() == (0, 0)
    }

    /// True when the triangles bound a solid: every edge is run along as
    /// often in one direction as in the other. That holds for closed,
    /// consistently oriented meshes, and still where two sheets touch along
    /// an edge (which [`Mesh::is_closed`] rejects); it fails at holes, at
    /// faces wound the wrong way and at folded-over flaps. Seen from
    /// outside such a mesh, every back face is hidden behind a front face,
    /// so a renderer may skip them.
    pub fn bounds_solid(&self) -> bool {
        let mut edges: Vec<(u64, i32)> = self
            .triangles
            .iter()
            .flat_map(|&t| directed_edges(t))
            .map(|(a, b)| (edge_key(a, b), if a < b { 1 } else { -1 }))
            .collect();
        edges.sort_unstable_by_key(|e| e.0);
        !self.triangles.is_empty() && edges.chunk_by(|a, b| a.0 == b.0).all(|run| run.iter().map(|e| e.1).sum::<i32>() == 0)
    }

    /// Rewinds faces for rendering with back faces culled: every face of a
    /// closed manifold mesh ([`Mesh::is_closed`]) agrees with its
    /// neighbours and each shell faces outward (positive volume; a cavity's
    /// wall, never seen from outside, is turned outward too), and a mesh
    /// that bounds a solid inside out is turned round. Scans have patches
    /// wound backwards (LM-O's eggbox), which culling would show as holes.
    /// Returns whether the mesh now bounds a solid ([`Mesh::bounds_solid`]);
    /// a mesh that is neither closed nor solid, or not orientable, is left
    /// as is.
    pub fn orient(&mut self) -> bool {
        let solid = self.bounds_solid();
        if solid || !self.is_closed() {
            if solid && self.signed_volume(0..self.triangles.len()) < 0.0 {
                self.triangles.iter_mut().for_each(|t| t.swap(1, 2));
            }
            return solid;
        }
        let Some((flip, shells)) = self.winding_flips() else {
            return false; // not orientable
        };
        for shell in shells {
            for &f in &shell {
                if flip[f] {
                    self.triangles[f].swap(1, 2);
                }
            }
            if self.signed_volume(shell.iter().copied()) < 0.0 {
                for &f in &shell {
                    self.triangles[f].swap(1, 2);
                }
            }
        }
        // Every edge has two faces, now running along it in opposite
        // directions: balanced by construction.
        debug_assert!(self.bounds_solid());
        true
    }

    /// For a closed manifold mesh: which faces to turn round so that each
    /// agrees with its neighbours (the two run along their shared edge in
    /// opposite directions), found by walking each shell from a seed face,
    /// and the shells' faces; `None` when some shell cannot agree (not
    /// orientable).
    fn winding_flips(&self) -> Option<(Vec<bool>, Vec<Vec<usize>>)> {
        let neighbours = self.face_neighbours();
        // Whether face t runs along edge key e from its smaller vertex.
        let forward = |t: [u32; 3], e: u64| directed_edges(t).contains(&((e >> 32) as u32, e as u32));
        let mut flip: Vec<Option<bool>> = vec![None; self.triangles.len()];
        let mut shells = Vec::new();
        for seed in 0..self.triangles.len() {
            if flip[seed].is_some() {
                continue;
            }
            flip[seed] = Some(false);
            let (mut shell, mut stack) = (vec![seed], vec![seed]);
            while let Some(f) = stack.pop() {
                for &(g, e) in &neighbours[f] {
                    let g = g as usize;
                    let want = forward(self.triangles[f], e) ^ (flip[f] == Some(true)) == forward(self.triangles[g], e);
                    match flip[g] {
                        None => {
                            flip[g] = Some(want);
                            shell.push(g);
                            stack.push(g);
                        }
                        Some(have) if have != want => return None,
                        Some(_) => {}
                    }
                }
            }
            shells.push(shell);
        }
        Some((flip.into_iter().map(|f| f == Some(true)).collect(), shells))
    }

    /// Each face's three neighbours across its edges, with the edge's key
    /// (smaller vertex in the high half), for a mesh whose every edge has
    /// exactly two faces (one flat array: 2M-triangle scans pass here).
    fn face_neighbours(&self) -> Vec<[(u32, u64); 3]> {
        let mut edges: Vec<(u64, u32)> = (0..self.triangles.len() as u32)
            .flat_map(|f| directed_edges(self.triangles[f as usize]).map(|(a, b)| (edge_key(a, b), f)))
            .collect();
        edges.sort_unstable();
        let mut neighbours = vec![[(0u32, 0u64); 3]; self.triangles.len()];
        let mut filled = vec![0u8; self.triangles.len()];
        for pair in edges.chunks_exact(2) {
            for (f, g) in [(pair[0].1, pair[1].1), (pair[1].1, pair[0].1)] {
                let slot = &mut filled[f as usize];
                neighbours[f as usize][(*slot as usize).min(2)] = (g, pair[0].0);
                *slot = slot.saturating_add(1);
            }
        }
        neighbours
    }

    /// Six times the volume the given faces enclose, signed: positive when
    /// they are wound outward.
    fn signed_volume(&self, faces: impl Iterator<Item = usize>) -> f64 {
        faces
            .map(|f| {
                let [a, b, c] = self.corners(f);
                a.dot(b.cross(c))
            })
            .sum()
    }

    /// The three corners of triangle `i`.
    pub fn corners(&self, i: usize) -> [DVec3; 3] {
        let t = self.triangles[i];
        [self.vertices[t[0] as usize], self.vertices[t[1] as usize], self.vertices[t[2] as usize]]
    }

    /// Unit normal of triangle `i` (counter-clockwise winding = outward).
    pub fn face_normal(&self, i: usize) -> DVec3 {
        let [a, b, c] = self.corners(i);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// Total surface area in square metres.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Splits every edge into `n` equal parts and every triangle into `n²`
    /// (same surface, `n²` times the triangles): used by the benchmarks to
    /// measure how cost grows with triangle count on one shape.
    pub fn subdivided(&self, n: u32) -> Mesh {
        let n = n.max(1);
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for i in 0..self.triangles.len() {
            let [a, b, c] = self.corners(i);
            // Lattice point (r, s): a + (b - a) r/n + (c - a) s/n, r + s <= n.
            let mut index = vec![vec![0u32; (n + 1) as usize]; (n + 1) as usize];
            for r in 0..=n {
                for s in 0..=(n - r) {
                    index[r as usize][s as usize] = vertices.len() as u32;
                    vertices.push(a + (b - a) * (r as f64 / n as f64) + (c - a) * (s as f64 / n as f64));
                }
            }
            for r in 0..n {
                for s in 0..(n - r) {
                    let (p, q, t) = (index[r as usize][s as usize], index[r as usize + 1][s as usize], index[r as usize][s as usize + 1]);
                    triangles.push([p, q, t]);
                    if s + 1 < n - r {
                        let u = index[r as usize + 1][s as usize + 1];
                        triangles.push([q, u, t]);
                    }
                }
            }
        }
        let mut m = Mesh { vertices, triangles, source: self.source.clone() };
        m.weld();
        m
    }

    /// Merges vertices that coincide (to 1e-9 of the bounding-box diagonal):
    /// OBJ/STL files often repeat positions per face, which hides the mesh's
    /// connectivity.
    pub fn weld(&mut self) {
        let q = 1e-9 * self.diagonal().max(f64::MIN_POSITIVE);
        let mut map: HashMap<[i64; 3], u32> = HashMap::with_capacity(self.vertices.len());
        let mut remap = Vec::with_capacity(self.vertices.len());
        let mut out = Vec::new();
        for v in &self.vertices {
            let key = [(v.x / q).round() as i64, (v.y / q).round() as i64, (v.z / q).round() as i64];
            let id = *map.entry(key).or_insert_with(|| {
                out.push(*v);
                (out.len() - 1) as u32
            });
            remap.push(id);
        }
        for t in &mut self.triangles {
            for i in t.iter_mut() {
                *i = remap[*i as usize];
            }
        }
        self.vertices = out;
    }
}

/// Largest bounding-box diagonal a mesh file may have, in its own units.
pub const MAX_FILE_DIAGONAL: f64 = 1e30;

/// Axis-aligned bounds `(min, max)` of points (inverted infinities for
/// none).
pub fn bounds_of(points: &[DVec3]) -> (DVec3, DVec3) {
    points.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), v| (lo.min(*v), hi.max(*v)))
}

/// Refuses the first vertex that is not finite, naming it.
pub(crate) fn check_finite(path: &Path, vertices: &[DVec3]) -> Result<()> {
    match vertices.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        Some((index, v)) => Err(Error::NonFiniteVertex { path: path.to_path_buf(), index, value: v.to_array() }),
        None => Ok(()),
    }
}

/// Validation shared by every loader: finite vertices, indices in range, at
/// least one non-degenerate triangle, units, and a boundary check.
fn validate_and_clean(
    path: PathBuf,
    vertices: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    units: MeshUnits,
) -> Result<(Mesh, MeshReport)> {
    check_finite(&path, &vertices)?;
    for (face, t) in triangles.iter().enumerate() {
        if let Some(&i) = t.iter().find(|&&i| i as usize >= vertices.len()) {
            return Err(Error::IndexOutOfRange { path, face, index: i as u64, count: vertices.len() });
        }
    }
    if triangles.is_empty() {
        return Err(Error::NoTriangles { path });
    }
    let mut report = MeshReport { scale_to_metres: 1.0, ..Default::default() };
    let mut mesh = Mesh { vertices, triangles, source: Some(path.clone()) };
    let diag = mesh.diagonal();
    // Far past any object in any unit, and past what the kernels' f32
    // (3.4e38) and the mass properties' f64 (volumes and inertias overflow
    // near 1e61) hold: a 1e150 tetrahedron had reached the drop tests with
    // a NaN volume.
    if diag.is_nan() || diag > MAX_FILE_DIAGONAL {
        return Err(Error::MalformedMesh {
            path,
            reason: format!(
                "its bounding-box diagonal is {} in the file's units: above {MAX_FILE_DIAGONAL:.0e} no unit makes it an object",
                crate::error::compact(diag, 1)
            ),
        });
    }
    match units {
        MeshUnits::Metres => {}
        MeshUnits::Millimetres => report.scale_to_metres = 1e-3,
        MeshUnits::Centimetres => report.scale_to_metres = 1e-2,
        MeshUnits::Auto => {
            if diag > MAX_DIAGONAL_M {
                report.scale_to_metres = 1e-3;
                report.warnings.push(format!(
                    "bounding-box diagonal is {} units; above {MAX_DIAGONAL_M} m, so the mesh is \
                     taken to be in millimetres (state the units if it is in metres or centimetres)",
                    crate::error::compact(diag, 1)
                ));
            } else if diag < MIN_DIAGONAL_M {
                report.warnings.push(format!(
                    "bounding-box diagonal is {:.2} mm; this is unusually small for an object in metres \
                     (pass --mesh-units to state the units)",
                    diag * 1e3
                ));
            }
        }
    }
    if report.scale_to_metres != 1.0 {
        mesh.scale(report.scale_to_metres);
    }
    // Stated units that make an implausible object are said too: a 150 m
    // or 0.15 mm "object" scores 0 everywhere without anything else noting it.
    if units != MeshUnits::Auto {
        let d = diag * report.scale_to_metres;
        if !(MIN_DIAGONAL_M..=MAX_DIAGONAL_M).contains(&d) {
            report.warnings.push(format!(
                "with the stated units the object's bounding-box diagonal is {} m: is that its real size? (the units may be wrong)",
                crate::error::compact(d, 4)
            ));
        }
    }
    // Drop faces without area: they cannot be hit and have no normal.
    let scale = mesh.diagonal().max(f64::MIN_POSITIVE);
    let before = mesh.triangles.len();
    let verts = &mesh.vertices;
    mesh.triangles.retain(|t| {
        let (a, b, c) = (verts[t[0] as usize], verts[t[1] as usize], verts[t[2] as usize]);
        (b - a).cross(c - a).length() > 1e-14 * scale * scale
    });
    report.degenerate_faces = before - mesh.triangles.len();
    if mesh.triangles.is_empty() {
        return Err(Error::MalformedMesh { path, reason: "every face is degenerate (zero area)".into() });
    }
    if report.degenerate_faces > 0 {
        report.warnings.push(format!("dropped {} degenerate (zero-area) faces", report.degenerate_faces));
    }
    let mut welded = mesh.clone();
    welded.weld();
    let (boundary, nonmanifold) = welded.edge_counts();
    report.boundary_edges = boundary;
    report.nonmanifold_edges = nonmanifold;
    if boundary > 0 {
        report.warnings.push(format!(
            "mesh is open ({boundary} boundary edges): both sides of every face are rendered"
        ));
    }
    Ok((mesh, report))
}

/// The three edges of triangle `t`, in its winding order.
fn directed_edges(t: [u32; 3]) -> [(u32, u32); 3] {
    [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]
}

/// An undirected edge's key, the smaller vertex in the high half: sorting
/// the keys brings each edge's uses together.
fn edge_key(a: u32, b: u32) -> u64 {
    (a.min(b) as u64) << 32 | a.max(b) as u64
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_mesh_past_any_unit_is_refused_by_its_size() {
        let tet = |s: f64| vec![DVec3::ZERO, DVec3::X * s, DVec3::Y * s, DVec3::Z * s];
        let faces = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let err = Mesh::from_raw("huge", tet(1e150), faces.clone()).unwrap_err().to_string();
        assert!(err.contains("1.732e150 in the file's units"), "{err}");
        assert!(Mesh::from_raw("large", tet(1e20), faces).is_ok());
    }

    #[test]
    fn bounds_solid_allows_touching_sheets_and_rejects_holes_flips_and_flaps() {
        let v = |p: &[[f64; 3]]| p.iter().map(|&a| glam::DVec3::from(a)).collect::<Vec<_>>();
        let tet = |o: u32| vec![[o, o + 2, o + 1], [o, o + 1, o + 3], [o + 1, o + 2, o + 3], [o, o + 3, o + 2]];
        let corners = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mesh = |pts: Vec<glam::DVec3>, tris: Vec<[u32; 3]>| Mesh::from_raw("t", pts, tris).unwrap().0;
        let one = mesh(v(&corners), tet(0));
        assert!(one.bounds_solid() && one.is_closed());
        let mut flipped = tet(0);
        flipped[0] = [0, 1, 2];
        assert!(!mesh(v(&corners), flipped).bounds_solid());
        assert!(!mesh(v(&corners), tet(0)[..3].to_vec()).bounds_solid());
        // Two tetrahedra sharing the edge 0-1 (a pinch): solid, not closed.
        let mut pts = corners.to_vec();
        pts.extend([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]);
        let other = tet(0).into_iter().map(|t| t.map(|k| [0, 1, 4, 5][k as usize])); // tet(0) turned 180° about x
        let pinch = mesh(v(&pts), tet(0).into_iter().chain(other).collect());
        assert!(pinch.bounds_solid() && !pinch.is_closed(), "{:?}", pinch.edge_counts());
        // A face wound backwards is turned round, and a shell wound inside
        // out as a whole is turned outward.
        let mut flipped = tet(0);
        flipped[2] = [1, 3, 2];
        let mut m = mesh(v(&corners), flipped);
        assert!(!m.bounds_solid() && m.orient());
        assert_eq!(m.triangles, tet(0));
        let mut inside_out = mesh(v(&corners), tet(0).into_iter().map(|[a, b, c]| [a, c, b]).collect());
        assert!(inside_out.orient());
        assert_eq!(inside_out.triangles, tet(0));
        // A flap: one triangle twice on an edge of the tetrahedron.
        let flap = mesh(v(&pts), [tet(0), vec![[1, 0, 4], [1, 0, 4]]].concat());
        assert!(!flap.bounds_solid());
    }

    use super::*;

    /// Centimetres scale by 1/100 and are not second-guessed.
    #[test]
    fn centimetres_are_a_unit() {
        let v = vec![DVec3::ZERO, DVec3::new(15.0, 0.0, 0.0), DVec3::new(0.0, 10.0, 0.0), DVec3::new(0.0, 0.0, 5.0)];
        let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let (m, report) = validate_and_clean(std::path::PathBuf::from("cm.obj"), v, t, "cm".parse().unwrap()).unwrap();
        assert_eq!(report.scale_to_metres, 1e-2);
        assert!((m.diagonal() - (15f64.powi(2) + 100.0 + 25.0).sqrt() * 1e-2).abs() < 1e-12);
        assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    }

    pub(crate) fn unit_cube() -> Mesh {
        crate::shapes::cuboid(DVec3::splat(0.5))
    }

    #[test]
    fn cube_is_closed_with_area_6() {
        let m = unit_cube();
        assert!(m.is_closed());
        assert!((m.area() - 6.0).abs() < 1e-12);
    }

    #[test]
    fn subdivision_keeps_surface() {
        let m = unit_cube().subdivided(5);
        assert_eq!(m.triangles.len(), 12 * 25);
        assert!(m.is_closed());
        assert!((m.area() - 6.0).abs() < 1e-9);
    }
}
