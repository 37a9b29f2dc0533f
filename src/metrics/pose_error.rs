//! Pose errors exactly as the BOP toolkit defines them (`pose_error.py`):
//! ADD, ADI, MSSD, MSPD, rotation and translation error, the symmetry set
//! of an object, and the toolkit's shortcuts.
//!
//! Units are the caller's: the evaluation passes BOP millimetres (poses and
//! model points as the files store them), so the numbers, and the ties at
//! thresholds, are the toolkit's. Rotations are used as given, not
//! re-orthonormalized, as the toolkit does.

use glam::{DMat3, DVec3};

use crate::bop::{ModelInfo, PoseMm, Projection};
use crate::lens::LensCamera;

/// A symmetry transformation of a model (model frame, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Symmetry {
    pub r: DMat3,
    pub t: DVec3,
}

impl Symmetry {
    pub const IDENTITY: Symmetry = Symmetry { r: DMat3::IDENTITY, t: DVec3::ZERO };
}

/// The BOP'19 `max_sym_disc_step`: continuous symmetries are sampled so that
/// no model point moves more than 1 % of the diameter between samples.
pub const MAX_SYM_DISC_STEP: f64 = 0.01;

/// Rotation by `angle` about `axis` (normalized here), written as the
/// toolkit's `transform.rotation_matrix` does: cos·I + (1 − cos)·aaᵀ + sin·[a]×.
pub fn rotation_about(axis: DVec3, angle: f64) -> DMat3 {
    let a = axis / axis.length();
    let (s, c) = angle.sin_cos();
    let mut m = [[0.0; 3]; 3];
    let v = [a.x, a.y, a.z];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = if i == j { c } else { 0.0 } + v[i] * v[j] * (1.0 - c);
        }
    }
    let (sx, sy, sz) = (a.x * s, a.y * s, a.z * s);
    m[0][1] += -sz;
    m[0][2] += sy;
    m[1][0] += sz;
    m[1][2] += -sx;
    m[2][0] += -sy;
    m[2][1] += sx;
    DMat3::from_cols_array_2d(&m).transpose()
}

/// The symmetry set of an object (`misc.get_symmetry_transformations`):
/// identity and the discrete symmetries, each combined with every sample
/// of the continuous ones (ceil(π / step) samples over a full turn).
pub fn symmetries(info: &ModelInfo, max_sym_disc_step: f64) -> Vec<Symmetry> {
    let mut disc = vec![Symmetry::IDENTITY];
    for m in &info.symmetries_discrete {
        let r = DMat3::from_cols_array(&[m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10]]);
        disc.push(Symmetry { r, t: DVec3::new(m[3], m[7], m[11]) });
    }
    let mut cont = Vec::new();
    for s in &info.symmetries_continuous {
        let steps = (std::f64::consts::PI / max_sym_disc_step).ceil() as usize;
        let step = 2.0 * std::f64::consts::PI / steps as f64;
        for i in 0..steps {
            let r = rotation_about(s.axis, i as f64 * step);
            cont.push(Symmetry { r, t: -(r * s.offset) + s.offset });
        }
    }
    if cont.is_empty() {
        return disc;
    }
    let mut out = Vec::with_capacity(disc.len() * cont.len());
    for d in &disc {
        for c in &cont {
            out.push(Symmetry { r: c.r * d.r, t: c.r * d.t + c.t });
        }
    }
    out
}

#[inline]
fn apply(p: &PoseMm, x: DVec3) -> DVec3 {
    p.r * x + p.t
}

/// The ground-truth pose moved by a symmetry: R_g·S_R, R_g·S_t + t_g.
#[inline]
pub fn symmetric_pose(gt: &PoseMm, s: &Symmetry) -> PoseMm {
    PoseMm { r: gt.r * s.r, t: gt.r * s.t + gt.t }
}

/// Maximum Symmetry-aware Surface Distance: min over symmetries of the
/// largest distance between corresponding model points.
pub fn mssd(est: &PoseMm, gt: &PoseMm, pts: &[DVec3], syms: &[Symmetry]) -> f64 {
    py_min(syms.iter().map(|s| {
        let g = symmetric_pose(gt, s);
        np_max(pts.iter().map(|&x| (apply(est, x) - apply(&g, x)).length()))
    }))
}

/// numpy's `max` of distances: NaN when any is NaN (a point or projection
/// that overflowed), which no threshold accepts. A plain `f64::max` fold
/// drops NaN and would score such an estimate 0, i.e. perfect.
fn np_max(v: impl Iterator<Item = f64>) -> f64 {
    v.fold(0.0, |m, x| if m.is_nan() || x.is_nan() { f64::NAN } else { m.max(x) })
}

