//! `plausible stable-poses ...` and `plausible bench stable`.

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use plausible::mesh::{Mesh, MeshUnits};
use plausible::stable::cluster::{ClusterKind, ClusterParams};
use plausible::stable::db::Db;
use plausible::stable::{self, ColliderKind, RunParams, Shard};

/// Stable resting poses: drop tests, clustering, analytic cross-check, database.
///
/// `plausible stable-poses MESH... --db stable.sqlite` runs the drop tests
/// (same as `plausible stable-poses run MESH... --db ...`; use the explicit
/// `run` form when a mesh file is literally called show, merge or export).
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct StableArgs {
    #[command(subcommand)]
    pub action: Option<StableAction>,
    #[command(flatten)]
    pub run: RunArgs,
}

#[derive(clap::Subcommand, Debug)]
pub enum StableAction {
    /// Run drop tests for meshes (the default action).
    Run(RunArgs),
    /// Print each mesh's clusters and analytic poses as tables.
    Show(ShowArgs),
    /// Merge databases (e.g. shards) into one; clusters are recomputed.
    Merge(MergeArgs),
    /// Export clusters, families and analytic poses as JSON.
    Export(ExportArgs),
}

#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    /// Mesh files (OBJ, PLY, STL, glTF/GLB).
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// SQLite database to create or continue.
    #[arg(long, required = true)]
    pub db: Option<PathBuf>,
    /// Number of drops per mesh.
    #[arg(long, default_value_t = 1000)]
    pub drops: u64,
    /// Seed of the random orientations (with the mesh hash and drop index).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Run only shard k of n (the worlds of 32 consecutive drops with world % n == k-1), e.g. 2/8.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Worker threads (default, or 0: all logical CPUs).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Collider: `hull` (one simplified convex hull) or `decomposition`
    /// (the file's connected components when it has several, else VHACD).
    #[arg(long, default_value = "hull")]
    pub collider: ColliderKind,
    /// Vertex budget of each simplified collider hull.
    #[arg(long, default_value_t = 96)]
    pub hull_points: usize,
    /// Angular threshold of the clustering (degrees).
    #[arg(long, default_value_t = 5.0)]
    pub cluster_deg: f64,
    /// Cap on simulated time per drop (seconds) for a 0.15 m object; other
    /// sizes get it times √(diagonal / 0.15 m) (the whole drop is
    /// time-scaled so: a smaller object moves faster under gravity, a larger
    /// one slower).
    #[arg(long, default_value_t = 10.0)]
    pub max_time: f64,
    /// Simulation steps per second for a 0.15 m object (others step
    /// √(0.15 m / diagonal) times as often, so every size takes the same
    /// steps per drop). 240 gives
    /// converged pose frequencies; 60 is about 4x faster with the same poses
    /// but shifted frequencies.
    #[arg(long, default_value_t = 240.0)]
    pub step_hz: f64,
    /// Units of the mesh files: m, cm, mm or auto.
    #[arg(long, default_value = "auto")]
    pub mesh_units: MeshUnits,
    /// Also write the JSON export of the processed meshes here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// No progress bar and no summary (errors and warnings still go to stderr).
    #[arg(long, short)]
    pub quiet: bool,
}

