//! The contact classifier (eq. 6-9, 13) and the support-polygon stability,
//! as the CPU twin. The GPU kernel (`shaders/contacts.wgsl`, dispatched by
//! [`super::gpu`]) computes the same per-sample classification from the
//! trilinear grid values; the twin uses the same grid values and refines
//! every sample whose grid value lies within the grid's error bound of the
//! contact band (|δ| < ε + bound) with the exact distance, so its
//! intersecting / contact / supported sets are exact.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use super::scene::Plane;
use super::sdf::{Distance, SdfGrid};
use super::support;
use crate::error::{Error, Result};
use crate::pose::Pose;

/// A supported point's closest scene normal must satisfy `n · ĝ < −SUPPORT_COS`
/// (eq. 13 asks for `< 0`; the small slack keeps contacts with vertical walls,
/// where rounding puts `n · ĝ` a hair below zero, out of the support set).
pub const SUPPORT_COS: f64 = 1e-3;

/// What one surface sample is (eq. 6, 7, 13).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleClass {
    /// δ ≥ ε: away from the scene.
    Free,
    /// δ < −ε.
    Intersecting,
    /// |δ| < ε, the closest scene normal does not oppose gravity.
    Contact,
    /// |δ| < ε and the closest scene normal opposes gravity.
    Supported,
}

/// Running counts of the critical point sets (eq. 6, 7, 13) of one pose:
/// shared by the CPU twin and the GPU path's exact refinement.
#[derive(Default)]
pub(crate) struct Tally {
    pub intersecting: u32,
    pub contact: u32,
    /// World positions of the supported points.
    pub supported: Vec<DVec3>,
}

impl Tally {
    pub fn add(&mut self, class: SampleClass, x: DVec3) {
        match class {
            SampleClass::Intersecting => self.intersecting += 1,
            SampleClass::Contact => self.contact += 1,
            SampleClass::Supported => {
                self.contact += 1;
                self.supported.push(x);
            }
            SampleClass::Free => {}
        }
    }
}

/// Per-object verdict, decided in this order: intersecting (|I| > 0),
/// floating (|C| = 0), unstable (centre of mass not strictly inside the
/// support polygon), plausible.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Plausible,
    Floating,
    Intersecting,
    Unstable,
}

impl Verdict {
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Plausible => "plausible",
            Verdict::Floating => "floating",
            Verdict::Intersecting => "intersecting",
            Verdict::Unstable => "unstable",
        }
    }
}

/// An obstacle: a baked grid placed in the world (model to world pose).
#[derive(Clone, Debug)]
pub struct Obstacle {
    pub sdf: Arc<SdfGrid>,
    pub pose: Pose,
}

/// What a posed object is checked against: planes, other objects, gravity.
#[derive(Clone, Debug)]
pub struct Environment {
    pub planes: Vec<Plane>,
    pub obstacles: Vec<Obstacle>,
    pub gravity: DVec3,
}

impl Environment {
    /// Largest trilinear error bound of the obstacles' grids (0 without).
    pub fn error_bound(&self) -> f64 {
        self.obstacles
            .iter()
            .map(|o| o.sdf.error_bound())
            .fold(0.0, f64::max)
    }

    /// Checks ε is usable with these grids: positive, and ε plus the error
    /// bound inside every grid's margin (else points outside a grid could
    /// be contacts the grid cannot see).
    pub fn check_epsilon(&self, eps: f64) -> Result<()> {
        if !(eps.is_finite() && eps > 0.0) {
            return Err(Error::InvalidInput(format!(
                "ε must be a positive number of metres, got {eps}"
            )));
        }
        for o in &self.obstacles {
            if eps + o.sdf.error_bound() > o.sdf.margin {
                return Err(Error::InvalidInput(format!(
                    "ε = {eps} m plus the grid error bound {:.2e} m exceeds the grid margin {:.3} m; use a smaller ε",
                    o.sdf.error_bound(),
                    o.sdf.margin
                )));
            }
        }
        Ok(())
    }