/// Python's `min` of the per-symmetry errors, as the toolkit takes it: the
/// first, replaced by each later one that is smaller (a NaN first stays, a
/// later NaN never replaces).
fn py_min(v: impl Iterator<Item = f64>) -> f64 {
    let mut it = v;
    let Some(mut m) = it.next() else { return f64::INFINITY };
    for x in it {
        if x < m {
            m = x;
        }
    }
    m
}

/// Projection matrix P = K·[R | t] (3×4), as `misc.project_pts` builds it.
fn projection(k: &[f64; 9], p: &PoseMm) -> [[f64; 4]; 3] {
    let r = p.r_row_major();
    let rt = [[r[0], r[1], r[2], p.t.x], [r[3], r[4], r[5], p.t.y], [r[6], r[7], r[8], p.t.z]];
    let mut out = [[0.0; 4]; 3];
    for i in 0..3 {
        for j in 0..4 {
            out[i][j] = k[i * 3] * rt[0][j] + k[i * 3 + 1] * rt[1][j] + k[i * 3 + 2] * rt[2][j];
        }
    }
    out
}

#[inline]
fn project(p: &[[f64; 4]; 3], x: DVec3) -> (f64, f64) {
    let h = |r: &[f64; 4]| r[0] * x.x + r[1] * x.y + r[2] * x.z + r[3];
    let z = h(&p[2]);
    (h(&p[0]) / z, h(&p[1]) / z)
}

/// A pose seen through a camera: model point → pixel.
enum Projector<'a> {
    /// `cam_K`: P = K·[R | t] applied at once, as `misc.project_pts`.
    Pinhole([[f64; 4]; 3]),
    /// A lens model: the point moved to the camera frame, then projected,
    /// as the toolkit's `pose_error_htt.project_pts_htt`.
    Lens(&'a LensCamera, PoseMm),
}

impl Projector<'_> {
    fn new<'a>(camera: &'a Projection, pose: &PoseMm) -> Projector<'a> {
        match camera {
            Projection::Pinhole(k) => Projector::Pinhole(projection(k, pose)),
            Projection::Lens(l) => Projector::Lens(l, *pose),
        }
    }

    #[inline]
    fn at(&self, x: DVec3) -> (f64, f64) {
        match self {
            Projector::Pinhole(p) => project(p, x),
            Projector::Lens(l, pose) => {
                let [u, v] = l.project(apply(pose, x));
                (u, v)
            }
        }
    }
}

/// Maximum Symmetry-aware Projection Distance (pixels) through `camera`:
/// a pinhole `cam_K`, or a lens model (HOT3D's fisheyes) as the toolkit
/// projects it with the Hand Tracking Toolkit.
pub fn mspd(est: &PoseMm, gt: &PoseMm, camera: &Projection, pts: &[DVec3], syms: &[Symmetry]) -> f64 {
    let pe = Projector::new(camera, est);
    let proj_est: Vec<(f64, f64)> = pts.iter().map(|&x| pe.at(x)).collect();
    py_min(syms.iter().map(|s| {
        let pg = Projector::new(camera, &symmetric_pose(gt, s));
        np_max(pts.iter().zip(&proj_est).map(|(&x, e)| {
            let g = pg.at(x);
            ((e.0 - g.0).powi(2) + (e.1 - g.1).powi(2)).sqrt()
        }))
    }))
}

/// Sum of `v` by pairwise summation, in numpy's order (blocks of up to 128
/// summed in eight interleaved partial sums, halved above that): the
/// toolkit's ADD and ADI are numpy means. A plain running sum of a
/// model's thousands of distances carries about 1e-11 mm of rounding,
/// enough to put an error that lies exactly on the threshold on the other
/// side of it from the toolkit's.
pub fn pairwise_sum(v: &[f64]) -> f64 {
    const BLOCK: usize = 128;
    let n = v.len();
    if n < 8 {
        return v.iter().fold(0.0, |s, x| s + x);
    }
    if n <= BLOCK {
        let mut r: [f64; 8] = v[..8].try_into().expect("eight");
        let whole = n - n % 8;
        for chunk in v[8..whole].chunks_exact(8) {
            for (acc, x) in r.iter_mut().zip(chunk) {
                *acc += x;
            }
        }
        let head = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        return v[whole..].iter().fold(head, |s, x| s + x);
    }
    let half = n / 2 - (n / 2) % 8;
    pairwise_sum(&v[..half]) + pairwise_sum(&v[half..])
}