#[derive(clap::Args, Debug)]
pub struct ShowArgs {
    /// SQLite database written by `stable-poses run` (read only).
    #[arg(long)]
    pub db: PathBuf,
    /// Only meshes whose path contains this text (or whose hash starts with it).
    pub mesh: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct MergeArgs {
    /// Input databases.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output database (created or extended).
    #[arg(short, long)]
    pub output: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// SQLite database written by `stable-poses run` (read only).
    #[arg(long)]
    pub db: PathBuf,
    /// JSON file to write (what `hypotheses --stable`, `estimate --stable` and `report` read).
    #[arg(long)]
    pub json: PathBuf,
    /// Only meshes whose path contains this text (or whose hash starts with it).
    pub mesh: Option<String>,
}

/// `plausible bench stable`: drop-test throughput on the meshes in assets/.
#[derive(clap::Args, Debug)]
pub struct BenchStableArgs {
    /// Drops per mesh.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub drops: u64,
    /// Worker threads (default, or 0: all logical CPUs).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Meshes to use (default: duck_vhacd.obj, duck.obj and
    /// 003_cracker_box.stl from assets/).
    #[arg(long)]
    pub mesh: Vec<PathBuf>,
    /// Rescale every mesh to this bounding-box diagonal (m), as the pybullet peer does (1 mm to 10 m).
    #[arg(long, default_value_t = 0.15, value_parser = diameter_m)]
    pub diameter: f64,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Collider for every mesh: `hull` (default) or `decomposition`.
    #[arg(long)]
    pub collider: Option<ColliderKind>,
    /// Vertex budget of each simplified collider hull.
    #[arg(long, default_value_t = 96)]
    pub hull_points: usize,
    /// Simulation steps per second (see `stable-poses --help`).
    #[arg(long, default_value_t = 240.0)]
    pub step_hz: f64,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Entry point of `plausible stable-poses`.
pub fn stable_poses(args: StableArgs) -> anyhow::Result<()> {
    match args.action {
        None => run(args.run),
        Some(StableAction::Run(r)) => run(r),
        Some(StableAction::Show(s)) => show(s),
        Some(StableAction::Merge(m)) => merge(m),
        Some(StableAction::Export(e)) => export(e),
    }
}

/// `--threads`: absent or 0 is every logical CPU; more than 1024 is refused
/// (each worker holds its own physics world).
fn threads(t: Option<usize>) -> anyhow::Result<usize> {
    if let Some(n) = t.filter(|&n| n > 1024) {
        bail!("--threads {n}: give 1 to 1024 worker threads, or 0 for every logical CPU");
    }
    Ok(t.filter(|&t| t > 0).unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)))
}

