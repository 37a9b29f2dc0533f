//! `plausible demo`: visual and physical plausibility end to end on shipped
//! data.
//!
//! Loads the duck from `assets/`, puts it on a table in its most probable
//! resting pose (the quasi-static analysis of `stable`), and synthesises a
//! camera's view at 0.7 m, 45° above the table (depth of duck and table + 1
//! mm Gaussian noise + 5 % missing pixels, stored as a BOP 16-bit PNG, and
//! the duck's mask). It fits the support plane to the depth outside the
//! mask, then scores 4096 hypotheses (the truth, 2047 perturbed around it,
//! 2048 with random rotations) visually and physically in one GPU pass,
//! ranks them physically plausible first, and writes the inputs, the
//! records and a picture to the output folder, so `plausible plane` and
//! `plausible score --plane --physics` can be run on them too.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context as _, Result};
use glam::{DVec2, DVec3};
use plausible::hypotheses::around_and_random;
use plausible::hypotheses::on_plane::{analytic_resting_poses, on_plane_hypotheses, rest_on_plane, OnPlaneParams};
use plausible::kernels::raster::render_cpu;
use plausible::kernels::score::{ScoreParams, ScoreRecord};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::physical::batch::PlanePhysics;
use plausible::physical::samples::{DEFAULT_SAMPLES, DEFAULT_SEED};
use plausible::physical::scene::CameraPlaneJson;
use plausible::physical::Verdict;
use plausible::pose::{axis_angle, poses_to_json, Pose};
use plausible::support_plane::{fit_support_plane, PlaneFitParams};
use plausible::synth::{linemod_camera, look_at, observe_on_table, SensorNoise};
use plausible::visual::{ranks, ranks_with_physics, score_poses_with_physics, Device};


#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Number of hypotheses.
    #[arg(long, default_value_t = 4096, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1_000_000))]
    pub n: usize,
    /// Seed of the noise and the hypotheses.
    #[arg(long, default_value_t = 42)]
    pub seed: u64,
    /// Output folder for the observation, hypotheses, scores and picture.
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    #[command(flatten)]
    pub device: super::AutoDeviceArgs,
}

/// The benchmark's pose: the duck seen from an oblique angle at 0.7 m.
pub fn demo_true_pose() -> Pose {
    Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7))
}

/// The duck on the table (model to world, z up, table top z = 0) in its
/// most probable quasi-static resting pose, turned 35° about the vertical;
/// returns the pose and that resting pose's probability.
fn resting_on_table(mesh: &Mesh) -> Result<(Pose, f64)> {
    let rests = analytic_resting_poses(mesh)?;
    let top = rests.first().context("the duck has no stable resting pose")?;
    let r = axis_angle(DVec3::Z, 35f64.to_radians()) * top.r_model_to_plane;
    Ok((rest_on_plane(mesh, r, DVec2::ZERO), top.probability))
}

/// The demo's scene: the duck on a table, observed with noise, and the
/// support plane fitted to the observation.
struct DemoScene {
    mesh: Mesh,
    rmesh: RenderMesh,
    truth: Pose,
    obs: plausible::observation::DepthImage,
    mask: Vec<bool>,
    fit: plausible::support_plane::PlaneFit,
}

