//! `plausible report`: a self-contained HTML page from the outputs of the
//! demo (score records and pictures), a stable-pose export and an eval
//! report, all made here from shipped assets with small parameters; bad
//! inputs refused by name; and the page opened in headless Chromium
//! (skipped without Chromium unless PLAUSIBLE_REQUIRE_CHROMIUM=1).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

fn asset(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn ok(out: &Output, what: &str) {
    assert!(out.status.success(), "{what} failed:\n{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
}

/// The inputs, made once per test binary: the demo's folder, a stable-pose
/// export of the cube (with its mesh) and a copy naming a missing mesh,
/// and the eval report of the shipped LM-O subset.
struct Inputs {
    demo: PathBuf,
    stable: PathBuf,
    stable_no_mesh: PathBuf,
    eval: PathBuf,
}

fn inputs() -> &'static Inputs {
    static INPUTS: OnceLock<Inputs> = OnceLock::new();
    INPUTS.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("report-inputs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let demo = dir.join("demo");
        let out = plausible().args(["demo", "--n", "256", "--device", "cpu", "--out"]).arg(&demo).output().unwrap();
        ok(&out, "demo");
        let stable = dir.join("stable.json");
        let out = plausible()
            .args(["stable-poses", "run", "-q", "--drops", "40"])
            .arg(asset("assets/physics/cube.obj"))
            .arg("--db")
            .arg(dir.join("stable.sqlite"))
            .arg("--json")
            .arg(&stable)
            .output()
            .unwrap();
        ok(&out, "stable-poses");
        let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stable).unwrap()).unwrap();
        v["meshes"][0]["mesh"] = serde_json::json!("gone/missing_mesh.obj");
        let stable_no_mesh = dir.join("stable_no_mesh.json");
        std::fs::write(&stable_no_mesh, serde_json::to_string(&v).unwrap()).unwrap();
        let eval = dir.join("eval.json");
        let lmo = asset("assets/lmo-synth");
        let out = plausible()
            .args(["eval", "--quiet", "--device", "cpu", "--dataset"])
            .arg(&lmo)
            .arg("--results")
            .arg(lmo.join("perturbed.csv"))
            .arg("--out")
            .arg(&eval)
            .output()
            .unwrap();
        ok(&out, "eval");
        Inputs { demo, stable, stable_no_mesh, eval }
    })
}

/// Writes the full report of every input into `out`.
fn full_report(out: &Path) -> String {
    let i = inputs();
    let res = plausible()
        .arg("report")
        .arg(i.demo.join("scores.json"))
        .arg(i.demo.join("explain"))
        .arg(i.demo.join("alignment.png"))
        .arg(&i.stable)
        .arg(&i.stable_no_mesh)
        .arg(&i.eval)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap();
    ok(&res, "report");
    std::fs::read_to_string(out).unwrap()
}

#[test]
fn report_of_demo_stable_and_eval_is_self_contained() {
    let dir = tempfile::tempdir().unwrap();
    let html = full_report(&dir.path().join("report.html"));
    // Nothing fetched from anywhere: no URL at all, and a policy that
    // forbids other sources.
    for bad in ["http://", "https://", "src=\"//", "href=\"//", "url("] {
        assert!(!html.contains(bad), "the report refers to {bad}");
    }
    assert!(html.contains("Content-Security-Policy"));
    // The score table: the best 200 of 256 (the explained 0 and 111 are
    // among them), pictures embedded and linked.
    assert!(html.contains("256 hypotheses"));
    assert_eq!(html.matches("<tr id=\"row-").count(), 200);
    for id in ["row-0", "row-111", "pic-0", "pic-111"] {
        assert!(html.contains(&format!("id=\"{id}\"")), "no {id}");
    }
    assert!(html.contains("intersecting") && html.contains("plausible"));
    // Embedded pictures: 2 hypotheses, the alignment and the cube's drawn
    // resting poses; the export without its mesh shows text instead.
    assert!(html.matches("src=\"data:image/png;base64,").count() >= 4);
    assert!(html.contains("class=\"pose\""), "no drawn resting pose");
    assert!(html.contains("class=\"textpose\""), "no textual resting pose");
    assert!(html.contains("missing_mesh.obj not found"));
    // Eval: recall curves and per-object bars as inline SVG.
    for want in ["VSD recall", "MSSD recall", "MSPD recall", "AR and its parts per object", "<polyline", "<rect"] {
        assert!(html.contains(want), "no {want}");
    }
}

