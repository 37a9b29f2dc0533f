//! Hypotheses on a support plane: stable poses × yaw × in-plane position
//! from the segmented depth, scored visually and physically, recover the
//! pose of a duck resting on a table.

use glam::{DMat3, DVec2, DVec3};
use plausible::hypotheses::on_plane::{analytic_resting_poses, on_plane_hypotheses, resting_poses_from_export, rest_on_plane, ExportMatch, OnPlaneParams};
use plausible::kernels::score::ScoreParams;
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::physical::batch::PlanePhysics;
use plausible::pose::{axis_angle, Pose};
use plausible::support_plane::{fit_support_plane, PlaneFitParams};
use plausible::synth::{linemod_camera, look_at, observe_on_table, SensorNoise};
use plausible::visual::{ranks_with_physics, score_poses_with_physics, Device};

fn duck() -> Mesh {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    Mesh::load(path, MeshUnits::Metres).unwrap().0.normalized(0.15)
}

/// The duck resting on the table in its `rest`-th analytic pose, turned by
/// `yaw` and moved to `(x, y)`.
fn on_table(mesh: &Mesh, rest: usize, yaw: f64, x: f64, y: f64) -> Pose {
    let rests = analytic_resting_poses(mesh).unwrap();
    rest_on_plane(mesh, axis_angle(DVec3::Z, yaw) * rests[rest].r_model_to_plane, DVec2::new(x, y))
}

#[test]
fn gpu_stable_pose_hypotheses_recover_a_duck_on_a_table() {
    let mesh = duck();
    let rmesh = RenderMesh::new(&mesh).unwrap();
    let k = linemod_camera();
    let rests = analytic_resting_poses(&mesh).unwrap();
    assert!(rests.len() >= 2 && (rests.iter().map(|r| r.probability).sum::<f64>() - 1.0).abs() < 1e-6);
    let device = Device::Gpu(Box::new(plausible::gpu::test_context()));
    // Two scenes: the most probable resting pose and the second one, at yaws
    // between the 15° steps, off the image centre.
    for (scene, (rest, yaw, x, y)) in [(0usize, 35f64, 0.02, -0.01), (1, 100.0, -0.03, 0.02)].into_iter().enumerate() {
        let truth_world = on_table(&mesh, rest, yaw.to_radians(), x, y);
        let cam = look_at(DVec3::new(0.1, -0.5, 0.5), DVec3::new(0.0, 0.0, 0.04), DVec3::Z).unwrap();
        let truth = cam.compose(&truth_world);
        let (obs, mask, _) = observe_on_table(&mesh, &truth_world, &cam, &k, 1.0, SensorNoise::default(), scene as u64).unwrap();
        let plane = fit_support_plane(&obs, Some(&mask), &PlaneFitParams::default()).unwrap().plane;
        let hyps = on_plane_hypotheses(&mesh, &rests, &plane, &obs, &mask, &OnPlaneParams::default()).unwrap();
        let poses: Vec<Pose> = hyps.iter().map(|h| h.pose).collect();
        let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
        let physics = PlanePhysics::new(&mesh, &plane, None, 1024, 0, None).unwrap();
        let (records, evals, _) =
            score_poses_with_physics(&device, &rmesh, &target, &poses, ScoreParams::default(), &physics, |_| {}).unwrap();
        let rank = ranks_with_physics(&records, &evals);
        let best = rank.iter().position(|&r| r == 1).unwrap();
        let angle = poses[best].rotation_angle_to(&truth).to_degrees();
        let dist = (poses[best].t - truth.t).length();
        eprintln!(
            "scene {scene}: {} hypotheses; best {best} (rest {}, yaw {:.0}°) is {angle:.1}° and {:.1} mm from the truth, {:?}, score {:.3}",
            poses.len(),
            hyps[best].rest,
            hyps[best].yaw.to_degrees(),
            dist * 1e3,
            evals[best].verdict,
            records[best].score
        );
        assert_eq!(hyps[best].rest, rest);
        assert!(angle < 11.0 && dist < 0.01, "scene {scene}: {angle}°, {dist} m");
        // Every hypothesis rests on the fitted plane.
        assert!(evals.iter().all(|e| e.min_distance.abs() < 1e-3), "hypotheses are put on the plane");
        // Each setting within its range, but their product too large: refused
        // before any work, not hundreds of millions of poses in memory.
        let huge = OnPlaneParams { yaw_steps: 3600, grid_radius: 20, min_probability: 0.0, ..Default::default() };
        let e = on_plane_hypotheses(&mesh, &rests, &plane, &obs, &mask, &huge).unwrap_err().to_string();
        assert!(e.contains("at most 1000000"), "{e}");
    }
}

