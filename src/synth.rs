//! Synthetic observations for the demo, tests and benchmarks: a mesh
//! rendered at a known pose, with documented sensor noise.
//!
//! Noise model (a structured-light / time-of-flight sensor at ~0.7 m):
//! - Gaussian depth noise with standard deviation `sigma` (default 1 mm),
//! - a fraction `dropout` of pixels (default 5 %) missing (depth 0),
//! - depth stored as BOP 16-bit millimetres (quantized to 1 mm) when saved.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::camera::Intrinsics;
use crate::kernels::raster::render_cpu;
use crate::kernels::RenderMesh;
use crate::observation::DepthImage;
use crate::pose::Pose;

/// Sensor noise of a synthetic observation.
#[derive(Clone, Copy, Debug)]
pub struct SensorNoise {
    /// Standard deviation of additive depth noise (m).
    pub sigma: f64,
    /// Fraction of pixels with no measurement.
    pub dropout: f64,
}

impl Default for SensorNoise {
    fn default() -> Self {
        SensorNoise { sigma: 0.001, dropout: 0.05 }
    }
}

/// LINEMOD / LM-O intrinsics (640 x 480), the camera of the demo.
pub fn linemod_camera() -> Intrinsics {
    Intrinsics { fx: 572.4114, fy: 573.57043, cx: 325.2611, cy: 242.04899, width: 640, height: 480 }
}

/// A standard normal sample (Box-Muller).
pub fn gaussian(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Renders `mesh` at `pose` and adds `noise`; returns the depth image and the
/// object's mask (the noise-free silhouette, as a segmentation would give).
pub fn observe(mesh: &RenderMesh, pose: &Pose, k: &Intrinsics, noise: SensorNoise, seed: u64) -> (DepthImage, Vec<bool>) {
    let img = render_cpu(mesh, pose, k);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mask: Vec<bool> = img.depth.iter().map(|&d| d > 0.0).collect();
    let depth = img
        .depth
        .iter()
        .map(|&d| {
            if d <= 0.0 {
                return 0.0;
            }
            let n = gaussian(&mut rng) * noise.sigma;
            if rng.random::<f64>() < noise.dropout {
                0.0
            } else {
                (d as f64 + n).max(0.0) as f32
            }
        })
        .collect();
    (DepthImage { intrinsics: *k, depth }, mask)
}
