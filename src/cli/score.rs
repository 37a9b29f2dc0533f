//! `plausible score`: rank pose hypotheses against an observed depth frame.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context as _, Result};
use plausible::kernels::score::{ScoreParams, ScoreRecord};
use plausible::kernels::RenderMesh;
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::observation::DepthImage;
use plausible::pose::{read_poses_selected, Pose, PoseUnits, SceneGtSelection};
use plausible::physical::batch::PlanePhysics;
use plausible::physical::samples::{DEFAULT_SAMPLES, DEFAULT_SEED};
use plausible::physical::scene::read_camera_plane;
use plausible::physical::{Evaluation, Verdict};
use plausible::visual::{scoring_mesh, LodChoice, ranks, ranks_with_physics, score_poses_with_physics, Device, Scorer};

use super::{MeshArgs, ObservationArgs, SampleArgs};

#[derive(clap::Args, Debug)]
pub struct ScoreArgs {
    #[command(flatten)]
    pub mesh: MeshArgs,
    #[command(flatten)]
    pub obs: ObservationArgs,
    /// Hypotheses: JSON list of {"cam_R_m2c": [9, row-major], "cam_t_m2c": [3, mm]}.
    #[arg(long)]
    pub poses: PathBuf,
    /// With a BOP scene_gt.json as --poses: the object whose instances in
    /// the image --frame are the hypotheses.
    #[arg(long, requires = "frame")]
    pub obj_id: Option<u32>,
    /// Units of cam_t_m2c in the pose file.
    #[arg(long, default_value = "mm", value_parser = ["mm", "m"])]
    pub pose_units: String,
    /// Project slightly non-orthonormal rotations onto SO(3) instead of rejecting them.
    #[arg(long)]
    pub orthonormalize: bool,
    /// Write every record (input order, with rank) to .json or .csv.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Rows of the printed ranking.
    #[arg(long, default_value_t = 10)]
    pub top: usize,
    /// Depth tolerance τ of eq. 4, metres.
    #[arg(long, default_value_t = 0.02)]
    pub tau: f32,
    /// Normal tolerance α of eq. 5.
    #[arg(long, default_value_t = 0.7)]
    pub alpha: f32,
    /// Level of detail of the mesh the visual score renders: `auto` (the
    /// coarsest simplification whose geometric error stays within a quarter
    /// of a pixel at the observed object), `off` (the full mesh) or a triangle
    /// count. The physical terms always use the full mesh.
    #[arg(long, default_value = "auto")]
    pub lod: LodChoice,
    /// Region of interest resampled to RES x RES pixels (clipped to the image, so an object cut by the border gets fewer pixels of the same size); 0 = native pixels.
    #[arg(long, default_value_t = 128)]
    pub res: u32,
    /// Growth of the mask's bounding box on each side, as a fraction of its size.
    #[arg(long, default_value_t = DEFAULT_ROI_MARGIN)]
    pub margin: f64,
    /// Support plane in the camera frame (JSON: {"point": [x, y, z], "normal":
    /// [nx, ny, nz], "units": "mm"}; `plausible plane` fits one from the depth).
    /// Needs --physics.
    #[arg(long, requires = "physics")]
    pub plane: Option<PathBuf>,
    /// Add the physical terms against --plane to every record (computed in
    /// the same GPU pass as the visual score) and rank physically plausible
    /// hypotheses first: plausible, then unstable, floating, intersecting;
    /// within each group by visual score.
    #[arg(long, requires = "plane")]
    pub physics: bool,
    #[command(flatten)]
    pub sampling: SampleArgs,
    /// Write a picture per explained hypothesis to this folder
    /// (`hypothesis_<index>.png`): observed depth | rendered depth |
    /// alignment, and with --physics the samples, support polygon and centre
    /// of mass from above and from the side under a band in the verdict's colour.
    /// An earlier run's pictures there (listed in `.plausible-explain`) are
    /// removed first; any other `hypothesis_<index>.png` is refused.
    #[arg(long)]
    pub explain: Option<PathBuf>,
    /// Hypotheses (input indices) to explain; default: the best 3.
    #[arg(long, value_delimiter = ',', requires = "explain")]
    pub explain_ids: Vec<usize>,
    #[command(flatten)]
    pub device: super::AutoDeviceArgs,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Scores and ranks the hypotheses. With `--trace`, its span is the root of
/// the trace and its stages (load, setup, scoring, ranking, report, write,
/// explain) are its direct children, covering it.
#[tracing::instrument(name = "plausible score", level = "trace", skip_all)]
pub fn run(a: ScoreArgs, verbose: u8) -> Result<()> {
    let (mesh, obs, mask, poses) = tracing::trace_span!("load").in_scope(|| load(&a))?;
    let setup = tracing::trace_span!("setup").entered();
    let setup_start = Instant::now();
    // The device first, so that the score kernel compiles while the
    // observation, mesh and meshlets are prepared.
    let device = a.device.open(verbose)?;
    let compiling = match a.physics && a.plane.is_some() {
        false => Scorer::precompile(&device),
        true => plausible::gpu::Compiling::none(),
    };
    let sampling = if a.res == 0 { RoiSampling::Native } else { RoiSampling::Square(a.res) };
    let target = ScoreTarget::new(&obs, mask.as_deref(), sampling, a.margin)?;
    target.check_observed().context("--res (0 scores native pixels)")?;
    if let Some(w) = target.distance_mismatch(&poses) {
        eprintln!("warning: {w} (--camera's depth_scale, --pose-units)");
    }
    let scoring = scoring_mesh(&mesh, a.lod, &target)?;
    if verbose > 0 || scoring.mesh.triangles.len() != scoring.full_triangles {
        eprintln!("{}", scoring.describe());
    }
    let rmesh = RenderMesh::new(&scoring.mesh)?;
    let params = ScoreParams { tau: a.tau, alpha: a.alpha };
    let choice: plausible::gpu::DeviceChoice = a.device.device.parse()?;
    let (device, too_big) = device.for_mesh(choice, &rmesh, target.intrinsics.pixels());
    if let Some(note) = too_big {
        eprintln!("note: {note}");
    }
    if let (Device::Cpu, Some(first), true) = (&device, poses.first(), verbose > 0) {
        let rect = plausible::kernels::raster::screen_rect(&first.into(), rmesh.radius, &target.intrinsics);
        let px = rect.map_or(0, |r| (r[2] - r[0] + 1) * (r[3] - r[1] + 1));
        eprintln!(
            "CPU renderer: {} for the first hypothesis ({} triangles over a {px}-pixel rectangle; the BVH ray caster above {} per pixel)",
            rmesh.cpu_renderer(px),
            rmesh.triangles.len(),
            plausible::kernels::RAY_CAST_TRIANGLES_PER_PIXEL
        );
    }

    let physics = match (&a.plane, a.physics) {
        (Some(path), true) => {
            let plane = read_camera_plane(path)?;
            plausible::hypotheses::on_plane::check_plane_under_observation(&plane, &obs, mask.as_deref(), mesh.diagonal())
                .with_context(|| format!("--plane {}", path.display()))?;
            let sm = &a.sampling;
            Some(PlanePhysics::new(&mesh, &plane, None, sm.samples, sm.seed, sm.epsilon)?)
        }
        _ => None,
    };
    // The scorer too (its buffers uploaded, its kernel compiled), so that
    // the throughput printed is the scoring's.
    let scorer = match physics {
        None => Some(Scorer::new(&device, &rmesh, &target, params, poses.len())?),
        Some(_) => None,
    };
    drop(compiling);
    let setup_secs = setup_start.elapsed().as_secs_f64();
    drop(setup);

    let t0 = Instant::now();
    let pb = super::progress(poses.len() as u64, "scoring");
    if a.quiet {
        pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    if let Some(physics) = &physics {
        let (records, evals, _) = tracing::trace_span!("scoring").in_scope(|| {
            score_poses_with_physics(&device, &rmesh, &target, &poses, params, physics, |n| pb.set_position(n as u64))
        })?;
        pb.finish_and_clear();
        let secs = t0.elapsed().as_secs_f64();
        let rank = tracing::trace_span!("ranking").in_scope(|| ranks_with_physics(&records, &evals));
        tracing::trace_span!("report").in_scope(|| {
            print_throughput(&device, &target, poses.len(), secs, setup_secs);
            let plane = physics.kernel_params().plane;
            println!(
                "physics against the plane n = ({:.3}, {:.3}, {:.3}), {:.1} mm from the camera: {} samples, ε = {:.2} mm; {}",
                plane[0],
                plane[1],
                plane[2],
                plane[3].abs() * 1e3,
                physics.body().samples.len(),
                physics.body().epsilon * 1e3,
                verdict_counts(&evals)
            );
            warn_if_below_plane(&evals, mesh.diagonal());
            print_table(&records, Some(&evals), &rank, a.top);
        });
        let written = write_outputs(&a, &records, Some(&evals), &rank, &poses, &rmesh, &target, &params, Some(physics));
        release(device);
        return written;
    }
    let scorer = scorer.expect("made in set-up without physics");
    let records = tracing::trace_span!("scoring").in_scope(|| scorer.score(&poses, &mut |n| pb.set_position(n as u64)))?.0;
    pb.finish_and_clear();
    let secs = t0.elapsed().as_secs_f64();
    let rank = tracing::trace_span!("ranking").in_scope(|| ranks(&records));
    tracing::trace_span!("report").in_scope(|| {
        print_throughput(&device, &target, poses.len(), secs, setup_secs);
        print_table(&records, None, &rank, a.top);
    });
    let written = write_outputs(&a, &records, None, &rank, &poses, &rmesh, &target, &params, None);
    release((scorer, device));
    written
}

/// Drops the GPU objects (the scorer's buffers, the context) in a stage of
/// their own, so that freeing them is not time in the trace's root that no
/// stage covers. The device itself stays open for the process
/// (`gpu::shared`); before it did, its teardown (64 ms on an H200) came when
/// the scorer, its last user, was dropped after this stage.
fn release<T>(gpu: T) {
    tracing::trace_span!("release").in_scope(|| drop(gpu));
}

/// The checked arguments and the inputs: mesh, observation (depth, mask)
/// and poses. `--out` is checked here, before any work.
#[allow(clippy::type_complexity)]
fn load(a: &ScoreArgs) -> Result<(plausible::mesh::Mesh, DepthImage, Option<Vec<bool>>, Vec<Pose>)> {
    if !(a.tau > 0.0 && a.tau <= 1.0) {
        bail!("--tau {}: the depth tolerance is in metres and must lie in (0, 1] (the usual value is 0.02)", a.tau);
    }
    use plausible::observation::{MAX_ROI_MARGIN, MAX_ROI_SIDE};
    if !(a.margin.is_finite() && (0.0..=MAX_ROI_MARGIN).contains(&a.margin)) {
        bail!("--margin {}: the region's growth on each side, a fraction of the mask's size, must lie in [0, {MAX_ROI_MARGIN}]", a.margin);
    }
    if a.res > MAX_ROI_SIDE {
        bail!("--res {}: the region is resampled to at most {MAX_ROI_SIDE} pixels a side (0 scores native pixels)", a.res);
    }
    // 1 - cos of two normals is at most 2: a larger α never reaches it.
    if !(a.alpha > 0.0 && a.alpha <= 2.0) {
        bail!("--alpha {}: the normal tolerance (on 1 - cos of the angle) must lie in (0, 2] (the usual value is 0.7)", a.alpha);
    }
    let sm = &a.sampling;
    if !a.physics && (sm.samples != DEFAULT_SAMPLES || sm.seed != DEFAULT_SEED || sm.epsilon.is_some()) {
        bail!("--samples, --seed and --epsilon set the physical terms: add --plane P.json --physics");
    }
    sm.check()?;
    // On the table of one object, beyond 5 cm is no contact tolerance.
    if let Some(e) = sm.epsilon.filter(|e| *e >= 0.05) {
        bail!("--epsilon {e}: ε is in metres and must lie in (0, 0.05) (the default is 2-5 mm)");
    }
    if let Some(out) = &a.out {
        check_out(out)?;
        let inputs = [("--mesh", Some(a.mesh.mesh.as_path())), ("--poses", Some(a.poses.as_path())), ("--plane", a.plane.as_deref())];
        super::distinct_files(&[("--out", Some(out))], &[&inputs[..], &a.obs.inputs()].concat())?;
    }
    if let Some(dir) = &a.explain {
        let inputs = [("--mesh", Some(a.mesh.mesh.as_path())), ("--poses", Some(a.poses.as_path())), ("--plane", a.plane.as_deref())];
        prepare_explain_dir(dir, &[&inputs[..], &a.obs.inputs()].concat()).context("--explain")?;
    }
    let mesh = a.mesh.load()?;
    let (obs, mask) = tracing::trace_span!("observation").in_scope(|| a.obs.load(a.obj_id.is_some()))?;
    let units = if a.pose_units == "m" { PoseUnits::Metres } else { PoseUnits::Millimetres };
    let select = a.obj_id.map(|o| SceneGtSelection { frame: a.obs.frame.as_deref().unwrap_or_default(), obj_id: Some(o) });
    let poses = tracing::trace_span!("poses")
        .in_scope(|| read_poses_selected(&a.poses, units, a.orthonormalize, select))
        .map_err(|e| {
            // The library's hints in this command's flags.
            let msg = e.to_string().replace("read them as metres if they really are", "pass --pose-units m if the file really holds metres");
            let context = match e.input() {
                Some(plausible::Input::Selection) => "--poses (--frame and --obj-id pick an image's poses from a BOP scene_gt.json)",
                _ => "--poses",
            };
            anyhow::anyhow!(msg).context(context)
        })?;
    if let Some(&bad) = a.explain_ids.iter().find(|&&i| i >= poses.len()) {
        bail!("--explain-ids {bad}: there are only {} hypotheses (indices start at 0)", poses.len());
    }
    Ok((mesh, obs, mask, poses))
}

/// Writes `--out` and the `--explain` pictures, each in its own stage span.
#[allow(clippy::too_many_arguments)]
fn write_outputs(
    a: &ScoreArgs,
    records: &[ScoreRecord],
    evals: Option<&[Evaluation]>,
    rank: &[usize],
    poses: &[Pose],
    rmesh: &RenderMesh,
    target: &ScoreTarget,
    params: &ScoreParams,
    physics: Option<&PlanePhysics>,
) -> Result<()> {
    if let Some(out) = &a.out {
        let _s = tracing::trace_span!("write").entered();
        write_records(out, records, evals, rank)?;
        println!("wrote {} records to {}", records.len(), out.display());
    }
    if let Some(dir) = &a.explain {
        let _s = tracing::trace_span!("explain").entered();
        let ids = explain_ids(&a.explain_ids, rank);
        write_explanations(dir, &ids, poses, records, rank, rmesh, target, params, physics)?;
    }
    Ok(())
}

/// The hypotheses to explain: those asked for (checked against the poses
/// in `load`), each once, else the best 3.
fn explain_ids(asked: &[usize], rank: &[usize]) -> Vec<usize> {
    if asked.is_empty() {
        return by_rank(rank).into_iter().take(3).collect();
    }
    let mut seen = std::collections::HashSet::new();
    asked.iter().copied().filter(|i| seen.insert(*i)).collect()
}

/// Writes `hypothesis_<index>.png` for every id (see `--explain`).
#[allow(clippy::too_many_arguments)]
pub fn write_explanations(
    dir: &std::path::Path,
    ids: &[usize],
    poses: &[plausible::pose::Pose],
    records: &[ScoreRecord],
    rank: &[usize],
    rmesh: &RenderMesh,
    target: &ScoreTarget,
    params: &ScoreParams,
    physics: Option<&PlanePhysics>,
) -> Result<()> {
    prepare_explain_dir(dir, &[])?;
    // Pictures of an earlier run would sit beside this run's rows in a
    // report as if they were its own: those it listed are removed, and
    // nothing else. The list names this run's pictures before the first
    // is written (a kill leaves none unlisted) and only them after.
    let earlier = earlier_pictures(dir);
    let names: Vec<String> = ids.iter().map(|i| format!("hypothesis_{i}.png")).collect();
    let mut both = earlier.clone();
    both.extend(names.iter().cloned());
    list_pictures(dir, &both)?;
    for name in &earlier {
        let path = dir.join(name);
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e).with_context(|| format!("cannot remove the earlier run's {}", path.display())),
            _ => {}
        }
    }
    for &i in ids {
        let render = plausible::kernels::raster::render_cpu(rmesh, &poses[i], &target.intrinsics);
        // The band shows the verdict of the views drawn below it.
        let views = physics.map(|p| p.explain(&poses[i]));
        let r = &records[i];
        let mut title = format!(
            "hypothesis {i} (rank {} of {}): score {:.3} (a_d {:.3}, a_n {:.3})",
            rank[i],
            records.len(),
            r.score,
            r.mean_ad,
            r.mean_an
        );
        if let Some((_, e)) = &views {
            title += &format!(", {}", e.verdict.as_str());
        }
        let pic = plausible::explain::hypothesis_picture(target, &render, params, views.as_ref().map(|(v, e)| (v, e.verdict)), &title);
        let path = dir.join(format!("hypothesis_{i}.png"));
        plausible::io::save_png(&path, &pic)?;
        println!("wrote {}", path.display());
    }
    list_pictures(dir, &names)
}

