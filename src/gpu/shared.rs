//! One device per adapter, opened once and kept for the process.
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
//! Contexts ask for an adapter by name or for the default one; names are
//! resolved to adapters on an instance kept per set of backends, so two
//! names for one adapter share its device, and asking which adapter a name
//! picks opens nothing (`--device auto` looks before it opens).
//!
//! A device the driver reports lost, or one opened before the process
//! forked (Python's multiprocessing forks on Linux), is not handed out
//! again: the next context opens a new one (`tests/fork.rs`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use super::{Dispatched, PipelineCache};
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
    pub dispatched: Dispatched,
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
        SharedDevice { device, queue, info, required, features, cache: Default::default(), dispatched: Default::default(), lost, pid: std::process::id() }
    }

    fn lost(&self) -> bool {
        self.lost.load(Ordering::Relaxed)
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

/// The open devices by the key that asked for each (two keys naming one
/// adapter, say the default and its name, hold the same device), and the
/// instances adapters are looked up on, one per set of backends: kept, so
/// that asking about an adapter neither opens a device nor creates and
/// destroys an instance each time.
struct Registry {
    devices: Vec<(DeviceKey, Arc<SharedDevice>)>,
    instances: Vec<(wgpu::Backends, u32, wgpu::Instance)>,
}

static OPEN: Mutex<Registry> = Mutex::new(Registry { devices: Vec::new(), instances: Vec::new() });

impl Registry {
    /// Forgets lost devices, and what a parent process opened before it
    /// forked. The parent's objects are leaked, not destroyed: their driver
    /// state belongs to the parent, and destroying a copy of it in the
    /// child is undefined (the parent goes on using the originals).
    fn prune(&mut self) {
        let pid = std::process::id();
        for (_, d) in self.devices.extract_if(.., |(_, d)| d.pid != pid) {
            std::mem::forget(d);
        }
        for (_, _, i) in self.instances.extract_if(.., |(_, p, _)| *p != pid) {
            std::mem::forget(i);
        }
        self.devices.retain(|(_, d)| !d.lost());
    }

    /// The registry, locked, without lost devices or a parent's objects.
    fn locked() -> std::sync::MutexGuard<'static, Registry> {
        let mut reg = OPEN.lock().unwrap_or_else(PoisonError::into_inner);
        reg.prune();
        reg
    }

    /// The device open for `key`, if any.
    fn open_for(&self, key: &DeviceKey) -> Option<&Arc<SharedDevice>> {
        self.devices.iter().find(|(k, _)| k == key).map(|(_, d)| d)
    }

    /// The instance for `backends`, created the first time.
    fn instance(&mut self, backends: wgpu::Backends) -> wgpu::Instance {
        if let Some((_, _, i)) = self.instances.iter().find(|(b, _, _)| *b == backends) {
            return i.clone();
        }
        // The process environment is never changed here (unsound with
        // threads); the binary switches Mesa's device-select layer off at
        // start-up.
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle().with_env();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        self.instances.push((backends, std::process::id(), instance.clone()));
        instance
    }
}

/// Finds the adapter a key names on an instance.
pub(crate) type FindAdapter = fn(&wgpu::Instance, &DeviceKey) -> Result<wgpu::Adapter>;

/// The adapter `key` names, without opening a device on it: the one open
/// for it already, or the one `find` picks.
pub(crate) fn adapter_info(key: &DeviceKey, find: FindAdapter) -> Result<wgpu::AdapterInfo> {
    let mut reg = Registry::locked();
    if let Some(d) = reg.open_for(key) {
        return Ok(d.info.clone());
    }
    let instance = reg.instance(key.backends);
    Ok(find(&instance, key)?.get_info())
}

/// The device for `key`: the one open for it or for another key naming
/// the same adapter, else one `open` opens on the adapter `find` picks (or
/// again, when the one kept is lost or was opened before a fork). The
/// registry is locked while a device opens, so two threads asking at once
/// get one device, and no device ever opens beside another's opening. A
/// failed open is not kept: the next call tries again.
pub(crate) fn device(key: DeviceKey, find: FindAdapter, open: impl FnOnce(wgpu::Adapter) -> Result<SharedDevice>) -> Result<Arc<SharedDevice>> {
    let mut reg = Registry::locked();
    if let Some(d) = reg.open_for(&key) {
        return Ok(d.clone());
    }
    let instance = reg.instance(key.backends);
    let adapter = find(&instance, &key)?;
    let info = adapter.get_info();
    let d = match reg.devices.iter().find(|(_, d)| d.info == info) {
        Some((_, d)) => d.clone(),
        None => Arc::new(open(adapter)?),
    };
    reg.devices.push((key, d.clone()));
    Ok(d)
}