/// Drops, clusters and stores every mesh. With `--trace` its span is the
/// trace's root: load, then per mesh prepare, drop tests and clustering.
#[tracing::instrument(name = "plausible stable-poses", level = "trace", skip_all)]
fn run(args: RunArgs) -> anyhow::Result<()> {
    let Some(db_path) = args.db.clone() else {
        bail!("--db is required")
    };
    if args.drops == 0 {
        bail!("--drops must be at least 1");
    }
    if let Some(json) = &args.json {
        plausible::io::check_writable(json).context("--json")?;
    }
    let meshes: Vec<(&str, Option<&std::path::Path>)> = args.meshes.iter().map(|m| ("a mesh", Some(m.as_path()))).collect();
    super::distinct_files(&[("--db", Some(&db_path)), ("--json", args.json.as_deref())], &meshes)?;
    if !(0.0..90.0).contains(&args.cluster_deg) || args.cluster_deg == 0.0 {
        bail!("--cluster-deg must be between 0 and 90 degrees");
    }
    // A drop of the reference object settles in 0.3-2 s; 10 minutes of
    // simulated time is 144,000 steps a drop, and 1e30 s ran for ever.
    if !(args.max_time.is_finite() && args.max_time > 0.0 && args.max_time <= 600.0) {
        bail!(
            "--max-time {}: the simulated seconds a drop may take must lie in (0, 600] (the default 10 s is 2,400 steps at 240 Hz)",
            plausible::error::compact(args.max_time, 3)
        );
    }
    let dt = step_dt(args.step_hz)?;
    let params = RunParams {
        drops: args.drops,
        seed: args.seed,
        collider: args.collider,
        hull_max_points: hull_points(args.hull_points)?,
        sim: stable::drop::SimParams {
            max_time: args.max_time,
            dt,
            ..Default::default()
        },
        ..Default::default()
    };
    let cluster_params = ClusterParams {
        cluster_deg: args.cluster_deg,
        ..Default::default()
    };
    let nthreads = threads(args.threads)?;
    let show_progress = !args.quiet && std::io::stderr().is_terminal();
    // Every mesh is read before the first drop: a missing or broken file
    // fails at once, not after hours of simulating the meshes before it.
    let load = tracing::trace_span!("load").entered();
    let mut loaded = Vec::with_capacity(args.meshes.len());
    for path in &args.meshes {
        // `stable-poses --db X show` reads `show` as a mesh: say where a
        // subcommand goes.
        let action = ["run", "show", "merge", "export"].iter().find(|a| path.as_os_str() == **a && !path.exists());
        let hint = action.map_or(String::new(), |a| format!(" (for the `{a}` subcommand, name it first: `plausible stable-poses {a} --db ...`)"));
        loaded.push(Mesh::load(path, args.mesh_units).with_context(|| format!("loading {}{hint}", path.display()))?);
    }
    drop(load);
    // Opened once every mesh has loaded: a mistyped command leaves no
    // empty database behind.
    let mut db = tracing::trace_span!("open_db").in_scope(|| Db::open(&db_path))?;
    let mut names = Vec::new();
    for (path, (mesh, report)) in args.meshes.iter().zip(loaded) {
        for w in &report.warnings {
            eprintln!("warning: {}: {w}", path.display());
        }
        let name = path.display().to_string();
        let _span = tracing::trace_span!("mesh_run", mesh = %name).entered();
        let prepared = stable::prepare(mesh, &name, &params)?;
        for w in &prepared.warnings {
            eprintln!("warning: {w}");
        }
        // A finely tessellated round mesh can give a hundred rounding notes:
        // the first few say what happened, the database keeps them all.
        const SHOWN_NOTES: usize = 5;
        let shown = if args.quiet { 0 } else { SHOWN_NOTES };
        for n in prepared.analytic.notes.iter().take(shown) {
            eprintln!("note: {name}: analytic: {n}");
        }
        if !args.quiet && prepared.analytic.notes.len() > SHOWN_NOTES {
            eprintln!("note: {name}: analytic: {} more such notes (kept in the database)", prepared.analytic.notes.len() - SHOWN_NOTES);
        }
        let units = match (args.mesh_units, report.scale_to_metres == 1.0) {
            (MeshUnits::Metres, _) | (MeshUnits::Auto, true) => "m",
            (MeshUnits::Centimetres, _) => "cm",
            _ => "mm",
        };
        let bar = if show_progress {
            ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr())
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{msg} [{bar:30}] {pos}/{len} drops, {per_sec}, ETA {eta}",
            )
            .map_err(|e| anyhow::anyhow!("progress template: {e}"))?
            .progress_chars("=> "),
        );
        bar.set_message(short_name(path));
        let summary = stable::run_into_db(
            &mut db,
            &prepared,
            units,
            report.scale_to_metres,
            &params,
            args.shard,
            nthreads,
            cluster_params,
            |done, total| {
                bar.set_length(total);
                bar.set_position(done);
            },
        )?;
        bar.finish_and_clear();
        if !args.quiet {
            let poses = summary
                .clusters
                .iter()
                .filter(|c| c.kind == ClusterKind::Pose)
                .count();
            let families = summary.clusters.len() - poses;
            println!(
                "{name}: {} drops simulated ({} reused) in {:.1} s ({:.0} drops/s on {nthreads} threads); \
                 {}/{} stored drops settled; {poses} clusters, {families} families; {} analytic poses",
                summary.simulated,
                summary.reused,
                summary.seconds,
                summary.simulated as f64 / summary.seconds.max(1e-9),
                summary.settled,
                summary.stored,
                prepared.analytic.poses.len()
            );
        }
        warn_unsettled(&name, summary.settled, summary.stored);
        names.push(prepared.sha256.clone());
    }
    if let Some(json) = &args.json {
        let _span = tracing::trace_span!("export").entered();
        let mut ex = stable::export::export(&db, None)?;
        ex.meshes.retain(|m| names.contains(&m.sha256));
        write_json(json, &ex)?;
    }
    Ok(())
}