/// The file in an `--explain` folder that lists the pictures written
/// there, one name a line: a later run removes or replaces those, and
/// never a file it did not write (an input, a user's own picture).
const PICTURE_LIST: &str = ".plausible-explain";

/// The pictures an earlier run listed in `dir` (names of the form
/// `hypothesis_<index>.png` only: the list cannot point elsewhere).
fn earlier_pictures(dir: &std::path::Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join(PICTURE_LIST)).unwrap_or_default();
    text.lines().filter(|n| plausible_picture_index(n).is_some()).map(str::to_string).collect()
}

/// Lists every `hypothesis_<index>.png` in `dir` as an earlier run's, for
/// a folder that only plausible writes (the demo's `explain/`, whose
/// pictures from before the list existed are not listed).
pub fn adopt_pictures(dir: &std::path::Path) -> Result<()> {
    if !dir.is_dir() {
        return Ok(());
    }
    let mut names = earlier_pictures(dir);
    names.extend(unlisted_pictures(dir, &names)?);
    list_pictures(dir, &names)
}

/// The `hypothesis_<index>.png` names in `dir` that are not in `ours`
/// (what earlier runs listed: [`earlier_pictures`]).
fn unlisted_pictures(dir: &std::path::Path, ours: &[String]) -> Result<Vec<String>> {
    let entries = std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))?;
    Ok(entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| plausible_picture_index(name).is_some() && !ours.contains(name))
        .collect())
}

