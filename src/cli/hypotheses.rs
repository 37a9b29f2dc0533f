//! `plausible hypotheses`: pose hypotheses of an object resting on a support
//! plane (stable poses × yaw × in-plane position from the segmented depth),
//! written as the BOP pose JSON `plausible score` reads.

use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use plausible::hypotheses::on_plane::{analytic_resting_poses, check_mesh_size, on_plane_hypotheses, resting_poses_from_export, ExportMatch, OnPlaneParams};
use plausible::physical::scene::read_camera_plane;
use plausible::Input;

#[derive(clap::Args, Debug)]
pub struct HypothesesArgs {
    #[command(flatten)]
    pub mesh: super::MeshArgs,
    #[command(flatten)]
    pub obs: super::ObservationArgs,
    /// Support plane in the camera frame (`plausible plane` writes one).
    #[arg(long)]
    pub plane: PathBuf,
    /// Resting poses from `plausible stable-poses export --json`, or its
    /// SQLite database (default: the quasi-static analysis of the mesh's
    /// convex hull).
    #[arg(long)]
    pub stable: Option<PathBuf>,
    /// Yaw angles per resting pose, evenly spaced over 360°.
    #[arg(long, default_value_t = 24)]
    pub yaw_steps: usize,
    /// Leave out resting poses less probable than this [default: 0.01;
    /// where no pose reaches the default, as on a round object, the 64 most
    /// probable are kept].
    #[arg(long)]
    pub min_probability: Option<f64>,
    /// In-plane grid of (2r + 1)² offsets around each aligned position.
    #[arg(long, default_value_t = 0)]
    pub grid_radius: usize,
    /// Spacing of that grid in millimetres.
    #[arg(long, default_value_t = 5.0)]
    pub grid_step_mm: f64,
    /// Write the hypotheses here (BOP pose JSON, with their provenance).
    #[arg(long, default_value = "hypotheses.json")]
    pub out: PathBuf,
}

#[tracing::instrument(name = "plausible hypotheses", level = "trace", skip_all)]
pub fn run(a: HypothesesArgs) -> Result<()> {
    plausible::io::check_writable(&a.out).context("--out")?;
    let inputs = [("--mesh", Some(a.mesh.mesh.as_path())), ("--plane", Some(a.plane.as_path())), ("--stable", a.stable.as_deref())];
    super::distinct_files(&[("--out", Some(&a.out))], &[&inputs[..], &a.obs.inputs()].concat())?;
    if a.min_probability.is_some_and(|p| !(0.0..1.0).contains(&p)) {
        bail!("--min-probability must lie in [0, 1)");
    }
    if !(a.grid_step_mm.is_finite() && a.grid_step_mm > 0.0) {
        bail!("--grid-step-mm must be a positive number of millimetres");
    }
    use plausible::hypotheses::on_plane::{MAX_GRID_RADIUS, MAX_YAW_STEPS};
    if !(1..=MAX_YAW_STEPS).contains(&a.yaw_steps) {
        bail!("--yaw-steps {}: between 1 and {MAX_YAW_STEPS} (0.1° apart)", a.yaw_steps);
    }
    if a.grid_radius > MAX_GRID_RADIUS {
        bail!("--grid-radius {}: at most {MAX_GRID_RADIUS} ({} offsets per hypothesis)", a.grid_radius, (2 * MAX_GRID_RADIUS + 1).pow(2));
    }
    let mesh = a.mesh.load()?;
    let (obs, mask) = a.obs.load(false)?;
    let Some(mask) = mask else {
        bail!("--mask is required: the object's observed points place the hypotheses on the plane");
    };
    let plane = read_camera_plane(&a.plane)?;
    // Library words, with the flag that fixes a mesh read in wrong units.
    let units = |e: String| format!("--mesh {}: {e} (--mesh-units m, cm or mm states its units)", a.mesh.mesh.display());
    if let Some(w) = check_mesh_size(&mesh, &obs, &mask).map_err(|e| anyhow::anyhow!(units(e.to_string())))? {
        eprintln!("warning: {}", units(w));
    }
    let (rests, source) = match &a.stable {
        Some(path) => {
            let text = super::estimate::read_stable(path)?;
            let name = a.mesh.mesh.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let sha = plausible::stable::mesh_sha256(&mesh);
            let (rests, how) = resting_poses_from_export(&text, &sha, &name).with_context(|| path.display().to_string())?;
            warn_match(how, path, &a.mesh.mesh);
            (rests, format!("drop-test clusters of {}", path.display()))
        }
        None => (
            analytic_resting_poses(&mesh).with_context(|| format!("--mesh {}: its resting poses", a.mesh.mesh.display()))?,
            "the quasi-static analysis of the convex hull".to_string(),
        ),
    };
    let min_probability = probability_cut(&rests, a.min_probability)?;
    let params = OnPlaneParams {
        yaw_steps: a.yaw_steps,
        min_probability,
        grid_radius: a.grid_radius,
        grid_step: a.grid_step_mm * 1e-3,
        ..Default::default()
    };
    let used = rests.iter().filter(|r| r.group_probability >= params.min_probability).count();
    if used == 0 {
        bail!("no resting poses");
    }
    let hyps = on_plane_hypotheses(&mesh, &rests, &plane, &obs, &mask, &params).map_err(|e| {
        // The library's words, with the flag of the input they are about.
        let flag = match e.input() {
            Some(Input::SupportPlane) => format!("--plane {}", a.plane.display()),
            Some(Input::Mask) => format!("--mask {}", a.obs.mask.as_deref().map(|p| p.display().to_string()).unwrap_or_default()),
            _ => "hypotheses".to_string(),
        };
        anyhow::anyhow!(e).context(flag)
    })?;
    let json: Vec<serde_json::Value> = hyps
        .iter()
        .map(|h| {
            serde_json::json!({
                "cam_R_m2c": h.pose.r_row_major(),
                "cam_t_m2c": (h.pose.t * 1e3).to_array(),
                "rest": h.rest,
                "rest_probability": rests[h.rest].probability,
                "yaw_deg": h.yaw.to_degrees(),
                "offset_mm": (h.offset * 1e3).to_array(),
            })
        })
        .collect();
    let body = serde_json::to_string_pretty(&json)? + "\n";
    plausible::io::write_atomically(&a.out, |w| std::io::Write::write_all(w, body.as_bytes())).context("--out")?;
    println!(
        "{} hypotheses: {used} resting poses (from {source}) x {} yaws x {} in-plane offsets, each on the plane and centred on the observed object",
        hyps.len(),
        a.yaw_steps,
        (2 * a.grid_radius + 1).pow(2)
    );
    println!("wrote {}", a.out.display());
    Ok(())
}

