//! `plausible demo`: the scorer end to end on shipped data.
//!
//! Loads the duck from `assets/`, synthesises an observation at a known pose
//! (rendered depth + 1 mm Gaussian noise + 5 % missing pixels, stored as a
//! BOP 16-bit PNG), ranks 4096 hypotheses (the truth, 2047 perturbed around
//! it, 2048 with random rotations), and writes the inputs, the scores and a
//! picture to the output folder so `plausible score` can be run on them too.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context as _, Result};
use glam::DVec3;
use plausible::hypotheses::around_and_random;
use plausible::kernels::raster::render_cpu;
use plausible::kernels::score::{GpuScorer, ScoreParams};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::pose::{axis_angle, poses_to_json, Pose};
use plausible::synth::{linemod_camera, observe, SensorNoise};
use plausible::visual::{ranks, score_poses, Device};

use super::DeviceArgs;

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Number of hypotheses.
    #[arg(long, default_value_t = 4096)]
    pub n: usize,
    /// Seed of the noise and the hypotheses.
    #[arg(long, default_value_t = 42)]
    pub seed: u64,
    /// Output folder for the observation, hypotheses, scores and picture.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// The demo's true pose: the duck seen from an oblique angle at 0.7 m.
pub fn demo_true_pose() -> Pose {
    Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7))
}

pub fn run(a: DemoArgs, verbose: u8) -> Result<()> {
    let mesh_path = super::asset("assets/pybullet/duck.obj");
    let (mesh, _) = Mesh::load(&mesh_path, MeshUnits::Metres)?;
    let mesh = mesh.normalized(0.15);
    let rmesh = RenderMesh::new(&mesh)?;
    println!(
        "mesh: {} ({} triangles, scaled to a 0.15 m diagonal)",
        mesh_path.display(),
        mesh.triangles.len()
    );
    let k = linemod_camera();
    let truth = demo_true_pose();
    let noise = SensorNoise::default();
    let (obs, mask) = observe(&rmesh, &truth, &k, noise, a.seed);
    println!(
        "observation: {}x{} depth at the true pose, noise σ = {} mm, {:.0} % pixels missing",
        k.width,
        k.height,
        noise.sigma * 1e3,
        noise.dropout * 100.0
    );
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN)?;
    let poses = around_and_random(&truth, a.n, a.seed);
    let device = a.device.open(verbose, true)?;
    let params = ScoreParams::default();

    // Warm up (pipeline compilation, first-submit cost), then time.
    if let Device::Gpu(ctx) = &device {
        GpuScorer::new(ctx, &rmesh, &target, params, 64)?.score(&poses[..64.min(poses.len())])?;
    }
    let t0 = Instant::now();
    let (records, _) = score_poses(&device, &rmesh, &target, &poses, params)?;
    let secs = t0.elapsed().as_secs_f64();
    let rank = ranks(&records);

    println!(
        "scored {} hypotheses on {} in {:.3} s: {:.0} hypotheses/s (region 128x128)",
        poses.len(),
        device.describe(),
        secs,
        poses.len() as f64 / secs
    );
    println!("\ntop 5 (index 0 is the true pose):");
    super::score::print_table(&records, None, &rank, 5);
    let best = rank.iter().position(|&r| r == 1).unwrap_or(0);
    println!(
        "\ntrue pose: rank {} of {}, score {:.4}; best hypothesis {} is {:.1}° and {:.1} mm from the truth",
        rank[0],
        poses.len(),
        records[0].score,
        best,
        poses[best].rotation_angle_to(&truth).to_degrees(),
        (poses[best].t - truth.t).length() * 1e3
    );

    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    // BOP-style inputs, so `plausible score` can be run on them.
    let depth_scale = 0.1; // value x 0.1 = mm
    let depth16: Vec<u16> = obs.depth.iter().map(|&d| ((d as f64 * 1e3 / depth_scale).round()).clamp(0.0, 65535.0) as u16).collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(k.width, k.height, depth16)
        .unwrap()
        .save(a.out.join("depth.png"))?;
    let mask8: Vec<u8> = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    image::GrayImage::from_raw(k.width, k.height, mask8).unwrap().save(a.out.join("mask.png"))?;
    std::fs::write(
        a.out.join("camera.json"),
        serde_json::to_string_pretty(&serde_json::json!({
            "cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            "depth_scale": depth_scale,
        }))?,
    )?;
    std::fs::write(a.out.join("poses.json"), serde_json::to_string(&poses_to_json(&poses))?)?;
    // The mesh in metres as the demo used it.
    let mut obj = String::new();
    for v in &mesh.vertices {
        obj += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in &mesh.triangles {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(a.out.join("duck_0.15m.obj"), obj)?;
    super::score::write_records(&a.out.join("scores.json"), &records, None, &rank)?;
    let render = render_cpu(&rmesh, &poses[best], &target.intrinsics);
    let pic = plausible::explain::alignment_panels(&target, &render, &params, 3);
    let pic_path = a.out.join("alignment.png");
    pic.save(&pic_path)?;
    println!(
        "\nwrote {}: observed depth | best hypothesis' depth | per-pixel alignment (yellow = aligned, red = rendered only, blue = observed only)",
        pic_path.display()
    );
    println!(
        "wrote the inputs to {0}/ (depth.png, mask.png, camera.json, poses.json, duck_0.15m.obj) and all scores to {0}/scores.json",
        a.out.display()
    );
    Ok(())
}
