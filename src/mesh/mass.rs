//! Mass properties of a solid of uniform density bounded by a triangle mesh:
//! volume, centre of mass and inertia tensor about the centre of mass.
//!
//! For a closed mesh they are exact integrals over the enclosed volume, from
//! the signed tetrahedra that each triangle spans with a reference point
//! (divergence theorem), once every face is wound to bound the solid
//! (each shell outward, a cavity's wall inward: [`orient_shells`]; faces
//! wound backwards otherwise move the centre of mass and lose volume
//! silently). An open mesh does not enclose a volume, so its
//! integrals depend on the arbitrary reference point; for such meshes the
//! properties are taken from the convex hull of the vertices instead (a
//! documented fallback: exact for convex objects, an over-estimate of the
//! volume of concave ones), and a warning says so.
//!
//! These are the properties physics uses (drop tests, stability): physics
//! engines would otherwise derive them from the collider (a hull or a convex
//! decomposition), which moves the centre of mass of concave objects.

use glam::{DMat3, DVec3};

use super::Mesh;
use crate::error::{Error, Result};

/// Where the mass properties came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MassSource {
    /// Integrated over the closed mesh itself.
    ClosedMesh,
    /// The mesh is open; integrated over the convex hull of its vertices.
    ConvexHullFallback,
}

/// Volume, centre of mass and inertia of a uniform solid.
#[derive(Clone, Debug, PartialEq)]
pub struct MassProperties {
    /// Volume in m³ (always positive).
    pub volume: f64,
    /// Centre of mass in model coordinates (metres).
    pub com: DVec3,
    /// Inertia tensor about the centre of mass, model axes, for unit density
    /// (kg/m³), in m⁵. Multiply by the density for kg·m².
    pub inertia_unit_density: DMat3,
    pub source: MassSource,
}

impl MassProperties {
    /// Mass in kg for the given density in kg/m³.
    pub fn mass(&self, density: f64) -> f64 {
        self.volume * density
    }

    /// Inertia tensor about the centre of mass in kg·m² for a density in kg/m³.
    pub fn inertia(&self, density: f64) -> DMat3 {
        self.inertia_unit_density * density
    }

    /// The same properties as rapier's (f32) mass properties of a body of
    /// uniform `density`, for setting on a rigid body instead of deriving
    /// them from its collider.
    ///
    /// The principal axes are found here, in f64 and on the tensor scaled to
    /// unit size ([`principal_axes`]), not by parry's
    /// `MassProperties::with_inertia_matrix`: its 3×3 eigensolver (glamx
    /// 0.3) takes any tensor whose column cross products are below an
    /// absolute 1e-20 for an isotropic one and returns the x axis as the
    /// first principal axis. Below about 1e-5 kg·m² (a 5 g pencil, any
    /// object under a few centimetres at 1000 kg/m³) the body then spun
    /// about the wrong axes: a 5.7 mm × 0.15 m rod got its long axis'
    /// inertia on a transverse axis and rocked, sunk into the ground, for
    /// the whole drop.
    pub fn to_rapier(&self, density: f64) -> rapier3d::parry::mass_properties::MassProperties {
        let (principal, frame) = principal_axes(&self.inertia(density));
        rapier3d::parry::mass_properties::MassProperties::with_principal_inertia_frame(
            self.com.as_vec3(),
            self.mass(density) as f32,
            principal.as_vec3(),
            frame.as_quat().normalize(),
        )
    }

