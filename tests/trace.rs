//! `--trace`: the Chrome trace of a `score` run is valid JSON Trace Event
//! Format, names the stages, and the root span's direct children cover it.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

/// Writes the demo's inputs (256 hypotheses) into `out`.
fn demo(out: &Path) {
    let o = plausible().args(["demo", "--n", "256", "--device", "cpu", "--out"]).arg(out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `plausible score` on the demo's inputs.
fn score(out: &Path) -> Command {
    let mut c = plausible();
    c.arg("score").arg("--mesh").arg(out.join("duck_0.15m.obj"));
    c.arg("--camera").arg(out.join("camera.json"));
    c.arg("--depth").arg(out.join("depth.png"));
    c.arg("--mask").arg(out.join("mask.png"));
    c.arg("--poses").arg(out.join("poses.json"));
    c.arg("--quiet");
    c
}

/// A span rebuilt from its begin and end events.
#[derive(Debug)]
struct Span {
    name: String,
    start: f64,
    end: f64,
    parent: Option<usize>,
}

impl Span {
    fn duration(&self) -> f64 {
        self.end - self.start
    }
}

/// The events of a trace file: a JSON array, or an object with
/// `traceEvents`. Every event has a name and a phase, and a timestamp
/// unless it is metadata (`ph: "M"`, a thread's name).
fn events(path: &Path) -> Vec<Value> {
    let v: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).expect("the trace is JSON");
    let events = match v {
        Value::Array(a) => a,
        Value::Object(mut o) => match o.remove("traceEvents") {
            Some(Value::Array(a)) => a,
            other => panic!("traceEvents is not an array: {other:?}"),
        },
        other => panic!("a trace is an array or an object, not {other}"),
    };
    for e in &events {
        assert!(e["name"].is_string(), "event without a name: {e}");
        let ph = e["ph"].as_str().unwrap_or_else(|| panic!("event without a phase: {e}"));
        assert!(ph == "M" || e["ts"].is_number(), "event without a timestamp: {e}");
    }
    events
}

/// The spans of a trace, from B/E pairs per thread (and X events), each
/// with the span open around it on its thread as parent.
fn spans(events: &[Value]) -> Vec<Span> {
    let mut spans: Vec<Span> = Vec::new();
    let mut open: std::collections::HashMap<u64, Vec<usize>> = Default::default();
    for e in events {
        let tid = e["tid"].as_u64().unwrap_or(0);
        let ts = e["ts"].as_f64().unwrap_or(0.0);
        let name = e["name"].as_str().unwrap().to_string();
        let stack = open.entry(tid).or_default();
        match e["ph"].as_str().unwrap() {
            "B" => {
                spans.push(Span { name, start: ts, end: f64::NAN, parent: stack.last().copied() });
                stack.push(spans.len() - 1);
            }
            "E" => {
                let i = stack.pop().unwrap_or_else(|| panic!("an end without a begin: {e}"));
                assert_eq!(spans[i].name, name, "spans end in the order they began");
                spans[i].end = ts;
            }
            "X" => {
                let end = ts + e["dur"].as_f64().expect("X events have a duration");
                spans.push(Span { name, start: ts, end, parent: stack.last().copied() });
            }
            _ => {}
        }
    }
    assert!(open.values().all(Vec::is_empty), "every span ends (the trace file is complete)");
    spans
}

/// Checks the trace of a `score` run: the root span, its stages, and that
/// the stages add up to the root within 10 %. Returns the events.
fn check_score_trace(path: &Path, expected: &[&str]) -> Vec<Value> {
    let events = events(path);
    let spans = spans(&events);
    let names: Vec<&str> = spans.iter().map(|s| s.name.as_str()).collect();
    for name in expected {
        assert!(names.contains(name), "no span {name} in {names:?}");
    }
    let roots: Vec<usize> = (0..spans.len()).filter(|&i| spans[i].name == "plausible score").collect();
    assert_eq!(roots.len(), 1, "one root span: {names:?}");
    let root = &spans[roots[0]];
    assert_eq!(root.parent, None, "the command's span is the root");
    let children: Vec<&Span> = spans.iter().filter(|s| s.parent == Some(roots[0])).collect();
    let sum: f64 = children.iter().map(|s| s.duration()).sum();
    let ratio = sum / root.duration();
    assert!(
        (0.9..=1.0 + 1e-9).contains(&ratio),
        "the stages cover {:.1} % of the root ({sum:.0} of {:.0} µs): {children:?}",
        ratio * 100.0,
        root.duration()
    );
    events
}

#[test]
fn score_trace_on_the_cpu_covers_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    demo(&out);
    let trace = dir.path().join("trace.json");
    let o = score(&out).args(["--device", "cpu", "--out"]).arg(dir.path().join("s.json")).arg("--trace").arg(&trace).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let expected = ["load", "mesh", "observation", "poses", "setup", "scoring", "cpu_twin", "ranking", "report", "write"];
    check_score_trace(&trace, &expected);
}

