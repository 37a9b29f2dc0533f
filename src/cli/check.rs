//! `plausible check scene.json`: the physical plausibility of every object
//! of a scene (eq. 6-13), with the reasons.

use std::path::PathBuf;

use anyhow::{Context as _, Result};
use plausible::physical::check::{check_scene, CheckOptions, CheckRecord};
use plausible::physical::simulate::{displacement, Displacement, SimSettings};
use plausible::physical::Scene;
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct CheckArgs {
    /// Scene JSON (world frame, metres, z up; see docs/physics.md).
    pub scene: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub sampling: super::SampleArgs,
    /// Signed-distance grid cells across each mesh's longest side.
    #[arg(long, default_value_t = plausible::physical::sdf::DEFAULT_RESOLUTION)]
    pub sdf_resolution: usize,
    /// Friction coefficient μ of the static-equilibrium check (eq. 10-12).
    #[arg(long, default_value_t = plausible::physical::friction::DEFAULT_FRICTION)]
    pub friction: f64,
    /// Also simulate (rapier): rounds of a few steps with velocities reset
    /// to zero after each, reporting every dynamic object's displacement.
    #[arg(long)]
    pub sim: bool,
    /// Simulation time step (s).
    #[arg(long, default_value_t = 1.0 / 60.0)]
    pub sim_dt: f64,
    /// Steps per round.
    #[arg(long, default_value_t = 3)]
    pub sim_steps: usize,
    /// Rounds (velocities reset to zero after each).
    #[arg(long, default_value_t = 10)]
    pub sim_rounds: usize,
    /// Write a picture (PNG): samples by class, support polygons and
    /// centres of mass from above, and a side view (see docs/physics.md).
    #[arg(long)]
    pub explain: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report<'a> {
    version: &'static str,
    scene: String,
    samples: usize,
    seed: u64,
    friction: f64,
    objects: Vec<CheckRecord<'a>>,
}

/// Checks the scene. With `--trace` its span is the trace's root: load,
/// check (prepare, one span per object), explain, simulate, report.
#[tracing::instrument(name = "plausible check", level = "trace", skip_all)]
pub fn run(a: CheckArgs) -> Result<()> {
    let sim_defaults = SimSettings::default();
    if !a.sim && (a.sim_dt != sim_defaults.dt || a.sim_steps != sim_defaults.steps || a.sim_rounds != sim_defaults.rounds) {
        anyhow::bail!("--sim-dt, --sim-steps and --sim-rounds set the simulation: add --sim");
    }
    a.sampling.check()?;
    if !(a.friction.is_finite() && a.friction >= 0.0) {
        anyhow::bail!("--friction {}: the friction coefficient must be a finite number ≥ 0 (the default is {})", a.friction, plausible::physical::friction::DEFAULT_FRICTION);
    }
    if let Some(path) = &a.explain {
        if path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() != Some("png") {
            anyhow::bail!("--explain {}: the picture is a PNG; give a file name ending in .png", path.display());
        }
        plausible::io::check_writable(path).context("--explain")?;
    }
    let scene = tracing::trace_span!("load")
        .in_scope(|| Scene::load(&a.scene))
        .with_context(|| format!("reading scene {}", a.scene.display()))?;
    let opts = CheckOptions {
        samples: a.sampling.samples,
        seed: a.sampling.seed,
        epsilon: a.sampling.epsilon,
        sdf_resolution: a.sdf_resolution,
        friction: a.friction,
        ..Default::default()
    };
    let checks = tracing::trace_span!("check").in_scope(|| check_scene(&scene, &opts))?;
    if let Some(path) = &a.explain {
        let _span = tracing::trace_span!("explain").entered();
        plausible::io::save_png(path, &plausible::physical::explain::explain_image(&scene, &checks))?;
        eprintln!("wrote {}", path.display());
    }
    let sim: Vec<Option<Vec<Displacement>>> = if a.sim {
        let settings = SimSettings {
            dt: a.sim_dt,
            steps: a.sim_steps,
            rounds: a.sim_rounds,
            ..SimSettings::default()
        };
        displacement(&scene, &settings)?
    } else {
        vec![None; checks.len()]
    };
    let _report = tracing::trace_span!("report").entered();
    // Once per mesh (objects sharing one repeat its notes).
    let mut said = std::collections::HashSet::new();
    for note in checks.iter().flat_map(|c| &c.notes) {
        if said.insert(note) {
            eprintln!("warning: {note}");
        }
    }
    if a.json {
        let report = Report {
            version: env!("CARGO_PKG_VERSION"),
            scene: a.scene.display().to_string(),
            samples: a.sampling.samples,
            seed: a.sampling.seed,
            friction: a.friction,
            objects: checks
                .iter()
                .zip(&sim)
                .map(|(c, d)| c.record(d.as_deref()))
                .collect(),
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "{:<16} {:<22} {:>5} {:>5} {:>5} {:>10} {:>11} {:>6} {:>17}  friction (μ = {})",
        "object",
        "verdict",
        "|I|",
        "|C|",
        "|S|",
        "min δ mm",
        "margin mm",
        "ε mm",
        if a.sim { "moved mm / deg" } else { "" },
        a.friction
    );
    for (o, d) in checks.iter().zip(&sim) {
        let e = &o.evaluation;
        let verdict = if o.is_static {
            format!("{} (static)", e.verdict.as_str())
        } else {
            e.verdict.as_str().to_string()
        };
        println!(
            "{:<16} {:<22} {:>5} {:>5} {:>5} {:>10.2} {:>11} {:>6.2} {:>17}  {}",
            o.name,
            verdict,
            e.intersecting,
            e.contact,
            e.supported,
            e.min_distance * 1e3,
            e.stability_margin
                .map(|m| format!("{:.2}", m * 1e3))
                .unwrap_or_else(|| "-".into()),
            o.epsilon * 1e3,
            d.as_ref()
                .and_then(|v| v.last())
                .map(|l| format!("{:.2} / {:.2}", l.translation * 1e3, l.rotation_deg))
                .unwrap_or_default(),
            match o.friction_equilibrium {
                Some(true) if o.methods_disagree() =>
                    "balanced (disagrees with the support polygon)",
                Some(false) if o.methods_disagree() =>
                    "not balanced (disagrees with the support polygon)",
                Some(true) => "balanced",
                Some(false) => "not balanced",
                None => "-",
            }
        );
    }
    Ok(())
}