    /// Computes the mass properties of `mesh`, returning warnings about the
    /// fallbacks used (open mesh, inverted winding).
    ///
    /// Errors when the solid has (numerically) zero volume: a flat or
    /// degenerate mesh has no meaningful centre of mass or inertia.
    pub fn of_mesh(mesh: &Mesh) -> Result<(MassProperties, Vec<String>)> {
        let name = mesh
            .source
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "mesh".into());
        let mut warnings = Vec::new();
        let mut welded = mesh.clone();
        welded.weld();
        let (boundary, nonmanifold) = welded.edge_counts();
        if boundary == 0 && nonmanifold == 0 {
            orient_shells(&mut welded, &name, &mut warnings);
            let mut props = integrate(&welded.vertices, &welded.triangles);
            if props.volume < 0.0 {
                warnings.push(format!(
                    "{name}: faces are wound inwards (negative volume); mass properties use the reversed orientation"
                ));
                props.volume = -props.volume;
                props.inertia_unit_density = -props.inertia_unit_density;
            }
            check_volume(&name, &props, mesh.diagonal())?;
            // A closed surface can still fail to bound one solid (bodies that
            // intersect each other, components wound against each other):
            // then its centre of mass can land outside the object. The
            // convex hull bounds every solid the vertices can make, so a
            // centre outside it (or more volume than it) means the closed
            // integration is not a solid's; use the hull instead.
            if let Some(hull) = hull_disagrees(&mesh.vertices, &props, mesh.diagonal()) {
                warnings.push(format!(
                    "{name}: the closed surface does not bound one solid (its centre of mass or volume exceeds \
                     the convex hull: intersecting or inconsistently wound bodies); mass properties are computed \
                     from the convex hull of its vertices"
                ));
                let mut props = hull;
                props.source = MassSource::ConvexHullFallback;
                if props.volume < 0.0 {
                    props.volume = -props.volume;
                    props.inertia_unit_density = -props.inertia_unit_density;
                }
                check_volume(&name, &props, mesh.diagonal())?;
                return Ok((props, warnings));
            }
            return Ok((props, warnings));
        }
        warnings.push(format!(
            "{name}: mesh is not closed ({boundary} boundary, {nonmanifold} non-manifold edges), so it encloses \
             no well-defined volume; mass properties are computed from the convex hull of its vertices \
             (uniform density; this over-estimates the volume of concave objects and can move their centre of mass)"
        ));
        let (hv, ht) = convex_hull(&mesh.vertices).map_err(|reason| {
            Error::InvalidInput(format!("{name}: cannot compute mass properties: {reason}"))
        })?;
        let mut props = integrate(&hv, &ht);
        props.source = MassSource::ConvexHullFallback;
        if props.volume < 0.0 {
            props.volume = -props.volume;
            props.inertia_unit_density = -props.inertia_unit_density;
        }
        check_volume(&name, &props, mesh.diagonal())?;
        Ok((props, warnings))
    }
}

/// Most shells whose nesting [`orient_shells`] works out (a pair of shells
/// costs up to a solid-angle sum over one of them per test point); beyond
/// it each shell keeps the winding most of its faces have.
pub const MAX_NESTING_SHELLS: usize = 64;

/// Test points per shell in the nesting test of [`orient_shells`].
const NESTING_SAMPLES: usize = 7;

/// Winds the faces of a closed manifold mesh the way the divergence theorem
/// needs them, before integrating: every face agrees with its neighbours
/// ([`Mesh::winding_flips`], per connected shell), every shell bounds its
/// solid outward (positive signed volume), except a shell nested inside an
/// odd number of other shells, the wall of a cavity, which is wound inward
/// (negative), so that its volume is taken away. A scan with patches wound
/// backwards (LM-O's eggbox has 26 faces) or a file whose shells were saved
/// inside out would otherwise integrate to a wrong volume and centre of mass
/// without notice (a 10×6×3 cm box with one flipped triangle: 150 cm³ and a
/// centre 7.5 mm off). Nesting is decided by the winding number (the sum of
/// solid angles) of one shell's vertices about the other, for up to
/// [`MAX_NESTING_SHELLS`] shells; past that each shell keeps the winding
/// most of its faces have (a part with many cavities is usually wound
/// right). Warns when faces were re-wound. A mesh that is not orientable
/// is left as it is.
fn orient_shells(mesh: &mut Mesh, name: &str, warnings: &mut Vec<String>) {
    let Some((flip, shells)) = mesh.winding_flips() else { return };
    let (lo, hi) = mesh.bounds();
    let centre = if lo.is_finite() && hi.is_finite() { 0.5 * (lo + hi) } else { DVec3::ZERO };
    // A shell's faces wound alike (as its seed face is).
    fn agreeing<'a>(tris: &'a [[u32; 3]], flip: &'a [bool], shell: &'a [usize]) -> impl Iterator<Item = [u32; 3]> + 'a {
        shell.iter().map(move |&f| reversed(tris[f], flip[f]))
    }
    // Whole-shell turn that makes each shell outward; past
    // MAX_NESTING_SHELLS, where cavities are not looked for, the one that
    // keeps the winding most of the shell's faces have (a correctly wound
    // part with 64 cavities stays as it is).
    let many = shells.len() > MAX_NESTING_SHELLS;
    let mut turn: Vec<bool> = if many {
        shells.iter().map(|s| 2 * s.iter().filter(|&&f| flip[f]).count() > s.len()).collect()
    } else {
        shells.iter().map(|s| six_volume(&mesh.vertices, agreeing(&mesh.triangles, &flip, s), centre) < 0.0).collect()
    };
    let nested = if shells.len() > 1 && !many {
        let shell_tris: Vec<Vec<[u32; 3]>> =
            shells.iter().zip(&turn).map(|(s, &turn)| agreeing(&mesh.triangles, &flip, s).map(|t| reversed(t, turn)).collect()).collect();
        shell_nesting(&mesh.vertices, &shell_tris)
    } else {
        vec![0; shells.len()]
    };
    let mut cavities = 0;
    for (s, depth) in nested.iter().enumerate() {
        if depth % 2 == 1 {
            turn[s] = !turn[s];
            cavities += 1;
        }
    }
    let mut rewound = 0usize;
    for (s, shell) in shells.iter().enumerate() {
        for &f in shell {
            if flip[f] ^ turn[s] {
                mesh.triangles[f].swap(1, 2);
                rewound += 1;
            }
        }
    }
    if rewound > 0 {
        let cavities = match cavities {
            0 => String::new(),
            1 => " (one shell lies inside another: a cavity, wound inward)".to_string(),
            n => format!(" ({n} shells lie inside others: cavities, wound inward)"),
        };
        warnings.push(format!(
            "{name}: {rewound} of {} faces are wound against the rest of their shell or their shell is inside out; \
             mass properties use them re-wound, every shell bounding its solid outward{cavities}",
            mesh.triangles.len()
        ));
    }
    if many && rewound > 0 {
        warnings.push(format!(
            "{name}: {} closed shells, more than {MAX_NESTING_SHELLS}: each keeps the winding most of its faces have, \
             without looking for cavities or inside-out shells",
            shells.len()
        ));
    }
}

