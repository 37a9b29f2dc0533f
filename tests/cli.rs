//! The `plausible` binary end to end: the demo writes BOP-style inputs,
//! `score` reads them back and writes the documented JSON and CSV.

use std::process::Command;

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

fn device_args() -> Vec<&'static str> {
    // Use the GPU when one exists (and insist on it when CI requires it).
    if plausible::gpu::test_context().is_some() {
        vec!["--device", "gpu"]
    } else {
        vec!["--device", "cpu"]
    }
}

#[test]
fn demo_then_score_round_trip() {
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
    for f in ["alignment.png", "depth.png", "mask.png", "camera.json", "poses.json", "duck_0.15m.obj", "scores.json"] {
        assert!(out.join(f).exists(), "{f} missing");
    }

    let json = dir.path().join("scores.json");
    let csv = dir.path().join("scores.csv");
    for (path, dev) in [(&json, device_args()), (&csv, vec!["--device", "cpu"])] {
        let o = plausible()
            .arg("score")
            .arg("--mesh").arg(out.join("duck_0.15m.obj"))
            .arg("--camera").arg(out.join("camera.json"))
            .arg("--depth").arg(out.join("depth.png"))
            .arg("--mask").arg(out.join("mask.png"))
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

#[test]
fn score_reports_bad_input_without_panicking() {
    let o = plausible()
        .args(["score", "--mesh", "/nonexistent/m.obj", "--camera", "c.json", "--depth", "d.png", "--poses", "p.json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("error: /nonexistent/m.obj: file not found"), "{err}");
    assert!(!err.contains("panicked"));
}
