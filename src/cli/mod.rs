//! Subcommands of the `plausible` binary (anyhow lives here, not in the
//! library).

pub mod bench;
pub mod bench_estimate;
pub mod bench_eval;
pub mod bench_physics;
pub mod check;
pub mod demo;
pub mod estimate;
pub mod eval;
pub mod eval_coco;
pub mod hypotheses;
pub mod machine;
pub mod plane;
pub mod refine;
pub mod report;
pub mod score;
pub mod stable;
pub mod trace;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use plausible::gpu::DeviceChoice;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{read_camera_file, read_depth_png, read_mask_png, CameraFile, DepthImage};
use plausible::visual::Device;

/// The object mesh, shared by the subcommands that take one.
#[derive(clap::Args, Clone, Debug)]
pub struct MeshArgs {
    /// Object mesh (.obj, .ply, .stl, .gltf, .glb).
    #[arg(long)]
    pub mesh: PathBuf,
    /// Units of the mesh file: m, cm, mm or auto (a bounding-box diagonal above
    /// 5 m is taken as millimetres, and that is reported).
    #[arg(long, default_value = "auto")]
    pub mesh_units: MeshUnits,
}

impl MeshArgs {
    /// Loads the mesh, printing its warnings.
    pub fn load(&self) -> Result<Mesh> {
        let (mesh, report) = Mesh::load(&self.mesh, self.mesh_units)?;
        for w in &report.warnings {
            eprintln!("warning: {}: {w}", self.mesh.display());
        }
        Ok(mesh)
    }
}

/// An observed depth frame (BOP files), shared by the subcommands that
/// read one.
#[derive(clap::Args, Clone, Debug)]
pub struct ObservationArgs {
    /// Camera JSON: a BOP scene_camera.json entry {"cam_K": [...], "depth_scale": s}
    /// (or a whole scene_camera.json with --frame).
    #[arg(long)]
    pub camera: PathBuf,
    /// Frame id to pick from a whole scene_camera.json.
    #[arg(long)]
    pub frame: Option<String>,
    /// 16-bit depth PNG (value x depth_scale = millimetres).
    #[arg(long)]
    pub depth: PathBuf,
    /// 8-bit mask PNG of the object, non-zero = object (`score` without
    /// one scores the whole frame; `plane` leaves the mask, grown by
    /// --mask-margin, out; `hypotheses` needs it).
    #[arg(long)]
    pub mask: Option<PathBuf>,
}