/// The stable-pose export JSON: the entry is found by hash, as the only
/// entry, or by name; malformed entries are errors that say what is wrong.
#[test]
fn resting_poses_are_read_from_a_stable_pose_export() {
    let r = DMat3::from_cols_array(&[0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0]).transpose();
    let cluster = |p: f64| serde_json::json!({"probability": p, "R_model_to_plane": DMat3::to_cols_array(&r.transpose())});
    let export = |meshes: Vec<serde_json::Value>| serde_json::json!({"format": "plausible-stable-poses/1", "meshes": meshes}).to_string();
    let a = serde_json::json!({"mesh": "models/duck.obj", "sha256": "aa", "clusters": [cluster(0.6), cluster(0.4)]});
    let b = serde_json::json!({"mesh": "models/box.ply", "sha256": "bb", "clusters": [cluster(1.0)]});
    let (one, how) = resting_poses_from_export(&export(vec![a.clone()]), "zz", "whatever").unwrap();
    assert_eq!(how, ExportMatch::OnlyEntry);
    assert_eq!(one.len(), 2);
    assert!((one[0].r_model_to_plane - r).to_cols_array().iter().all(|x| x.abs() < 1e-12));
    let by = |sha: &str, name: &str| {
        let (r, how) = resting_poses_from_export(&export(vec![a.clone(), b.clone()]), sha, name).unwrap();
        (r.len(), how)
    };
    assert_eq!(by("bb", "duck"), (1, ExportMatch::Hash));
    assert_eq!(by("zz", "duck"), (2, ExportMatch::Name));
    // The mesh's file name, as estimate and Python pass it, matches by its
    // stem (they passed "obj_000001.ply", which never matched).
    assert_eq!(by("zz", "duck.obj"), (2, ExportMatch::Name));
    // A single entry matched by name is a name match, not a fallback.
    assert_eq!(resting_poses_from_export(&export(vec![a.clone()]), "zz", "duck").unwrap().1, ExportMatch::Name);
    let err = resting_poses_from_export(&export(vec![a.clone(), b]), "zz", "cup").unwrap_err().to_string();
    assert!(err.contains("no entry for this mesh") && err.contains("duck, box"), "{err}");
    let skewed = serde_json::json!({"mesh": "x.obj", "sha256": "x", "clusters": [{"probability": 1.0, "R_model_to_plane": [1, 0, 0, 0, 2, 0, 0, 0, 1]}]});
    assert!(resting_poses_from_export(&export(vec![skewed]), "x", "x").unwrap_err().to_string().contains("not a rotation"));
    let mirrored = serde_json::json!({"mesh": "x.obj", "sha256": "x", "clusters": [{"probability": 1.0, "R_model_to_plane": [-1, 0, 0, 0, -1, 0, 0, 0, -1]}]});
    assert!(resting_poses_from_export(&export(vec![mirrored]), "x", "x").unwrap_err().to_string().contains("reflection"));
    // Probabilities are shares of the same settled drops: 0.6 + 0.6 is an
    // edited file and named as such; 1.005 is rounding.
    let doubled = serde_json::json!({"mesh": "models/duck.obj", "sha256": "x", "clusters": [cluster(0.6), cluster(0.6)]});
    let e = resting_poses_from_export(&export(vec![doubled]), "x", "x").unwrap_err().to_string();
    assert!(e.contains("the entry of models/duck.obj") && e.contains("sum to 1.200"), "{e}");
    let rounded = serde_json::json!({"mesh": "x.obj", "sha256": "x", "clusters": [cluster(0.5)], "families": [{"kind": "circle", "axis": [0.0, 0.0, 1.0], "probability": 0.505}]});
    assert!(resting_poses_from_export(&export(vec![rounded]), "x", "x").is_ok());
    let improbable = serde_json::json!({"mesh": "x.obj", "sha256": "x", "clusters": [{"probability": 5.0, "R_model_to_plane": [1, 0, 0, 0, 1, 0, 0, 0, 1]}]});
    assert!(resting_poses_from_export(&export(vec![improbable]), "x", "x").unwrap_err().to_string().contains("not in [0, 1]"));
    // An export without meshes says so (the message was cut off).
    let e = resting_poses_from_export(&export(vec![]), "x", "duck").unwrap_err().to_string();
    assert!(e.contains("it has no meshes"), "{e}");
    let e = resting_poses_from_export(r#"{"format": "plausible-stable-poses/1"}"#, "x", "x").unwrap_err().to_string();
    assert!(e.contains("missing field `meshes`"), "{e}");
    // The format tag is checked: another tool's JSON is not read as ours.
    let e = resting_poses_from_export(r#"{"format": "other-tool/2", "meshes": []}"#, "x", "x").unwrap_err();
    assert!(e.to_string().contains("format 'other-tool/2'"), "{e}");
    assert_eq!(e.input(), Some(plausible::Input::StablePoses));
    // A rolling family: 12 roll angles sharing its probability, each with
    // the rolling axis horizontal.
    let can = serde_json::json!({"mesh": "can.obj", "sha256": "c", "clusters": [cluster(0.4)],
        "families": [{"kind": "circle", "axis": [0.0, 0.0, 1.0], "probability": 0.6},
                     {"kind": "scattered", "axis": null, "probability": 0.0}]});
    let (rests, _) = resting_poses_from_export(&export(vec![can]), "c", "can").unwrap();
    assert_eq!(rests.len(), 1 + 12);
    for r in &rests[1..] {
        assert!((r.probability - 0.05).abs() < 1e-12 && r.group_probability == 0.6);
        assert!((r.r_model_to_plane * DVec3::Z).z.abs() < 1e-12, "the axis lies flat");
    }
}

/// A drop test stopped before clustering (killed, or Ctrl-C) had been
/// reported as "the mesh has no clusters (did its drops settle?)" though
/// every drop it finished had settled: the entry is named and the message
/// says to resume the run; a finished run of the same mesh is preferred to
/// an unfinished larger one.
#[test]
fn an_unfinished_drop_test_is_named_and_resumed_not_blamed_on_settling() {
    let export = |meshes: Vec<serde_json::Value>| serde_json::json!({"format": "plausible-stable-poses/1", "meshes": meshes}).to_string();
    let cluster = serde_json::json!({"probability": 1.0, "R_model_to_plane": [1, 0, 0, 0, 1, 0, 0, 0, 1]});
    let killed = serde_json::json!({"mesh": "models/obj_000001.ply", "sha256": "a", "drops": 2176, "drops_requested": 3000, "settled": 2176, "clusters": []});
    let e = resting_poses_from_export(&export(vec![killed.clone()]), "a", "obj_000001.ply").unwrap_err().to_string();
    assert!(e.contains("the entry of models/obj_000001.ply") && e.contains("unfinished (2176 of 3000 drops stored"), "{e}");
    assert!(e.contains("stable-poses run` again with the same arguments") && !e.contains("did its drops settle"), "{e}");
    // Every drop run, none settled: that is what the message says.
    let unsettled = serde_json::json!({"mesh": "models/ball.ply", "sha256": "a", "drops": 64, "drops_requested": 64, "settled": 0, "clusters": []});
    let e = resting_poses_from_export(&export(vec![unsettled]), "a", "ball.ply").unwrap_err().to_string();
    assert!(e.contains("the entry of models/ball.ply") && e.contains("none of its 64 drops settled"), "{e}");
    // Only ball-like families: no resting orientation to offer.
    let ball = serde_json::json!({"mesh": "ball.ply", "sha256": "a", "drops": 64, "drops_requested": 64, "settled": 64, "clusters": [],
        "families": [{"kind": "scattered", "axis": null, "probability": 1.0}]});
    let e = resting_poses_from_export(&export(vec![ball]), "a", "ball.ply").unwrap_err().to_string();
    assert!(e.contains("ball-like"), "{e}");
    // A finished 64-drop run beside the killed 3000-drop one: the finished one.
    let finished = serde_json::json!({"mesh": "models/obj_000001.ply", "sha256": "a", "drops": 64, "drops_requested": 64, "settled": 64, "clusters": [cluster]});
    let (rests, how) = resting_poses_from_export(&export(vec![killed, finished]), "a", "obj_000001.ply").unwrap();
    assert_eq!((rests.len(), how), (1, ExportMatch::Hash));
}

/// 100000 resting poses x 3600 yaws had collected 360 million (pose, yaw)
/// jobs (a 5.8 GB allocation that aborted the process) before the count
/// was checked; the count is now checked first, from the numbers alone.
#[test]
fn the_hypothesis_count_is_refused_before_anything_is_allocated() {
    let k = plausible::camera::Intrinsics { fx: 500.0, fy: 500.0, cx: 31.5, cy: 23.5, width: 64, height: 48 };
    let obs = plausible::observation::DepthImage { intrinsics: k, depth: vec![0.7; 64 * 48] };
    let mask = vec![true; 64 * 48];
    let rest = plausible::hypotheses::on_plane::RestingPose { r_model_to_plane: DMat3::IDENTITY, probability: 1e-5, group_probability: 1e-5 };
    let rests = vec![rest; 100_000];
    let plane = plausible::physical::Plane::in_camera(DVec3::new(0.0, 0.0, 0.75), DVec3::new(0.0, 0.0, -1.0)).unwrap();
    let p = OnPlaneParams { yaw_steps: 3600, min_probability: 0.0, ..Default::default() };
    let t = std::time::Instant::now();
    let e = on_plane_hypotheses(&duck(), &rests, &plane, &obs, &mask, &p).unwrap_err().to_string();
    assert!(e.contains("100000 resting poses x 3600 yaws x 1 offsets make 360000000 hypotheses; at most 1000000"), "{e}");
    assert!(t.elapsed().as_secs_f64() < 1.0, "refused at once, not after the work");
}

/// The lmo-synth scene the CLI tests run `plausible hypotheses` on: frame 3
/// of scene 2, the ape's mask, and a plane fitted there (written to `dir`).
struct ApeFrame {
    dir: tempfile::TempDir,
}

impl ApeFrame {
    fn new() -> ApeFrame {
        let dir = tempfile::tempdir().unwrap();
        let f = ApeFrame { dir };
        let plane = f.path("plane.json");
        let mut args = vec!["plane".to_string()];
        args.extend(f.observation());
        args.extend(["--out".to_string(), plane]);
        let (code, err) = run(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(code, 0, "{err}");
        f
    }

    fn path(&self, name: &str) -> String {
        self.dir.path().join(name).to_string_lossy().into_owned()
    }

    fn observation(&self) -> Vec<String> {
        let s = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/lmo-synth/test/000002");
        ["--camera", &format!("{s}/scene_camera.json"), "--frame", "3", "--depth", &format!("{s}/depth/000003.png"), "--mask", &format!("{s}/mask_visib/000003_000000.png")]
            .map(String::from)
            .to_vec()
    }

    /// Runs `plausible hypotheses` on `mesh` with `extra` flags (the fitted
    /// plane unless they give one); returns (exit code, stderr).
    fn hypotheses(&self, mesh: &str, extra: &[&str]) -> (i32, String) {
        let mut args = vec!["hypotheses".to_string(), "--mesh".to_string(), mesh.to_string()];
        args.extend(self.observation());
        if !extra.contains(&"--plane") {
            args.extend(["--plane".to_string(), self.path("plane.json")]);
        }
        args.extend(["--out".to_string(), self.path("hypotheses.json")]);
        args.extend(extra.iter().map(|s| s.to_string()));
        run(&args.iter().map(String::as_str).collect::<Vec<_>>())
    }
}

/// Runs the binary; returns (exit code, stderr).
fn run(args: &[&str]) -> (i32, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_plausible")).args(args).output().unwrap();
    (o.status.code().unwrap_or(-1), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn lmo_model(id: u32) -> String {
    format!(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/lmo-synth/models/obj_{:06}.ply"), id)
}

/// Every BOP dataset names its models obj_0000NN.ply: a database made from
/// another dataset (here the eggbox saved as obj_000001.ply) had given the
/// ape the eggbox's resting poses without a word. It still may, but says so.
#[test]
fn resting_poses_matched_by_file_name_only_are_warned_about() {
    let f = ApeFrame::new();
    let other = f.dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::copy(lmo_model(10), other.join("obj_000001.ply")).unwrap();
    std::fs::copy(lmo_model(11), other.join("obj_000099.ply")).unwrap();
    let db = f.path("other.db");
    let (a, b) = (other.join("obj_000001.ply"), other.join("obj_000099.ply"));
    let (code, err) = run(&["stable-poses", "run", "--db", &db, "--drops", "32", "--quiet", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let (code, err) = f.hypotheses(&lmo_model(1), &["--stable", &db]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("matches the file name only, not the geometry"), "{err}");
    // The ape's own database: found by geometry, no warning.
    let own = f.path("own.db");
    let (code, err) = run(&["stable-poses", "run", "--db", &own, "--drops", "32", "--quiet", &lmo_model(1), &lmo_model(10)]);
    assert_eq!(code, 0, "{err}");
    let (code, err) = f.hypotheses(&lmo_model(1), &["--stable", &own]);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("file name only"), "{err}");
}

/// The mesh's size against what the mask sees: a millimetre model read as
/// centimetres or metres (10 and 1000 times too large) had given poses
/// "centred on the observed object" metres away from it, and a metre model
/// read as millimetres a grid-step error while the grid was off.
#[test]
fn a_mesh_in_the_wrong_units_is_refused_or_warned_about() {
    let f = ApeFrame::new();
    let ape = lmo_model(1);
    let (code, err) = f.hypotheses(&ape, &[]);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("times smaller"), "the right units: no warning: {err}");
    for units in ["cm", "m"] {
        let (code, err) = f.hypotheses(&ape, &["--mesh-units", units]);
        assert_eq!(code, 0, "{units}: {err}");
        assert!(err.contains("times smaller: is the mesh in other units") && err.contains("--mesh-units"), "{units}: {err}");
    }
    let duck = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    let (code, err) = f.hypotheses(duck, &["--mesh-units", "mm"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("the visible part cannot be larger than the object") && err.contains("--mesh-units"), "{err}");
    assert!(!err.contains("grid step"), "the grid is off: {err}");
    // The grid step is checked against the object only with a grid.
    let (code, err) = f.hypotheses(&ape, &["--grid-step-mm", "500"]);
    assert_eq!(code, 0, "{err}");
    let (code, err) = f.hypotheses(&ape, &["--grid-step-mm", "500", "--grid-radius", "1"]);
    assert!(code == 1 && err.contains("a grid step of 0.500 m is larger than the object (0.142 m across)"), "{err}");
}

/// Values such as 1e300 in a flag or a plane file had been printed in full
/// (300 digits) in error messages.
#[test]
fn huge_values_are_printed_short_in_messages() {
    let f = ApeFrame::new();
    let ape = lmo_model(1);
    let (code, err) = f.hypotheses(&ape, &["--grid-step-mm", "1e308", "--grid-radius", "1"]);
    assert!(code == 1 && err.contains("a grid step of 1.000e305 m"), "{err}");
    assert!(err.len() < 400, "{err}");
    let far = f.path("far.json");
    std::fs::write(&far, r#"{"point": [1e300, 1e300, 1e300], "normal": [0, 0, 1]}"#).unwrap();
    let (code, err) = f.hypotheses(&ape, &["--plane", &far]);
    assert!(code == 1 && err.contains("lie 1.000e297 m above the support plane"), "{err}");
    assert!(err.len() < 600, "{err}");
    // A plane through the camera, its point far along it: the hint's
    // distance is short too.
    let through = f.path("through.json");
    std::fs::write(&through, r#"{"point": [1e150, 0, 5], "normal": [0, 0, 1]}"#).unwrap();
    let (code, err) = f.hypotheses(&ape, &["--plane", &through]);
    assert!(code == 1 && err.contains("the point is 1.000e150 mm from the camera"), "{err}");
    assert!(err.len() < 600, "{err}");
}
