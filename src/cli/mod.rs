//! Subcommands of the `plausible` binary (anyhow lives here, not in the
//! library).

pub mod bench;
pub mod bench_physics;
pub mod check;
pub mod demo;
pub mod hypotheses;
pub mod plane;
pub mod score;
pub mod stable;

use std::path::{Path, PathBuf};

use anyhow::Result;
use plausible::gpu::{Context, GpuOptions};
use plausible::visual::Device;

/// Where to run, shared by every subcommand that runs kernels.
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

impl DeviceArgs {
    /// Opens the requested device. With `fallback`, a missing GPU adapter is
    /// reported and the CPU twin is used instead.
    pub fn open(&self, verbose: u8, fallback: bool) -> Result<Device> {
        if self.device == "cpu" {
            return Ok(Device::Cpu);
        }
        match Context::new(&GpuOptions { adapter: self.adapter.clone(), limits: None }) {
            Ok(ctx) => {
                if verbose > 0 {
                    eprintln!("adapter: {} (backend {:?}, {:?})", ctx.info.name, ctx.info.backend, ctx.info.device_type);
                }
                if ctx.info.backend == wgpu::Backend::Gl {
                    eprintln!("note: running on the OpenGL backend; a Vulkan driver is faster and more robust");
                }
                Ok(Device::Gpu(Box::new(ctx)))
            }
            Err(e) if fallback => {
                eprintln!("note: {e}\nnote: falling back to the CPU twin");
                Ok(Device::Cpu)
            }
            Err(e) => Err(e.into()),
        }
    }
}

/// Finds a shipped asset whether the binary runs from the repository root
/// or elsewhere.
pub fn asset(rel: &str) -> PathBuf {
    let here = Path::new(rel);
    if here.exists() {
        return here.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// A progress bar on stderr, hidden when stderr is not a terminal.
pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {per_sec} ETA {eta}")
            .unwrap()
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}
