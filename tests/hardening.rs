//! Regression tests for inputs tried as an attacker would: each case gave a
//! panic, an abort, unbounded memory or a silent wrong answer before, and
//! must now give a clear error (or the right answer).

use std::path::Path;
use std::process::Command;

use plausible::kernels::{check_loop_budget, GpuMeshlet, RenderMesh, MAX_GPU_MESHLETS, MAX_GPU_PIXELS};
use plausible::observation::{DepthImage, RoiSampling, ScoreTarget};
use plausible::pose::{read_poses, PoseUnits};

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

/// Runs the binary; returns (exit code, stderr).
fn run(args: &[&str]) -> (i32, String) {
    let o = plausible().args(args).output().unwrap();
    (o.status.code().unwrap_or(-1), String::from_utf8_lossy(&o.stderr).into_owned())
}

#[test]
fn gpu_loop_budget_is_refused_not_returned_as_zeros() {
    let mut mesh = RenderMesh::new(&plausible::shapes::cuboid(glam::DVec3::splat(0.1))).unwrap();
    assert!(check_loop_budget(&mesh, MAX_GPU_PIXELS).is_ok());
    let e = check_loop_budget(&mesh, MAX_GPU_PIXELS + 1).unwrap_err().to_string();
    assert!(e.contains("pixels"), "{e}");
    // Only the count matters to the check: a mesh of too many meshlets.
    mesh.meshlets.resize(MAX_GPU_MESHLETS + 1, GpuMeshlet::default());
    let e = check_loop_budget(&mesh, 100).unwrap_err().to_string();
    assert!(e.contains("meshlets") && e.contains("CPU twin"), "{e}");
}

/// `--device auto` keeps a mesh past the rasterizer's loop budget on the
/// GPU (its BVH ray caster takes it), and scores on the CPU twin (saying
/// so) instead of failing what no GPU renderer takes: a region past the
/// pixel budget, or such a mesh made to rasterize; `gpu` keeps the refusal.
#[test]
fn gpu_auto_device_moves_an_oversized_mesh_to_the_cpu() {
    use plausible::gpu::{test_context, Device, DeviceChoice};
    use plausible::kernels::{CpuRenderer, RendererChoice, MAX_GPU_PIXELS};
    let gpu = || Device::Gpu(Box::new(test_context()));
    let mut mesh = RenderMesh::new(&plausible::shapes::cuboid(glam::DVec3::splat(0.1))).unwrap();
    let (d, note) = gpu().for_mesh(DeviceChoice::Auto, &mesh, 1000);
    assert!(matches!(d, Device::Gpu(_)) && note.is_none());
    mesh.meshlets.resize(MAX_GPU_MESHLETS + 1, GpuMeshlet::default());
    assert_eq!(mesh.gpu_renderer(), CpuRenderer::RayCast);
    let (d, note) = gpu().for_mesh(DeviceChoice::Auto, &mesh, 1000);
    assert!(matches!(d, Device::Gpu(_)) && note.is_none());
    let (d, note) = gpu().for_mesh(DeviceChoice::Auto, &mesh, MAX_GPU_PIXELS + 1);
    assert!(matches!(d, Device::Cpu) && note.unwrap().contains("CPU twin"));
    mesh.renderer = RendererChoice::Raster;
    let (d, note) = gpu().for_mesh(DeviceChoice::Auto, &mesh, 1000);
    assert!(matches!(d, Device::Cpu) && note.unwrap().contains("CPU twin"));
    let (d, _) = gpu().for_mesh(DeviceChoice::Gpu, &mesh, 1000);
    assert!(matches!(d, Device::Gpu(_)));
}

fn flat_observation() -> DepthImage {
    let k = plausible::camera::Intrinsics { fx: 500.0, fy: 500.0, cx: 31.5, cy: 23.5, width: 64, height: 48 };
    DepthImage { intrinsics: k, depth: vec![0.7; 64 * 48] }
}

