//! One device per adapter choice, opened once and kept for the process.
//!
//! NVIDIA's Vulkan driver crashes a process that opens and closes devices on
//! several threads (SIGSEGV, or glibc's "corrupted size vs. prev_size in
//! fastbins"). On an H200 (driver 580.159) the GPU tests crashed in 4 of 10
//! runs, and still in 2 of 6 with every open, close and pipeline compile
//! taking turns, so serialising the calls is not enough; kvark/blade#336 and
//! gfx-rs/wgpu#5930 and #10234 report the same family of driver bugs. A
//! device opened once and never closed avoids the pattern, and a second
//! context in the same process (the Python package's scorers, a test
//! suite, `estimate` beside `eval`) skips the open, about 0.2 s on that H200.
//! Its compiled pipelines are shared too, so each kernel compiles once per
//! process.
//!
//! What stays per context is the caller's own view: its batch limits
//! ([`GpuOptions::limits`](super::GpuOptions)).
//!
//! A device the driver reports lost, or one opened before the process
//! forked (Python's multiprocessing forks on Linux), is not handed out
//! again: the next context opens a new one.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use super::PipelineCache;
use crate::error::Result;

/// An open device and what the contexts on it share.
pub(crate) struct SharedDevice {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// The limits the device was opened with.
    pub required: wgpu::Limits,
    pub features: wgpu::Features,
    pub cache: PipelineCache,
    /// Set by the device-lost callback.
    lost: Arc<AtomicBool>,
    /// The process that opened it.
    pid: u32,
}

impl SharedDevice {
    pub fn new(device: wgpu::Device, queue: wgpu::Queue, info: wgpu::AdapterInfo, required: wgpu::Limits, features: wgpu::Features) -> Self {
        let lost = Arc::new(AtomicBool::new(false));
        let flag = lost.clone();
        // Only a flag: the callback may run on any thread, with any lock
        // held, so it takes none.
        device.set_device_lost_callback(move |_, _| flag.store(true, Ordering::Relaxed));
        SharedDevice { device, queue, info, required, features, cache: Default::default(), lost, pid: std::process::id() }
    }

    fn usable(&self) -> bool {
        !self.lost.load(Ordering::Relaxed) && self.pid == std::process::id()
    }
}

/// What picks a device: the adapter asked for by name (lower-case, as it
/// is matched), and the backends and power preference read from the
/// environment when it was opened.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct DeviceKey {
    pub adapter: Option<String>,
    pub backends: wgpu::Backends,
    pub power: wgpu::PowerPreference,
}

static OPEN: Mutex<Vec<(DeviceKey, Arc<SharedDevice>)>> = Mutex::new(Vec::new());

/// The device for `key`, opened by `open` the first time (or again, when
/// the one kept is lost or was opened before a fork). The registry is
/// locked while a device opens, so two threads asking at once get one
/// device, and no device ever opens beside another's opening. A failed
/// open is not kept: the next call tries again.
pub(crate) fn device(key: DeviceKey, open: impl FnOnce() -> Result<SharedDevice>) -> Result<Arc<SharedDevice>> {
    let mut devices = OPEN.lock().unwrap_or_else(PoisonError::into_inner);
    devices.retain(|(_, d)| d.usable());
    if let Some((_, d)) = devices.iter().find(|(k, _)| *k == key) {
        return Ok(d.clone());
    }
    let d = Arc::new(open()?);
    devices.push((key, d.clone()));
    Ok(d)
}