/// The runs of `db` with fewer drops stored than asked for (a shard not
/// merged yet, or still running), each as a sentence: merged shards give
/// the single run's result only once all of them are in.
fn incomplete_runs(db: &Db) -> anyhow::Result<Vec<String>> {
    let names: std::collections::HashMap<String, String> = db.meshes()?.into_iter().map(|m| (m.sha256, m.source)).collect();
    let mut out = Vec::new();
    for run in db.runs()? {
        let stored = db.finished_drops(run.id)?.len() as u64;
        if stored < run.drops {
            let name = names.get(&run.mesh_sha256).cloned().unwrap_or_else(|| run.mesh_sha256.chars().take(12).collect());
            out.push(format!(
                "{name} (seed {}): {stored} of its {} drops are in; merge the other shards (or finish them) before using its clusters",
                run.seed, run.drops
            ));
        }
    }
    Ok(out)
}

/// Share of stored drops below which a run is warned about (also under
/// `--quiet`): the clusters then describe only the drops that came to
/// rest, and a body that never rests (a needle 0.1 mm thick rolled at the
/// time cap in every drop) has none.
const MIN_SETTLED: f64 = 0.99;

fn warn_unsettled(name: &str, settled: u64, stored: u64) {
    if stored > 0 && (settled as f64) < MIN_SETTLED * stored as f64 {
        eprintln!(
            "warning: {name}: only {settled} of {stored} drops came to rest within --max-time ({:.1} %); the clusters describe those alone. \
             A body that is still rolling or rocking at the cap (very thin, very light, or round) may need a longer --max-time or another collider",
            100.0 * settled as f64 / stored as f64
        );
    }
}

fn short_name(p: &Path) -> String {
    p.file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

/// Writes JSON to `path` (atomically), or to standard output for `-`.
fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    if path.as_os_str() == "-" {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "{text}")?;
        return Ok(out.flush()?);
    }
    plausible::io::write_atomically(path, |w| {
        use std::io::Write;
        writeln!(w, "{text}")
    })?;
    Ok(())
}

fn fmt_vec(v: [f64; 3]) -> String {
    format!("({:+.3}, {:+.3}, {:+.3})", v[0], v[1], v[2])
}

fn show(args: ShowArgs) -> anyhow::Result<()> {
    let db = Db::open_existing(&args.db)?;
    let meshes = db.meshes()?;
    let mut any = false;
    let mut out = String::new();
    for run in db.runs()? {
        let source = meshes
            .iter()
            .find(|m| m.sha256 == run.mesh_sha256)
            .map(|m| m.source.as_str())
            .unwrap_or("?");
        if let Some(f) = &args.mesh {
            if !source.contains(f.as_str()) && !run.mesh_sha256.starts_with(f.as_str()) {
                continue;
            }
        }
        any = true;
        let drops = db.drops(run.id)?;
        let settled = drops.iter().filter(|d| d.settled).count();
        let clusters = db.clusters(run.id)?;
        let analytic = db.analytic(run.id)?;
        let matches = stable::match_analytic(&clusters, &analytic);
        writeln!(
            out,
            "{source}  sha256 {}  seed {}  collider {}  revision {}  drops {}/{}  settled {} ({:.1} %)",
            &run.mesh_sha256[..12.min(run.mesh_sha256.len())],
            run.seed,
            run.collider,
            run.drop_revision(),
            drops.len(),
            run.drops,
            settled,
            100.0 * settled as f64 / drops.len().max(1) as f64
        )?;
        writeln!(
            out,
            "  {:>3}  {:<9} {:>7}  {:>17}  {:>5}  {:<27} {:>9}   analytic match (angle, p_drop - p_analytic)",
            "#",
            "kind",
            "p",
            "95% CI",
            "count",
            "gravity in model",
            "height m",
        )?;
        for (i, (c, m)) in clusters.iter().zip(&matches).enumerate() {
            let kind = match &c.kind {
                ClusterKind::Pose => "pose".to_string(),
                ClusterKind::Circle { .. } => "rolling".to_string(),
                ClusterKind::Scattered => "scattered".to_string(),
            };
            let dir = match &c.kind {
                ClusterKind::Circle { axis } => format!("axis {}", fmt_vec(*axis)),
                ClusterKind::Scattered => "-".to_string(),
                ClusterKind::Pose => fmt_vec(c.gravity_in_model),
            };
            let m = match m {
                Some((a, angle, dp)) => format!("A{a}: {angle:5.1}°, {dp:+.3}"),
                None => "-".into(),
            };
            writeln!(
                out,
                "  {:>3}  {:<9} {:>7.4}  [{:.4}, {:.4}]  {:>5}  {:<27} {:>9.4}   {}",
                i, kind, c.probability, c.ci95[0], c.ci95[1], c.count, dir, c.height, m
            )?;
        }
        if !analytic.is_empty() {
            writeln!(out, "  analytic (quasi-static) poses:")?;
            writeln!(
                out,
                "  {:>3}  {:>7}  {:<27} {:>9}  {:>9}",
                "#", "p", "gravity in model", "height m", "margin m"
            )?;
            for (i, a) in analytic.iter().enumerate() {
                writeln!(
                    out,
                    "  A{:<2}  {:>7.4}  {:<27} {:>9.4}  {:>9.4}",
                    i,
                    a.probability,
                    fmt_vec(a.gravity_in_model),
                    a.height,
                    a.margin
                )?;
            }
        }
        for n in &run.analytic_notes {
            writeln!(out, "  note: {n}")?;
        }
        writeln!(out)?;
    }
    if !any {
        match &args.mesh {
            Some(f) => bail!("{}: no mesh matching '{f}'", args.db.display()),
            None => writeln!(out, "{}: no runs yet", args.db.display())?,
        }
    }
    print_ignoring_closed_pipe(&out)
}

