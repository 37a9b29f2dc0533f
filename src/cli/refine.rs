//! `plausible refine`: refine another method's BOP results (REF, SIR, RIR)
//! image by image, resumable and shardable.

use std::collections::HashMap;
use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use plausible::bop::results::{format_line, HEADER};
use plausible::bop::dataset::Scene;
use plausible::bop::{read_results, Dataset};
use plausible::refine::dataset::{image_jobs, load_models, refine_image, resume_from, ImageStats, Masks};
use plausible::refine::{Method, RefineParams};

const DEFAULT_EXPLORATION: f64 = 0.1;
const DEFAULT_DISCOUNT: f64 = 1.0;

#[derive(clap::Args, Debug)]
pub struct RefineArgs {
    /// BOP dataset folder (models/ or models_eval/, the split with depth/
    /// and, for the oracle masks, mask_visib/).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Split folder inside the dataset.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Sensor of a split annotated per sensor (scene_gt_{sensor}.json,
    /// depth_{sensor}/, mask_visib_{sensor}/: BOP-H3 and the BOP'24
    /// industrial datasets, e.g. photoneo for ipd, xyz for xyzibd).
    #[arg(long)]
    pub sensor: Option<String>,
    /// Initial estimates: a BOP results CSV (several estimates of an object
    /// in an image are its hypotheses).
    #[arg(long)]
    pub init: PathBuf,
    /// Refined results CSV. Written image by image: if it exists, the
    /// images already in it are skipped (a killed run resumes).
    #[arg(long)]
    pub out: PathBuf,
    /// ref (ICP), pir (ICP after a short simulation on the support plane
    /// among the other objects), sir (PIR steps kept only if the score
    /// improves) or rir (SIR steps spread over the hypotheses by UCB1).
    #[arg(long, default_value = "rir", value_parser = ["ref", "pir", "sir", "rir"])]
    pub method: String,
    /// SIR and RIR without the simulation (ICP steps only).
    #[arg(long)]
    pub no_physics: bool,
    /// Level of detail of the mesh the visual score renders: `off` (the
    /// full model, default), `auto` (the coarsest simplification within a
    /// quarter of a pixel at each object) or a triangle count (the paper's
    /// Table 1: 704, 352, 70, 34). ICP, the simulation and the evaluation
    /// keep the full model.
    #[arg(long, default_value = "off")]
    pub lod: plausible::mesh::lod::LodChoice,
    /// Refinement steps per hypothesis (RIR: the budget is this times the
    /// object's hypotheses).
    #[arg(long, default_value_t = 2)]
    pub steps: usize,
    /// RIR: refinement steps per object, spread over its hypotheses by UCB1
    /// (default: --steps times its hypotheses).
    #[arg(long)]
    pub budget: Option<usize>,
    /// ICP iterations per refinement step.
    #[arg(long, default_value_t = 5)]
    pub icp_iterations: usize,
    /// UCB exploration constant (RIR).
    #[arg(long, default_value_t = DEFAULT_EXPLORATION)]
    pub exploration: f64,
    /// UCB discount γ in (0, 1]: 1 is UCB1; below 1 is discounted UCB,
    /// which forgets old rewards (the paper: 0.99 when rewards change as
    /// the rest of the scene does). RIR.
    #[arg(long, default_value_t = DEFAULT_DISCOUNT)]
    pub discount: f64,
#[command(flatten)]
    pub run: ImageRunArgs,
}

/// What `refine` and `estimate` share: the masks, which images, where the
/// summary and pictures go, the progress bar and the device.
#[derive(clap::Args, Debug)]
pub struct ImageRunArgs {
    /// Masks: `oracle` (the dataset's mask_visib/, one mask per ground-truth
    /// instance) or a folder with SSSSSS/IIIIII_OOOOOO.png (scene, image,
    /// object id).
    #[arg(long, default_value = "oracle")]
    pub masks: String,
    /// Only these scenes (comma-separated ids).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<u32>,
    /// Only these images (comma-separated ids; with --scenes, of those
    /// scenes).
    #[arg(long, value_delimiter = ',')]
    pub images: Vec<u32>,
    /// Only images i (0-based, in scene/image order) with i mod n = k - 1:
    /// run shards 1/n .. n/n apart and concatenate their outputs (each
    /// after its header line).
    #[arg(long)]
    pub shard: Option<String>,
    /// Write a JSON summary (counts, timings per stage) here.
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Write a picture per image to this folder (SSSSSS_IIIIII.png): each
    /// object's alignment before and after refinement, its verdict, and the
    /// scene's physical views.
    #[arg(long)]
    pub explain: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub dev: super::AutoDeviceArgs,
}

