//! `plausible refine` and `estimate` on the shipped 12-frame LM-O subset (synthetic noisy
//! depth, oracle masks), measured with `plausible eval`: the AR gain on
//! perturbed estimates, the GT kept, resume after a kill, shards.

use std::path::{Path, PathBuf};
use std::process::Command;

fn plausible() -> Command {
    Command::new(env!("CARGO_BIN_EXE_plausible"))
}

fn dataset() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/lmo-synth")
}

fn run(c: &mut Command) -> String {
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn refine(init: &Path, out: &Path, extra: &[&str]) -> String {
    run(plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(init).arg("--out").arg(out).args(["--quiet", "--device", "cpu"]).args(extra))
}

fn ar(results: &Path, dir: &Path) -> f64 {
    let json = dir.join("eval.json");
    run(plausible().arg("eval").arg("--dataset").arg(dataset()).arg("--results").arg(results).args(["--quiet", "--device", "cpu", "--out"]).arg(&json));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    v["ar"].as_f64().unwrap_or_else(|| panic!("no ar in {v}"))
}

/// Every line but the time column, sorted (times are wall clock).
fn rows(path: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect();
    v.sort();
    v
}

#[test]
fn rir_raises_ar_on_perturbed_estimates_and_keeps_the_ground_truth() {
    let d = tempfile::tempdir().unwrap();
    let init = dataset().join("perturbed.csv");
    let out = d.path().join("refined.csv");
    let text = refine(&init, &out, &[]);
    assert!(text.contains("refined 12 images"), "{text}");
    let (before, after) = (ar(&init, d.path()), ar(&out, d.path()));
    eprintln!("AR {before:.4} -> {after:.4}");
    assert!(after >= before + 0.10, "AR {before} -> {after}");
    // The ground truth as estimates: refinement keeps it (AR drops ≤ 0.01).
    let gt = d.path().join("gt.csv");
    run(plausible().arg("eval").arg("--dataset").arg(dataset()).arg("--gt-as-results").arg(&gt).args(["--quiet", "--device", "cpu"]));
    let gt_out = d.path().join("gt-refined.csv");
    refine(&gt, &gt_out, &[]);
    let kept = ar(&gt_out, d.path());
    assert!(kept >= 0.99, "refining the ground truth gives AR {kept}");
}

#[test]
fn a_killed_run_resumes_and_shards_merge_into_the_single_run() {
    let d = tempfile::tempdir().unwrap();
    let init = dataset().join("perturbed.csv");
    let single = d.path().join("single.csv");
    refine(&init, &single, &["--method", "sir"]);
    // A kill mid-run: the first image complete, the second cut in the middle
    // of its second line. The resumed run redoes the second image only.
    let text = std::fs::read_to_string(&single).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let first_im = lines[1].split(',').nth(1).unwrap();
    let n_first = lines[1..].iter().take_while(|l| l.split(',').nth(1) == Some(first_im)).count();
    let partial = d.path().join("partial.csv");
    let second = lines[2 + n_first];
    std::fs::write(&partial, format!("{}\n{}\n{}", lines[..1 + n_first].join("\n"), lines[1 + n_first], &second[..second.len() / 2])).unwrap();
    // A killed run has its settings record (written before any result).
    std::fs::copy(d.path().join("single.csv.settings.json"), d.path().join("partial.csv.settings.json")).unwrap();
    let text = refine(&init, &partial, &["--method", "sir"]);
    assert!(text.contains("refined 11 images"), "{text}");
    assert_eq!(rows(&partial), rows(&single));
    // The settings are recorded beside the output: resuming with others
    // is refused and names them (the kept images would not match the
    // rest); the same settings resume.
    assert!(d.path().join("single.csv.settings.json").is_file());
    let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(&single).args(["--method", "sir", "--lod", "auto", "--quiet", "--device", "cpu"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("other settings (lod;"), "{err}");
    refine(&init, &single, &["--method", "sir"]);
    assert_eq!(rows(&partial), rows(&single));
    // Results this command did not start (a copy of the input) are not
    // resumed as if refined.
    let copy = d.path().join("copy.csv");
    std::fs::copy(&init, &copy).unwrap();
    let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(&copy).args(["--quiet", "--device", "cpu"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("no settings record"), "{err}");
    // Shards 1/3..3/3 concatenated = the single run.
    let merged = d.path().join("merged.csv");
    let mut all = String::from("scene_id,im_id,obj_id,score,R,t,time\n");
    for k in 1..=3 {
        let part = d.path().join(format!("part{k}.csv"));
        refine(&init, &part, &["--method", "sir", "--shard", &format!("{k}/3")]);
        all += &std::fs::read_to_string(&part).unwrap().lines().skip(1).map(|l| l.to_string() + "\n").collect::<String>();
    }
    std::fs::write(&merged, all).unwrap();
    assert_eq!(rows(&merged), rows(&single));
    // The shards written in turn into one file: each keeps the others'
    // images. A kill that cuts the last image's rows short (its journal
    // line not yet written) redoes that image only.
    let one = d.path().join("one.csv");
    for k in 1..=3 {
        refine(&init, &one, &["--method", "sir", "--shard", &format!("{k}/3")]);
    }
    assert_eq!(rows(&one), rows(&single));
    let journal = std::fs::read_to_string(d.path().join("one.csv.done")).unwrap();
    assert_eq!(journal.lines().count(), 12, "{journal}");
    let text = std::fs::read_to_string(&one).unwrap();
    let last_im = text.lines().last().unwrap().split(',').nth(1).unwrap().to_string();
    let kept: Vec<&str> = text.lines().collect();
    std::fs::write(&one, kept[..kept.len() - 1].join("\n") + "\n").unwrap();
    let cut: Vec<&str> = journal.lines().filter(|l| l.split(' ').nth(1) != Some(last_im.as_str())).collect();
    std::fs::write(d.path().join("one.csv.done"), cut.join("\n") + "\n").unwrap();
    let text = refine(&init, &one, &["--method", "sir"]);
    assert!(text.contains("refined 1 images"), "{text}");
    assert_eq!(rows(&one), rows(&single));
}

#[test]
fn refine_refuses_bad_flags_before_any_work() {
    let d = tempfile::tempdir().unwrap();
    let init = dataset().join("perturbed.csv");
    for (extra, want) in [
        (vec!["--steps", "0"], "steps"),
        (vec!["--budget", "0"], "budget"),
        (vec!["--discount", "1.5"], "discount"),
        (vec!["--budget", "3", "--method", "sir"], "--budget"),
        (vec!["--icp-iterations", "100000"], "ICP iterations"),
        (vec!["--exploration", "nan"], "exploration"),
        (vec!["--shard", "4/3"], "--shard"),
        (vec!["--masks", "/nonexistent"], "--masks"),
        (vec!["--summary", "/nonexistent/s.json"], "--summary"),
        // Flags the method has no use for are refused, not ignored.
        (vec!["--method", "sir", "--exploration", "5"], "--exploration and --discount are for --method rir"),
        (vec!["--method", "pir", "--no-physics"], "--no-physics is for --method sir and rir"),
        (vec!["--adapter", "llvm", "--device", "cpu"], "uses no adapter"),
        // Outputs where the dataset reads would change it (a summary over
        // a scene's ground truth, pictures among its depth images).
        (vec!["--summary", "assets/lmo-synth/test/000002/scene_gt.json"], "this is where --dataset reads from"),
        (vec!["--summary", "assets/lmo-synth/test_targets_bop19.json"], "this is where --dataset reads from"),
        (vec!["--explain", "assets/lmo-synth/models"], "this is where --dataset reads from"),
    ] {
        let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(d.path().join("o.csv")).args(&extra).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains(want), "{extra:?}: {err}");
    }
    // No output overwrites an input or another output, side files included.
    let out = d.path().join("o.csv");
    let journal = d.path().join("o.csv.done");
    let lock = d.path().join("o.csv.lock");
    for (outs, want) in [
        (vec![&init], "--out and --init name the same file"),
        (vec![&out, &out], "--summary and --out name the same file"),
        (vec![&out, &journal], "--summary and --out's journal name the same file"),
        (vec![&out, &lock], "--summary and --out's lock name the same file"),
    ] {
        let mut cmd = plausible();
        cmd.arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(outs[0]);
        if let Some(s) = outs.get(1) {
            cmd.arg("--summary").arg(s);
        }
        let o = cmd.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains(want), "{err}");
    }
    // A second run writing the same output meanwhile is refused: both
    // would rewrite and append to it, doubling or losing rows.
    let lock = std::fs::File::create(d.path().join("o.csv.lock")).unwrap();
    lock.try_lock().unwrap();
    let link = d.path().join("link.csv");
    std::os::unix::fs::symlink(&out, &link).unwrap();
    // Every spelling of the output shares its lock (a symlink too).
    for spelled in [&out, &link] {
        let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(spelled).args(["--device", "cpu"]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains("another run is writing it"), "{err}");
    }
    drop(lock);
    // A hard link to the input is the input.
    let hard = d.path().join("hard.csv");
    std::fs::hard_link(&init, &hard).unwrap();
    let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(&hard).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("--out and --init name the same file"), "{err}");
    // A device as the output: never read for resuming (reading /dev/full
    // grew memory until the process was killed); the write error is named.
    if std::path::Path::new("/dev/full").exists() {
        let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).args(["--out", "/dev/full", "--quiet", "--device", "cpu"]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains("/dev/full"), "{err}");
    }
}