fn list_pictures(dir: &std::path::Path, names: &[String]) -> Result<()> {
    plausible::io::write_atomically(&dir.join(PICTURE_LIST), |w| names.iter().try_for_each(|n| writeln!(w, "{n}"))).map_err(Into::into)
}

/// The folder of `--explain` pictures, made now (before the scoring) and
/// checked writable. A `hypothesis_<index>.png` there that no earlier run
/// listed, or any of `inputs` under such a name, is refused: this run
/// could replace it.
fn prepare_explain_dir(dir: &std::path::Path, inputs: &[(&str, Option<&std::path::Path>)]) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        bail!("{}: is a file; --explain takes a folder for the pictures", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the folder {}", dir.display()))?;
    plausible::io::check_writable(&dir.join(".plausible-write-test")).with_context(|| format!("{}", dir.display()))?;
    if let Some(name) = unlisted_pictures(dir, &earlier_pictures(dir))?.first() {
        bail!(
            "{}: not a picture of an earlier run (none lists it in {PICTURE_LIST}), and this run could replace it: move it, or give a folder of its own for the pictures",
            dir.join(name).display()
        );
    }
    let here = dir.canonicalize().with_context(|| format!("cannot resolve {}", dir.display()))?;
    for (flag, p) in inputs {
        let Some(p) = p.and_then(|p| p.canonicalize().ok()) else { continue };
        if p.parent() == Some(here.as_path()) && p.file_name().is_some_and(|n| plausible_picture_index(&n.to_string_lossy()).is_some()) {
            bail!("{flag} {}: an input named like the pictures written into this folder; move it, or give a folder of its own for the pictures", p.display());
        }
    }
    Ok(())
}