/// `t` wound the other way round when `reverse`.
fn reversed(t: [u32; 3], reverse: bool) -> [u32; 3] {
    if reverse { [t[0], t[2], t[1]] } else { t }
}

/// Six times the signed volume a closed surface encloses, from the
/// tetrahedra its triangles span with `at` (the sum does not depend on the
/// point for a closed surface, but is better conditioned near it).
fn six_volume(vertices: &[DVec3], tris: impl Iterator<Item = [u32; 3]>, at: DVec3) -> f64 {
    tris.map(|t| {
        let [a, b, c] = t.map(|i| vertices[i as usize] - at);
        a.dot(b.cross(c))
    })
    .sum()
}

/// For each shell (closed, wound outward), how many of the others enclose
/// it: shell `j` encloses shell `i` when `i`'s bounding box lies in `j`'s,
/// `i` is the smaller, and the winding number of `j` about `i`'s test points
/// (its extreme vertices along ±x, ±y, ±z and its first vertex, leaving out
/// vertices `j` shares) is one at each. A test point whose winding number is
/// near ½ (on `j`'s surface) does not count; shells that cross each other
/// (some points in, some out) do not enclose one another.
fn shell_nesting(vertices: &[DVec3], shells: &[Vec<[u32; 3]>]) -> Vec<usize> {
    let n = shells.len();
    let bounds: Vec<(DVec3, DVec3)> = shells
        .iter()
        .map(|tris| {
            tris.iter().flatten().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(l, h), &v| {
                let p = vertices[v as usize];
                (l.min(p), h.max(p))
            })
        })
        .collect();
    let volumes: Vec<f64> = (0..n).map(|s| six_volume(vertices, shells[s].iter().copied(), 0.5 * (bounds[s].0 + bounds[s].1))).collect();
    let mut used: Vec<Vec<u32>> = shells.iter().map(|t| t.iter().flatten().copied().collect()).collect();
    for u in &mut used {
        u.sort_unstable();
        u.dedup();
    }
    // Test points: the first vertex, then the extremes along the axes.
    let samples: Vec<Vec<u32>> = used
        .iter()
        .map(|u| {
            let mut s = vec![u[0]];
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                for sign in [1.0, -1.0] {
                    let key = |&&i: &&u32| sign * vertices[i as usize].dot(axis);
                    if let Some(&best) = u.iter().max_by(|a, b| key(a).total_cmp(&key(b))) {
                        s.push(best);
                    }
                }
            }
            s.dedup();
            s.truncate(NESTING_SAMPLES);
            s
        })
        .collect();
    let size = bounds.iter().fold(0.0f64, |m, (l, h)| m.max((*h - *l).length()));
    let tol = 1e-9 * size;
    let encloses = |j: usize, i: usize| -> bool {
        let ((li, hi), (lj, hj)) = (bounds[i], bounds[j]);
        if li.cmplt(lj - tol).any() || hi.cmpgt(hj + tol).any() || volumes[i] >= volumes[j] {
            return false;
        }
        let mut inside = 0;
        for &v in samples[i].iter().filter(|v| used[j].binary_search(v).is_err()) {
            let w = winding_number(vertices, &shells[j], vertices[v as usize]);
            if w < 0.25 {
                return false;
            }
            if w > 0.75 {
                inside += 1;
            }
        }
        inside > 0
    };
    (0..n).map(|i| (0..n).filter(|&j| j != i && encloses(j, i)).count()).collect()
}

/// Winding number of a closed surface (outward triangles) about `p`: one
/// inside, zero outside, ½ on the surface. The sum of the triangles' signed
/// solid angles (Van Oosterom and Strackee 1983) over 4π.
fn winding_number(vertices: &[DVec3], tris: &[[u32; 3]], p: DVec3) -> f64 {
    let total: f64 = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize] - p);
            let (la, lb, lc) = (a.length(), b.length(), c.length());
            let num = a.dot(b.cross(c));
            let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
            2.0 * num.atan2(den)
        })
        .sum();
    total / (4.0 * std::f64::consts::PI)
}

