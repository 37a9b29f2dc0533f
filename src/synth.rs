//! Synthetic observations for the demo, tests and benchmarks: a mesh
//! rendered at a known pose, with documented sensor noise.
//!
//! Noise model (a structured-light / time-of-flight sensor at ~0.7 m):
//! - Gaussian depth noise with standard deviation `sigma` (default 1 mm),
//! - a fraction `dropout` of pixels (default 5 %) missing (depth 0),
//! - depth stored as BOP 16-bit millimetres (quantized to 1 mm) when saved.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use glam::{DMat3, DVec3};

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::kernels::raster::render_cpu;
use crate::kernels::RenderMesh;
use crate::mesh::Mesh;
use crate::observation::DepthImage;
use crate::physical::Plane;
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

/// The plane with unit normal `up` through the lowest vertex (along `up`) of
/// `mesh` at `pose`: a support plane under a posed object, for benchmarks.
pub fn plane_under(mesh: &Mesh, pose: &Pose, up: DVec3) -> Plane {
    let up = up.normalize();
    let low = mesh.vertices.iter().map(|&v| pose.transform_point(v)).min_by(|p, q| p.dot(up).total_cmp(&q.dot(up)));
    Plane { point: low.unwrap_or(pose.t), normal: up }
}

/// The camera pose (world to camera, OpenCV axes) of a camera at `eye`
/// looking at `target`, with world `up` pointing up in the image.
pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> Result<Pose> {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    if !(z.is_finite() && x.is_finite()) {
        return Err(Error::InvalidInput("look_at: the eye equals the target or looks along `up`".into()));
    }
    let y = z.cross(x);
    let r = DMat3::from_cols(x, y, z).transpose();
    Ok(Pose::new(r, -(r * eye)))
}

/// A tabletop observation: `mesh` at `object` (model to world; the table
/// top is the plane z = 0 of the world, z up) on a square table of side
/// `table_side` metres and 3 cm thickness, seen by a camera at
/// `cam_from_world`. Returns the noisy depth of object and table, the
/// object's mask (its visible, noise-free pixels, as a segmentation would
/// give) and the table plane in the camera frame.
pub fn observe_on_table(
    mesh: &Mesh,
    object: &Pose,
    cam_from_world: &Pose,
    k: &Intrinsics,
    table_side: f64,
    noise: SensorNoise,
    seed: u64,
) -> Result<(DepthImage, Vec<bool>, Plane)> {
    let table = crate::shapes::cuboid(DVec3::new(table_side / 2.0, table_side / 2.0, 0.015));
    let mut vertices: Vec<DVec3> = mesh.vertices.iter().map(|&v| object.transform_point(v)).collect();
    let mut triangles = mesh.triangles.clone();
    let off = vertices.len() as u32;
    vertices.extend(table.vertices.iter().map(|&v| v - DVec3::Z * 0.015));
    triangles.extend(table.triangles.iter().map(|t| t.map(|i| i + off)));
    let scene = Mesh::from_raw("tabletop scene", vertices, triangles)?.0;
    let scene = RenderMesh::new(&scene)?;
    let (depth, _) = observe(&scene, cam_from_world, k, noise, seed);
    // The object's visible pixels: where it renders and nothing is in front.
    let alone = render_cpu(&RenderMesh::new(mesh)?, &cam_from_world.compose(object), k);
    let both = render_cpu(&scene, cam_from_world, k);
    let mask = alone.depth.iter().zip(&both.depth).map(|(&a, &b)| a > 0.0 && (a - b).abs() < 1e-4).collect();
    let plane = Plane { point: cam_from_world.t, normal: cam_from_world.r * DVec3::Z };
    Ok((depth, mask, plane))
}