#[test]
fn report_refuses_bad_inputs_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("r.html");
    let empty = d.join("empty.json");
    std::fs::write(&empty, "").unwrap();
    let binary = d.join("blob.bin");
    std::fs::write(&binary, [0u8, 159, 146, 150, 255, 0, 1]).unwrap();
    let truncated = d.join("truncated.json");
    std::fs::write(&truncated, "[{\"index\": 0, \"rank\": 1, \"sco").unwrap();
    let fake_png = d.join("fake.png");
    std::fs::write(&fake_png, b"\x89PNG\r\n\x1a\nnot a picture").unwrap();
    let huge = d.join("huge.json");
    std::fs::File::create(&huge).unwrap().set_len(3 << 30).unwrap();
    let empty_dir = d.join("no_pictures");
    std::fs::create_dir(&empty_dir).unwrap();
    let poses = inputs().demo.join("poses.json");
    let plane = inputs().demo.join("plane.json");
    for bad in [&empty, &binary, &truncated, &fake_png, &huge, &empty_dir, &poses, &plane, &d.join("absent.json")] {
        let res = plausible().arg("report").arg(bad).arg("-o").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&res.stderr);
        assert_eq!(res.status.code(), Some(1), "{}: {err}", bad.display());
        assert!(err.contains(&*bad.file_name().unwrap().to_string_lossy()), "{}: the error does not name it: {err}", bad.display());
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "a report was written for {}", bad.display());
    }
    // The output is checked before the inputs are read.
    let scores = inputs().demo.join("scores.json");
    for (o, why) in [(d.join("missing/r.html"), "does not exist"), (d.join("r.txt"), ".html"), (scores.clone(), ".html")] {
        let res = plausible().arg("report").arg(&scores).arg("-o").arg(&o).output().unwrap();
        let err = String::from_utf8_lossy(&res.stderr);
        assert_eq!(res.status.code(), Some(1), "{err}");
        assert!(err.contains(why), "{}: {err}", o.display());
    }
}

#[test]
fn report_escapes_text_from_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let check = dir.path().join("check.json");
    let hostile = "<script>alert('x')</script>&\"";
    let json = serde_json::json!({
        "version": "0", "scene": hostile, "samples": 8, "seed": 0, "friction": 0.5,
        "objects": [{"name": hostile, "verdict": "floating", "static": false, "intersecting": 0, "contact": 1,
                     "supported": 1, "min_distance": 0.0, "stability_margin": null, "friction_equilibrium": null,
                     "methods_disagree": false, "displacement": null, "feasible": true, "stable": false,
                     "epsilon": 0.002, "grid_error_bound": 0.0, "mass_kg": 1.0, "centre_of_mass": [0, 0, 0]}]
    });
    std::fs::write(&check, json.to_string()).unwrap();
    let out = dir.path().join("r.html");
    let res = plausible().arg("report").arg(&check).arg("-o").arg(&out).output().unwrap();
    ok(&res, "report");
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(!html.contains("<script>alert"), "unescaped input text");
    assert!(html.contains("&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt;&amp;&quot;"));
    assert_eq!(html.matches("<script>").count(), 1, "only the report's own script");
}

