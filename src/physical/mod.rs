//! Physical plausibility of object poses (paper section 2.2, eq. 6-13).
//!
//! A posed object is checked against its scene (analytic planes and other
//! objects) through the signed distance δ of surface samples:
//! intersecting δ < −ε (eq. 6), contact |δ| < ε (eq. 7), supported = contact
//! whose closest scene normal opposes gravity (eq. 13). An object is
//! feasible when it has contacts and no intersections (eq. 8-9), and stable
//! when its centre of mass, projected along gravity, falls inside the convex
//! hull of its supported points; the signed distance to that hull's
//! boundary is reported as the stability margin.
//!
//! Modules:
//! - [`scene`]: the scene JSON (world or camera frame) and its validation.
//! - [`samples`]: seeded, area-weighted surface samples and the default ε.
//! - [`sdf`]: signed-distance grids baked on the CPU with exact closest
//!   points, and the exact query used to refine near ±ε.
//! - [`contacts`]: the classifier: the CPU twin (exact near ±ε) and the GPU
//!   kernel (`shaders/contacts.wgsl`, trilinear grid values).
//! - [`support`]: 2D convex hull and signed stability margin.
//! - [`friction`]: static equilibrium with friction cones (eq. 10-12).
//! - [`simulate`]: displacement over a few simulated steps (rapier).
//! - [`explain`]: a top and a side view of a checked scene.
//! - [`batch`]: camera-frame hypotheses on a support plane, and the ranking
//!   rule (physically plausible first).

pub mod batch;
pub mod check;
pub mod contacts;
pub mod explain;
pub mod friction;
pub mod gpu;
pub mod samples;
pub mod scene;
pub mod sdf;
pub mod simulate;
pub mod support;

pub use contacts::{Evaluation, SampleClass, Verdict};
pub use scene::{Plane, Scene, SceneObject};
