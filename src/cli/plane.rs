//! `plausible plane`: fit the support plane to an observed depth frame and
//! write it as the JSON `plausible score --plane` reads.

use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use plausible::physical::scene::CameraPlaneJson;
use plausible::support_plane::{fit_support_plane, PlaneFitParams};

#[derive(clap::Args, Debug)]
pub struct PlaneArgs {
    #[command(flatten)]
    pub obs: super::ObservationArgs,
    /// Write the plane here (JSON, point in mm).
    #[arg(long, default_value = "plane.json")]
    pub out: PathBuf,
    /// Inlier distance in millimetres.
    #[arg(long, default_value_t = 5.0)]
    pub inlier_mm: f64,
    /// RANSAC hypotheses.
    #[arg(long, default_value_t = 500, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1_000_000))]
    pub iterations: usize,
    /// Pixels the mask is grown by.
    #[arg(long, default_value_t = 5)]
    pub mask_margin: usize,
    /// Seed of the RANSAC sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

#[tracing::instrument(name = "plausible plane", level = "trace", skip_all)]
pub fn run(a: PlaneArgs) -> Result<()> {
    plausible::io::check_writable(&a.out).context("--out")?;
    super::distinct_files(&[("--out", Some(&a.out))], &a.obs.inputs())?;
    if a.iterations == 0 {
        bail!("--iterations must be at least 1");
    }
    if !(a.inlier_mm.is_finite() && a.inlier_mm > 0.0 && a.inlier_mm < 500.0) {
        bail!("--inlier-mm {}: the inlier distance must lie in (0, 500) mm (default 5)", plausible::error::compact(a.inlier_mm, 1));
    }
    let (obs, mask) = a.obs.load(false)?;
    let params = PlaneFitParams {
        inlier_m: a.inlier_mm * 1e-3,
        iterations: a.iterations,
        seed: a.seed,
        mask_margin_px: a.mask_margin,
        ..Default::default()
    };
    let fit = fit_support_plane(&obs, mask.as_deref(), &params)?;
    let p = fit.plane;
    println!(
        "support plane: normal ({:.4}, {:.4}, {:.4}), {:.1} mm from the camera; {} of {} points within {} mm (RMS {:.2} mm)",
        p.normal.x,
        p.normal.y,
        p.normal.z,
        p.normal.dot(p.point).abs() * 1e3,
        fit.inliers,
        fit.candidates,
        a.inlier_mm,
        fit.rms * 1e3
    );
    if fit.inliers * 5 < fit.candidates {
        eprintln!(
            "warning: only {:.0} % of the depth outside the mask lies on this plane; check that the support surface is in view",
            100.0 * fit.inliers as f64 / fit.candidates as f64
        );
    }
    let json = CameraPlaneJson::from_plane(&p);
    let body = serde_json::to_string_pretty(&json)? + "\n";
    plausible::io::write_atomically(&a.out, |w| std::io::Write::write_all(w, body.as_bytes())).context("--out")?;
    println!("wrote {}", a.out.display());
    Ok(())
}