#[test]
fn region_margin_and_resolution_are_bounded() {
    let obs = flat_observation();
    let mut mask = vec![false; 64 * 48];
    mask[24 * 64 + 32] = true;
    for m in [-1.0, f64::NAN, 1e9] {
        let e = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), m).unwrap_err().to_string();
        assert!(e.contains("margin"), "{m}: {e}");
    }
    for n in [0, 100_000] {
        let e = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(n), 0.1).unwrap_err().to_string();
        assert!(e.contains("resolution"), "{n}: {e}");
    }
    assert!(ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), 0.1).is_ok());
}

#[test]
fn orthonormalize_refuses_scaled_matrices() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("p.json");
    std::fs::write(&p, r#"[{"cam_R_m2c": [2,0,0,0,2,0,0,0,2], "cam_t_m2c": [0,0,700]}]"#).unwrap();
    let e = read_poses(&p, PoseUnits::Millimetres, true).unwrap_err().to_string();
    assert!(e.contains("far from orthonormal"), "{e}");
    // A slightly noisy rotation is still projected.
    std::fs::write(&p, r#"[{"cam_R_m2c": [1.002,0,0,0,1,0,0,0,1], "cam_t_m2c": [0,0,700]}]"#).unwrap();
    assert!(read_poses(&p, PoseUnits::Millimetres, true).is_ok());
}

#[test]
fn corrupt_database_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.sqlite");
    drop(plausible::stable::db::Db::open(&p).unwrap());
    let mut bytes = std::fs::read(&p).unwrap();
    assert!(bytes.len() > 8192, "the schema spans several pages");
    for b in &mut bytes[4096..4096 + 200] {
        *b = 0xA5;
    }
    std::fs::write(&p, &bytes).unwrap();
    let e = plausible::stable::db::Db::open(&p).err().expect("a corrupt database must not open").to_string();
    assert!(e.contains("s.sqlite") && (e.contains("corrupt") || e.contains("malformed")), "{e}");
}