/// Writes to stdout; a closed pipe (`... | head`) ends output quietly.
fn print_ignoring_closed_pipe(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}

fn merge(args: MergeArgs) -> anyhow::Result<()> {
    for i in &args.inputs {
        if std::fs::canonicalize(i).ok() == std::fs::canonicalize(&args.output).ok()
            && args.output.exists()
        {
            bail!("{}: input and output are the same file", i.display());
        }
    }
    // Every input is opened (and integrity-checked) before the output is
    // touched, and the merge is written to a copy renamed into place at the
    // end: a bad input or a kill never leaves a half-merged output.
    for i in &args.inputs {
        Db::open_existing(i).with_context(|| format!("input {}", i.display()))?;
    }
    // Through a symbolic link, the file it names is merged into.
    let output = plausible::io::link_target(&args.output);
    let tmp = output.with_file_name(format!(
        ".{}.merge-{}.tmp",
        output.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        std::process::id()
    ));
    if output.exists() {
        std::fs::copy(&output, &tmp).with_context(|| format!("copying {}", args.output.display()))?;
    }
    let result = (|| -> anyhow::Result<(u64, Vec<String>)> {
        let mut out = Db::open(&tmp)?;
        let mut total = 0;
        for i in &args.inputs {
            let added = out.merge_from(i)?;
            println!("{}: {added} new drops", i.display());
            total += added;
        }
        Ok((total, incomplete_runs(&out)?))
    })();
    match result {
        Ok((total, incomplete)) => {
            std::fs::rename(&tmp, &output).with_context(|| format!("writing {}", args.output.display()))?;
            println!("{}: {total} drops merged", args.output.display());
            for w in incomplete {
                eprintln!("warning: {w}");
            }
            Ok(())
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e.context(format!("{} was left unchanged", args.output.display())))
        }
    }
}

fn export(args: ExportArgs) -> anyhow::Result<()> {
    super::distinct_files(&[("--json", Some(&args.json))], &[("--db", Some(&args.db))])?;
    let db = Db::open_existing(&args.db)?;
    let ex = stable::export::export(&db, args.mesh.as_deref())?;
    if let (Some(filter), true) = (&args.mesh, ex.meshes.is_empty()) {
        bail!("no mesh of {} matches '{filter}' (by path or hash prefix); `stable-poses show --db {}` lists them", args.db.display(), args.db.display());
    }
    write_json(&args.json, &ex)
}