/// Warns when the stable poses used were not found by the mesh's geometry:
/// BOP datasets all name their models obj_0000NN.ply, so a database of
/// another dataset matches by name and would give one object another's
/// resting poses without a word.
fn warn_match(how: ExportMatch, stable: &std::path::Path, mesh: &std::path::Path) {
    let (stable, mesh) = (stable.display(), mesh.display());
    match how {
        ExportMatch::Hash => {}
        ExportMatch::Name => eprintln!(
            "warning: --stable {stable}: its entry for {mesh} matches the file name only, not the geometry (another object of the same name, \
             other units or an edited mesh?); using its resting poses anyway"
        ),
        ExportMatch::OnlyEntry => eprintln!("warning: --stable {stable}: its only mesh matches neither the geometry of {mesh} nor its name; using it anyway"),
    }
}

/// Most probable resting poses taken when none reaches `--min-probability`:
/// a round object (a ball, a lemon, a can on its side) rests on any of
/// hundreds of hull facets, each a fraction of a percent probable.
const ROUND_POSES: usize = 64;

/// The probability cut for the resting poses: `asked`, or without it the
/// default 0.01, and where no pose reaches the default, the cut that keeps
/// the [`ROUND_POSES`] most probable (said on stderr). A cut asked for that
/// no pose reaches is an error: lowering it by itself would keep poses the
/// user left out.
fn probability_cut(rests: &[plausible::hypotheses::on_plane::RestingPose], asked: Option<f64>) -> Result<f64> {
    let cut = asked.unwrap_or(DEFAULT_MIN_PROBABILITY);
    let top = rests.iter().map(|r| r.group_probability).fold(f64::NEG_INFINITY, f64::max);
    if top >= cut || rests.is_empty() {
        return Ok(cut);
    }
    if let Some(asked) = asked {
        bail!("--min-probability {}: no resting pose is that probable (the most probable is {top:.4}); give a lower cut", plausible::error::compact(asked, 4));
    }
    let mut p: Vec<f64> = rests.iter().map(|r| r.group_probability).collect();
    p.sort_by(|a, b| b.total_cmp(a));
    let cut = p[p.len().min(ROUND_POSES) - 1];
    let kept: f64 = p.iter().filter(|&&v| v >= cut).sum();
    eprintln!(
        "note: no resting pose is at least {DEFAULT_MIN_PROBABILITY} probable (a round object rests on any of its {} hull facets): \
         using the {} most probable, {:.0} % of the probability (--min-probability sets the cut)",
        p.len(),
        p.iter().filter(|&&v| v >= cut).count(),
        100.0 * kept
    );
    Ok(cut)
}

/// `--min-probability` when not given.
const DEFAULT_MIN_PROBABILITY: f64 = 0.01;

#[cfg(test)]
mod tests {
    use super::*;
    use plausible::hypotheses::on_plane::RestingPose;

    fn rests(p: &[f64]) -> Vec<RestingPose> {
        p.iter().map(|&p| RestingPose { r_model_to_plane: glam::DMat3::IDENTITY, probability: p, group_probability: p }).collect()
    }

    #[test]
    fn a_cut_asked_for_is_kept_and_only_the_default_falls_back() {
        let duck = rests(&[0.37, 0.2, 0.1, 0.0004]);
        assert_eq!(probability_cut(&duck, Some(0.37)).unwrap(), 0.37);
        // No pose reaches the cut asked for: refused, never lowered.
        assert!(probability_cut(&duck, Some(0.38)).unwrap_err().to_string().contains("most probable is 0.3700"));
        // A round object (every facet below the default): the 64 most
        // probable are kept.
        let round = rests(&vec![1.0 / 100.0 - 1e-4; 100]);
        assert!(probability_cut(&round, None).unwrap() < DEFAULT_MIN_PROBABILITY);
        assert_eq!(probability_cut(&duck, None).unwrap(), DEFAULT_MIN_PROBABILITY);
    }
}