/// `numpy.mean` of `v`: [`pairwise_sum`] over the count; 0 for none.
pub fn np_mean(v: &[f64]) -> f64 {
    if v.is_empty() { 0.0 } else { pairwise_sum(v) / v.len() as f64 }
}

/// Average Distance of model points (Hinterstoisser et al.): mean distance
/// between corresponding points.
pub fn add(est: &PoseMm, gt: &PoseMm, pts: &[DVec3]) -> f64 {
    np_mean(&pts.iter().map(|&x| (apply(est, x) - apply(gt, x)).length()).collect::<Vec<_>>())
}

/// ADI: mean distance from each ground-truth point to the nearest
/// estimated point. `tree` indexes the model points in the model frame
/// (a rigid motion keeps nearest neighbours); the distance itself is taken
/// between the transformed points, as the toolkit does. An estimated
/// rotation that is not orthonormal (results files allow a few per cent)
/// does not keep them, so its points are indexed where they are.
pub fn adi(est: &PoseMm, gt: &PoseMm, pts: &[DVec3], tree: &PointTree) -> f64 {
    if pts.is_empty() {
        return 0.0;
    }
    let gram = est.r.transpose() * est.r - DMat3::IDENTITY;
    if gram.to_cols_array().iter().any(|e| e.abs() > RIGID_TOLERANCE) {
        let moved: Vec<DVec3> = pts.iter().map(|&x| apply(est, x)).collect();
        let tree = PointTree::new(&moved);
        return np_mean(&pts.iter().map(|&x| (moved[tree.nearest(apply(gt, x))] - apply(gt, x)).length()).collect::<Vec<_>>());
    }
    let inv = est.r.inverse();
    np_mean(
        &pts.iter()
            .map(|&x| {
                let q = apply(gt, x);
                let nn = tree.nearest(inv * (q - est.t));
                (apply(est, pts[nn]) - q).length()
            })
            .collect::<Vec<_>>(),
    )
}

/// Largest |RᵀR − I| entry up to which a rotation is taken as rigid for
/// the nearest-neighbour search: results files print rotations to 6-9
/// digits (|RᵀR − I| up to a few 1e-6), and below 1e-4 the neighbour found
/// in the model frame can differ from the camera frame's only between two
/// points within 0.1 mm per metre of the same distance, which changes the
/// error by less than that; past it the points are indexed where they are.
const RIGID_TOLERANCE: f64 = 1e-4;

