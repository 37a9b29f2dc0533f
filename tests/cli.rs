//! The `plausible` binary end to end: the demo writes BOP-style inputs,
//! `score` reads them back and writes the documented JSON and CSV.

use std::process::Command;

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

/// `sub` on the demo's inputs in `out`: camera, depth and mask, plus the
/// mesh unless `sub` is `plane`.
fn on_demo(sub: &str, out: &std::path::Path) -> Command {
    let mut c = plausible();
    c.arg(sub);
    if sub != "plane" {
        c.arg("--mesh").arg(out.join("duck_0.15m.obj"));
    }
    c.arg("--camera").arg(out.join("camera.json"));
    c.arg("--depth").arg(out.join("depth.png"));
    c.arg("--mask").arg(out.join("mask.png"));
    c
}

/// The demo's inputs for `n` poses, made on the CPU twin into `dir/demo`.
fn cpu_demo(dir: &std::path::Path, n: usize) -> std::path::PathBuf {
    let out = dir.join("demo");
    let o = plausible().args(["demo", "--n", &n.to_string(), "--device", "cpu", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn device_args() -> Vec<&'static str> {
    // The GPU (these tests have `gpu` in their names: `cargo test -- --skip
    // gpu` skips them where no adapter exists).
    let _ = plausible::gpu::test_context();
    vec!["--device", "gpu"]
}

#[test]
fn gpu_demo_then_score_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = plausible()
        .args(["demo", "--n", "256", "--out"])
        .arg(&out)
        .args(device_args())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("true pose: rank 1 of 256"), "{stdout}");
    assert!(stdout.contains("visual score alone: true pose rank 1"), "{stdout}");
    for f in ["alignment.png", "depth.png", "mask.png", "camera.json", "poses.json", "plane.json", "duck_0.15m.obj", "scores.json"] {
        assert!(out.join(f).exists(), "{f} missing");
    }

    let json = dir.path().join("scores.json");
    let csv = dir.path().join("scores.csv");
    for (path, dev) in [(&json, device_args()), (&csv, vec!["--device", "cpu"])] {
        let o = on_demo("score", &out)
            .arg("--poses").arg(out.join("poses.json"))
            .args(["--top", "3", "--quiet", "--out"])
            .arg(path)
            .args(dev)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let records: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(records.len(), 256);
    for key in ["index", "rank", "score", "a_d", "a_n", "valid", "rendered", "observed"] {
        assert!(records[0].get(key).is_some(), "missing {key}");
    }
    assert_eq!(records[0]["rank"], 1);
    let mut ranks: Vec<u64> = records.iter().map(|r| r["rank"].as_u64().unwrap()).collect();
    ranks.sort();
    assert_eq!(ranks, (1..=256).collect::<Vec<u64>>());

    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("index,rank,score,a_d,a_n,valid,rendered,observed"));
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 256);
    // GPU (or CPU) JSON and CPU-twin CSV agree within the twin tolerance.
    for (r, j) in rows.iter().zip(&records) {
        assert!((r[2] - j["score"].as_f64().unwrap()).abs() < 1e-3);
    }
}

