//! Static equilibrium with friction (eq. 10-12): can contact forces inside
//! friction cones at the contact points balance gravity and its torque about
//! the centre of mass?
//!
//! A second-order-cone feasibility problem solved with Clarabel (an
//! interior-point conic solver): per contact i a force
//! `f_i = a_i n_i + b_i t_i + c_i u_i` in the contact's frame (n_i the scene
//! normal at the closest point, pointing into free space, i.e. onto the
//! object), with `‖(b_i, c_i)‖ ≤ μ a_i` (Coulomb cone, eq. 12), and
//! `Σ f_i = −m g` (eq. 10), `Σ (x_i − c_m) × f_i = 0` (eq. 11). Forces are
//! in units of the weight and lever arms in units of the object's size, so
//! the problem is well scaled for any mass and size.
//!
//! Unlike the support polygon, this also holds for contacts that are not on
//! one plane (objects leaning on each other), and it uses every contact,
//! not only the supported ones; on contacts that all lie on one horizontal
//! plane the two agree (friction cannot produce a torque about a horizontal
//! axis there).

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use glam::DVec3;

/// Default friction coefficient μ (the reference value 0.1: cautious, about
/// that of smooth plastic on plastic).
pub const DEFAULT_FRICTION: f64 = 0.1;

/// Whether the contacts can hold the object: `Some(true)` balanced,
/// `Some(false)` no admissible forces exist, `None` when there are no
/// contacts or the solver could not decide (reported, never guessed).
pub fn static_equilibrium(
    points: &[DVec3],
    normals: &[DVec3],
    com: DVec3,
    gravity: DVec3,
    mu: f64,
    scale: f64,
) -> Option<bool> {
    let k = points.len();
    // (Written so that NaN fails too.)
    if k == 0 || normals.len() != k || mu.is_nan() || mu < 0.0 || scale.is_nan() || scale <= 0.0 {
        return None;
    }
    let g = gravity.normalize();
    if mu < FRICTIONLESS_BELOW {
        return frictionless_equilibrium(points, normals, com, g, scale);
    }
    let n_var = 3 * k;
    let (mut rows, mut cols, mut vals) = (Vec::new(), Vec::new(), Vec::new());
    let mut push = |r: usize, c: usize, v: f64| {
        if v != 0.0 {
            rows.push(r);
            cols.push(c);
            vals.push(v);
        }
    };
    for (i, (&x, &n)) in points.iter().zip(normals).enumerate() {
        let n = n.normalize_or_zero();
        if n == DVec3::ZERO {
            return None;
        }
        let helper = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let t = (helper - n * helper.dot(n)).normalize();
        let u = n.cross(t);
        let r = (x - com) / scale;
        for (j, axis) in [n, t, u].into_iter().enumerate() {
            let col = 3 * i + j;
            // Force balance rows 0-2, torque balance rows 3-5.
            let torque = r.cross(axis);
            for d in 0..3 {
                push(d, col, axis[d]);
                push(3 + d, col, torque[d]);
            }
        }
        // Cone rows: s = (μ a, b, c) = −A x.
        let base = 6 + 3 * i;
        push(base, 3 * i, -mu);
        push(base + 1, 3 * i + 1, -1.0);
        push(base + 2, 3 * i + 2, -1.0);
    }
    let m = 6 + 3 * k;
    let a = CscMatrix::new_from_triplets(m, n_var, rows, cols, vals);
    let p = CscMatrix::zeros((n_var, n_var));
    let q = vec![0.0; n_var];
    let mut b = vec![0.0; m];
    b[0] = -g.x;
    b[1] = -g.y;
    b[2] = -g.z;
    let mut cones = vec![SupportedConeT::ZeroConeT(6)];
    cones.extend(std::iter::repeat_n(SupportedConeT::SecondOrderConeT(3), k));
    feasible(&p, &q, &a, &b, &cones)
}

/// Solves the feasibility problem: `Some(true)` feasible, `Some(false)`
/// infeasible, `None` when the solver cannot decide.
fn feasible(p: &CscMatrix<f64>, q: &[f64], a: &CscMatrix<f64>, b: &[f64], cones: &[SupportedConeT<f64>]) -> Option<bool> {
    let settings = DefaultSettingsBuilder::default().verbose(false).max_iter(200).build().ok()?;
    let mut solver = DefaultSolver::new(p, q, a, b, cones, settings).ok()?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => Some(true),
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => Some(false),
        _ => None,
    }
}

/// Below this μ the cones are solved as frictionless contacts (normal
/// forces only, a linear program): a second-order cone of radius ~0 has no
/// interior, and the interior-point solver then reported "balanced" at
/// μ = 0 where every μ from 1e-6 up said not. Treating μ < 1e-6 as 0 keeps
/// feasibility monotone in μ.
pub const FRICTIONLESS_BELOW: f64 = 1e-6;