/// Rotation error in degrees: acos((tr(R_e R_g⁻¹) − 1) / 2).
pub fn re(est: &DMat3, gt: &DMat3) -> f64 {
    let m = *est * gt.inverse();
    let c = (0.5 * (m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0)).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// Translation error: ‖t_e − t_g‖.
pub fn te(est: DVec3, gt: DVec3) -> f64 {
    (gt - est).length()
}

/// The toolkit's shortcut for MSSD, ADD, ADI: the bounding spheres overlap
/// (centre distance below the diameter); otherwise the error is infinite.
pub fn spheres_overlap(est: DVec3, gt: DVec3, diameter: f64) -> bool {
    (est - gt).length() < diameter
}

/// The toolkit's shortcut for VSD (`misc.overlapping_sphere_projections`,
/// approximate): do the projections of two spheres of `radius` around the
/// two centres overlap? VSD is 1 when they do not.
pub fn sphere_projections_overlap(radius: f64, a: DVec3, b: DVec3) -> bool {
    if a.z == 0.0 || b.z == 0.0 {
        return false;
    }
    let pa = a / a.z;
    let pb = b / b.z;
    let d = ((pa.x - pb.x).powi(2) + (pa.y - pb.y).powi(2)).sqrt();
    d < radius * (1.0 / a.z + 1.0 / b.z)
}

/// Exact nearest-neighbour search over model points (an R*-tree from the
/// `rstar` crate; ADI needs the true nearest point, not an approximation).
pub struct PointTree {
    tree: rstar::RTree<rstar::primitives::GeomWithData<[f64; 3], usize>>,
}

impl PointTree {
    pub fn new(pts: &[DVec3]) -> PointTree {
        let items = pts.iter().enumerate().map(|(i, p)| rstar::primitives::GeomWithData::new(p.to_array(), i)).collect();
        PointTree { tree: rstar::RTree::bulk_load(items) }
    }

    /// Index of the point nearest to `q`.
    pub fn nearest(&self, q: DVec3) -> usize {
        self.tree.nearest_neighbor(&q.to_array()).map(|g| g.data).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_overflowing_projection_is_nan_not_zero() {
        // An estimate metres beyond f64's range projects to NaN: no
        // threshold may accept it (a plain max fold made it 0 px, perfect).
        let k = [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0];
        let pts = [DVec3::new(10.0, 0.0, 0.0), DVec3::new(0.0, 10.0, 5.0)];
        let gt = PoseMm { r: DMat3::IDENTITY, t: DVec3::new(0.0, 0.0, 500.0) };
        let far = PoseMm { r: DMat3::IDENTITY, t: DVec3::new(f64::INFINITY, 0.0, 1.0) };
        assert!(mspd(&far, &gt, &Projection::Pinhole(k), &pts, &[Symmetry::IDENTITY]).is_nan());
        assert!(mssd(&far, &gt, &pts, &[Symmetry::IDENTITY]).is_infinite());
        // Python's min over symmetries: a NaN first stays, a later one does not win.
        assert!(py_min([f64::NAN, 1.0].into_iter()).is_nan());
        assert_eq!(py_min([2.0, f64::NAN, 1.0].into_iter()), 1.0);
    }

    fn pose(r: DMat3, t: DVec3) -> PoseMm {
        PoseMm { r, t }
    }

    fn cube_points() -> Vec<DVec3> {
        let mut v = Vec::new();
        for x in [-1.0, 1.0] {
            for y in [-1.0, 1.0] {
                for z in [-1.0, 1.0] {
                    v.push(DVec3::new(x, y, z) * 10.0);
                }
            }
        }
        v
    }

    #[test]
    fn translation_only_errors_by_hand() {
        let pts = cube_points();
        let gt = pose(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 1000.0));
        let est = pose(DMat3::IDENTITY, DVec3::new(3.0, 4.0, 1000.0));
        let ident = [Symmetry::IDENTITY];
        assert!((add(&est, &gt, &pts) - 5.0).abs() < 1e-12);
        assert!((mssd(&est, &gt, &pts, &ident) - 5.0).abs() < 1e-12);
        assert!((te(est.t, gt.t) - 5.0).abs() < 1e-12);
        assert!(re(&est.r, &gt.r).abs() < 1e-9);
        // f = 500 px at 1 m: a 3 mm x shift and 4 mm y shift project to 1.5 and 2 px.
        let k = [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0];
        let e = mspd(&est, &gt, &Projection::Pinhole(k), &pts, &ident);
        // Points at z = 990 and 1010: the largest shift is at z = 990.
        let want = 500.0 * 5.0 / 990.0;
        assert!((e - want).abs() < 1e-9, "{e} vs {want}");
        // ADI over the cube's corners: every shifted corner's nearest is its own.
        assert!((adi(&est, &gt, &pts, &PointTree::new(&pts)) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn rotation_errors_by_hand() {
        let pts = vec![DVec3::new(10.0, 0.0, 0.0), DVec3::new(-10.0, 0.0, 0.0)];
        let gt = pose(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 500.0));
        let est = pose(rotation_about(DVec3::Z, std::f64::consts::FRAC_PI_2), gt.t);
        // Each point moves on a quarter circle of radius 10: chord 10·√2.
        assert!((add(&est, &gt, &pts) - 10.0 * 2f64.sqrt()).abs() < 1e-9);
        assert!((re(&est.r, &gt.r) - 90.0).abs() < 1e-9);
        // A 180° turn swaps the two points: ADD is 20, ADI 0.
        let flip = pose(rotation_about(DVec3::Z, std::f64::consts::PI), gt.t);
        assert!((add(&flip, &gt, &pts) - 20.0).abs() < 1e-9);
        assert!(adi(&flip, &gt, &pts, &PointTree::new(&pts)) < 1e-9);
    }

    #[test]
    fn pairwise_sum_is_numpys_and_exact_on_equal_terms() {
        // 5,000 equal distances: the running sum drifts off by about 1e-11,
        // the pairwise one (numpy's, as the toolkit sums) does not.
        let d = 16.4627588;
        let v = vec![d; 5000];
        let running = v.iter().sum::<f64>() / 5000.0;
        assert!((super::pairwise_sum(&v) / 5000.0 - d).abs() <= 4.0 * f64::EPSILON * d);
        assert!((running - d).abs() > 1e-13, "{running}");
        // Small and odd lengths are summed whole.
        for n in [0usize, 1, 7, 8, 9, 127, 128, 129, 1000] {
            let v: Vec<f64> = (0..n).map(|i| i as f64 * 0.5).collect();
            assert_eq!(super::pairwise_sum(&v), (n * n.saturating_sub(1)) as f64 / 4.0, "n = {n}");
        }
    }

    #[test]
    fn adi_of_a_non_rigid_rotation_is_the_toolkits() {
        // A grid of points and an estimate 4 % off orthonormal: the toolkit
        // takes the nearest neighbour among the estimated points in the
        // camera frame; brute force here.
        let pts: Vec<DVec3> = (0..125).map(|i| DVec3::new((i % 5) as f64, ((i / 5) % 5) as f64, (i / 25) as f64 * 1.7) * 9.0).collect();
        let gt = pose(rotation_about(DVec3::Z, 0.3), DVec3::new(5.0, -3.0, 600.0));
        let mut est = pose(rotation_about(DVec3::X, 0.2) * rotation_about(DVec3::Z, 0.25), DVec3::new(6.0, -2.0, 603.0));
        est.r.x_axis *= 1.04;
        let brute = pts
            .iter()
            .map(|&x| {
                let q = apply(&gt, x);
                pts.iter().map(|&y| (apply(&est, y) - q).length()).fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / pts.len() as f64;
        assert!((adi(&est, &gt, &pts, &PointTree::new(&pts)) - brute).abs() < 1e-9);
    }

    #[test]
    fn flipped_symmetric_object_is_correct_only_with_its_symmetry() {
        let pts = cube_points().into_iter().map(|p| DVec3::new(p.x * 3.0, p.y, p.z)).collect::<Vec<_>>();
        let gt = pose(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 800.0));
        let est = pose(rotation_about(DVec3::Z, std::f64::consts::PI), gt.t);
        let flip = [-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let sym = ModelInfo { diameter: 66.3, symmetries_discrete: vec![flip], symmetries_continuous: vec![] };
        let plain = ModelInfo { symmetries_discrete: vec![], ..sym.clone() };
        let k = [572.0, 0.0, 320.0, 0.0, 573.0, 240.0, 0.0, 0.0, 1.0];
        assert!(mssd(&est, &gt, &pts, &symmetries(&sym, MAX_SYM_DISC_STEP)) < 1e-9);
        assert!(mspd(&est, &gt, &Projection::Pinhole(k), &pts, &symmetries(&sym, MAX_SYM_DISC_STEP)) < 1e-9);
        assert!(mssd(&est, &gt, &pts, &symmetries(&plain, MAX_SYM_DISC_STEP)) > 60.0);
        assert!(mspd(&est, &gt, &Projection::Pinhole(k), &pts, &symmetries(&plain, MAX_SYM_DISC_STEP)) > 40.0);
    }

    #[test]
    fn continuous_symmetry_is_sampled_within_the_step() {
        let info = ModelInfo {
            diameter: 100.0,
            symmetries_discrete: vec![],
            symmetries_continuous: vec![crate::bop::ContinuousSymmetry { axis: DVec3::Z, offset: DVec3::ZERO }],
        };
        let syms = symmetries(&info, MAX_SYM_DISC_STEP);
        assert_eq!(syms.len(), 315); // ceil(π / 0.01)
                                     // A cylinder-like point set turned by an arbitrary angle about its axis
                                     // is within one step's chord of a sample: 2π/315 rad at radius 50.
        let pts: Vec<DVec3> = (0..36).map(|i| DVec3::new(50.0 * (i as f64).cos(), 50.0 * (i as f64).sin(), 10.0)).collect();
        let gt = pose(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 700.0));
        let est = pose(rotation_about(DVec3::Z, 1.234), gt.t);
        let e = mssd(&est, &gt, &pts, &syms);
        assert!(e <= 50.0 * std::f64::consts::PI / 315.0 + 1e-9, "{e}");
    }

    #[test]
    fn shortcuts() {
        assert!(spheres_overlap(DVec3::ZERO, DVec3::new(99.0, 0.0, 0.0), 100.0));
        assert!(!spheres_overlap(DVec3::ZERO, DVec3::new(100.0, 0.0, 0.0), 100.0));
        let a = DVec3::new(0.0, 0.0, 1000.0);
        assert!(sphere_projections_overlap(50.0, a, DVec3::new(99.0, 0.0, 1000.0)));
        assert!(!sphere_projections_overlap(50.0, a, DVec3::new(100.0, 0.0, 1000.0)));
        assert!(!sphere_projections_overlap(50.0, a, DVec3::new(0.0, 0.0, 0.0)));
    }
}