/// A hull face is a sliver, left out of containment tests, when its normal
/// is rounding noise: its corners are collinear to about 1e-6 rad (doubled
/// area below `SLIVER_REL` × its squared longest edge), or its doubled area
/// is below `SLIVER_ABS` × the squared size of the hull, where the f32
/// rounding of its corners tilts its plane enough to misplace points across
/// the object. The one rule for every hull test (mass properties, the hull's
/// own check, the stable-pose analysis).
pub const SLIVER_REL: f64 = 1e-6;
/// See [`SLIVER_REL`].
pub const SLIVER_ABS: f64 = 1e-9;

/// Unit normal and offset (`n·x = d`) of the triangle `(a, b, c)` of a hull
/// of extent `size` (normal by the right-hand rule), or a zero normal for a
/// sliver ([`SLIVER_REL`]).
pub fn face_plane(a: DVec3, b: DVec3, c: DVec3, size: f64) -> (DVec3, f64) {
    let n = (b - a).cross(c - a);
    let edge2 = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
    let area2 = n.length();
    let n = if area2 > SLIVER_REL * edge2 && area2 > SLIVER_ABS * size * size { n.normalize() } else { DVec3::ZERO };
    (n, n.dot(a))
}

/// The face planes of a hull (zero normals for slivers), its extent taken
/// from its vertices' bounding box.
pub fn hull_planes(verts: &[DVec3], tris: &[[u32; 3]]) -> Vec<(DVec3, f64)> {
    let (lo, hi) = verts.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(l, h), v| (l.min(*v), h.max(*v)));
    let size = (hi - lo).length();
    tris.iter().map(|t| face_plane(verts[t[0] as usize], verts[t[1] as usize], verts[t[2] as usize], size)).collect()
}

/// Largest distance of `p` outside the non-sliver planes of an outward hull
/// (negative inside; −∞ when every face is a sliver).
pub fn outside_planes(planes: &[(DVec3, f64)], p: DVec3) -> f64 {
    planes.iter().filter(|(n, _)| *n != DVec3::ZERO).map(|(n, d)| n.dot(p) - d).fold(f64::NEG_INFINITY, f64::max)
}

/// Vertices whose hull is taken first in [`hull_disagrees`].
const HULL_CHECK_POINTS: usize = 250_000;

/// The mass properties of the vertices' convex hull when the closed
/// integration `props` does not fit inside it (centre of mass outside, or
/// more volume), else `None`. On large meshes the hull of an evenly strided
/// subset is tried first (it lies inside the full hull, so agreement with
/// it is agreement with the full one), and only a disagreement is confirmed
/// on the full hull: a multi-million-vertex hull costs gigabytes.
fn hull_disagrees(vertices: &[DVec3], props: &MassProperties, diagonal: f64) -> Option<MassProperties> {
    let disagrees = |pts: &[DVec3]| -> Option<MassProperties> {
        let (hv, ht) = convex_hull(pts).ok()?;
        let hull = integrate(&hv, &ht);
        let outside = outside_planes(&hull_planes(&hv, &ht), props.com);
        (outside > 1e-9 * diagonal || props.volume > hull.volume.abs() * 1.001).then_some(hull)
    };
    if vertices.len() > HULL_CHECK_POINTS {
        let stride = vertices.len().div_ceil(HULL_CHECK_POINTS);
        let subset: Vec<DVec3> = vertices.iter().step_by(stride).copied().collect();
        disagrees(&subset)?;
    }
    disagrees(vertices)
}

/// Rejects solids whose volume is negligible against their bounding box
/// (flat sheets, a single triangle, collapsed scans).
fn check_volume(name: &str, props: &MassProperties, diagonal: f64) -> Result<()> {
    let scale = diagonal.powi(3).max(f64::MIN_POSITIVE);
    if !props.volume.is_finite() || props.volume <= 1e-9 * scale || !props.com.is_finite() {
        return Err(Error::InvalidInput(format!(
            "{name}: the mesh encloses (almost) zero volume ({:.3e} m³ for a {} m bounding-box diagonal); \
             mass, centre of mass and stable poses need a solid object",
            props.volume,
            crate::error::compact(diagonal, 3)
        )));
    }
    Ok(())
}