impl ImageRunArgs {
    /// The parsed `--shard` and `--masks`.
    pub fn shard_and_masks(&self) -> Result<(Option<(usize, usize)>, Masks)> {
        Ok((self.shard.as_deref().map(parse_shard).transpose()?, parse_masks(&self.masks)?))
    }

    /// `--masks` as recorded in an output's settings: `oracle` or the
    /// folder's absolute path.
    pub fn masks_setting(&self) -> String {
        if self.masks == "oracle" {
            self.masks.clone()
        } else {
            path_setting(std::path::Path::new(&self.masks))
        }
    }

    /// The jobs of the images chosen by `--scenes` and `--images` (all
    /// without them); `key` gives a job's (scene, image), `what` names
    /// where the jobs come from. A chosen scene or image without a job is
    /// an error, not an empty run.
    pub fn select_images<T>(&self, jobs: Vec<T>, key: impl Fn(&T) -> (u32, u32), what: &str) -> Result<Vec<T>> {
        let in_scenes = |s: u32| self.scenes.is_empty() || self.scenes.contains(&s);
        for s in &self.scenes {
            if !jobs.iter().any(|j| key(j).0 == *s) {
                bail!("--scenes {s}: no {what} in scene {s} (the scenes with {what}: {})", id_list(jobs.iter().map(|j| key(j).0)));
            }
        }
        for i in &self.images {
            if !jobs.iter().any(|j| key(j).1 == *i && in_scenes(key(j).0)) {
                bail!("--images {i}: no {what} in image {i} of the chosen scenes");
            }
        }
        let jobs: Vec<T> = jobs.into_iter().filter(|j| in_scenes(key(j).0) && (self.images.is_empty() || self.images.contains(&key(j).1))).collect();
        if jobs.is_empty() {
            let chosen = if self.scenes.is_empty() && self.images.is_empty() { "" } else { " in the chosen scenes and images" };
            bail!("no {what}{chosen}");
        }
        Ok(jobs)
    }

    /// With a folder of masks: refuses a run where none of the wanted
    /// (scene, image, object) masks is there (another naming, the wrong
    /// folder) and warns when some are missing, whose objects are left out.
    pub fn check_masks(&self, masks: &Masks, wanted: &[(u32, u32, u32)], consequence: &str) -> Result<()> {
        // A mask that is there but no file (a FIFO, a folder) would fail
        // its image after the work on every image before it.
        if let Masks::Dir(d) = masks {
            if let Some(p) = wanted.iter().map(|&(s, i, o)| Masks::dir_file(d, s, i, o)).find(|p| p.exists() && !p.is_file()) {
                bail!("--masks {}: {} is not a regular file", d.display(), p.display());
            }
        }
        let missing = masks.missing(wanted);
        if missing.is_empty() {
            return Ok(());
        }
        let Masks::Dir(d) = masks else { return Ok(()) };
        let (s, i, o) = missing[0];
        let example = Masks::dir_file(d, s, i, o);
        if missing.len() == wanted.len() {
            bail!("--masks {}: none of the {} masks the images need is there (the first: {}; the folder holds SSSSSS/IIIIII_OOOOOO.png by scene, image and object id)", d.display(), wanted.len(), example.display());
        }
        eprintln!("warning: --masks {}: {} of {} masks are missing (the first: {}); {consequence}", d.display(), missing.len(), wanted.len(), example.display());
        Ok(())
    }