/// Images that cannot be read are found before the first image is worked
/// on (they had failed the run after all the others), a camera that does
/// not fit its image is refused or warned about, and an input read from a
/// pipe is recorded by what was read (a second read hashed nothing, so any
/// other input resumed the output).
#[test]
fn dataset_runs_check_every_image_first_and_record_what_they_read() {
    let d = tempfile::tempdir().unwrap();
    let targets: serde_json::Value = serde_json::from_slice(&std::fs::read(dataset().join("test_targets_bop19.json")).unwrap()).unwrap();
    let mut t = targets.as_array().unwrap().clone();
    t.push(serde_json::json!({"scene_id": 2, "im_id": 5000, "obj_id": 1, "inst_count": 1}));
    let bad_targets = d.path().join("targets.json");
    std::fs::write(&bad_targets, serde_json::to_vec(&t).unwrap()).unwrap();
    let out = d.path().join("e.csv");
    let o = plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--targets").arg(&bad_targets).arg("--out").arg(&out).args(["--quiet", "--device", "cpu"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("scene 2 image 5000"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap_or_default().lines().count(), 0, "nothing estimated before the error");
    // A copy of the dataset whose image 3 has a K of another camera.
    let copy = d.path().join("ds");
    copy_dir(&dataset(), &copy);
    let cams = copy.join("test/000002/scene_camera.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&cams).unwrap()).unwrap();
    let k = v["3"]["cam_K"].clone();
    v["3"]["cam_K"] = serde_json::json!([0.572, 0, 0.325, 0, 0.573, 0.242, 0, 0, 1]);
    std::fs::write(&cams, serde_json::to_vec(&v).unwrap()).unwrap();
    let o = plausible().arg("estimate").arg("--dataset").arg(&copy).arg("--out").arg(d.path().join("k.csv")).args(["--images", "3", "--quiet", "--device", "cpu"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("fx = 0.572 px is not plausible"), "{err}");
    v["3"]["cam_K"] = k;
    v["3"]["cam_K"][2] = serde_json::json!(700.0);
    std::fs::write(&cams, serde_json::to_vec(&v).unwrap()).unwrap();
    let o = plausible().arg("estimate").arg("--dataset").arg(&copy).arg("--out").arg(d.path().join("k2.csv")).args(["--images", "3", "--steps", "0", "--quiet", "--device", "cpu"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && err.contains("principal point (700.0, 242.0) lies outside"), "{err}");
    // --init from a pipe, then another --init from a pipe into the same output.
    let init = dataset().join("perturbed.csv");
    let lines: Vec<String> = std::fs::read_to_string(&init).unwrap().lines().map(str::to_string).collect();
    let (a, b) = (d.path().join("a.csv"), d.path().join("b.csv"));
    std::fs::write(&a, lines[..4].join("\n")).unwrap();
    std::fs::write(&b, [&lines[..1], &lines[16..20]].concat().join("\n")).unwrap();
    let piped = |init: &Path| {
        let script = format!("{:?} refine --dataset {:?} --init <(cat {:?}) --out {:?} --steps 1 --quiet --device cpu", env!("CARGO_BIN_EXE_plausible"), dataset(), init, d.path().join("p.csv"));
        Command::new("bash").arg("-c").arg(script).output().unwrap()
    };
    assert!(piped(&a).status.success());
    let o = piped(&b);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("written with other settings (init"), "{err}");
    // An output started by an earlier version, which recorded the digest
    // of the --init file's bytes, still resumes.
    let legacy = d.path().join("legacy.csv");
    refine(&a, &legacy, &["--steps", "1", "--images", "3"]);
    let stamp = d.path().join("legacy.csv.settings.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&stamp).unwrap()).unwrap();
    use sha2::Digest as _;
    let bytes: String = sha2::Sha256::digest(std::fs::read(&a).unwrap()).iter().map(|b| format!("{b:02x}")).collect();
    v["init"] = serde_json::json!(bytes);
    std::fs::write(&stamp, serde_json::to_vec(&v).unwrap()).unwrap();
    refine(&a, &legacy, &["--steps", "1"]);
}

/// A mask larger than its object (a loose detector mask, or one file
/// shared by two instances) is no reason to stop a dataset run: estimate
/// places hypotheses from it as before (the mesh-size check that refuses
/// such a mask is `hypotheses`', whose mesh units come from the user).
#[test]
fn estimate_takes_a_loose_mask() {
    let d = tempfile::tempdir().unwrap();
    let ape = image::open(dataset().join("test/000002/mask_visib/000003_000000.png")).unwrap().to_luma8();
    let (w, h) = ape.dimensions();
    let grow = 25i64;
    let loose = image::GrayImage::from_fn(w, h, |x, y| {
        let near = (-grow..=grow).step_by(5).any(|dy| {
            (-grow..=grow).step_by(5).any(|dx| {
                let (u, v) = (x as i64 + dx, y as i64 + dy);
                u >= 0 && v >= 0 && u < w as i64 && v < h as i64 && ape.get_pixel(u as u32, v as u32)[0] > 0
            })
        });
        image::Luma([if near { 255 } else { 0 }])
    });
    std::fs::create_dir_all(d.path().join("masks/000002")).unwrap();
    loose.save(d.path().join("masks/000002/000003_000001.png")).unwrap();
    let targets = d.path().join("targets.json");
    std::fs::write(&targets, r#"[{"scene_id": 2, "im_id": 3, "obj_id": 1, "inst_count": 1}]"#).unwrap();
    let out = d.path().join("e.csv");
    let text = run(plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--targets").arg(&targets).arg("--masks").arg(d.path().join("masks")).arg("--out").arg(&out).args(["--steps", "0", "--top", "1", "--yaw-steps", "4", "--quiet", "--device", "cpu"]));
    assert!(text.contains("estimated 1 instances"), "{text}");
    assert_eq!(rows(&out).len(), 1);
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// `estimate` from the quasi-static resting poses on the fitted plane, with
/// the oracle masks, reaches the issue's AR of 0.65 on the 12 shipped frames
/// (30 targets), and its timings summary has every stage.
#[test]
fn estimate_reaches_ar_065_on_the_shipped_frames() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("estimates.csv");
    let summary = d.path().join("summary.json");
    let text = run(plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--out").arg(&out).arg("--summary").arg(&summary).args(["--quiet", "--device", "cpu"]));
    assert!(text.contains("estimated 30 instances in 12 images"), "{text}");
    let ar = ar(&out, d.path());
    eprintln!("estimate: AR {ar:.4}");
    assert!(ar >= 0.65, "AR {ar}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    for k in ["plane", "hypotheses_and_scoring", "scene_refinement"] {
        assert!(v["stage_seconds_per_image"][k].as_f64().is_some(), "{v}");
    }
    for k in ["scene", "score", "icp", "simulate"] {
        assert!(v["scene_refinement_stages_per_image"][k].as_f64().is_some(), "{v}");
    }
}

/// `estimate --stable` takes the `stable-poses` database itself or its JSON
/// export, with the same estimates; a file that is neither is refused.
#[test]
fn estimate_takes_the_stable_pose_database_or_its_export() {
    let d = tempfile::tempdir().unwrap();
    let (db, json) = (d.path().join("stable.sqlite"), d.path().join("stable.json"));
    let models: Vec<PathBuf> = ["obj_000001.ply", "obj_000010.ply", "obj_000011.ply"].iter().map(|m| dataset().join("models").join(m)).collect();
    run(plausible().arg("stable-poses").args(&models).arg("--db").arg(&db).arg("--json").arg(&json).args(["--mesh-units", "mm", "--drops", "60", "--quiet"]));
    let estimate = |stable: &Path, out: &str| {
        let out = d.path().join(out);
        run(plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--out").arg(&out).arg("--stable").arg(stable).args(["--images", "3", "--steps", "0", "--quiet", "--device", "cpu"]));
        rows(&out)
    };
    let (from_db, from_json) = (estimate(&db, "db.csv"), estimate(&json, "json.csv"));
    assert_eq!(from_db.len(), 3);
    assert_eq!(from_db, from_json);
    // The export from a pipe is read once (sniffing it for a database had
    // eaten its first bytes: "expected value at line 1 column 1").
    let piped = d.path().join("piped.csv");
    let script = format!(
        "{:?} estimate --dataset {:?} --out {:?} --stable <(cat {:?}) --images 3 --steps 0 --quiet --device cpu",
        env!("CARGO_BIN_EXE_plausible"), dataset(), piped, json
    );
    let o = Command::new("bash").arg("-c").arg(script).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(rows(&piped), from_json);
    // A dataset with models_eval/ (other geometry hashes) finds the
    // database's entries of models/ by file name.
    let copy = d.path().join("ds");
    copy_dir(&dataset(), &copy);
    copy_dir(&copy.join("models"), &copy.join("models_eval"));
    for m in ["obj_000001.ply", "obj_000010.ply", "obj_000011.ply"] {
        let p = copy.join("models_eval").join(m);
        let mut bytes = std::fs::read(&p).unwrap();
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let first = bytes[end..].iter().position(|&c| c == b' ').unwrap() + end;
        bytes.insert(first, b'1'); // the first vertex's x gets another digit
        std::fs::write(&p, bytes).unwrap();
    }
    let out = d.path().join("eval_models.csv");
    run(plausible().arg("estimate").arg("--dataset").arg(&copy).arg("--out").arg(&out).arg("--stable").arg(&db).args(["--images", "3", "--steps", "0", "--quiet", "--device", "cpu"]));
    assert_eq!(rows(&out).len(), 3);
    let bad = d.path().join("bad.bin");
    std::fs::write(&bad, [0xffu8, 0xfe, 0, 1]).unwrap();
    let o = plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--out").arg(d.path().join("x.csv")).arg("--stable").arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("--stable"), "{err}");
}

/// `--explain DIR` draws one picture per image (refine and estimate), and a
/// folder that cannot be made is refused before any work.
#[test]
fn explain_draws_a_picture_per_image() {
    let d = tempfile::tempdir().unwrap();
    let pics = d.path().join("pics");
    let init = dataset().join("perturbed.csv");
    let text = refine(&init, &d.path().join("r.csv"), &["--shard", "1/12", "--explain", pics.to_str().unwrap()]);
    assert!(text.contains("refined 1 images"), "{text}");
    run(plausible().arg("estimate").arg("--dataset").arg(dataset()).arg("--out").arg(d.path().join("e.csv")).arg("--explain").arg(&pics).args(["--images", "89", "--quiet", "--device", "cpu"]));
    let mut names: Vec<String> = std::fs::read_dir(&pics).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["000002_000003.png", "000002_000089.png"]);
    for n in &names {
        let img = image::open(pics.join(n)).unwrap();
        assert!(img.width() >= 1024 && img.height() > 512, "{n}: {}x{}", img.width(), img.height());
    }
    let o = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(d.path().join("x.csv")).args(["--explain", "/dev/null/pics"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("--explain"), "{err}");
}

/// A cube stacked on a slab, seen at 45° with only its front face in the
/// mask (its top hidden, as by an occluder): the estimate floats 8 mm above
/// the slab, which ICP cannot see (the front face slides along itself).
/// Refined as a scene (support order: slab, then cube) with the simulation
/// (SIR with PIR) the cube comes out resting on the slab; without it, it
/// stays in the air.
#[test]
fn a_cube_stacked_on_a_slab_comes_out_resting_on_it() {
    use glam::{DMat3, DVec3};
    use plausible::camera::Intrinsics;
    use plausible::kernels::render::render_cpu;
    use plausible::kernels::RenderMesh;
    use plausible::observation::DepthImage;
    use plausible::physical::Plane;
    use plausible::pose::{axis_angle, Pose};
    use plausible::refine::dataset::Model;
    use plausible::refine::scene::{refine_scene, SceneObject, Support};
    use plausible::refine::{Method, RefineParams};

    // World: table z = 0, slab 12 × 12 × 2 cm on it, 4 cm cube on the slab.
    let centre = DVec3::new(0.0, -0.4, 0.4);
    let (x, f) = (DVec3::X, (-centre).normalize());
    let r_cw = DMat3::from_cols(x, f.cross(x), f).transpose();
    let cam = Pose::new(r_cw, -(r_cw * centre));
    let slab_mesh = plausible::shapes::cuboid(DVec3::new(0.06, 0.06, 0.01));
    let cube_mesh = plausible::shapes::cuboid(DVec3::splat(0.02));
    let slab_pose = cam.compose(&Pose::new(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 0.01)));
    let yaw = axis_angle(DVec3::Z, 0.4);
    let truth = cam.compose(&Pose::new(yaw, DVec3::new(0.01, 0.0, 0.04)));
    let k = Intrinsics::from_k(&[600.0, 0.0, 320.0, 0.0, 600.0, 240.0, 0.0, 0.0, 1.0], 640, 480).unwrap();
    let slab_img = render_cpu(&RenderMesh::new(&slab_mesh).unwrap(), &slab_pose, &k);
    let cube_img = render_cpu(&RenderMesh::new(&cube_mesh).unwrap(), &truth, &k);
    // The cube's front face (outward normal −y turned by the yaw) where the
    // cube is the nearest surface; the depth of both objects.
    let front = (r_cw * (yaw * -DVec3::Y)).as_vec3();
    let front_cube = |i: usize| cube_img.depth[i] > 0.0 && (slab_img.depth[i] == 0.0 || cube_img.depth[i] < slab_img.depth[i]);
    let mask: Vec<bool> = (0..k.pixels()).map(|i| front_cube(i) && cube_img.normals[i].dot(front) > 0.9).collect();
    assert!(mask.iter().filter(|&&m| m).count() > 500, "the front face is in view");
    let depth: Vec<f32> = (0..k.pixels())
        .map(|i| match (cube_img.depth[i], slab_img.depth[i]) {
            (0.0, s) => s,
            (c, 0.0) => c,
            (c, s) => c.min(s),
        })
        .collect();
    let obs = DepthImage { intrinsics: k, depth };
    let plane = Plane { point: cam.transform_point(DVec3::ZERO), normal: r_cw * DVec3::Z };
    let start = cam.compose(&Pose::new(axis_angle(DVec3::X, 3f64.to_radians()) * yaw, DVec3::new(0.01, 0.0, 0.048)));
    let height = |p: &Pose| {
        let world = cam.inverse().compose(p);
        cube_mesh.vertices.iter().map(|v| world.transform_point(*v).z).fold(f64::INFINITY, f64::min) - 0.02
    };
    assert!((height(&start) - 0.008).abs() < 2e-3);
    // The slab's visible pixels are its mask; both objects are refined as
    // one scene, in support order: the slab (on the plane) first, then the
    // cube simulated on the refined slab.
    let slab_mask: Vec<bool> = (0..k.pixels()).map(|i| slab_img.depth[i] > 0.0 && !front_cube(i) && !(cube_img.depth[i] > 0.0 && cube_img.depth[i] < slab_img.depth[i])).collect();
    let run = |physics: bool| {
        let p = RefineParams { method: Method::Sir, steps: 8, physics, ..Default::default() };
        let cube = Model::new(cube_mesh.clone(), &p).unwrap();
        let slab = Model::new(slab_mesh.clone(), &p).unwrap();
        let objects = [
            SceneObject { model: &cube, mask: &mask, hypotheses: vec![start], lead: 0 },
            SceneObject { model: &slab, mask: &slab_mask, hypotheses: vec![slab_pose], lead: 0 },
        ];
        let out = refine_scene(&plausible::visual::Device::Cpu, &obs, Some(&plane), &objects, 5, &p).unwrap();
        assert_eq!(out.support, vec![Support::Object(1), Support::Plane], "the cube rests on the slab, the slab on the plane");
        assert_eq!(out.order, vec![1, 0], "the slab is refined first");
        out.objects[0].as_ref().unwrap()[0]
    };
    let (with, without) = (run(true), run(false));
    eprintln!("gap above the slab: start {:.4} m, with the simulation {:.4} m, without {:.4} m", height(&start), height(&with.pose), height(&without.pose));
    assert!(height(&with.pose).abs() < 2e-3, "with the simulation the cube rests on the slab: gap {} m", height(&with.pose));
    assert!(height(&without.pose) > 4e-3, "ICP alone cannot see the gap: {} m", height(&without.pose));
}

/// The paper's Table 1 trend on the shipped frames: scoring with a 352-face
/// or an `auto` level of detail refines as well as the full models; 34
/// faces is measurably worse but still refines.
#[test]
fn refine_with_a_level_of_detail_matches_the_full_models() {
    let d = tempfile::tempdir().unwrap();
    let init = dataset().join("perturbed.csv");
    let mut ars = Vec::new();
    for lod in ["off", "auto", "352", "34"] {
        let out = d.path().join(format!("refined-{lod}.csv"));
        refine(&init, &out, &["--lod", lod, "--method", "ref"]);
        ars.push(ar(&out, d.path()));
    }
    eprintln!("AR off / auto / 352 / 34: {ars:?}");
    assert!((ars[1] - ars[0]).abs() <= 0.005 && (ars[2] - ars[0]).abs() <= 0.005, "{ars:?}");
    assert!(ars[3] > ar(&init, d.path()), "{ars:?}");
    let bad = plausible().arg("refine").arg("--dataset").arg(dataset()).arg("--init").arg(&init).arg("--out").arg(d.path().join("x.csv")).args(["--lod", "2"]).output().unwrap();
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("--lod"), "{}", String::from_utf8_lossy(&bad.stderr));
}

/// The score column is the visual score on every row: an object without a
/// mask in its image keeps its pose and scores 0 (a pose against no
/// observed pixel), never its input score, which is on another method's
/// scale.
#[test]
fn objects_without_a_mask_keep_their_pose_and_score_zero() {
    let d = tempfile::tempdir().unwrap();
    // Image 3's mask of object 1 only (its instance 0 in mask_visib).
    std::fs::create_dir_all(d.path().join("masks/000002")).unwrap();
    std::fs::copy(dataset().join("test/000002/mask_visib/000003_000000.png"), d.path().join("masks/000002/000003_000001.png")).unwrap();
    let out = d.path().join("r.csv");
    let masks = d.path().join("masks");
    refine(&dataset().join("perturbed.csv"), &out, &["--images", "3", "--method", "ref", "--masks", masks.to_str().unwrap()]);
    let init: Vec<plausible::bop::Estimate> = plausible::bop::read_results(&dataset().join("perturbed.csv")).unwrap().into_iter().filter(|e| e.im_id == 3).collect();
    let got = plausible::bop::read_results(&out).unwrap();
    assert_eq!(got.len(), init.len());
    assert!(init.len() > 1 && init.iter().all(|e| e.score > 0.0));
    for (g, i) in got.iter().zip(&init) {
        assert_eq!(g.obj_id, i.obj_id);
        if g.obj_id == 1 {
            assert!(g.score > 0.0 && g.score != i.score, "object 1: {} (input {})", g.score, i.score);
        } else {
            assert_eq!(g.score, 0.0, "object {}", g.obj_id);
            assert_eq!(g.pose, i.pose, "object {}", g.obj_id);
        }
    }
}

/// A model edited between a kill and the rerun refuses the resume: the
/// settings record holds every model file's digest, so the images done
/// with the old geometry are not kept beside ones done with the new. An
/// output started before the record had models still resumes.
#[test]
fn a_model_edited_before_the_rerun_refuses_the_resume() {
    let d = tempfile::tempdir().unwrap();
    let ds = d.path().join("ds");
    copy_dir(&dataset(), &ds);
    let out = d.path().join("r.csv");
    let refine_on = |ds: &Path| {
        plausible()
            .arg("refine").arg("--dataset").arg(ds)
            .arg("--init").arg(dataset().join("perturbed.csv"))
            .arg("--out").arg(&out)
            .args(["--images", "3", "--method", "ref", "--quiet", "--device", "cpu"])
            .output()
            .unwrap()
    };
    assert!(refine_on(&ds).status.success());
    // Without the models in the record (an older version's), it resumes.
    let stamp = d.path().join("r.csv.settings.json");
    let mut rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stamp).unwrap()).unwrap();
    rec.as_object_mut().unwrap().remove("models");
    std::fs::write(&stamp, rec.to_string()).unwrap();
    assert!(refine_on(&ds).status.success());
    // A fresh output records the models; the same models resume.
    std::fs::remove_file(&out).unwrap();
    std::fs::remove_file(&stamp).unwrap();
    std::fs::remove_file(d.path().join("r.csv.done")).ok();
    assert!(refine_on(&ds).status.success());
    assert!(refine_on(&ds).status.success(), "the same models resume");
    let model = ds.join("models/obj_000001.ply");
    let mut bytes = std::fs::read(&model).unwrap();
    bytes.push(b'\n');
    std::fs::write(&model, bytes).unwrap();
    let o = refine_on(&ds);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("other settings (models;"), "{err}");
}