#[tracing::instrument(name = "plausible demo", level = "trace", skip_all)]
pub fn run(a: DemoArgs, verbose: u8) -> Result<()> {
    // The shipped duck and the output folder first: a missing repository
    // or a wrong --out fails before any work (and leaves no empty folder).
    let mesh_path = super::asset("assets/pybullet/duck.obj")?;
    if a.out.is_file() {
        anyhow::bail!("--out {}: is a file; the demo writes a folder of outputs", a.out.display());
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("--out {}: cannot create the folder", a.out.display()))?;
    plausible::io::check_writable(&a.out.join(".plausible-write-test")).with_context(|| format!("--out {}", a.out.display()))?;
    let scene = build_scene(&mesh_path, a.seed)?;
    let target = ScoreTarget::new(&scene.obs, Some(&scene.mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN)?;
    let poses = around_and_random(&scene.truth, a.n, a.seed);
    let device = a.device.open(verbose)?;
    let params = ScoreParams::default();
    let physics = PlanePhysics::new(&scene.mesh, &scene.fit.plane, None, DEFAULT_SAMPLES, DEFAULT_SEED, None)?;
    let scored = score_and_report(&device, &scene, &target, &poses, params, &physics)?;
    let est_poses = estimate(&device, &scene, &target, params, &physics)?;
    write_outputs(&a.out, &scene, &target, &poses, &est_poses, &scored, params, &physics)
}

/// Loads the duck, puts it on a table in its most probable resting pose,
/// observes it and fits the support plane, printing each step.
fn build_scene(mesh_path: &std::path::Path, seed: u64) -> Result<DemoScene> {
    let (mesh, _) = Mesh::load(mesh_path, MeshUnits::Metres)?;
    let mesh = mesh.normalized(0.15);
    let rmesh = RenderMesh::new(&mesh)?;
    println!("mesh: {} ({} triangles, scaled to a 0.15 m diagonal)", mesh_path.display(), mesh.triangles.len());
    let k = linemod_camera();
    let (on_table, probability) = resting_on_table(&mesh)?;
    // The camera 0.7 m from the duck's centre, 45° above the table.
    let (lo, hi) = mesh.bounds();
    let centre = on_table.transform_point((lo + hi) / 2.0);
    let eye = centre + DVec3::new(0.0, -1.0, 1.0).normalize() * 0.7;
    let cam_from_world = look_at(eye, centre, DVec3::Z)?;
    let truth = cam_from_world.compose(&on_table);
    let noise = SensorNoise::default();
    let (obs, mask, true_plane) = observe_on_table(&mesh, &on_table, &cam_from_world, &k, 1.0, noise, seed)?;
    println!(
        "scene: the duck in its most probable resting pose (probability {:.0} % by the quasi-static analysis) on a table, seen from 0.7 m at 45°",
        probability * 100.0
    );
    println!(
        "observation: {}x{} depth of duck and table, noise σ = {} mm, {:.0} % pixels missing",
        k.width,
        k.height,
        noise.sigma * 1e3,
        noise.dropout * 100.0
    );
    let fit = fit_support_plane(&obs, Some(&mask), &PlaneFitParams { seed, ..Default::default() })?;
    println!(
        "support plane fitted to {} of {} depth points outside the mask (RMS {:.2} mm): {:.3}° and {:.2} mm from the true table",
        fit.inliers,
        fit.candidates,
        fit.rms * 1e3,
        fit.plane.normal.angle_between(true_plane.normal).to_degrees(),
        true_plane.distance(fit.plane.point).abs() * 1e3
    );
    Ok(DemoScene { mesh, rmesh, truth, obs, mask, fit })
}

/// The scored hypotheses and their rankings.
struct Scored {
    records: Vec<ScoreRecord>,
    evals: Vec<plausible::physical::Evaluation>,
    rank: Vec<usize>,
    visual_rank: Vec<usize>,
    best: usize,
}

/// Scores the hypotheses visually and physically in one pass and prints the
/// ranking and where the true pose landed.
fn score_and_report(device: &Device, scene: &DemoScene, target: &ScoreTarget, poses: &[Pose], params: ScoreParams, physics: &PlanePhysics) -> Result<Scored> {
    // Warm up (pipeline compilation, first-submit cost), then time.
    if let Device::Gpu(ctx) = device {
        let warm = &poses[..64.min(poses.len())];
        physics.gpu_scorer(ctx, &scene.rmesh, target, params, 64)?.score_with_physics(warm, |_| {})?;
    }
    let t0 = Instant::now();
    let (records, evals, _) = score_poses_with_physics(device, &scene.rmesh, target, poses, params, physics, |_| {})?;
    let secs = t0.elapsed().as_secs_f64();
    let rank = ranks_with_physics(&records, &evals);
    let visual_rank = ranks(&records);
    println!(
        "scored {} hypotheses visually and physically in one pass on {} in {:.3} s: {:.0} hypotheses/s (region 128x128, {} surface samples)",
        poses.len(),
        device.describe(),
        secs,
        poses.len() as f64 / secs,
        physics.body().samples.len()
    );
    println!("physical verdicts: {}", super::score::verdict_counts(&evals));
    let shown = poses.len().min(5);
    println!("\ntop {shown}, physically plausible first (index 0 is the true pose):");
    super::score::print_table(&records, Some(&evals), &rank, shown);
    let best = rank.iter().position(|&r| r == 1).unwrap_or(0);
    let visual_best = visual_rank.iter().position(|&r| r == 1).unwrap_or(0);
    let truth = &scene.truth;
    println!(
        "\ntrue pose: rank {} of {} ({}, score {:.4}, margin {:.1} mm); best hypothesis {} is {:.1}° and {:.1} mm from the truth",
        rank[0],
        poses.len(),
        evals[0].verdict.as_str(),
        records[0].score,
        evals[0].stability_margin.unwrap_or(f64::NAN) * 1e3,
        best,
        poses[best].rotation_angle_to(truth).to_degrees(),
        (poses[best].t - truth.t).length() * 1e3
    );
    println!(
        "visual score alone: true pose rank {}; best hypothesis {} is {}",
        visual_rank[0],
        visual_best,
        evals[visual_best].verdict.as_str()
    );
    Ok(Scored { records, evals, rank, visual_rank, best })
}

/// Pose estimation without a learned model (paper section 3.1): the duck's
/// resting poses x 24 yaws, each put on the fitted plane and centred on the
/// observed points, scored the same way. Returns the hypotheses.
fn estimate(device: &Device, scene: &DemoScene, target: &ScoreTarget, params: ScoreParams, physics: &PlanePhysics) -> Result<Vec<Pose>> {
    let rests = analytic_resting_poses(&scene.mesh)?;
    let t1 = Instant::now();
    let estimates = on_plane_hypotheses(&scene.mesh, &rests, &scene.fit.plane, &scene.obs, &scene.mask, &OnPlaneParams::default())?;
    let est_poses: Vec<Pose> = estimates.iter().map(|h| h.pose).collect();
    let (est_records, est_evals, _) = score_poses_with_physics(device, &scene.rmesh, target, &est_poses, params, physics, |_| {})?;
    let est_rank = ranks_with_physics(&est_records, &est_evals);
    let est_best = est_rank.iter().position(|&r| r == 1).unwrap_or(0);
    println!(
        "\npose estimation from stable poses: {} hypotheses ({} resting poses x 24 yaws on the fitted plane, centred on the observed points) generated and scored in {:.2} s",
        est_poses.len(),
        rests.iter().filter(|r| r.group_probability >= OnPlaneParams::default().min_probability).count(),
        t1.elapsed().as_secs_f64()
    );
    println!(
        "best: resting pose {} ({:.0} %), yaw {:.0}°, score {:.4}, {}: {:.1}° and {:.1} mm from the truth",
        estimates[est_best].rest,
        rests[estimates[est_best].rest].probability * 100.0,
        estimates[est_best].yaw.to_degrees(),
        est_records[est_best].score,
        est_evals[est_best].verdict.as_str(),
        est_poses[est_best].rotation_angle_to(&scene.truth).to_degrees(),
        (est_poses[est_best].t - scene.truth.t).length() * 1e3
    );
    Ok(est_poses)
}

/// Writes the BOP-style inputs, the records and the pictures to `out`.
#[allow(clippy::too_many_arguments)] // the demo's state, written once
fn write_outputs(
    out: &std::path::Path,
    scene: &DemoScene,
    target: &ScoreTarget,
    poses: &[Pose],
    est_poses: &[Pose],
    s: &Scored,
    params: ScoreParams,
    physics: &PlanePhysics,
) -> Result<()> {
    write_inputs(out, scene, poses, est_poses)?;
    super::score::write_records(&out.join("scores.json"), &s.records, Some(&s.evals), &s.rank)?;
    let render = render_cpu(&scene.rmesh, &poses[s.best], &target.intrinsics);
    let r = &s.records[s.best];
    let title = format!(
        "demo: best hypothesis {} of {}: score {:.3} (a_d {:.3}, a_n {:.3}), {}",
        s.best,
        poses.len(),
        r.score,
        r.mean_ad,
        r.mean_an,
        s.evals[s.best].verdict.as_str()
    );
    let panels = plausible::explain::alignment_panels(target, &render, &params, 3);
    let pic = plausible::draw::with_title(&panels, &title, plausible::explain::verdict_colour(s.evals[s.best].verdict));
    let pic_path = out.join("alignment.png");
    write_named(out, "alignment.png", |p| plausible::io::save_png(p, &pic))?;
    println!(
        "\nwrote {}: observed depth | best hypothesis' depth | per-pixel alignment (yellow = aligned, red = rendered only, blue = observed only)",
        pic_path.display()
    );
    // Why physics matters: the visually best hypothesis that is not plausible.
    let implausible = (0..poses.len()).filter(|&i| s.evals[i].verdict != Verdict::Plausible).min_by_key(|&i| s.visual_rank[i]);
    let mut ids = vec![s.best];
    ids.extend(implausible);
    // The demo's own folder: pictures there are an earlier demo's.
    super::score::adopt_pictures(&out.join("explain"))?;
    super::score::write_explanations(&out.join("explain"), &ids, poses, &s.records, &s.rank, &scene.rmesh, target, &params, Some(physics))?;
    if let Some(i) = implausible {
        let e = &s.evals[i];
        let why = match e.verdict {
            Verdict::Intersecting => "red samples below the table",
            Verdict::Floating => "no sample touches the table",
            _ => "the centre of mass (red cross) lies outside the support polygon",
        };
        println!(
            "  hypothesis_{}.png: the top-ranked one; hypothesis_{i}.png: the visually best implausible one \
             (visual rank {}, {}: |I| = {}, min δ = {:.1} mm; {why})",
            s.best,
            s.visual_rank[i],
            e.verdict.as_str(),
            e.intersecting,
            e.min_distance * 1e3
        );
    }
    println!(
        "wrote the inputs to {0}/ (depth.png, mask.png, camera.json, poses.json, hypotheses.json, plane.json, duck_0.15m.obj) and all records to {0}/scores.json",
        out.display()
    );
    Ok(())
}

/// BOP-style inputs, so `plausible score` can be run on them.
fn write_inputs(out: &std::path::Path, scene: &DemoScene, poses: &[Pose], est_poses: &[Pose]) -> Result<()> {
    let k = scene.obs.intrinsics;
    let depth_scale = 0.1; // value x 0.1 = mm
    let depth16: Vec<u16> = scene.obs.depth.iter().map(|&d| ((d as f64 * 1e3 / depth_scale).round()).clamp(0.0, 65535.0) as u16).collect();
    let depth = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(k.width, k.height, depth16).context("depth image size")?;
    write_named(out, "depth.png", |p| plausible::io::save_png(p, &depth))?;
    let mask8: Vec<u8> = scene.mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    let mask = image::GrayImage::from_raw(k.width, k.height, mask8).context("mask image size")?;
    write_named(out, "mask.png", |p| plausible::io::save_png(p, &mask))?;
    let camera = serde_json::to_string_pretty(&serde_json::json!({
        "cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        "depth_scale": depth_scale,
    }))?;
    write_named(out, "camera.json", |p| std::fs::write(p, camera))?;
    let poses = serde_json::to_string(&poses_to_json(poses))?;
    write_named(out, "poses.json", |p| std::fs::write(p, poses))?;
    let hypotheses = serde_json::to_string(&poses_to_json(est_poses))?;
    write_named(out, "hypotheses.json", |p| std::fs::write(p, hypotheses))?;
    let plane = serde_json::to_string_pretty(&CameraPlaneJson::from_plane(&scene.fit.plane))? + "\n";
    write_named(out, "plane.json", |p| std::fs::write(p, plane))?;
    // The mesh in metres as the demo used it.
    let mut obj = String::new();
    for v in &scene.mesh.vertices {
        obj += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in &scene.mesh.triangles {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    write_named(out, "duck_0.15m.obj", |p| std::fs::write(p, obj))
}

/// Writes file `name` in `out` with `write`; an error names the file.
fn write_named<E: std::error::Error + Send + Sync + 'static>(out: &std::path::Path, name: &str, write: impl FnOnce(&std::path::Path) -> std::result::Result<(), E>) -> Result<()> {
    let path = out.join(name);
    write(&path).with_context(|| format!("cannot write {}", path.display()))
}