    /// Before any work, so a bad path fails fast: checks that `out` and
    /// `--summary` can be written, that no output names an input (or
    /// another output: the side files of `out` and the `--explain` folder
    /// included) or lies where the dataset reads, makes the `--explain`
    /// folder, and takes `out`'s lock, held until the returned file is
    /// dropped.
    pub fn prepare_outputs(&self, ds: &Dataset, out: &std::path::Path, inputs: &[(&str, Option<&std::path::Path>)]) -> Result<Option<std::fs::File>> {
        plausible::io::check_writable(out)?;
        let (settings, journal, lock) = (settings_path(out), plausible::refine::dataset::journal_path(out), lock_path(out));
        let outputs = [
            ("--out", Some(out)),
            ("--out's settings record", Some(settings.as_path())),
            ("--out's journal", Some(journal.as_path())),
            ("--out's lock", Some(lock.as_path())),
            ("--summary", self.summary.as_deref()),
            ("--explain", self.explain.as_deref()),
        ];
        super::distinct_files(&outputs, inputs)?;
        super::outside_dataset(ds, &outputs)?;
        if let Some(p) = &self.summary {
            plausible::io::check_writable(p).context("--summary")?;
        }
        if let Some(d) = &self.explain {
            if d.exists() && !d.is_dir() {
                bail!("--explain {}: is a file; it names the folder the pictures are written to", d.display());
            }
            std::fs::create_dir_all(d).with_context(|| format!("--explain {}: cannot create the folder", d.display()))?;
            plausible::io::check_writable(&d.join(".plausible-write-test")).with_context(|| format!("--explain {}", d.display()))?;
        }
        lock_output(out)
    }

    /// A progress bar over `n` images (hidden with `--quiet`).
    pub fn progress(&self, n: usize) -> indicatif::ProgressBar {
        let pb = super::progress(n as u64, "images");
        if self.quiet {
            pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        pb
    }

    /// Writes an image's picture as `SSSSSS_IIIIII.png` in the `--explain` folder.
    pub fn save_picture(&self, scene_id: u32, im_id: u32, picture: Option<&image::RgbImage>) -> Result<()> {
        if let (Some(d), Some(pic)) = (&self.explain, picture) {
            let path = d.join(format!("{scene_id:06}_{im_id:06}.png"));
            let title = format!("scene {scene_id}, image {im_id}: each object's alignment before | after refinement, and the physics after");
            plausible::io::save_png(&path, &plausible::draw::with_title(pic, &title, image::Rgb([225, 225, 225])))?;
        }
        Ok(())
    }
}

/// Distinct ids, in order, for a message (the first 20).
fn id_list(ids: impl Iterator<Item = u32>) -> String {
    let set: std::collections::BTreeSet<u32> = ids.collect();
    let mut s: Vec<String> = set.iter().take(20).map(u32::to_string).collect();
    if set.len() > 20 {
        s.push("...".into());
    }
    s.join(", ")
}

/// The scenes of `images`, each image checked before any work: its camera
/// entry, its depth PNG and intrinsics that fit its size. A missing one
/// had failed the run after every image before it was done. A principal
/// point outside the image is warned about once per scene.
pub fn load_scenes(ds: &Dataset, images: impl Iterator<Item = (u32, u32)>) -> Result<HashMap<u32, Scene>> {
    let mut scenes: HashMap<u32, Scene> = HashMap::new();
    let mut warned = std::collections::HashSet::new();
    for (scene_id, im_id) in images {
        if let std::collections::hash_map::Entry::Vacant(e) = scenes.entry(scene_id) {
            e.insert(ds.scene(scene_id).with_context(|| format!("scene {scene_id}"))?);
        }
        let scene = &scenes[&scene_id];
        let at = || format!("scene {scene_id} image {im_id}");
        // A lens camera first: HOT3D has no depth either, and the lens is the reason.
        scene.pinhole_k(im_id).with_context(at)?;
        let depth = scene.depth_path(im_id);
        if !depth.is_file() {
            bail!("{}: no depth image {}", at(), depth.display());
        }
        let (w, h) = scene.image_size(im_id).with_context(at)?;
        let k = scene.intrinsics(im_id, w, h).with_context(at)?;
        if let Some(note) = k.principal_point_note().filter(|_| warned.insert(scene_id)) {
            eprintln!("warning: {} (image {im_id}, and maybe others of the scene): {note}", scene.file("scene_camera").display());
        }
    }
    Ok(scenes)
}

/// Refuses `--no-physics` where it would be ignored (refine and estimate):
/// ref never simulates, pir always does. `RefineParams::validate` refuses
/// it too, in library words; this names the flag.
pub fn check_no_physics(no_physics: bool, method: Method) -> Result<()> {
    if no_physics && matches!(method, Method::Ref | Method::Pir) {
        bail!("--no-physics is for --method sir and rir: ref never simulates, pir always does (it is ICP after a simulation)");
    }
    Ok(())
}

/// `oracle` or a folder of masks.
pub fn parse_masks(s: &str) -> Result<Masks> {
    if s == "oracle" {
        return Ok(Masks::Oracle);
    }
    let d = PathBuf::from(s);
    if !d.is_dir() {
        bail!("--masks {}: not a folder (give 'oracle' or a folder of masks)", d.display());
    }
    Ok(Masks::Dir(d))
}

/// A results CSV written image by image: each image's lines in one write,
/// synced, then a line in the journal beside it
/// ([`plausible::refine::dataset::journal_path`]), so a kill loses at most
/// the image being written (and resuming drops a partial one).
pub struct ResultsAppender {
    file: std::fs::File,
    path: PathBuf,
    /// A regular file is synced after each image and journaled (a pipe or
    /// device cannot be).
    journal: Option<(std::fs::File, PathBuf)>,
}

impl ResultsAppender {
    pub fn open(path: &std::path::Path) -> Result<ResultsAppender> {
        let append = |p: &std::path::Path| std::fs::OpenOptions::new().create(true).append(true).open(p).with_context(|| format!("cannot open {}", p.display()));
        let file = append(path)?;
        let regular = file.metadata().is_ok_and(|m| m.is_file());
        let journal = if regular {
            let j = plausible::refine::dataset::journal_path(path);
            Some((append(&j)?, j))
        } else {
            None
        };
        let empty = !regular || file.metadata().map(|m| m.len()).unwrap_or(0) == 0;
        let mut out = ResultsAppender { file, path: path.to_path_buf(), journal };
        if empty {
            let header = format!("{HEADER}\n");
            write_synced(&mut out.file, &out.path, &header, regular)?;
        }
        Ok(out)
    }