/// Frictionless contacts: non-negative normal forces alone must balance
/// gravity and its torque.
fn frictionless_equilibrium(points: &[DVec3], normals: &[DVec3], com: DVec3, g: DVec3, scale: f64) -> Option<bool> {
    let k = points.len();
    let (mut rows, mut cols, mut vals) = (Vec::new(), Vec::new(), Vec::new());
    for (i, (&x, &n)) in points.iter().zip(normals).enumerate() {
        let n = n.normalize_or_zero();
        if n == DVec3::ZERO {
            return None;
        }
        let torque = ((x - com) / scale).cross(n);
        for d in 0..3 {
            for (r, v) in [(d, n[d]), (3 + d, torque[d])] {
                if v != 0.0 {
                    rows.push(r);
                    cols.push(i);
                    vals.push(v);
                }
            }
        }
        rows.push(6 + i);
        cols.push(i);
        vals.push(-1.0);
    }
    let a = CscMatrix::new_from_triplets(6 + k, k, rows, cols, vals);
    let p = CscMatrix::zeros((k, k));
    let q = vec![0.0; k];
    let mut b = vec![0.0; 6 + k];
    b[0] = -g.x;
    b[1] = -g.y;
    b[2] = -g.z;
    let cones = [SupportedConeT::ZeroConeT(6), SupportedConeT::NonnegativeConeT(k)];
    feasible(&p, &q, &a, &b, &cones)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64) -> Vec<DVec3> {
        vec![
            DVec3::new(-1.0, -1.0, z),
            DVec3::new(1.0, -1.0, z),
            DVec3::new(1.0, 1.0, z),
            DVec3::new(-1.0, 1.0, z),
        ]
    }

    #[test]
    fn planar_contacts_balance_exactly_when_the_com_is_over_them() {
        let pts = square(0.0);
        let up = vec![DVec3::Z; 4];
        let g = DVec3::new(0.0, 0.0, -9.81);
        assert_eq!(
            static_equilibrium(&pts, &up, DVec3::new(0.3, -0.2, 1.0), g, 0.1, 1.0),
            Some(true)
        );
        assert_eq!(
            static_equilibrium(&pts, &up, DVec3::new(1.3, 0.0, 1.0), g, 0.1, 1.0),
            Some(false)
        );
        // Even a lot of friction cannot help on a plane.
        assert_eq!(
            static_equilibrium(&pts, &up, DVec3::new(1.3, 0.0, 1.0), g, 2.0, 1.0),
            Some(false)
        );
    }

    #[test]
    fn feasibility_is_monotone_in_mu_down_to_zero() {
        // A box leaning against a frictionless wall at 30° from vertical:
        // needs μ_floor ≥ tan(30°)/2 ≈ 0.29 at the foot.
        let angle = 30f64.to_radians();
        let foot = DVec3::ZERO;
        let top = DVec3::new(angle.sin(), 0.0, angle.cos());
        let pts = vec![foot, top];
        let normals = vec![DVec3::Z, -DVec3::X];
        let com = top * 0.5;
        let g = DVec3::new(0.0, 0.0, -9.81);
        let mut prev = Some(false);
        for mu in [0.0, 1e-12, 1e-9, 1e-6, 1e-3, 0.1, 0.28, 0.3, 0.5, 1.0] {
            let r = static_equilibrium(&pts, &normals, com, g, mu, 1.0);
            assert!(r.is_some(), "μ = {mu}: undecided");
            assert!(!(prev == Some(true) && r == Some(false)), "not monotone at μ = {mu}");
            if mu < 0.28 {
                assert_eq!(r, Some(false), "μ = {mu}");
            } else if mu >= 0.3 {
                assert_eq!(r, Some(true), "μ = {mu}");
            }
            prev = r;
        }
    }

    #[test]
    fn leaning_against_a_wall_needs_friction() {
        // A plank leaning on a vertical wall (x = 0, normal +x) with its
        // foot on the floor (normal +z), centre of mass halfway.
        let pts = vec![
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(0.0, 0.2, 1.0),
            DVec3::new(0.5, 0.0, 0.0),
            DVec3::new(0.5, 0.2, 0.0),
        ];
        let n = vec![DVec3::X, DVec3::X, DVec3::Z, DVec3::Z];
        let com = DVec3::new(0.25, 0.1, 0.5);
        let g = DVec3::new(0.0, 0.0, -9.81);
        // Needs μ_floor ≥ tan(angle)/2 = 0.25 at the foot (frictionless wall).
        assert_eq!(static_equilibrium(&pts, &n, com, g, 0.1, 1.0), Some(false));
        assert_eq!(static_equilibrium(&pts, &n, com, g, 0.4, 1.0), Some(true));
    }
}