/// The index of a `hypothesis_<index>.png` this command writes.
fn plausible_picture_index(name: &str) -> Option<usize> {
    name.strip_prefix("hypothesis_")?.strip_suffix(".png")?.parse().ok()
}

fn print_throughput(device: &Device, target: &ScoreTarget, n: usize, secs: f64, setup_secs: f64) {
    println!(
        "{} hypotheses scored in {:.3} s ({:.0} hypotheses/s) on {} after {:.3} s of set-up; region {}x{}, {} observed pixels",
        n,
        secs,
        n as f64 / secs,
        device.describe(),
        setup_secs,
        target.intrinsics.width,
        target.intrinsics.height,
        target.observed_pixels()
    );
}

/// A plane that most hypotheses are far below is probably the wrong plane
/// (or in the wrong units): say so rather than rank 4096 intersecting poses.
fn warn_if_below_plane(evals: &[Evaluation], diagonal: f64) {
    let mut mins: Vec<f64> = evals.iter().map(|e| e.min_distance).collect();
    if mins.is_empty() {
        return;
    }
    mins.sort_by(f64::total_cmp);
    let median = mins[mins.len() / 2];
    if median < -diagonal {
        eprintln!(
            "warning: half the hypotheses reach more than {:.0} mm below the support plane (median min δ = {:.0} mm), \
             farther than the object's size: is --plane the surface the object rests on, with its point in the stated units?",
            diagonal * 1e3,
            median * 1e3
        );
    }
}