/// `plane` fits the demo's table again, and `score --plane --physics` adds
/// the physical terms to every record and ranks plausible hypotheses first.
#[test]
fn gpu_plane_then_score_with_physics() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = plausible().args(["demo", "--n", "300", "--out"]).arg(&out).args(device_args()).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plane = dir.path().join("plane.json");
    let o = on_demo("plane", &out)
        .arg("--out").arg(&plane)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let read = |p: &std::path::Path| -> serde_json::Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
    let (a, b) = (read(&plane), read(&out.join("plane.json")));
    // The same plane (the demo fitted the float depth, `plane` the 0.1 mm PNG).
    let v = |j: &serde_json::Value, key: &str| glam::DVec3::from_array([0, 1, 2].map(|i| j[key][i].as_f64().unwrap()));
    assert!(v(&a, "normal").angle_between(v(&b, "normal")).to_degrees() < 0.01);
    assert!(v(&b, "normal").dot(v(&a, "point") - v(&b, "point")).abs() < 0.1, "mm");

    let json = dir.path().join("records.json");
    let o = on_demo("score", &out)
        .arg("--poses").arg(out.join("poses.json"))
        .arg("--plane").arg(&plane)
        .args(["--physics", "--quiet", "--out"])
        .arg(&json)
        .arg("--explain").arg(dir.path().join("why"))
        .args(["--explain-ids", "0,7"])
        .args(device_args())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("plausible") && stdout.contains("intersecting"), "{stdout}");
    let records: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(records.len(), 300);
    for key in ["verdict", "intersecting", "contact", "supported", "min_distance", "stability_margin", "feasible", "stable"] {
        assert!(records[0].get(key).is_some(), "missing {key}");
    }
    assert_eq!(records[0]["rank"], 1);
    assert_eq!(records[0]["verdict"], "plausible");
    // Physics first: every plausible record outranks every other one.
    let worst_plausible = records.iter().filter(|r| r["verdict"] == "plausible").map(|r| r["rank"].as_u64().unwrap()).max().unwrap();
    let best_other = records.iter().filter(|r| r["verdict"] != "plausible").map(|r| r["rank"].as_u64().unwrap()).min().unwrap();
    assert!(worst_plausible < best_other);
    // One picture per explained hypothesis, under a band in its verdict's colour.
    for i in [0, 7] {
        let img = image::open(dir.path().join(format!("why/hypothesis_{i}.png"))).unwrap().to_rgb8();
        assert!(img.width() >= 1024 && img.height() > 800);
        let band = img.get_pixel(5, 2).0;
        let want = match records[i]["verdict"].as_str().unwrap() {
            "plausible" => [40, 160, 70],
            "unstable" => [240, 150, 20],
            "floating" => [140, 80, 200],
            _ => [220, 30, 30],
        };
        assert_eq!(band, want, "hypothesis {i}");
    }
    assert!(out.join("explain").read_dir().unwrap().count() >= 1, "the demo explains its best hypothesis");
    // Hypotheses from the duck's resting poses on the fitted plane: 24 yaws
    // each, all of them resting on the plane, the best within 10° and 5 mm of
    // the demo's truth (index 0 of poses.json).
    let hyps = dir.path().join("hyps.json");
    let o = on_demo("hypotheses", &out)
        .arg("--plane").arg(&plane)
        .arg("--out").arg(&hyps)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let list: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&hyps).unwrap()).unwrap();
    assert_eq!(list.len() % 24, 0);
    assert!(list[0].get("rest").is_some() && list[0].get("yaw_deg").is_some());
    // The same plane's millimetre numbers declared as metres: the object is
    // not on it, so no hypotheses 370 m away said to be centred on it.
    let mut wrong: serde_json::Value = serde_json::from_slice(&std::fs::read(&plane).unwrap()).unwrap();
    wrong["units"] = "m".into();
    let wrong_path = dir.path().join("plane-m.json");
    std::fs::write(&wrong_path, wrong.to_string()).unwrap();
    let o = on_demo("hypotheses", &out).arg("--plane").arg(&wrong_path).arg("--out").arg(dir.path().join("h2.json")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("other units"), "{err}");
    // A WGPU_BACKEND that names no backend is an error, not ignored.
    let o = on_demo("score", &out).arg("--poses").arg(&hyps).args(["--device", "gpu"]).env("WGPU_BACKEND", "vulkan,nonsense").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("WGPU_BACKEND='vulkan,nonsense' names no backend"), "{err}");
    let scored = dir.path().join("hyps-scored.json");
    let o = on_demo("score", &out)
        .arg("--poses").arg(&hyps)
        .arg("--plane").arg(&plane)
        .args(["--physics", "--quiet", "--out"])
        .arg(&scored)
        .args(device_args())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let recs: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&scored).unwrap()).unwrap();
    assert!(recs.iter().all(|r| r["verdict"] != "floating" && r["verdict"] != "intersecting"));
    let best = recs.iter().position(|r| r["rank"] == 1).unwrap();
    let poses: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(out.join("poses.json")).unwrap()).unwrap();
    let rot = |p: &serde_json::Value| glam::DMat3::from_cols_array(&std::array::from_fn(|i| p["cam_R_m2c"][i].as_f64().unwrap())).transpose();
    let pos = |p: &serde_json::Value| glam::DVec3::from_array(std::array::from_fn(|i| p["cam_t_m2c"][i].as_f64().unwrap()));
    let rel = rot(&list[best]).transpose() * rot(&poses[0]);
    let angle = ((rel.x_axis.x + rel.y_axis.y + rel.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
    assert!(angle < 10.0 && (pos(&list[best]) - pos(&poses[0])).length() < 5.0, "{angle}°");
    // The resting poses can come from a drop-test database instead.
    let db = dir.path().join("stable.sqlite");
    let export = dir.path().join("stable.json");
    let run = |c: &mut Command| {
        let o = c.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let mesh = out.join("duck_0.15m.obj");
    run(plausible().arg("stable-poses").arg(&mesh).args(["--mesh-units", "m", "--drops", "200", "--quiet", "--db"]).arg(&db));
    run(plausible().args(["stable-poses", "export", "--db"]).arg(&db).arg("--json").arg(&export));
    let text = run(on_demo("hypotheses", &out)
        .arg("--plane").arg(&plane)
        .arg("--stable").arg(&export)
        .args(["--yaw-steps", "12", "--out"])
        .arg(&hyps));
    assert!(text.contains("from drop-test clusters"), "{text}");
    let list: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&hyps).unwrap()).unwrap();
    assert!(!list.is_empty() && list.len() % 12 == 0);
    // And the demo wrote the same verdicts.
    let demo: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(out.join("scores.json")).unwrap()).unwrap();
    let same = demo.iter().zip(&records).filter(|(a, b)| a["verdict"] == b["verdict"]).count();
    assert!(same >= 299, "{same} of 300 verdicts agree");
}