impl ObservationArgs {
    /// The input files, by flag, for [`distinct_files`].
    pub fn inputs(&self) -> [(&'static str, Option<&std::path::Path>); 3] {
        [("--camera", Some(&self.camera)), ("--depth", Some(&self.depth)), ("--mask", self.mask.as_deref())]
    }

    /// Reads the depth and, when given, the mask. `frame_picks_poses`: the
    /// command also picks poses by `--frame` (score with --obj-id); without
    /// that, a `--frame` that a single camera file cannot use is refused
    /// rather than silently ignored.
    pub fn load(&self, frame_picks_poses: bool) -> Result<(DepthImage, Option<Vec<bool>>)> {
        let (cam, kind) = read_camera_file(&self.camera, self.frame.as_deref()).map_err(|e| {
            let frames = e.input() == Some(plausible::Input::Selection);
            anyhow::Error::new(e).context(if frames { "--camera (a frame of a scene_camera.json is picked with --frame)" } else { "--camera" })
        })?;
        if let (Some(f), false, CameraFile::Single) = (&self.frame, frame_picks_poses, kind) {
            bail!("--frame {f}: --camera {} holds one camera, not a scene_camera.json of frames, so there is nothing to pick", self.camera.display());
        }
        let obs = read_depth_png(&self.depth, &cam).context("--depth")?;
        if let Some(note) = obs.intrinsics.principal_point_note() {
            eprintln!("warning: --camera {}: {note}", self.camera.display());
        }
        let mask = match &self.mask {
            Some(p) => {
                let m = read_mask_png(p, obs.intrinsics.width, obs.intrinsics.height)?;
                plausible::observation::check_mask(&m, obs.intrinsics.width, obs.intrinsics.height).with_context(|| format!("--mask {}", p.display()))?;
                Some(m)
            }
            None => None,
        };
        Ok((obs, mask))
    }
}

/// Surface sampling of objects for the physical terms.
#[derive(clap::Args, Clone, Debug)]
pub struct SampleArgs {
    /// Surface samples per object (physical terms).
    #[arg(long, default_value_t = plausible::physical::samples::DEFAULT_SAMPLES)]
    pub samples: usize,
    /// Seed of the surface sampling.
    #[arg(long, default_value_t = plausible::physical::samples::DEFAULT_SEED)]
    pub seed: u64,
    /// Contact tolerance ε in metres (default: half the sample spacing,
    /// clamped to 2-5 mm, per object).
    #[arg(long)]
    pub epsilon: Option<f64>,
}

impl SampleArgs {
    /// Checks the flags before any work, naming them.
    pub fn check(&self) -> Result<()> {
        use plausible::physical::samples::MAX_SAMPLES;
        if !(1..=MAX_SAMPLES).contains(&self.samples) {
            bail!("--samples {}: between 1 and {MAX_SAMPLES} surface samples per object", self.samples);
        }
        if let Some(e) = self.epsilon.filter(|e| !(e.is_finite() && *e > 0.0)) {
            bail!("--epsilon {e}: ε is in metres and must be a positive number (the default is 2-5 mm)");
        }
        Ok(())
    }
}

/// Where to run, for the benchmarks: the adapter by default (the CPU twin
/// is measured beside it).
#[derive(clap::Args, Clone, Debug)]
pub struct DeviceArgs {
    /// `gpu` (any wgpu adapter, lavapipe included) or `cpu` (the CPU twins).
    #[arg(long, default_value = "gpu", value_parser = ["gpu", "cpu"])]
    pub device: String,
    /// Use the first adapter whose name contains this text. WGPU_BACKEND
    /// (vulkan, metal, dx12, gl) and WGPU_POWER_PREF are honoured too.
    #[arg(long)]
    pub adapter: Option<String>,
}

/// Where to run, for every command but the benchmarks (which measure the
/// adapter): `auto` by default.
#[derive(clap::Args, Clone, Debug)]
pub struct AutoDeviceArgs {
    /// `auto` (a hardware GPU when there is one, else the CPU twin, which
    /// beats a software adapter like lavapipe on the same cores), `gpu` (any
    /// wgpu adapter, lavapipe included) or `cpu` (the CPU twin).
    #[arg(long, default_value = "auto", value_parser = ["auto", "gpu", "cpu"])]
    pub device: String,
    /// Use the first adapter whose name contains this text (with `auto`
    /// too, even a software one; not found is an error). WGPU_BACKEND
    /// (vulkan, metal, dx12, gl) and WGPU_POWER_PREF are honoured too.
    #[arg(long)]
    pub adapter: Option<String>,
}

impl AutoDeviceArgs {
    /// Opens the device: `auto` falls back to the CPU twin (saying why)
    /// unless `--adapter` names one, `gpu` and `cpu` force (no adapter for
    /// `gpu` is an error; see `Device::open`).
    pub fn open(&self, verbose: u8) -> Result<Device> {
        open_device(&self.device, self.adapter.as_deref(), verbose, false)
    }
}

impl DeviceArgs {
    /// Opens the requested device. With `fallback`, a missing GPU adapter is
    /// reported and the CPU twin is used instead.
    pub fn open(&self, verbose: u8, fallback: bool) -> Result<Device> {
        open_device(&self.device, self.adapter.as_deref(), verbose, fallback)
    }
}

/// Opens `gpu`, `cpu` or `auto` ([`plausible::gpu::DeviceChoice`]), telling
/// the user about fallbacks, and with `-v` which adapter runs.
pub fn open_device(device: &str, adapter: Option<&str>, verbose: u8, fallback: bool) -> Result<Device> {
    let choice: DeviceChoice = device.parse()?;
    let opened = Device::open(choice, adapter, fallback)?;
    if let Some(note) = &opened.note {
        eprintln!("note: {note}");
    }
    if let (Device::Gpu(ctx), true) = (&opened.device, verbose > 0) {
        eprintln!("adapter: {} (backend {:?}, {:?})", ctx.info.name, ctx.info.backend, ctx.info.device_type);
    }
    Ok(opened.device)
}

/// Finds a shipped asset (`assets/...`, used by the demo and the default
/// benchmark inputs): in the working directory, in the repository the
/// binary was built from, or in the one holding the binary
/// (`REPO/target/release/plausible`). An installed binary whose repository
/// has gone has none, which is said with the way out.
pub fn asset(rel: &str) -> Result<PathBuf> {
    let mut roots = vec![PathBuf::from("."), PathBuf::from(env!("CARGO_MANIFEST_DIR"))];
    if let Some(repo) = std::env::current_exe().ok().and_then(|e| e.parent()?.parent()?.parent().map(Path::to_path_buf)) {
        roots.push(repo);
    }
    for root in &roots {
        let p = root.join(rel);
        if p.exists() {
            return Ok(if root == Path::new(".") { PathBuf::from(rel) } else { p });
        }
    }
    bail!(
        "{rel}, shipped with the repository, is not here nor in {}: run this from a clone of the repository, or give your own inputs (see --help)",
        roots[1..].iter().map(|r| r.display().to_string()).collect::<Vec<_>>().join(" or ")
    )
}

/// A progress bar on stderr, hidden when stderr is not a terminal.
pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {per_sec} ETA {eta}").unwrap().progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// A path as the file system resolves it, also for a file not made yet
/// (its folder resolved, its name kept), so two spellings of one file
/// compare equal.
fn resolved(p: &std::path::Path) -> Option<PathBuf> {
    if let Ok(r) = p.canonicalize() {
        return Some(r);
    }
    // A symlink to a file not made yet: the file it will make.
    let p = plausible::io::link_target(p);
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.canonicalize().ok()?,
        _ => std::env::current_dir().ok()?,
    };
    Some(dir.join(p.file_name()?))
}