    /// Appends image (scene_id, im_id)'s estimates and journals it.
    pub fn append(&mut self, (scene_id, im_id): (u32, u32), estimates: &[plausible::bop::Estimate]) -> Result<()> {
        let text: String = estimates.iter().map(|e| format_line(e) + "\n").collect();
        write_synced(&mut self.file, &self.path, &text, self.journal.is_some())?;
        if let Some((j, path)) = &mut self.journal {
            write_synced(j, path, &plausible::refine::dataset::journal_line(scene_id, im_id, estimates.len()), true)?;
        }
        Ok(())
    }
}

fn write_synced(file: &mut std::fs::File, path: &std::path::Path, text: &str, sync: bool) -> Result<()> {
    file.write_all(text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
    if sync {
        file.sync_data().with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// `k/n` with 1 ≤ k ≤ n.
pub fn parse_shard(s: &str) -> Result<(usize, usize)> {
    let (k, n) = s.split_once('/').context("--shard takes k/n, e.g. 2/4")?;
    let (k, n): (usize, usize) = (k.trim().parse().context("--shard: k is not a number")?, n.trim().parse().context("--shard: n is not a number")?);
    if n == 0 || k == 0 || k > n || n > 100_000 {
        bail!("--shard {s}: need 1 <= k <= n <= 100000");
    }
    Ok((k, n))
}

/// The images of shard `k/n` (every n-th, from the k-th), all without one.
pub fn shard_of<T>(jobs: Vec<T>, shard: Option<(usize, usize)>) -> Vec<T> {
    match shard {
        Some((k, n)) => jobs.into_iter().enumerate().filter(|(i, _)| i % n == k - 1).map(|(_, j)| j).collect(),
        None => jobs,
    }
}

/// How long a held lock is waited for before the run is refused: a run
/// killed a moment ago can hold it until the kernel has finished tearing
/// its process down (seen for up to a second after `kill -9`, while the
/// rerun the README tells users to make was already starting).
const LOCK_PATIENCE: std::time::Duration = std::time::Duration::from_secs(3);

/// `file.try_lock()`, retried for [`LOCK_PATIENCE`] while another holds it.
fn try_lock_awhile(file: &std::fs::File) -> std::result::Result<(), std::fs::TryLockError> {
    let start = std::time::Instant::now();
    loop {
        match file.try_lock() {
            Err(std::fs::TryLockError::WouldBlock) if start.elapsed() < LOCK_PATIENCE => std::thread::sleep(std::time::Duration::from_millis(50)),
            r => return r,
        }
    }
}

/// Takes `OUT.lock` for this run: two runs writing one output at once
/// would each rewrite it on resuming while the other appends to the file
/// it replaced, losing or doubling rows. The lock (flock) goes with the
/// process, however it ends; the small file stays, like the journal.
/// An output that is no regular file (/dev/null, a pipe) is never resumed
/// and gets no lock.
fn lock_output(out: &std::path::Path) -> Result<Option<std::fs::File>> {
    if std::fs::metadata(out).is_ok_and(|m| !m.is_file()) {
        return Ok(None);
    }
    // Named after the file itself, so every spelling of it (a symlink, a
    // relative path) takes the same lock.
    let out = super::resolved(out).unwrap_or_else(|| out.to_path_buf());
    let path = lock_path(&out);
    let file = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(&path).map_err(|e| plausible::Error::write(&path, e))?;
    match try_lock_awhile(&file) {
        Ok(()) => Ok(Some(file)),
        Err(std::fs::TryLockError::WouldBlock) => {
            bail!("--out {}: another run is writing it (it holds {}); wait for it to end, or give another --out", out.display(), path.display())
        }
        Err(std::fs::TryLockError::Error(e)) => {
            eprintln!("warning: {}: cannot lock ({e}); make sure no other run writes --out {} meanwhile", path.display(), out.display());
            Ok(Some(file))
        }
    }
}

/// The file beside `out` that records the settings its results were made
/// with.
pub fn settings_path(out: &std::path::Path) -> PathBuf {
    beside(out, ".settings.json")
}

/// The lock file a run writing `out` holds ([`lock_output`]).
fn lock_path(out: &std::path::Path) -> PathBuf {
    beside(out, ".lock")
}

/// `out` with `suffix` added to its file name (a side file of the output).
fn beside(out: &std::path::Path, suffix: &str) -> PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(suffix);
    PathBuf::from(name)
}

/// SHA-256 of what was read from an input, one canonical line per item,
/// for the settings record. Not of the file: a pipe (`--init <(...)`)
/// cannot be read twice, and a second read hashed nothing, so any other
/// input resumed the output silently; and a file rewritten with the same
/// contents is the same input.
pub fn read_digest(lines: impl Iterator<Item = String>) -> String {
    use sha2::Digest as _;
    let mut hash = sha2::Sha256::new();
    for line in lines {
        hash.update(line.as_bytes());
        hash.update(b"\n");
    }
    plausible::stable::db::hex(&hash.finalize())
}

/// SHA-256 of a regular file's bytes: what earlier versions recorded for
/// --init and --targets (see [`check_settings`]).
/// `None` for anything else (a pipe cannot be read twice).
pub fn legacy_file_digest(path: &std::path::Path) -> Option<String> {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return None;
    }
    std::fs::File::open(path).ok().and_then(|f| plausible::stable::db::sha256_hex_reader(f).ok())
}

/// A path as recorded in the settings: absolute where it resolves.
pub fn path_setting(path: &std::path::Path) -> String {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()).display().to_string()
}

/// Settings that records of earlier versions do not have: an output they
/// started resumes without the check (it had none then).
const NEWER_SETTINGS: [&str; 1] = ["models"];

/// Refuses to resume into `out` when it was written with other settings
/// (another --stable, --lod, method, ...): its images would be kept and the
/// rest made differently, a silently mixed result. The settings are kept in
/// `OUT.settings.json`, written when the output starts. A non-empty output
/// without one was not started by this command and is refused.
///
/// `legacy` gives, per key, how to get the value an earlier version
/// recorded for the same input (a digest of the file rather than of what
/// was read), so outputs it started still resume; it is asked only for a
/// key whose recorded value differs (it reads the whole file).
pub fn check_settings(out: &std::path::Path, settings: &serde_json::Value, legacy: &[(&str, &dyn Fn() -> Option<String>)]) -> Result<()> {
    let meta = std::fs::metadata(out).ok();
    let resumable = meta.as_ref().is_some_and(|m| m.is_file());
    let started = resumable && meta.as_ref().is_some_and(|m| m.len() > 0);
    let stamp = settings_path(out);
    if started {
        match std::fs::read_to_string(&stamp) {
            Ok(text) => {
                let before: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}: not a settings record", stamp.display()))?;
                let differ: Vec<&str> = settings
                    .as_object()
                    .into_iter()
                    .flatten()
                    .filter(|(k, v)| before.get(k.as_str()) != Some(*v))
                    // Recorded since 12-05: outputs started before lack it.
                    .filter(|(k, _)| !(NEWER_SETTINGS.contains(&k.as_str()) && before.get(k.as_str()).is_none()))
                    .filter(|(k, _)| {
                        let recorded = before.get(k.as_str()).and_then(|b| b.as_str());
                        !legacy.iter().any(|(l, old)| l == k && recorded.is_some() && old().as_deref() == recorded)
                    })
                    .map(|(k, _)| k.as_str())
                    .collect();
                if !differ.is_empty() {
                    bail!(
                        "{} was written with other settings ({}; recorded in {}): resuming would mix two kinds of results. Give another --out, or delete {} and {} to start again",
                        out.display(),
                        differ.join(", "),
                        stamp.display(),
                        out.display(),
                        stamp.display()
                    );
                }
                return Ok(());
            }
            // A results file that no run of this command started (another
            // method's results, a copy of the input): resuming would keep
            // its images as if refined or estimated.
            Err(_) => bail!(
                "{} already holds results but has no settings record ({}), so it was not written by this command: give another --out, or delete it to start again",
                out.display(),
                stamp.display()
            ),
        }
    } else if meta.is_some() && !resumable {
        return Ok(()); // a pipe or device: nothing to resume
    }
    let text = serde_json::to_string_pretty(settings)? + "\n";
    std::fs::write(&stamp, text).with_context(|| format!("cannot write {}", stamp.display()))
}