/// "12 plausible, 3 unstable, ..." over a batch.
pub fn verdict_counts(evals: &[Evaluation]) -> String {
    [Verdict::Plausible, Verdict::Unstable, Verdict::Floating, Verdict::Intersecting]
        .iter()
        .map(|v| format!("{} {}", evals.iter().filter(|e| e.verdict == *v).count(), v.as_str()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Prints the best `top` hypotheses (with their physical terms when given).
/// Hypothesis indices, best rank first.
fn by_rank(rank: &[usize]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..rank.len()).collect();
    order.sort_by_key(|&i| rank[i]);
    order
}

pub fn print_table(records: &[ScoreRecord], evals: Option<&[Evaluation]>, rank: &[usize], top: usize) {
    let order = by_rank(&rank[..records.len()]);
    print!("{:>5} {:>7} {:>7} {:>7} {:>7} {:>7}", "rank", "index", "score", "a_d", "a_n", "|V|");
    if evals.is_some() {
        print!(" {:>12} {:>5} {:>5} {:>5} {:>9} {:>10}", "verdict", "|I|", "|C|", "|S|", "min δ mm", "margin mm");
    }
    println!();
    for &i in order.iter().take(top) {
        let r = &records[i];
        print!("{:>5} {:>7} {:>7.4} {:>7.4} {:>7.4} {:>7}", rank[i], i, r.score, r.mean_ad, r.mean_an, r.valid);
        if let Some(e) = evals.map(|e| &e[i]) {
            let margin = e.stability_margin.map_or("-".to_string(), |m| format!("{:.1}", m * 1e3));
            print!(
                " {:>12} {:>5} {:>5} {:>5} {:>9.2} {:>10}",
                e.verdict.as_str(),
                e.intersecting,
                e.contact,
                e.supported,
                e.min_distance * 1e3,
                margin
            );
        }
        println!();
    }
}

/// Writes all records in input order as JSON or CSV (by extension), with
/// the physical terms when given.
pub fn write_records(
    path: &std::path::Path,
    records: &[ScoreRecord],
    evals: Option<&[Evaluation]>,
    rank: &[usize],
) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let mut body = Vec::new();
    let f = &mut body;
    match ext.as_str() {
        "json" => {
            let v: Vec<serde_json::Value> = records
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    let mut v = serde_json::json!({
                        "index": i, "rank": rank[i], "score": r.score, "a_d": r.mean_ad, "a_n": r.mean_an,
                        "valid": r.valid, "rendered": r.rendered, "observed": r.observed,
                    });
                    if let Some(e) = evals.map(|e| &e[i]) {
                        let m = v.as_object_mut().expect("a JSON object");
                        m.insert("verdict".into(), e.verdict.as_str().into());
                        m.insert("intersecting".into(), e.intersecting.into());
                        m.insert("contact".into(), e.contact.into());
                        m.insert("supported".into(), e.supported.into());
                        m.insert("min_distance".into(), e.min_distance.into());
                        m.insert("stability_margin".into(), e.stability_margin.into());
                        m.insert("feasible".into(), e.feasible.into());
                        m.insert("stable".into(), e.stable.into());
                    }
                    v
                })
                .collect();
            serde_json::to_writer_pretty(&mut *f, &v)?;
            writeln!(f)?;
        }
        "csv" => {
            write!(f, "index,rank,score,a_d,a_n,valid,rendered,observed")?;
            if evals.is_some() {
                write!(f, ",verdict,intersecting,contact,supported,min_distance,stability_margin,feasible,stable")?;
            }
            writeln!(f)?;
            for (i, r) in records.iter().enumerate() {
                write!(f, "{i},{},{},{},{},{},{},{}", rank[i], r.score, r.mean_ad, r.mean_an, r.valid, r.rendered, r.observed)?;
                if let Some(e) = evals.map(|e| &e[i]) {
                    let margin = e.stability_margin.map_or(String::new(), |m| m.to_string());
                    write!(
                        f,
                        ",{},{},{},{},{},{},{},{}",
                        e.verdict.as_str(),
                        e.intersecting,
                        e.contact,
                        e.supported,
                        e.min_distance,
                        margin,
                        e.feasible,
                        e.stable
                    )?;
                }
                writeln!(f)?;
            }
        }
        _ => bail!("--out {}: use a .json or .csv file name", path.display()),
    }
    plausible::io::write_atomically(path, |w| w.write_all(&body))?;
    Ok(())
}

/// Checks `--out` before the work: a .json or .csv name in a folder that exists.
fn check_out(path: &std::path::Path) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if ext != "json" && ext != "csv" {
        bail!("--out {}: use a .json or .csv file name", path.display());
    }
    plausible::io::check_writable(path).context("--out")?;
    Ok(())
}