/// The report's size is capped over all its inputs, not only per file: a
/// picture given many times is embedded once (one 9.7 MB PNG given 64
/// times had made an 830 MB page), pictures past the count or total size
/// are refused before any is decoded, and the stable-pose gallery is
/// capped over all meshes (an export of 100 meshes had made 4800 pictures).
#[test]
fn report_size_is_capped_over_all_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("r.html");
    let pic = d.join("a.png");
    image::RgbImage::from_pixel(8, 8, image::Rgb([200, 10, 10])).save(&pic).unwrap();
    let res = plausible().arg("report").args(std::iter::repeat_n(&pic, 64)).arg(d.join(".").join("a.png")).arg("-o").arg(&out).output().unwrap();
    ok(&res, "report");
    let html = std::fs::read_to_string(&out).unwrap();
    assert_eq!(html.matches("src=\"data:image/png;base64,").count(), 1, "the picture given 65 times is embedded once");
    std::fs::remove_file(&out).unwrap();
    // 30 pictures of 9 MiB (sparse files: only their signature is written)
    // pass the total; refused by their sizes, naming the largest.
    let big: Vec<PathBuf> = (0..30)
        .map(|i| {
            let p = d.join(format!("big{i:02}.png"));
            std::fs::write(&p, b"\x89PNG\r\n\x1a\n").unwrap();
            std::fs::OpenOptions::new().write(true).open(&p).unwrap().set_len(9 << 20).unwrap();
            p
        })
        .collect();
    let res = plausible().arg("report").args(&big).arg("-o").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&res.stderr);
    assert_eq!(res.status.code(), Some(1), "{err}");
    assert!(err.contains("270 MiB, more than the 256 MiB") && err.contains("big00.png (9.0 MiB)"), "{err}");
    assert!(!out.exists());
    // 201 pictures from several files and folders: refused before decoding.
    let many: Vec<PathBuf> = (0..201)
        .map(|i| {
            let p = d.join(format!("m{i:03}.png"));
            std::fs::copy(&pic, &p).unwrap();
            p
        })
        .collect();
    let res = plausible().arg("report").args(&many).arg("-o").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(err.contains("201 pictures, more than the 200"), "{err}");
    // An export of 6 meshes of 48 clusters each: 192 cards over all of them.
    let cluster = serde_json::json!({"probability": 0.02, "ci95": [0.01, 0.03], "count": 10, "gravity_in_model": [0, 0, -1],
                                     "R_model_to_plane": [1, 0, 0, 0, 1, 0, 0, 0, 1], "height": 0.025});
    let mesh = serde_json::json!({"mesh": asset("assets/physics/cube.obj"), "sha256": "x", "drops": 500, "settled": 500, "clusters": vec![cluster; 48]});
    let export = d.join("stable.json");
    std::fs::write(&export, serde_json::json!({"format": "plausible-stable-poses/1", "meshes": vec![mesh; 6]}).to_string()).unwrap();
    let res = plausible().arg("report").arg(&export).arg("-o").arg(&out).output().unwrap();
    ok(&res, "report");
    let html = std::fs::read_to_string(&out).unwrap();
    assert_eq!(html.matches("class=\"card\"").count(), 192);
    assert_eq!(html.matches("class=\"pose\"").count(), 192, "the cube is drawn");
    assert_eq!(html.matches("gallery pictures went to the meshes above").count(), 2);
}

/// Chromium, if installed.
fn chromium() -> Option<PathBuf> {
    let candidates = ["/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome"];
    candidates.iter().map(PathBuf::from).find(|p| p.is_file())
}

/// Runs headless Chromium on `page` with `args`, killed after two minutes;
/// returns its standard output and error. They go to files, not pipes: a
/// dumped DOM is larger than a pipe's buffer and would block Chromium
/// until it is read.
fn run_chromium(bin: &Path, profile: &Path, args: &[String], page: &Path) -> (String, String) {
    let (out_path, err_path) = (profile.with_extension("stdout"), profile.with_extension("stderr"));
    let mut child = Command::new(bin)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run"])
        .args(["--disable-background-networking", "--disable-component-update", "--disable-sync"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(format!("file://{}", page.display()))
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("chromium starts");
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("chromium did not finish in 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let read = |p: &Path| String::from_utf8_lossy(&std::fs::read(p).unwrap_or_default()).into_owned();
    (read(&out_path), read(&err_path))
}

#[test]
fn chromium_renders_the_report_and_runs_its_script() {
    let Some(bin) = chromium() else {
        if std::env::var("PLAUSIBLE_REQUIRE_CHROMIUM").as_deref() == Ok("1") {
            panic!("PLAUSIBLE_REQUIRE_CHROMIUM=1 but no chromium was found (apt-get install chromium)");
        }
        println!("skipped: no chromium (install it, or set PLAUSIBLE_REQUIRE_CHROMIUM=1 to make this a failure)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("report.html");
    full_report(&page);
    let shot = dir.path().join("shot.png");
    let args = [format!("--screenshot={}", shot.display()), "--window-size=1280,2000".to_string()];
    let (_, err) = run_chromium(&bin, &dir.path().join("profile-shot"), &args, &page);
    assert!(shot.is_file(), "no screenshot: {err}");
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 2000));
    let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    assert!(colours.len() > 200, "the screenshot looks blank: {} colours", colours.len());
    let white = img.pixels().filter(|p| p.0 == [255, 255, 255]).count() as f64 / (1280.0 * 2000.0);
    assert!(white < 0.97, "the screenshot is {:.1} % white", white * 100.0);
    // The DOM after the scripts ran: the sort script marks the tables and
    // counts their rows.
    let (dom, err) = run_chromium(&bin, &dir.path().join("profile-dom"), &["--dump-dom".to_string()], &page);
    assert!(dom.contains("data-report=\"ready\""), "the script did not run: {err}");
    let table = dom.find("id=\"scores-0\"").expect("the scores table is in the DOM");
    let tag_end = table + dom[table..].find('>').unwrap();
    let tag = &dom[dom[..table].rfind('<').unwrap()..tag_end];
    assert!(tag.contains("data-sortable=\"ready\"") && tag.contains("data-rows=\"200\""), "scores table: {tag}");
    assert_eq!(dom.matches("<tr id=\"row-").count(), 200);
}