/// Meshes shipped in assets/ for the benchmark: a convex decomposition, a
/// scanned-style mesh and a box.
fn bench_meshes() -> anyhow::Result<Vec<PathBuf>> {
    ["assets/pybullet/duck_vhacd.obj", "assets/pybullet/duck.obj", "assets/ycb/003_cracker_box.stl"]
        .iter()
        .map(|p| super::asset(p).context("--mesh"))
        .collect()
}

/// Parses a benchmark diameter in metres: finite, 1 mm to 10 m (a larger
/// world takes unbounded simulated time to settle).
fn diameter_m(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(v.is_finite() && (0.001..=10.0).contains(&v)) {
        return Err(format!("{v} m is outside 0.001-10 m"));
    }
    Ok(v)
}

/// Entry point of `plausible bench stable`.
pub fn bench_stable(args: BenchStableArgs) -> anyhow::Result<()> {
    let nthreads = threads(args.threads)?;
    let cpus = threads(None)?;
    if nthreads > cpus {
        bail!("--threads {nthreads}: this machine has {cpus} logical CPUs; more threads than that measure contention, and the per-core figure would be wrong");
    }
    let meshes = if args.mesh.is_empty() { bench_meshes()? } else { args.mesh.clone() };
    let dt = step_dt(args.step_hz)?;
    let hull_max_points = hull_points(args.hull_points)?;
    let mut rows = Vec::new();
    for path in &meshes {
        let (mesh, _) = Mesh::load(path, MeshUnits::Metres)?;
        // Scale about the origin (no re-centring), like the peer script.
        let mut mesh = mesh;
        let s = args.diameter / mesh.diagonal();
        mesh.scale(s);
        let collider = args.collider.unwrap_or(ColliderKind::Hull);
        let params = RunParams {
            drops: args.drops,
            seed: args.seed,
            collider,
            hull_max_points,
            sim: stable::drop::SimParams {
                dt,
                ..Default::default()
            },
            ..Default::default()
        };
        let t_prep = Instant::now();
        let prepared = stable::prepare(mesh, &path.display().to_string(), &params)?;
        let prep_s = t_prep.elapsed().as_secs_f64();
        let indices: Vec<u64> = (0..args.drops).collect();
        let mut results = Vec::with_capacity(indices.len());
        let t0 = Instant::now();
        stable::run_drops(&prepared, &params, &indices, nthreads, |r| {
            results.push(r);
            Ok(())
        })?;
        let secs = t0.elapsed().as_secs_f64();
        let settled = results.iter().filter(|d| d.settled).count();
        let steps: u64 = results.iter().map(|d| d.steps as u64).sum();
        let t_cluster = Instant::now();
        let clusters = stable::cluster::cluster(&results, ClusterParams::default());
        let cluster_s = t_cluster.elapsed().as_secs_f64();
        // Where a drop's time goes: a single-threaded pass over the first
        // worlds again (about 200 drops), timed by stage (same results as
        // above).
        let (mut stages, mut sample_steps, mut sample) = (stable::drop::DropTimes::default(), 0u64, 0u64);
        while sample < args.drops.min(200) {
            let members = stable::drop::world_members(sample, args.drops);
            let (rs, t) = stable::drop::simulate_world_timed(&prepared.body, &params.sim, &prepared.sha256, params.seed, members);
            stages += t;
            sample += rs.len() as u64;
            sample_steps += rs.iter().map(|r| r.steps as u64).sum::<u64>();
        }
        let (poses, families) = stable::export::split(&clusters);
        let drops_s = args.drops as f64 / secs;
        rows.push(serde_json::json!({
            "mesh": short_name(path),
            "triangles": prepared.mesh.triangles.len(),
            "collider": collider.as_str(),
            "collider_parts": prepared.collider_parts,
            "collider_points": prepared.collider_points,
            "drops": args.drops,
            "threads": nthreads,
            "seconds": secs,
            "prepare_seconds": prep_s,
            "drops_per_s": drops_s,
            "drops_per_s_per_core": drops_s / nthreads as f64,
            "mean_steps_per_drop": steps as f64 / args.drops as f64,
            "seconds_per_1000_drops": 1000.0 / drops_s,
            "settled": settled,
            "settled_fraction": settled as f64 / args.drops as f64,
            "cluster_seconds": cluster_s,
            "stages": {
                "sample_drops": sample,
                "setup_us_per_drop": 1e6 * stages.setup / sample as f64,
                "step_us": 1e6 * stages.step / sample_steps.max(1) as f64,
                "rest_test_us_per_step": 1e6 * stages.rest_test / sample_steps.max(1) as f64,
                "ms_per_drop": 1e3 * (stages.setup + stages.step + stages.rest_test) / sample as f64,
                "timing": "one thread, wall clock",
            },
            "clusters": poses.iter().take(12).map(|c| serde_json::json!({
                "p": c.probability, "ci95": c.ci95, "gravity_in_model": c.gravity_in_model
            })).collect::<Vec<_>>(),
            "families": families.len(),
            "analytic": prepared.analytic.poses.iter().take(12).map(|a| serde_json::json!({
                "p": a.probability, "gravity_in_model": a.gravity_in_model
            })).collect::<Vec<_>>(),
        }));
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "bench": "stable", "machine": super::machine::Machine::detect(None), "results": rows })
            )?
        );
    } else {
        println!("machine: {}", super::machine::Machine::detect(None).line());
        println!(
            "{:<24} {:>6} {:>6} {:>9} {:>10} {:>11} {:>10} {:>9} {:>8} {:>9} {:>8} {:>8}",
            "mesh",
            "tris",
            "hullpt",
            "drops/s",
            "per core",
            "steps/drop",
            "s/1000",
            "settled",
            "clusters",
            "setup us",
            "step us",
            "rest us"
        );
        for r in &rows {
            println!(
                "{:<24} {:>6} {:>6} {:>9.1} {:>10.1} {:>11.1} {:>10.2} {:>8.1}% {:>8} {:>9.1} {:>8.2} {:>8.2}",
                r["mesh"].as_str().unwrap_or("?"),
                // serde_json's Display ignores widths: print the numbers.
                r["triangles"].as_u64().unwrap_or(0),
                r["collider_points"].as_u64().unwrap_or(0),
                r["drops_per_s"].as_f64().unwrap_or(0.0),
                r["drops_per_s_per_core"].as_f64().unwrap_or(0.0),
                r["mean_steps_per_drop"].as_f64().unwrap_or(0.0),
                r["seconds_per_1000_drops"].as_f64().unwrap_or(0.0),
                100.0 * r["settled_fraction"].as_f64().unwrap_or(0.0),
                r["clusters"].as_array().map(|a| a.len()).unwrap_or(0),
                r["stages"]["setup_us_per_drop"].as_f64().unwrap_or(0.0),
                r["stages"]["step_us"].as_f64().unwrap_or(0.0),
                r["stages"]["rest_test_us_per_step"].as_f64().unwrap_or(0.0)
            );
        }
    }
    Ok(())
}

/// `--hull-points`, checked: fewer than 8 vertices make a collider too
/// coarse to stand for any real mesh (4 is a tetrahedron, whatever the
/// shape), and the simplification is made for a budget, not a full hull of
/// a million points.
fn hull_points(n: usize) -> anyhow::Result<usize> {
    if !(8..=100_000).contains(&n) {
        anyhow::bail!("--hull-points {n}: give 8 to 100000 vertices per collider hull (default 96)");
    }
    Ok(n)
}

/// The time step of `--step-hz`, checked: 10 to 10,000 steps per second.
fn step_dt(hz: f64) -> anyhow::Result<f64> {
    if !(10.0..=10_000.0).contains(&hz) {
        anyhow::bail!("--step-hz {hz}: give 10 to 10000 steps per second");
    }
    Ok(1.0 / hz)
}
