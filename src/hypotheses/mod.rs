//! Pose hypothesis generators (seeded: the same seed gives the same poses).
//!
//! - [`on_plane`]: stable resting poses × yaw × in-plane position from the
//!   segmented depth, for an object on a support plane (paper section 3.1).
//! - [`around_and_random`]: the demo's and benchmark's synthetic set.

pub mod on_plane;

use glam::{DMat3, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::pose::{axis_angle, Pose};
use crate::synth::gaussian;

/// A uniformly random rotation (Shoemake's method via a uniform quaternion).
pub fn random_rotation(rng: &mut impl Rng) -> DMat3 {
    let q = DQuat::from_xyzw(gaussian(rng), gaussian(rng), gaussian(rng), gaussian(rng)).normalize();
    DMat3::from_quat(q)
}

/// A uniformly random unit vector.
pub fn random_axis(rng: &mut impl Rng) -> DVec3 {
    loop {
        let v = DVec3::new(gaussian(rng), gaussian(rng), gaussian(rng));
        if v.length_squared() > 1e-12 {
            return v.normalize();
        }
    }
}

/// The demo's and benchmark's hypothesis set: `truth` first, then half of
/// the rest perturbed around it (rotation 2-30° about a random axis,
/// translation up to ±1 cm per axis), the other half with uniformly random
/// rotations at the true translation ±1 cm.
pub fn around_and_random(truth: &Pose, n: usize, seed: u64) -> Vec<Pose> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(n);
    if n == 0 {
        return out;
    }
    out.push(*truth);
    let near = n / 2;
    for i in 1..n {
        let dt = DVec3::new(
            rng.random_range(-0.01..0.01),
            rng.random_range(-0.01..0.01),
            rng.random_range(-0.01..0.01),
        );
        let r = if i < near {
            let angle = rng.random_range(2f64.to_radians()..30f64.to_radians());
            axis_angle(random_axis(&mut rng), angle) * truth.r
        } else {
            random_rotation(&mut rng)
        };
        out.push(Pose::new(r, truth.t + dt));
    }
    out
}