    /// Signed distance and closest normal at world point `x` from the grid
    /// values alone (what the GPU computes, in f64).
    pub fn grid_distance(&self, x: DVec3) -> Distance {
        self.distance(x, None)
    }

    /// Signed distance at `x` with exact refinement of every obstacle whose
    /// grid value is within the error bound of the band |δ| < `eps`.
    pub fn refined_distance(&self, x: DVec3, eps: f64) -> Distance {
        self.distance(x, Some(eps))
    }

    fn distance(&self, x: DVec3, refine: Option<f64>) -> Distance {
        let mut best = Distance {
            delta: f64::INFINITY,
            normal: DVec3::ZERO,
        };
        for p in &self.planes {
            let d = p.distance(x);
            if d < best.delta {
                best = Distance {
                    delta: d,
                    normal: p.normal,
                };
            }
        }
        for o in &self.obstacles {
            let rt = o.pose.r.transpose();
            let q = rt * (x - o.pose.t);
            let (n, d) = o.sdf.trilinear(q);
            let cand = match refine {
                Some(eps) if d.abs() < eps + o.sdf.error_bound() => {
                    let e = o.sdf.exact(q);
                    Distance {
                        delta: e.delta,
                        normal: o.pose.r * e.normal,
                    }
                }
                _ => Distance {
                    delta: d,
                    normal: o.pose.r * n.normalize_or_zero(),
                },
            };
            if cand.delta < best.delta {
                best = cand;
            }
        }
        best
    }
}

/// Classifies one sample with signed distance `d` and closest normal `n`.
pub fn classify(d: f64, n: DVec3, eps: f64, gravity_dir: DVec3) -> SampleClass {
    if d < -eps {
        SampleClass::Intersecting
    } else if d.abs() < eps {
        if n.dot(gravity_dir) < -SUPPORT_COS {
            SampleClass::Supported
        } else {
            SampleClass::Contact
        }
    } else {
        SampleClass::Free
    }
}

/// An object prepared for checks: surface samples and centre of mass
/// (model frame), and its ε.
#[derive(Clone, Debug)]
pub struct Body {
    pub samples: Vec<DVec3>,
    pub com: DVec3,
    pub epsilon: f64,
}

/// The physical plausibility of one pose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluation {
    /// |I|: samples with δ < −ε.
    pub intersecting: u32,
    /// |C|: samples with |δ| < ε (supported ones included).
    pub contact: u32,
    /// |S|: contacts whose closest scene normal opposes gravity.
    pub supported: u32,
    /// Smallest δ over the samples (m).
    pub min_distance: f64,
    /// |C| > 0 and |I| = 0.
    pub feasible: bool,
    /// Signed distance (m) from the projected centre of mass to the support
    /// polygon's boundary, negative outside; `None` without supported points.
    pub stability_margin: Option<f64>,
    /// Feasible and margin > 0.
    pub stable: bool,
    pub verdict: Verdict,
}

/// Per-sample detail of an evaluation (for explanations).
#[derive(Clone, Debug)]
pub struct Detail {
    pub world: Vec<DVec3>,
    pub delta: Vec<f64>,
    /// Unit normal of the closest scene point (world frame).
    pub normal: Vec<DVec3>,
    pub classes: Vec<SampleClass>,
    /// Support polygon and projected centre of mass in the support-plane
    /// basis of [`support::support_basis`].
    pub hull: Vec<DVec2>,
    pub com: DVec2,
    pub com_world: DVec3,
}

/// Completes an evaluation from counts, the minimum δ and the supported
/// points (world frame).
pub fn finish(
    intersecting: u32,
    contact: u32,
    min_distance: f64,
    supported: &[DVec3],
    com_world: DVec3,
    gravity: DVec3,
) -> (Evaluation, Vec<DVec2>, DVec2) {
    let (hull, c, margin) = support::stability(supported, com_world, gravity);
    let feasible = contact > 0 && intersecting == 0;
    let stable = feasible && margin.is_some_and(|m| m > 0.0);
    let verdict = if intersecting > 0 {
        Verdict::Intersecting
    } else if contact == 0 {
        Verdict::Floating
    } else if !stable {
        Verdict::Unstable
    } else {
        Verdict::Plausible
    };
    let e = Evaluation {
        intersecting,
        contact,
        supported: supported.len() as u32,
        min_distance,
        feasible,
        stability_margin: margin,
        stable,
        verdict,
    };
    (e, hull, c)
}