/// Integrates volume, first and second moments over signed tetrahedra
/// (reference point = bounding-box centre, to keep the sums well conditioned).
/// The sign of the result follows the winding (outward CCW = positive).
fn integrate(vertices: &[DVec3], triangles: &[[u32; 3]]) -> MassProperties {
    let (lo, hi) = vertices.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(l, h), v| (l.min(*v), h.max(*v)),
    );
    let origin = if lo.is_finite() {
        0.5 * (lo + hi)
    } else {
        DVec3::ZERO
    };
    let mut six_vol = 0.0;
    let mut first = DVec3::ZERO; // ∫ x dV, times 24
    let mut second = DMat3::ZERO; // ∫ x xᵀ dV, times 120
    for t in triangles {
        let a = vertices[t[0] as usize] - origin;
        let b = vertices[t[1] as usize] - origin;
        let c = vertices[t[2] as usize] - origin;
        let det = a.dot(b.cross(c));
        six_vol += det;
        let s = a + b + c;
        first += det * s;
        // ∫ x xᵀ over the tetrahedron (0, a, b, c) = det/120 (s sᵀ + a aᵀ + b bᵀ + c cᵀ).
        second += (outer(s, s) + outer(a, a) + outer(b, b) + outer(c, c)) * det;
    }
    let volume = six_vol / 6.0;
    let moment = first / 24.0;
    let cov = second * (1.0 / 120.0);
    let com_local = if volume.abs() > 0.0 {
        moment / volume
    } else {
        DVec3::ZERO
    };
    // Covariance about the centre of mass, then I = tr(C) 1 - C.
    let cov_com = cov - outer(com_local, com_local) * volume;
    let trace = cov_com.x_axis.x + cov_com.y_axis.y + cov_com.z_axis.z;
    let inertia = DMat3::from_diagonal(DVec3::splat(trace)) - cov_com;
    MassProperties {
        volume,
        com: com_local + origin,
        inertia_unit_density: inertia,
        source: MassSource::ClosedMesh,
    }
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Convex hull of a point set as a closed, outward-wound triangle mesh, its
/// vertices a subset of the points (exact, see
/// [`quickhull`](super::quickhull)). Errors (as text) for fewer than four
/// points, points that are not finite, or points that span no volume.
pub fn convex_hull(points: &[DVec3]) -> std::result::Result<(Vec<DVec3>, Vec<[u32; 3]>), String> {
    if points.len() < 4 {
        return Err(format!(
            "a convex hull needs at least 4 points, got {}",
            points.len()
        ));
    }
    let (lo, hi) = points.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(l, h), v| (l.min(*v), h.max(*v)),
    );
    if !lo.is_finite() || !hi.is_finite() {
        return Err("points are not finite".into());
    }
    let diag = (hi - lo).length();
    if diag <= 0.0 {
        return Err("all points coincide".into());
    }
    let flat = || "the points span no volume (flat or degenerate hull)".to_string();
    let (hv, ht) = super::quickhull::exact_hull(points).ok_or_else(flat)?;
    let volume: f64 = ht.iter().map(|t| hv[t[0] as usize].dot(hv[t[1] as usize].cross(hv[t[2] as usize]))).sum::<f64>() / 6.0;
    if volume <= 1e-9 * diag.powi(3) {
        return Err(flat());
    }
    Ok((hv, ht))
}