/// Drops the images already complete in `out` (see [`resume_from`]);
/// `key` gives a job's (scene, image) and `expected` its estimate count.
pub fn skip_done<T>(jobs: &mut Vec<T>, out: &std::path::Path, key: impl Fn(&T) -> (u32, u32), expected: impl Fn(&T) -> usize) -> Result<()> {
    let counts = jobs.iter().map(|j| (key(j), expected(j))).collect();
    let done = resume_from(out, &counts).context("--out (resuming)")?;
    let before = jobs.len();
    jobs.retain(|j| !done.contains(&key(j)));
    if before > jobs.len() {
        eprintln!("resuming: {} of {before} images are already in {}", before - jobs.len(), out.display());
    }
    Ok(())
}

#[tracing::instrument(name = "plausible refine", level = "trace", skip_all)]
pub fn run(a: RefineArgs, verbose: u8) -> Result<()> {
    let params = RefineParams {
        method: Method::parse(&a.method).context("--method")?,
        steps: a.steps,
        budget: a.budget,
        icp: plausible::refine::icp::IcpParams { iterations: a.icp_iterations, ..Default::default() },
        exploration: a.exploration,
        gamma: a.discount,
        physics: !a.no_physics,
        lod: a.lod,
        ..Default::default()
    };
    if a.budget.is_some() && params.method != Method::Rir {
        bail!("--budget is for --method rir (the other methods take --steps per hypothesis)");
    }
    // Flags the method has no use for are refused, not ignored.
    if params.method != Method::Rir && (a.exploration != DEFAULT_EXPLORATION || a.discount != DEFAULT_DISCOUNT) {
        bail!("--exploration and --discount are for --method rir (its UCB over the hypotheses)");
    }
    check_no_physics(a.no_physics, params.method)?;
    params.validate().context("check --steps, --budget, --icp-iterations, --exploration and --discount")?;
    let (shard, masks) = a.run.shard_and_masks()?;
    let ds = Dataset::open_sensor(&a.dataset, &a.split, a.sensor.as_deref()).map_err(|e| {
        let flag = super::dataset_flag(&e, a.sensor.is_some());
        anyhow::anyhow!(e).context(flag)
    })?;
    let _lock = a.run.prepare_outputs(&ds, &a.out, &[("--init", Some(&a.init))])?;
    let init = read_results(&a.init).context("--init")?;
    let mut jobs = shard_of(a.run.select_images(image_jobs(&init), |j| (j.scene_id, j.im_id), "estimates")?, shard);
    // What decides an image's refined poses (not which images).
    let mut settings = serde_json::json!({
        "command": "refine",
        "dataset": path_setting(&a.dataset),
        "split": a.split,
        "init": read_digest(init.iter().map(format_line)),
        "models": ds.models_digest()?,
        "method": a.method,
        "no_physics": a.no_physics,
        "lod": a.lod.to_string(),
        "steps": a.steps,
        "budget": a.budget,
        "icp_iterations": a.icp_iterations,
        "exploration": a.exploration,
        "discount": a.discount,
        "masks": a.run.masks_setting(),
    });
    if let Some(s) = &a.sensor {
        // Only when given: the records of runs without one stay valid.
        settings["sensor"] = serde_json::json!(s);
    }
    check_settings(&a.out, &settings, &[("init", &|| legacy_file_digest(&a.init))])?;
    skip_done(&mut jobs, &a.out, |j| (j.scene_id, j.im_id), |j| j.estimates.len())?;
    let mut objs: Vec<u32> = jobs.iter().flat_map(|j| j.estimates.iter().map(|e| e.obj_id)).collect();
    objs.sort_unstable();
    objs.dedup();
    if let Some(o) = objs.iter().find(|o| !ds.models_info.contains_key(o)) {
        bail!("--init: object {o} is not in the dataset's models_info.json");
    }
    let mask_keys: Vec<(u32, u32, u32)> = jobs.iter().flat_map(|j| j.estimates.iter().map(|e| (j.scene_id, j.im_id, e.obj_id))).collect::<std::collections::BTreeSet<_>>().into_iter().collect();
    a.run.check_masks(&masks, &mask_keys, "those objects' estimates are written as they were")?;
    let scenes = load_scenes(&ds, jobs.iter().map(|j| (j.scene_id, j.im_id)))?;
    let device = a.run.dev.open(verbose)?;
    // Compiled while the models load (Scorer::precompile).
    let _compiling = plausible::visual::Scorer::precompile(&device);
    eprintln!("refining {} images ({}, {} step(s) per hypothesis) with {}", jobs.len(), params.method.name(), params.steps, masks.describe());
    let models = load_models(&ds, &objs, &params).context("loading the models")?;
    let mut file = ResultsAppender::open(&a.out)?;
    let pb = a.run.progress(jobs.len());
    let mut total = ImageStats::default();
    for job in &jobs {
        let r = refine_image(&scenes[&job.scene_id], job, &models, &device, &masks, &params, a.run.explain.is_some())
            .with_context(|| format!("scene {} image {}", job.scene_id, job.im_id))?;
        a.run.save_picture(job.scene_id, job.im_id, r.picture.as_ref())?;
        file.append((job.scene_id, job.im_id), &r.estimates)?;
        total += r.stats;
        pb.inc(1);
    }
    pb.finish_and_clear();
    let per_image = total.seconds / jobs.len().max(1) as f64;
    println!(
        "refined {} images, {} objects ({} left as they were: no mask or too few observed points); {} steps, {} kept; {:.3} s per image",
        jobs.len(),
        total.objects,
        total.unrefined,
        total.steps,
        total.kept,
        per_image
    );
    println!("wrote {}", a.out.display());
    if let Some(p) = &a.run.summary {
        let v = serde_json::json!({
            "method": params.method.name(), "physics": params.method.simulates(params.physics), "steps": params.steps, "icp_iterations": params.icp.iterations,
            "masks": masks.describe(), "images": jobs.len(), "objects": total.objects, "unrefined": total.unrefined,
            "refinement_steps": total.steps, "kept_steps": total.kept, "seconds": total.seconds, "seconds_per_image": per_image,
            "stage_seconds_per_image": total.times.json(jobs.len().max(1) as f64),
        });
        plausible::io::write_atomically(p, |w| {
            serde_json::to_writer_pretty(&mut *w, &v)?;
            writeln!(w)
        })?;
    }
    Ok(())
}