/// The CPU twin for one pose, with per-sample detail.
pub fn evaluate_detailed(body: &Body, pose: &Pose, env: &Environment) -> (Evaluation, Detail) {
    let g = env.gravity.normalize();
    let eps = body.epsilon;
    let mut det = Detail {
        world: Vec::with_capacity(body.samples.len()),
        delta: Vec::with_capacity(body.samples.len()),
        normal: Vec::with_capacity(body.samples.len()),
        classes: Vec::with_capacity(body.samples.len()),
        hull: Vec::new(),
        com: DVec2::ZERO,
        com_world: pose.transform_point(body.com),
    };
    let mut tally = Tally::default();
    let mut min = f64::INFINITY;
    for s in &body.samples {
        let x = pose.transform_point(*s);
        let d = env.refined_distance(x, eps);
        let c = classify(d.delta, d.normal, eps, g);
        tally.add(c, x);
        min = min.min(d.delta);
        det.world.push(x);
        det.delta.push(d.delta);
        det.normal.push(d.normal);
        det.classes.push(c);
    }
    let (e, hull, c) = finish(tally.intersecting, tally.contact, min, &tally.supported, det.com_world, env.gravity);
    det.hull = hull;
    det.com = c;
    (e, det)
}

/// The CPU twin for one pose.
pub fn evaluate(body: &Body, pose: &Pose, env: &Environment) -> Evaluation {
    evaluate_detailed(body, pose, env).0
}

/// The CPU twin for a batch of poses, in parallel over poses.
pub fn evaluate_batch(body: &Body, poses: &[Pose], env: &Environment) -> Vec<Evaluation> {
    poses.par_iter().map(|p| evaluate(body, p, env)).collect()
}

/// Signed distances of every sample of every pose, exact near the band
/// (for the GPU comparison and the benchmark: pure queries, no hull).
pub fn distances_batch(body: &Body, poses: &[Pose], env: &Environment) -> Vec<f64> {
    poses
        .par_iter()
        .flat_map_iter(|p| {
            body.samples.iter().map(move |s| {
                env.refined_distance(p.transform_point(*s), body.epsilon)
                    .delta
            })
        })
        .collect()
}

impl Body {
    /// Samples `mesh` (`count` points, `seed`), takes the volumetric centre
    /// of mass from the closed mesh, and ε from `epsilon` or the default
    /// for the sample spacing ([`super::samples::default_epsilon`]).
    pub fn new(
        mesh: &crate::mesh::Mesh,
        count: usize,
        seed: u64,
        epsilon: Option<f64>,
    ) -> Result<Body> {
        let samples = super::samples::surface_samples(mesh, count, seed)?;
        let (mass, _) = crate::mesh::mass::MassProperties::of_mesh(mesh)?;
        let spacing = super::samples::sample_spacing(mesh.area(), count);
        let eps = epsilon.unwrap_or_else(|| super::samples::default_epsilon(spacing));
        if !(eps.is_finite() && eps > 0.0) {
            return Err(Error::InvalidInput(format!(
                "ε must be a positive number of metres, got {eps}"
            )));
        }
        // Samples farther apart than 2ε can all miss the strip of a face
        // that touches the support: a resting pose then reads as floating
        // (the demo's duck at 1-3 samples; 3 made an intersecting pose
        // "unstable", ranked first).
        if spacing > 2.0 * eps {
            let enough = (mesh.area() / (2.0 * eps).powi(2)).ceil();
            tracing::warn!(
                "{count} surface samples lie {:.1} mm apart on this object, more than twice the contact tolerance ε = {:.1} mm: contacts can go unseen (take at least {enough} samples, or a larger ε)",
                spacing * 1e3,
                eps * 1e3
            );
        }
        Ok(Body {
            samples,
            com: mass.com,
            epsilon: eps,
        })
    }
}