#[test]
fn writes_to_a_full_device_are_errors() {
    if !Path::new("/dev/full").exists() {
        return;
    }
    let e = plausible::io::write_atomically(Path::new("/dev/full"), |w| {
        use std::io::Write;
        w.write_all(&[0u8; 100_000])
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("No space left"), "{e}");
    assert!(Path::new("/dev/full").exists() && !Path::new("/dev/full").is_file(), "the device is still a device");
    let e = plausible::io::check_writable(Path::new("/nonexistent-dir/x.json")).unwrap_err().to_string();
    assert!(e.contains("does not exist"), "{e}");
    // The binary: stdout on a full device is an error (exit 1), not a panic (101).
    let out = std::fs::File::create("/dev/full").unwrap();
    let o = plausible().args(["eval", "--dataset", concat!(env!("CARGO_MANIFEST_DIR"), "/assets/lmo-synth"), "--gt-as-results", "/dev/null", "--device", "cpu", "--quiet"])
        .stdout(out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot write the output"));
}

#[test]
fn absurd_flags_are_refused_before_any_work() {
    for (args, want) in [
        (vec!["demo", "--n", "1000000000000"], "1000000000000"),
        (vec!["bench", "physics", "--n", "1000000000"], "1000000000"),
        (vec!["bench", "physics", "--n", "1000000", "--samples", "1024"], "sample-hypothesis queries"),
        (vec!["bench", "stable", "--diameter", "1e9"], "outside"),
        (vec!["bench", "stable", "--diameter", "nan"], "outside"),
        (vec!["stable-poses", "assets/physics/cube.obj", "--db", "x.sqlite", "--max-time", "1e30"], "must lie in (0, 600]"),
        (vec!["bench", "score", "--units", "mm"], "is for --mesh files"),
        (vec!["plane", "--camera", "c", "--depth", "d", "--iterations", "100000000", "--out", "p.json"], "100000000"),
        (vec!["check", "assets/physics/stack.json", "--explain", "pic"], ".png"),
        (vec!["eval", "--dataset", "assets/lmo-synth", "--gt-as-results", "/dev/null", "--batch-images", "0"], "batch size"),
        (vec!["eval", "--dataset", "assets/lmo-synth", "--gt-as-results", "/dev/null", "--task", "detection", "--errors", "vsd"], "--errors"),
        (vec!["eval", "--dataset", "assets/lmo-synth", "--gt-as-results", "/dev/null", "--task", "detection", "--max-estimates-per-image", "0"], "--max-estimates-per-image"),
        (vec!["eval", "--dataset", "assets/lmo-synth", "--gt-as-results", "/dev/null", "--max-estimates-per-image", "5"], "--task detection"),
        (vec!["eval", "--dataset", "assets/lmo-synth", "--gt-as-results", "/dev/null", "--task", "tracking"], "localization or detection"),
    ] {
        let (code, err) = run(&args);
        assert!(code == 1 || code == 2, "{args:?}: exit {code}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
}

#[test]
fn stable_poses_checks_every_mesh_before_the_first_drop() {
    let d = tempfile::tempdir().unwrap();
    let db = d.path().join("s.sqlite");
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let (code, err) = run(&["stable-poses", cube, "/nonexistent/duck.obj", "--drops", "100000", "--db", db.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("/nonexistent/duck.obj"), "{err}");
    // Nothing was simulated for the cube.
    if db.exists() {
        let conn = plausible::stable::db::Db::open(&db).unwrap();
        assert!(conn.runs().unwrap().is_empty());
    }
}

#[test]
fn a_bad_merge_input_leaves_the_output_unchanged() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out.sqlite");
    drop(plausible::stable::db::Db::open(&out).unwrap());
    let before = std::fs::read(&out).unwrap();
    let bad = d.path().join("bad.sqlite");
    std::fs::write(&bad, "not a database at all, just text that is long enough to have a header").unwrap();
    let good = d.path().join("good.sqlite");
    drop(plausible::stable::db::Db::open(&good).unwrap());
    let (code, err) = run(&["stable-poses", "merge", good.to_str().unwrap(), bad.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("bad.sqlite"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), before);
    let leftovers: Vec<_> = std::fs::read_dir(d.path()).unwrap().filter_map(|e| e.ok()).filter(|e| e.file_name().to_string_lossy().ends_with(".tmp")).collect();
    assert!(leftovers.is_empty());
}

#[test]
fn gpu_off_image_poses_are_not_dispatched_and_match_the_twin() {
    use glam::DVec3;
    use plausible::kernels::score::{score_cpu, GpuScorer, ScoreParams};
    use plausible::kernels::RenderMesh;
    use plausible::mesh::{Mesh, MeshUnits};
    use plausible::observation::DEFAULT_ROI_MARGIN;
    use plausible::pose::{axis_angle, Pose};
    use plausible::synth::{linemod_camera, observe, SensorNoise};
    let ctx = plausible::gpu::test_context();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    let mesh = RenderMesh::new(&Mesh::load(path, MeshUnits::Metres).unwrap().0.normalized(0.15)).unwrap();
    let truth = Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7));
    let (obs, mask) = observe(&mesh, &truth, &linemod_camera(), SensorNoise::default(), 7);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
    let mut poses = vec![truth; 8];
    poses.extend((0..5000).map(|i| Pose::new(truth.r, DVec3::new(5.0 + i as f64 * 1e-3, 0.0, 0.7))));
    let params = ScoreParams::default();
    let (gpu, _) = GpuScorer::new(&ctx, &mesh, &target, params, poses.len()).unwrap().score(&poses).unwrap();
    let cpu = score_cpu(&mesh, &target, &poses, &params);
    assert_eq!(gpu.len(), poses.len());
    for (g, c) in gpu.iter().zip(&cpu).skip(8) {
        assert_eq!(g, c);
    }
    assert!((gpu[0].score - cpu[0].score).abs() < 1e-3 && gpu[0].score > 0.8, "{:?} vs {:?}", gpu[0], cpu[0]);
}

#[test]
fn a_subdivided_duck_has_stable_poses() {
    use plausible::mesh::{Mesh, MeshUnits};
    // The duck with every triangle split in four (16,848 triangles, many
    // coplanar points): its convex hull came back with inward faces and
    // slivers, and the centre of mass was reported outside it.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    let duck = Mesh::load(path, MeshUnits::Metres).unwrap().0.normalized(0.15);
    let dense = duck.subdivided(2);
    assert_eq!(dense.triangles.len(), 16_848);
    let plain = plausible::hypotheses::on_plane::analytic_resting_poses(&duck).unwrap();
    let rests = plausible::hypotheses::on_plane::analytic_resting_poses(&dense).unwrap();
    assert!(rests.len() >= 2, "{}", rests.len());
    // The most probable resting pose is the same as the plain duck's.
    let angle = |a: &glam::DMat3, b: &glam::DMat3| ((a.transpose() * *b).to_cols_array()[0..9].iter().step_by(4).sum::<f64>() - 1.0).clamp(-2.0, 2.0);
    assert!(angle(&plain[0].r_model_to_plane, &rests[0].r_model_to_plane) > 1.9, "most probable poses differ");
}

#[test]
fn a_millimetre_scene_on_a_metre_mesh_names_the_object_size() {
    use glam::DVec3;
    // A 0.05 mm cube (a 50 mm cube read as metres, then scaled by 1e-3).
    let tiny = plausible::shapes::cuboid(DVec3::splat(0.000025));
    let e = plausible::physical::sdf::SdfGrid::bake(&tiny, 64).err().expect("a 0.05 mm object is refused").to_string();
    assert!(e.contains("0.0500 mm across") && e.contains("units"), "{e}");
}

#[test]
fn a_corrupt_database_column_is_an_error_not_a_default() {
    let d = tempfile::tempdir().unwrap();
    let db = d.path().join("s.sqlite");
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let (code, err) = run(&["stable-poses", cube, "--drops", "16", "--db", db.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let conn = rusqlite::Connection::open(&db).unwrap();
    conn.execute("UPDATE clusters SET r_model_to_plane = 'not json'", []).unwrap();
    drop(conn);
    let (code, err) = run(&["stable-poses", "export", "--db", db.to_str().unwrap(), "--json", "-"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("corrupt column"), "{err}");
}

/// A scene of a million objects (a 190 MB JSON) took 24 GB before being
/// killed; more than `MAX_OBJECTS` objects is now an error before any mesh
/// work.
#[test]
fn a_scene_with_too_many_objects_is_refused_before_loading_meshes() {
    let d = tempfile::tempdir().unwrap();
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let obj = format!(r#"{{"mesh": "{cube}", "units": "m", "R": [1,0,0,0,1,0,0,0,1], "t": [0,0,0.02]}}"#);
    let n = plausible::physical::scene::MAX_OBJECTS + 1;
    let text = format!(r#"{{"planes": [{{"point": [0,0,0], "normal": [0,0,1]}}], "objects": [{}]}}"#, vec![obj; n].join(","));
    let path = d.path().join("scene.json");
    std::fs::write(&path, text).unwrap();
    let (code, err) = run(&["check", path.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains(&format!("the scene has {n} objects")), "{err}");
}

/// A dense convex mesh (a 164k-vertex sphere, every vertex on its hull) has
/// mass properties and a stable-pose hull: the hull check no longer tests
/// every point against every face (hours at this size).
#[test]
fn a_dense_sphere_has_mass_properties_and_a_hull_quickly() {
    let sphere = plausible::shapes::icosphere(0.05, 7); // 327,680 triangles
    let (mass, _) = plausible::mesh::mass::MassProperties::of_mesh(&sphere).unwrap();
    let (hull, note) = plausible::stable::hull::Hull::of_mesh_vertices("sphere", &sphere.vertices).unwrap();
    assert!((mass.com.length()) < 1e-6 && hull.volume() > 0.99 * mass.volume, "{} vs {}", hull.volume(), mass.volume);
    assert!(note.is_none(), "163,842 vertices are below the subsampling limit");
}

/// The visual kernels read the triangles and the observation as textures:
/// a mesh with more rows of triangles, or a region wider, than the
/// adapter's textures hold is refused by name (and `--device auto` scores
/// it on the CPU twin), never bound past the limit. The limit is lowered
/// on the context to try it without a 16.7M-triangle mesh.
#[test]
fn gpu_tables_past_the_adapters_texture_size_are_refused() {
    use plausible::gpu::{test_context, Device, DeviceChoice};
    use plausible::kernels::raster::TRI_ROW;
    use plausible::kernels::score::{GpuScorer, ScoreParams};
    let mut ctx = test_context();
    ctx.max_texture_dim = 2;
    let mesh = RenderMesh::new(&plausible::shapes::cuboid(glam::DVec3::splat(0.1))).unwrap();
    let obs = flat_observation();
    let target = ScoreTarget::new(&obs, None, RoiSampling::Square(2), 0.1).unwrap();
    assert!(GpuScorer::new(&ctx, &mesh, &target, ScoreParams::default(), 1).is_ok());
    let mut big = mesh.clone();
    big.triangles.resize(2 * TRI_ROW + 1, big.triangles[0]);
    let e = GpuScorer::new(&ctx, &big, &target, ScoreParams::default(), 1).err().unwrap().to_string();
    assert!(e.contains("textures hold") && e.contains(&format!("{}", 2 * TRI_ROW)), "{e}");
    let (d, note) = Device::Gpu(Box::new(ctx.clone())).for_mesh(DeviceChoice::Auto, &big, 4);
    assert!(matches!(d, Device::Cpu) && note.unwrap().contains("CPU twin"));
    let wide = ScoreTarget::new(&obs, None, RoiSampling::Square(3), 0.1).unwrap();
    let e = GpuScorer::new(&ctx, &mesh, &wide, ScoreParams::default(), 1).err().unwrap().to_string();
    assert!(e.contains("3x3") && e.contains("textures"), "{e}");
}

/// `--out` on a FIFO: the check before the work must not open the pipe
/// (opening and closing it for writing had handed the reader an end of
/// file, and the real write then blocked for ever with no reader).
#[cfg(unix)]
#[test]
fn checking_a_fifo_output_leaves_its_reader_waiting() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("out.json");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read(&fifo).unwrap())
    };
    let (done, wait) = std::sync::mpsc::channel();
    {
        let fifo = fifo.clone();
        std::thread::spawn(move || {
            plausible::io::check_writable(&fifo).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(100));
            plausible::io::write_atomically(&fifo, |w| std::io::Write::write_all(w, b"[1, 2]")).unwrap();
            done.send(()).unwrap();
        });
    }
    if wait.recv_timeout(std::time::Duration::from_secs(10)).is_err() {
        // Unblock the writer stuck in open() before failing.
        let _ = std::fs::File::open(&fifo);
        panic!("the write to the FIFO blocked: its reader had already gone");
    }
    assert_eq!(reader.join().unwrap(), b"[1, 2]");
    assert!(fifo.exists() && !fifo.is_file(), "the FIFO is still a FIFO");
}

/// Outputs written through a symbolic link land in the file it names (a
/// rename over the link had replaced the link and left its target as it
/// was), and an image that is a FIFO is refused rather than waited on for
/// ever (a FIFO without a writer in a --masks folder hung refine).
#[cfg(unix)]
#[test]
fn writes_follow_symlinks_and_images_must_be_files() {
    let d = tempfile::tempdir().unwrap();
    let target = d.path().join("real.json");
    std::fs::write(&target, b"old").unwrap();
    let link = d.path().join("link.json");
    std::os::unix::fs::symlink("real.json", &link).unwrap();
    plausible::io::write_atomically(&link, |w| std::io::Write::write_all(w, b"new")).unwrap();
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link is still a link");
    assert_eq!(std::fs::read(&target).unwrap(), b"new");
    let fifo = d.path().join("mask.png");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let e = plausible::observation::read_mask_png(&fifo, 4, 4).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
}

/// `/dev/stdout` on a pipe links to "pipe:[N]", which names no file: an
/// output there is written in place, not through a temporary file beside
/// a path that does not exist.
#[cfg(unix)]
#[test]
fn an_output_on_a_piped_stdout_is_written_in_place() {
    assert_eq!(plausible::io::link_target(Path::new("/dev/null")), Path::new("/dev/null"));
    let d = tempfile::tempdir().unwrap();
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let script = format!("{:?} stable-poses {cube} --drops 8 --quiet --db {:?} --json /dev/stdout | cat", env!("CARGO_BIN_EXE_plausible"), d.path().join("s.db"));
    let piped = Command::new("bash").arg("-c").arg(script).output().unwrap();
    let out = String::from_utf8_lossy(&piped.stdout);
    assert!(piped.status.success() && out.contains("\"clusters\""), "{out}\n{}", String::from_utf8_lossy(&piped.stderr));
}