/// The flag to blame for an error reading the targets: `--targets` where
/// the error is about the targets file (given or the dataset's own), else
/// `--dataset` (the scene files that the targets are checked against).
pub fn targets_flag(e: &plausible::Error) -> &'static str {
    if e.input() == Some(plausible::Input::Targets) {
        "--targets"
    } else {
        "--dataset"
    }
}

/// The flag to blame for an error opening a dataset: `--sensor` where one
/// was given (its files are the likeliest culprit) or the error is about
/// which sensor to read, else `--dataset`.
pub fn dataset_flag(e: &plausible::Error, sensor_given: bool) -> &'static str {
    if sensor_given || e.input() == Some(plausible::Input::Sensor) {
        "--sensor"
    } else {
        "--dataset"
    }
}

/// Refuses two flags naming one file where one of them is written: an
/// output would overwrite an input, or another output.
pub fn distinct_files(outputs: &[(&str, Option<&std::path::Path>)], inputs: &[(&str, Option<&std::path::Path>)]) -> Result<()> {
    // The trace is written last, over whatever a command output there.
    let trace = trace::path();
    let outs: Vec<(&str, PathBuf)> =
        std::iter::once(("--trace", trace.as_deref())).chain(outputs.iter().copied()).filter_map(|(f, p)| Some((f, resolved(p?)?))).collect();
    for (i, (flag, path)) in outs.iter().enumerate() {
        for (other, q) in outs[..i].iter().map(|(f, p)| (*f, Some(p.clone()))).chain(inputs.iter().map(|(f, p)| (*f, p.and_then(resolved)))) {
            if q.as_deref().is_some_and(|q| same_file(q, path)) {
                anyhow::bail!("{flag} and {other} name the same file ({}): give {flag} another path", path.display());
            }
        }
    }
    Ok(())
}

/// Refuses outputs where `ds` reads from (its models and split folders,
/// its camera.json, its default targets file): writing there would change
/// the dataset, e.g. a summary over a scene's scene_gt.json.
pub fn outside_dataset(ds: &plausible::bop::Dataset, outputs: &[(&str, Option<&std::path::Path>)]) -> Result<()> {
    for (flag, p) in outputs {
        if let Some(r) = p.and_then(resolved).filter(|r| ds.reads_at(r)) {
            anyhow::bail!(
                "{flag} {}: this is where --dataset reads from (its models or split folders, camera files or targets files); give {flag} a path outside them",
                r.display()
            );
        }
    }
    Ok(())
}

/// Two resolved paths name one file: the same path, or (on Unix) two hard
/// links to one inode.
fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    if a == b {
        return true;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.is_file() && x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    false
}