#[test]
fn score_reports_bad_input_without_panicking() {
    let o = plausible()
        .args(["score", "--mesh", "/nonexistent/m.obj", "--camera", "c.json", "--depth", "d.png", "--poses", "p.json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("error: /nonexistent/m.obj: not found"), "{err}");
    assert!(!err.contains("panicked"));
    // Physics options without --physics are a mistake worth saying.
    let o = plausible()
        .args(["score", "--mesh", "m.obj", "--camera", "c.json", "--depth", "d.png", "--poses", "p.json", "--samples", "64"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("add --plane P.json --physics"));
    // A negative number reaches the flag's own range check (exit 1, the
    // flag named), not clap's "unexpected argument" (exit 2); a frame id a
    // single camera cannot use is refused, not ignored.
    let d = tempfile::tempdir().unwrap();
    let cam = d.path().join("camera.json");
    std::fs::write(&cam, r#"{"cam_K": [572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1], "depth_scale": 0.1}"#).unwrap();
    for (extra, want) in [
        (["--inlier-mm", "-5"], "--inlier-mm -5"),
        (["--inlier-mm", "-inf"], "--inlier-mm -inf"),
        (["--inlier-mm", "-NaN"], "--inlier-mm NaN"),
        (["--frame", "3"], "--frame 3"),
    ] {
        let o = plausible().args(["plane", "--depth", "d.png"]).arg("--camera").arg(&cam).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains(want), "{err}");
    }
}

/// An output never replaces an input: `--out` of score, plane and
/// hypotheses naming one of their inputs, and `--trace` naming a pose list
/// (a JSON array like a trace), are refused and the file is left as it was.
#[test]
fn outputs_and_traces_never_replace_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let out = cpu_demo(dir.path(), 64);
    let poses = out.join("poses.json");
    let kept: Vec<(std::path::PathBuf, Vec<u8>)> =
        ["poses.json", "depth.png", "duck_0.15m.obj", "plane.json"].iter().map(|f| (out.join(f), std::fs::read(out.join(f)).unwrap())).collect();
    let with = |mut c: Command, extra: &[&std::ffi::OsStr]| {
        c.args(extra);
        c
    };
    let (p, o_) = (poses.as_os_str(), std::ffi::OsStr::new("--out"));
    let (depth, mesh, plane) = (out.join("depth.png"), out.join("duck_0.15m.obj"), out.join("plane.json"));
    let mut trace = plausible();
    trace.arg("--trace").arg(&poses).args(on_demo("score", &out).get_args()).arg("--poses").arg(&poses);
    let cases = [
        (with(on_demo("score", &out), &["--poses".as_ref(), p, o_, p]), "--out and --poses name the same file"),
        (with(on_demo("plane", &out), &[o_, depth.as_os_str()]), "--out and --depth name the same file"),
        (with(on_demo("hypotheses", &out), &["--plane".as_ref(), plane.as_os_str(), o_, mesh.as_os_str()]), "--out and --mesh name the same file"),
        (trace, "is not a trace"),
    ];
    for (mut c, want) in cases {
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains(want), "{want}: {err}");
    }
    for (path, bytes) in &kept {
        assert!(std::fs::read(path).unwrap() == *bytes, "{} changed", path.display());
    }
}

/// `plausible ... | head -1`: the binary ends quietly when its reader goes
/// away, without a panic.
#[test]
fn closed_stdout_ends_quietly() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let mut child = plausible()
        .args(["demo", "--n", "64", "--device", "cpu", "--out"])
        .arg(dir.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
    assert!(first.starts_with("mesh:"), "{first}");
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
}

/// `bench score` alternates the GPU's and the twin's timed runs and reports
/// the median of the pairs' ratios, so both devices are timed in the same
/// moments of a machine whose speed drifts.
#[test]
fn gpu_bench_score_pairs_the_gpu_and_twin_runs() {
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let o = plausible()
        .args(["bench", "score", "--quick", "--json", "--repeat", "3", "--mesh", cube])
        .args(device_args())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(rows.len(), 2, "N = 256 and 1024");
    for r in &rows {
        let runs = |k: &str| r[k].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>();
        let (gpu, cpu) = (runs("gpu_runs_hyps_per_s"), runs("cpu_runs_hyps_per_s"));
        assert_eq!((gpu.len(), cpu.len()), (3, 3), "{r}");
        let mut ratios: Vec<f64> = gpu.iter().zip(&cpu).map(|(g, c)| g / c).collect();
        ratios.sort_by(f64::total_cmp);
        assert_eq!(r["gpu_cpu"].as_f64().unwrap(), ratios[1], "{r}");
        let mut sorted = cpu.clone();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(r["cpu_hyps_per_s"].as_f64().unwrap(), sorted[1], "{r}");
    }
    // Without the twin, no ratio.
    let o = plausible()
        .args(["bench", "score", "--quick", "--json", "--repeat", "1", "--no-cpu", "--mesh", cube])
        .args(device_args())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for l in String::from_utf8_lossy(&o.stdout).lines() {
        let r: serde_json::Value = serde_json::from_str(l).unwrap();
        assert!(r["gpu_cpu"].is_null() && r["cpu_runs_hyps_per_s"].as_array().unwrap().is_empty(), "{r}");
    }
}

/// `--explain DIR` replaces only the pictures an earlier run listed there:
/// a file of the user's under a picture's name (or an input) is refused
/// before any work and left as it was, and other files stay.
#[test]
fn explain_replaces_only_its_own_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let out = cpu_demo(dir.path(), 16);
    let why = dir.path().join("why");
    let score = |ids: &str| {
        on_demo("score", &out).arg("--poses").arg(out.join("poses.json")).args(["--quiet", "--device", "cpu", "--explain-ids", ids, "--explain"]).arg(&why).output().unwrap()
    };
    std::fs::create_dir_all(&why).unwrap();
    std::fs::write(why.join("hypothesis_3.png"), "my notes").unwrap();
    let o = score("3");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("hypothesis_3.png") && err.contains("not a picture of an earlier run"), "{err}");
    assert_eq!(std::fs::read_to_string(why.join("hypothesis_3.png")).unwrap(), "my notes");
    // Other files stay; each run's pictures replace the last run's.
    std::fs::rename(why.join("hypothesis_3.png"), why.join("notes.txt")).unwrap();
    assert!(score("1,2").status.success());
    let names = |d: &std::path::Path| {
        let mut v: Vec<String> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    };
    assert_eq!(names(&why), [".plausible-explain", "hypothesis_1.png", "hypothesis_2.png", "notes.txt"]);
    assert!(score("5").status.success());
    assert_eq!(names(&why), [".plausible-explain", "hypothesis_5.png", "notes.txt"]);
    // An input under a picture's name: refused, even where listed.
    std::fs::copy(out.join("mask.png"), why.join("hypothesis_5.png")).unwrap();
    let o = plausible()
        .arg("score")
        .arg("--mesh").arg(out.join("duck_0.15m.obj"))
        .arg("--camera").arg(out.join("camera.json"))
        .arg("--depth").arg(out.join("depth.png"))
        .arg("--mask").arg(why.join("hypothesis_5.png"))
        .arg("--poses").arg(out.join("poses.json"))
        .args(["--quiet", "--device", "cpu", "--explain"]).arg(&why)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--mask") && err.contains("an input named like the pictures"), "{err}");
    assert!(why.join("hypothesis_5.png").exists());
}

/// Surface samples farther apart than twice the contact tolerance can all
/// miss a resting face: `score --physics` says so (the demo's duck at 64
/// samples, about 20 mm apart against ε = 5 mm), and not at the default.
#[test]
fn sparse_surface_samples_are_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let out = cpu_demo(dir.path(), 16);
    let score = |samples: &str| {
        let o = on_demo("score", &out)
            .arg("--poses").arg(out.join("poses.json"))
            .arg("--plane").arg(out.join("plane.json"))
            .args(["--physics", "--quiet", "--device", "cpu", "--samples", samples])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let err = score("64");
    assert!(err.contains("contacts can go unseen") && err.contains("take at least"), "{err}");
    assert!(!score("1024").contains("unseen"));
}