#[test]
fn gpu_score_trace_has_the_passes() {
    let ctx = plausible::gpu::test_context();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    demo(&out);
    let trace = dir.path().join("trace.json");
    let o = score(&out).args(["--device", "gpu", "--trace"]).arg(&trace).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let expected = ["load", "setup", "compile", "gpu_setup", "scoring", "cull", "upload", "dispatch", "readback", "ranking", "report"];
    let events = check_score_trace(&trace, &expected);
    // With timestamp queries, the GPU time of the pass is in the trace,
    // marked not reliable on a software adapter.
    let gpu: Vec<&Value> = events.iter().filter(|e| e["name"] == "gpu pass").collect();
    if ctx.timestamps {
        assert!(!gpu.is_empty(), "no GPU time in the trace");
        let ms: f64 = gpu[0]["args"]["gpu_ms"].as_str().and_then(|s| s.parse().ok()).expect("gpu_ms");
        assert!(ms >= 0.0 && ms.is_finite(), "{ms}");
        let reliable = if ctx.is_software() { "false" } else { "true" };
        assert_eq!(gpu[0]["args"]["reliable"], reliable);
    }
}

/// A trace into a folder that does not exist fails at once, before the run.
#[test]
fn trace_into_a_missing_folder_fails_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    demo(&out);
    let trace = dir.path().join("no such folder").join("trace.json");
    let o = score(&out).args(["--device", "cpu", "--trace"]).arg(&trace).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("--trace") && stderr.contains("does not exist"), "{stderr}");
    assert!(o.stdout.is_empty(), "nothing was scored: {}", String::from_utf8_lossy(&o.stdout));
    assert!(!trace.exists());
}

/// A failing command still leaves a complete trace (the error path finishes
/// the file too).
#[test]
fn trace_is_complete_when_the_command_fails() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    demo(&out);
    let trace = dir.path().join("trace.json");
    let o = score(&out).args(["--device", "cpu", "--tau", "5", "--trace"]).arg(&trace).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    let spans = spans(&events(&trace));
    assert!(spans.iter().any(|s| s.name == "plausible score"), "{spans:?}");
}

/// A trace that cannot be written (a full disk) is an error, not a panic
/// of the writer thread or a silently cut file.
#[cfg(target_os = "linux")]
#[test]
fn trace_write_error_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    demo(&out);
    let o = score(&out).args(["--device", "cpu", "--trace", "/dev/full"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot write the trace /dev/full"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Ctrl-C (or SIGTERM) during a long run finishes the trace at the path
/// asked for (no hidden `.partial` file left), exits with 128 + the
/// signal, and leaves the run's database resumable.
#[cfg(unix)]
#[test]
fn interrupted_run_leaves_its_trace() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/pybullet/duck_vhacd.obj");
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let trace = dir.path().join(format!("trace{code}.json"));
        let db = dir.path().join(format!("drops{code}.sqlite"));
        let child = plausible()
            .args(["stable-poses", "--drops", "10000000", "--threads", "1", "--db"])
            .arg(&db)
            .arg(&mesh)
            .arg("--trace")
            .arg(&trace)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // The signals are taken once the trace file exists; wait for the
        // drops to start (the database), then interrupt.
        let start = std::time::Instant::now();
        while !db.exists() && start.elapsed().as_secs() < 120 {
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        std::thread::sleep(std::time::Duration::from_millis(500));
        let k = Command::new("kill").arg(signal).arg(child.id().to_string()).status().unwrap();
        assert!(k.success());
        let o = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{stderr}");
        assert!(stderr.contains("interrupted"), "{stderr}");
        let ev = events(&trace);
        assert!(ev.iter().any(|e| e["name"] == "plausible stable-poses"), "{ev:?}");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().filter_map(|e| e.ok()).filter(|e| e.file_name().to_string_lossy().ends_with(".partial")).collect();
        assert!(left.is_empty(), "{left:?}");
        let show = plausible().args(["stable-poses", "show", "--db"]).arg(&db).output().unwrap();
        assert!(show.status.success(), "{}", String::from_utf8_lossy(&show.stderr));
    }
}