/// The mean of `points` and their scatter matrix about it, Σ (x − m)(x − m)ᵀ
/// (the covariance times the count): the plane fit's normal and the
/// observed object's principal axes are its eigenvectors.
pub fn scatter_about_mean(points: &[DVec3]) -> (DVec3, DMat3) {
    let mean = points.iter().copied().sum::<DVec3>() / points.len() as f64;
    let mut scatter = DMat3::ZERO;
    for &x in points {
        let d = x - mean;
        scatter += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    (mean, scatter)
}

/// Principal moments and axes of a symmetric inertia tensor: `inertia =
/// R diag(moments) Rᵀ` with `R` the returned rotation (its columns are the
/// axes). The tensor is scaled to unit size first, so the result does not
/// depend on the units or the size of the body (see
/// [`MassProperties::to_rapier`]); negative round-off moments become zero.
pub fn principal_axes(inertia: &DMat3) -> (DVec3, glam::DQuat) {
    let scale = max_abs(inertia);
    if !(scale > 0.0 && scale.is_finite()) {
        return (DVec3::ZERO, glam::DQuat::IDENTITY);
    }
    let m = nalgebra::Matrix3::from_fn(|r, c| inertia.col(c)[r] / scale);
    let eig = nalgebra::SymmetricEigen::new(m);
    let col = |i: usize| DVec3::new(eig.eigenvectors[(0, i)], eig.eigenvectors[(1, i)], eig.eigenvectors[(2, i)]).normalize();
    let (x, y) = (col(0), col(1));
    // A right-handed frame: the third axis is ± the solver's third column
    // (which may make a reflection), so it keeps its moment.
    let y = (y - x * x.dot(y)).normalize();
    let z = x.cross(y);
    let moments = DVec3::new(eig.eigenvalues[0], eig.eigenvalues[1], eig.eigenvalues[2]);
    (moments.max(DVec3::ZERO) * scale, glam::DQuat::from_mat3(&DMat3::from_cols(x, y, z)))
}

/// The largest absolute element of `m`.
fn max_abs(m: &DMat3) -> f64 {
    m.to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    /// rapier's mass properties must give back the tensor they were made
    /// from, for a light thin rod (a 5 g pencil: parry's own eigensolver
    /// put its long axis on x), a rotated body, any scale and a sphere.
    #[test]
    fn rapier_mass_properties_keep_the_inertia_tensor() {
        let rod = DMat3::from_diagonal(DVec3::new(8.9e-6, 8.9e-6, 2.5e-8));
        let rot = glam::DMat3::from_quat(glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0));
        let tilted = rot * DMat3::from_diagonal(DVec3::new(1.0, 2.0, 2.0)) * rot.transpose();
        for (name, inertia) in [
            ("rod", rod),
            ("tiny rod", rod * 1e-9),
            ("big rod", rod * 1e9),
            ("tilted", tilted),
            ("tiny tilted", tilted * 1e-12),
            ("sphere", DMat3::from_diagonal(DVec3::splat(3e-7))),
        ] {
            let props = MassProperties {
                volume: 1e-5,
                com: DVec3::new(0.01, 0.0, -0.02),
                inertia_unit_density: inertia / 1000.0,
                source: MassSource::ClosedMesh,
            };
            let back = props.to_rapier(1000.0).reconstruct_inertia_matrix();
            let back = DMat3::from_cols(back.x_axis.as_dvec3(), back.y_axis.as_dvec3(), back.z_axis.as_dvec3());
            let err = max_abs(&(back - inertia)) / max_abs(&inertia);
            assert!(err < 1e-5, "{name}: {back} vs {inertia} (relative error {err})");
            let (moments, frame) = principal_axes(&inertia);
            assert!((frame.length() - 1.0).abs() < 1e-12 && moments.min_element() >= 0.0, "{name}");
        }
    }

    #[test]
    fn box_matches_closed_form() {
        let half = DVec3::new(0.1, 0.2, 0.3);
        let mut m = shapes::cuboid(half);
        for v in &mut m.vertices {
            *v += DVec3::new(1.0, -2.0, 0.5);
        }
        let (p, w) = MassProperties::of_mesh(&m).unwrap();
        assert!(w.is_empty());
        let (a, b, c) = (0.2, 0.4, 0.6);
        assert!((p.volume - a * b * c).abs() < 1e-12);
        assert!((p.com - DVec3::new(1.0, -2.0, 0.5)).length() < 1e-12);
        let v = a * b * c;
        let expect = DVec3::new(
            v * (b * b + c * c) / 12.0,
            v * (a * a + c * c) / 12.0,
            v * (a * a + b * b) / 12.0,
        );
        let got = DVec3::new(
            p.inertia_unit_density.x_axis.x,
            p.inertia_unit_density.y_axis.y,
            p.inertia_unit_density.z_axis.z,
        );
        assert!((got - expect).length() < 1e-12, "{got} vs {expect}");
        assert!(p.inertia_unit_density.x_axis.y.abs() < 1e-14);
    }

    #[test]
    fn cylinder_and_sphere_are_close_to_analytic() {
        let (p, _) = MassProperties::of_mesh(&shapes::cylinder(0.05, 0.2, 256)).unwrap();
        let v = std::f64::consts::PI * 0.05f64.powi(2) * 0.2;
        assert!((p.volume / v - 1.0).abs() < 1e-3);
        let izz = v * 0.05f64.powi(2) / 2.0;
        assert!((p.inertia_unit_density.z_axis.z / izz - 1.0).abs() < 2e-3);
        let (s, _) = MassProperties::of_mesh(&shapes::icosphere(1.0, 4)).unwrap();
        assert!((s.volume / (4.0 / 3.0 * std::f64::consts::PI) - 1.0).abs() < 5e-3);
        assert!(s.com.length() < 1e-9);
    }

    #[test]
    fn inverted_and_open_meshes_fall_back_with_warnings() {
        let mut m = shapes::cuboid(DVec3::splat(0.5));
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
        let (p, w) = MassProperties::of_mesh(&m).unwrap();
        assert!((p.volume - 1.0).abs() < 1e-12 && w.len() == 1);
        assert!(p.inertia_unit_density.x_axis.x > 0.0);
        // Remove the top face: open, so the hull fallback gives the full cube.
        let mut open = shapes::cuboid(DVec3::splat(0.5));
        open.triangles.drain(2..4);
        let (p, w) = MassProperties::of_mesh(&open).unwrap();
        assert_eq!(p.source, MassSource::ConvexHullFallback);
        assert!((p.volume - 1.0).abs() < 1e-5, "{}", p.volume);
        assert!(w[0].contains("not closed"));
    }

    /// Boxes of half extents `half` centred at `at`, each wound outward
    /// unless its flag says inward, in one mesh.
    fn boxes(parts: &[(DVec3, DVec3, bool)]) -> Mesh {
        let mut m = Mesh { vertices: Vec::new(), triangles: Vec::new(), source: None };
        for &(half, at, inward) in parts {
            let b = shapes::cuboid(half);
            let off = m.vertices.len() as u32;
            m.vertices.extend(b.vertices.iter().map(|v| *v + at));
            m.triangles.extend(b.triangles.iter().map(|t| {
                let t = t.map(|i| i + off);
                if inward { [t[0], t[2], t[1]] } else { t }
            }));
        }
        m
    }

    /// The exact properties of the 10×6×3 cm box of the reproducer, centred
    /// at `at`, whatever the winding of its faces.
    fn assert_box(p: &MassProperties, at: DVec3) {
        let (a, b, c) = (0.1, 0.06, 0.03);
        let v = a * b * c;
        assert!((p.volume - v).abs() < 1e-15, "volume {} vs {v}", p.volume);
        assert!((p.com - at).length() < 1e-12, "centre {} vs {at}", p.com);
        let i = DVec3::new(v * (b * b + c * c), v * (a * a + c * c), v * (a * a + b * b)) / 12.0;
        let got = DVec3::new(p.inertia_unit_density.x_axis.x, p.inertia_unit_density.y_axis.y, p.inertia_unit_density.z_axis.z);
        assert!((got - i).length() < 1e-12 * i.length(), "{got} vs {i}");
        assert_eq!(p.source, MassSource::ClosedMesh);
    }

    /// A closed box with one triangle (or a whole face) wound backwards has
    /// the box's exact volume, centre and inertia, and a warning; so does one
    /// whose every face but one is backwards.
    #[test]
    fn faces_wound_backwards_are_rewound() {
        let half = DVec3::new(0.05, 0.03, 0.015);
        let at = DVec3::new(0.0, 0.0, 0.015);
        for flipped in [vec![3], vec![0, 1], (1..12).collect::<Vec<_>>()] {
            let mut m = boxes(&[(half, at, false)]);
            for &f in &flipped {
                m.triangles[f].swap(1, 2);
            }
            let (p, w) = MassProperties::of_mesh(&m).unwrap();
            assert_box(&p, at);
            assert_eq!(w.len(), 1, "{w:?}");
            let n = flipped.len().min(12 - flipped.len());
            assert!(w[0].contains(&format!("{n} of 12 faces")), "{w:?}");
        }
        // Consistently wound: nothing to say.
        let (p, w) = MassProperties::of_mesh(&boxes(&[(half, at, false)])).unwrap();
        assert_box(&p, at);
        assert!(w.is_empty(), "{w:?}");
    }

    /// A box with a box-shaped cavity: the cavity's wall wound inward is
    /// kept inward and its volume taken away, however the file winds it
    /// (outward, inward, or one face wrong), and a solid inside the cavity
    /// (nested twice) counts again. Two disjoint boxes, one inside out, are
    /// the sum of both; two boxes that cross each other are not a cavity.
    #[test]
    fn cavities_stay_inward_and_separate_shells_turn_outward() {
        let (outer, inner) = (DVec3::new(0.05, 0.04, 0.03), DVec3::new(0.02, 0.01, 0.015));
        let (o, c) = (DVec3::new(1.0, -2.0, 0.5), DVec3::new(1.01, -2.005, 0.5));
        let (vo, vi) = (8.0 * outer.x * outer.y * outer.z, 8.0 * inner.x * inner.y * inner.z);
        let expect = (vo * o - vi * c) / (vo - vi);
        for (outer_in, inner_in, flip_one) in [(false, true, false), (false, false, false), (true, true, true), (true, false, true)] {
            let mut m = boxes(&[(outer, o, outer_in), (inner, c, inner_in)]);
            if flip_one {
                m.triangles[17].swap(1, 2);
            }
            let (p, w) = MassProperties::of_mesh(&m).unwrap();
            let case = format!("outer inward {outer_in}, inner inward {inner_in}, one flipped {flip_one}: {w:?}");
            assert!((p.volume - (vo - vi)).abs() < 1e-15, "{case}: volume {} vs {}", p.volume, vo - vi);
            assert!((p.com - expect).length() < 1e-12, "{case}: centre {} vs {expect}", p.com);
            assert_eq!(w.is_empty(), !outer_in && inner_in && !flip_one, "{case}");
        }
        // A solid box in the cavity.
        let core = DVec3::splat(0.005);
        let m = boxes(&[(outer, o, false), (inner, c, false), (core, c, true)]);
        let (p, w) = MassProperties::of_mesh(&m).unwrap();
        let vc = 8.0 * core.x * core.y * core.z;
        assert!((p.volume - (vo - vi + vc)).abs() < 1e-15, "{} {w:?}", p.volume);
        assert!((p.com - (vo * o - vi * c + vc * c) / (vo - vi + vc)).length() < 1e-12);
        // Two disjoint boxes, the second inside out (the reproducer).
        let half = DVec3::new(0.05, 0.03, 0.015);
        let (a, b) = (DVec3::ZERO, DVec3::new(0.2, 0.0, 0.0));
        let (p, w) = MassProperties::of_mesh(&boxes(&[(half, a, false), (half, b, true)])).unwrap();
        assert!((p.volume - 2.0 * 0.1 * 0.06 * 0.03).abs() < 1e-15, "{}", p.volume);
        assert!((p.com - 0.5 * (a + b)).length() < 1e-12, "{}", p.com);
        assert!(w.len() == 1 && w[0].contains("12 of 24 faces"), "{w:?}");
        // Two boxes crossing each other (as in convex decompositions): both
        // solid, not one the other's cavity, and no re-winding (their sum
        // exceeds their hull, so the hull is used, as before).
        let (p, w) = MassProperties::of_mesh(&boxes(&[(outer, o, false), (outer * 0.9, o + DVec3::X * 0.04, false)])).unwrap();
        assert!(p.volume > vo && w.len() == 1 && w[0].contains("does not bound one solid"), "{} {w:?}", p.volume);
    }

    /// A shell inside another is found however large or small: the winding
    /// number is one inside, zero outside, whatever the distance.
    #[test]
    fn winding_number_of_a_box() {
        let b = shapes::cuboid(DVec3::new(1.0, 2.0, 3.0));
        for (p, w) in [(DVec3::ZERO, 1.0), (DVec3::new(0.99, 1.99, -2.99), 1.0), (DVec3::new(1.01, 0.0, 0.0), 0.0), (DVec3::splat(1e6), 0.0)] {
            let got = winding_number(&b.vertices, &b.triangles, p);
            assert!((got - w).abs() < 1e-9, "{p}: {got}");
        }
    }

    #[test]
    fn flat_mesh_is_an_error() {
        let v = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, 1.0, 0.0)];
        let m = Mesh {
            vertices: v,
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            source: None,
        };
        let err = MassProperties::of_mesh(&m).unwrap_err().to_string();
        assert!(
            err.contains("zero volume") || err.contains("no volume"),
            "{err}"
        );
    }

    /// On the points of a subdivided duck (many coplanar points, where
    /// parry's f32 quickhull left points out) the hull holds every point,
    /// its vertices are input points, and its volume is the original
    /// duck's hull volume (subdividing adds no hull vertex).
    #[test]
    fn hull_of_a_subdivided_mesh_holds_every_point() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck_vhacd.obj");
        let (duck, _) = crate::mesh::Mesh::load(path, crate::mesh::MeshUnits::Metres).unwrap();
        let dense = duck.subdivided(2);
        let (hv, ht) = convex_hull(&dense.vertices).unwrap();
        let planes = hull_planes(&hv, &ht);
        let diag = dense.diagonal();
        assert!(dense.vertices.iter().all(|p| outside_planes(&planes, *p) <= 1e-12 * diag));
        assert!(hv.iter().all(|v| dense.vertices.contains(v)), "hull vertices are input points");
        let (fv, ft) = convex_hull(&duck.vertices).unwrap();
        let vol = |v: &[DVec3], t: &[[u32; 3]]| integrate(v, t).volume;
        let (a, b) = (vol(&hv, &ht), vol(&fv, &ft));
        assert!((a - b).abs() <= 1e-9 * b, "volumes {a} vs {b}");
    }

    /// One sliver rule: a needle face has no plane, nor a face at the
    /// rounding level of the hull's size; a small well-shaped face keeps its
    /// normal.
    #[test]
    fn slivers_have_no_plane_and_small_faces_keep_theirs() {
        let (n, _) = face_plane(DVec3::ZERO, DVec3::X, DVec3::new(0.5, 1e-9, 0.0), 1.0);
        assert_eq!(n, DVec3::ZERO, "needle");
        let (n, d) = face_plane(DVec3::ZERO, DVec3::X * 1e-3, DVec3::Y * 1e-3, 1.0);
        assert!((n - DVec3::Z).length() < 1e-12 && d == 0.0, "small but well shaped");
        let (n, _) = face_plane(DVec3::ZERO, DVec3::X * 1e-5, DVec3::Y * 1e-5, 1.0);
        assert_eq!(n, DVec3::ZERO, "at rounding level of a 1 m hull");
        let b = shapes::cuboid(DVec3::splat(0.5));
        let (hv, ht) = convex_hull(&b.vertices).unwrap();
        let planes = hull_planes(&hv, &ht);
        assert!((outside_planes(&planes, DVec3::ZERO) + 0.5).abs() < 1e-6);
        assert!((outside_planes(&planes, DVec3::new(0.0, 0.0, 0.7)) - 0.2).abs() < 1e-6);
    }
}
