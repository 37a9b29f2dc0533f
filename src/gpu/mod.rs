//! GPU context: adapter selection (with the user's overrides), device limits
//! that drive batch splitting, and small helpers for buffers and readback.

use std::sync::Arc;

use crate::error::{Error, Result};

mod shared;

/// How to pick the adapter.
#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    /// Pick the first adapter whose name contains this (case-insensitive).
    pub adapter: Option<String>,
    /// Cap the limits used for batch splitting (tests use this to force
    /// small batches); `None` uses the adapter's own limits.
    pub limits: Option<BatchLimits>,
}

/// The limits that decide how a batch is split.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BatchLimits {
    /// Largest storage-buffer binding in bytes.
    pub max_storage_binding: u64,
    /// Largest buffer in bytes.
    pub max_buffer: u64,
    /// Most workgroups in one dispatch dimension.
    pub max_workgroups: u32,
}

impl BatchLimits {
    fn from_wgpu(l: &wgpu::Limits) -> Self {
        BatchLimits {
            max_storage_binding: l.max_storage_buffer_binding_size,
            max_buffer: l.max_buffer_size,
            max_workgroups: l.max_compute_workgroups_per_dimension,
        }
    }

    /// The element-wise minimum of two sets of limits.
    pub fn min(self, o: BatchLimits) -> BatchLimits {
        BatchLimits {
            max_storage_binding: self.max_storage_binding.min(o.max_storage_binding),
            max_buffer: self.max_buffer.min(o.max_buffer),
            max_workgroups: self.max_workgroups.min(o.max_workgroups),
        }
    }

    /// Largest number of `elem`-byte items one storage binding can hold.
    pub fn max_items(&self, elem: u64) -> u64 {
        self.max_storage_binding.min(self.max_buffer) / elem
    }
}

/// Where the kernels run: a GPU context, or the CPU twins. It lives with
/// the GPU context so that every API (scoring, evaluation, physics) takes
/// the same choice.
#[derive(Clone, Debug)]
pub enum Device {
    /// Boxed: a context is a few hundred bytes, the CPU variant nothing.
    Gpu(Box<Context>),
    /// The CPU twins, multi-threaded with rayon.
    Cpu,
}

impl Device {
    pub fn describe(&self) -> String {
        match self {
            Device::Gpu(c) => c.describe(),
            Device::Cpu => format!("CPU twin ({} threads)", rayon::current_num_threads()),
        }
    }

    /// Opens the first adapter matching `opts` as a GPU device.
    pub fn gpu(opts: &GpuOptions) -> Result<Device> {
        Ok(Device::Gpu(Box::new(Context::new(opts)?)))
    }
}

/// Which device to run on, as users name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceChoice {
    /// A hardware GPU when there is one; the CPU twin when the only adapter
    /// is a software rasterizer (lavapipe runs the same kernels on the same
    /// cores, measurably slower than the twin) or there is none.
    Auto,
    /// Any wgpu adapter, lavapipe included.
    Gpu,
    /// The CPU twins.
    Cpu,
}

impl std::str::FromStr for DeviceChoice {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(DeviceChoice::Auto),
            "gpu" => Ok(DeviceChoice::Gpu),
            "cpu" => Ok(DeviceChoice::Cpu),
            _ => Err(Error::InvalidInput(format!("unknown device '{s}' (expected auto, gpu or cpu)"))),
        }
    }
}

/// A device opened by [`Device::open`], with what the caller should tell
/// its user about the choice (a fallback, a software adapter passed over).
#[derive(Debug)]
pub struct Opened {
    pub device: Device,
    pub note: Option<String>,
}

impl Device {
    /// Under `auto`, a mesh the GPU cannot score (past the rasterizer's
    /// loop budget, more than
    /// [`MAX_GPU_MESHLETS`](crate::kernels::MAX_GPU_MESHLETS) meshlets, with
    /// a BVH too deep for the GPU ray caster; or a region past the pixel
    /// budget; or triangles past what the adapter binds) is scored by the
    /// CPU twin instead of being refused; `gpu`
    /// keeps the refusal. Returns the device and, when it changed, why.
    pub fn for_mesh(self, choice: DeviceChoice, mesh: &crate::kernels::RenderMesh, pixels: usize) -> (Device, Option<String>) {
        match (&self, choice) {
            (Device::Gpu(ctx), DeviceChoice::Auto) => match crate::kernels::check_gpu_budget(ctx, mesh, pixels) {
                Ok(()) => (self, None),
                Err(e) => (Device::Cpu, Some(format!("{e}; device auto: scoring on the CPU twin"))),
            },
            _ => (self, None),
        }
    }

    /// Opens `choice` on the first adapter whose name contains `adapter`.
    /// With `fallback`, a missing adapter gives the CPU twin and a note
    /// instead of an error. `Auto` falls back too, and prefers the CPU twin
    /// to a software adapter, unless `adapter` names one: then that one is
    /// used, and a missing one is an error. `Cpu` with an adapter is an
    /// error (it would be ignored).
    pub fn open(choice: DeviceChoice, adapter: Option<&str>, fallback: bool) -> Result<Opened> {
        if choice == DeviceChoice::Cpu {
            // The adapter would be ignored: a user who named one meant the GPU.
            if let Some(a) = adapter {
                return Err(Error::InvalidInput(format!("adapter '{a}' was asked for, but the cpu device runs the CPU twins and uses no adapter")));
            }
            return Ok(Opened { device: Device::Cpu, note: None });
        }
        // An adapter named by the user is used even when it is a software
        // one: they asked for it. Otherwise `auto` looks at the adapter
        // before opening a device on it: a software one would only be
        // opened to be passed over (40-50 ms on lavapipe, and its threads
        // and memory kept for the process, see `shared`).
        if choice == DeviceChoice::Auto && adapter.is_none() {
            match shared::adapter_info(&device_key(None)?, find_adapter) {
                Ok(info) if info.device_type == wgpu::DeviceType::Cpu => {
                    return Ok(Opened {
                        device: Device::Cpu,
                        note: Some(format!(
                            "the only adapter is {} (software): using the CPU twin, which is faster there (device gpu uses the adapter)",
                            info.name
                        )),
                    })
                }
                Ok(_) => {}
                Err(e) => return Ok(Opened { device: Device::Cpu, note: Some(format!("{e}; falling back to the CPU twin")) }),
            }
        }
        match Context::new(&GpuOptions { adapter: adapter.map(str::to_string), limits: None }) {
            Ok(ctx) => {
                let note = (ctx.info.backend == wgpu::Backend::Gl)
                    .then(|| "running on the OpenGL backend; a Vulkan driver is faster and more robust".to_string());
                Ok(Opened { device: Device::Gpu(Box::new(ctx)), note })
            }
            Err(e) if fallback || (choice == DeviceChoice::Auto && adapter.is_none()) => {
                Ok(Opened { device: Device::Cpu, note: Some(format!("{e}; falling back to the CPU twin")) })
            }
            Err(e) => Err(e),
        }
    }
}

/// Lanes of 32 bits in the vector width an adapter name states ("N bits"),
/// 16 when it states none.
fn simd_lanes(name: &str) -> u32 {
    let bits = name.split_once(" bits").and_then(|(head, _)| head.rsplit([' ', ',', '(']).next()?.parse::<u32>().ok());
    bits.map_or(16, |b| (b / 32).clamp(1, 64))
}

#[cfg(test)]
mod cache_tests {
    use std::sync::Arc;

    const EMPTY: &str = "@compute @workgroup_size(1) fn main() {}";

    /// A pipeline compiled in the background and asked for by several
    /// threads at once is compiled once: every caller gets the same one.
    #[test]
    fn gpu_pipeline_compiles_once_across_threads() {
        let ctx = super::test_context();
        let _compiling = ctx.compile_in_background("test/empty", EMPTY, "main", Vec::new());
        let got: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4).map(|_| s.spawn(|| ctx.pipeline("test/empty", EMPTY, "main"))).collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert!(got.windows(2).all(|w| Arc::ptr_eq(&w[0], &w[1])));
        assert!(Arc::ptr_eq(&got[0], &ctx.pipeline("test/empty", EMPTY, "main")));
    }

    /// A pipeline's first dispatch with textures of given sizes is noted
    /// once per device, for every context on it: the scorer's warm-up
    /// dispatch (`GpuScorer::compile`) runs once, not per scorer.
    #[test]
    fn gpu_first_dispatch_is_noted_once_per_pipeline_and_texture_sizes() {
        let (a, b) = (super::test_context(), super::test_context());
        assert!(a.first_dispatch("test/first", vec![[64, 8], [128, 128]]));
        assert!(!b.first_dispatch("test/first", vec![[64, 8], [128, 128]]));
        assert!(b.first_dispatch("test/first", vec![[64, 16], [128, 128]]));
        assert!(a.first_dispatch("test/other", vec![[64, 8], [128, 128]]));
        assert!(!a.first_dispatch("test/first", vec![[64, 16], [128, 128]]));
    }

    /// Contexts opened and dropped on many threads at once, clones and
    /// background compiles among them, share one device and its pipelines
    /// (NVIDIA's driver crashed on this while each context opened its own
    /// device, see `shared`), and each keeps its own batch limits.
    #[test]
    fn gpu_contexts_opened_on_many_threads_share_one_device() {
        let first = super::test_context();
        let pipeline = first.pipeline("test/empty", EMPTY, "main");
        std::thread::scope(|s| {
            for _ in 0..6 {
                s.spawn(|| {
                    for _ in 0..3 {
                        let ctx = super::test_context();
                        assert!(ctx.shares_device_with(&first));
                        let compiling = ctx.clone().compile_in_background("test/empty", EMPTY, "main", Vec::new());
                        drop(ctx);
                        drop(compiling);
                    }
                });
            }
        });
        assert!(Arc::ptr_eq(&pipeline, &super::test_context().pipeline("test/empty", EMPTY, "main")));
        let small = super::BatchLimits { max_storage_binding: 1 << 20, ..first.limits };
        let limited = super::Context::new(&super::GpuOptions { adapter: None, limits: Some(small) }).unwrap();
        assert!(limited.shares_device_with(&first));
        assert_eq!(limited.limits.max_storage_binding, 1 << 20);
        assert!(first.limits.max_storage_binding > 1 << 20);
    }

    /// Two names for one adapter (the default, and its own name in capitals)
    /// hold one device: a second device on the same GPU is what NVIDIA's
    /// driver crashed on. Asking which adapter a name picks (what `auto`
    /// does before opening anything) gives that adapter.
    #[test]
    fn gpu_two_names_for_one_adapter_share_one_device() {
        let first = super::test_context();
        let opts = super::GpuOptions { adapter: Some(first.info.name.to_uppercase()), limits: None };
        let named = super::Context::new(&opts).unwrap();
        assert!(named.shares_device_with(&first));
        let key = super::device_key(Some(&first.info.name)).unwrap();
        assert_eq!(super::shared::adapter_info(&key, super::find_adapter).unwrap(), first.info);
    }

    /// `auto` without a named adapter scores on the CPU twin, with a note,
    /// where the default adapter is a software one (and on it otherwise);
    /// an adapter named by the user is used whatever it is.
    #[test]
    fn gpu_auto_passes_over_a_software_adapter_unless_named() {
        use super::{Device, DeviceChoice};
        let ctx = super::test_context();
        let auto = Device::open(DeviceChoice::Auto, None, false).unwrap();
        match auto.device {
            Device::Cpu => {
                assert!(ctx.is_software());
                assert!(auto.note.as_deref().is_some_and(|n| n.contains("(software): using the CPU twin")), "{:?}", auto.note);
            }
            Device::Gpu(g) => assert!(!ctx.is_software() && g.shares_device_with(&ctx)),
        }
        let named = Device::open(DeviceChoice::Auto, Some(&ctx.info.name), false).unwrap();
        assert!(matches!(named.device, Device::Gpu(g) if g.shares_device_with(&ctx)));
    }
}

#[cfg(test)]
mod lanes_tests {
    #[test]
    fn simd_lanes_read_from_the_adapter_name() {
        assert_eq!(super::simd_lanes("llvmpipe (LLVM 15.0.6, 256 bits)"), 8);
        assert_eq!(super::simd_lanes("llvmpipe (LLVM 17.0.6, 128 bits)"), 4);
        assert_eq!(super::simd_lanes("SwiftShader Device (Subzero)"), 16);
    }
}

/// A device and queue on a chosen adapter.
#[derive(Clone)]
pub struct Context {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: BatchLimits,
    /// Largest side of a 2D texture: the visual kernels read their
    /// read-only tables (triangles, meshlets, the observation) as textures.
    pub max_texture_dim: u32,
    /// Whether the device records GPU timestamps (used by `bench` for the
    /// per-stage split; wall clock is reported beside them).
    pub timestamps: bool,
    /// Lanes of a subgroup, when the device runs subgroup operations with
    /// one fixed subgroup size (lavapipe: its SIMD vector); the one-lane-per-
    /// hypothesis score kernel (`shaders/score_lanes.wgsl`) needs both.
    pub subgroup_lanes: Option<u32>,
    /// Pipelines are compiled once per device and kept here, shared by the
    /// contexts on it ([`shared`]), one cell per key: a thread asking for a
    /// pipeline another thread is compiling
    /// ([`compile_in_background`](Self::compile_in_background)) waits for
    /// that compile instead of starting its own.
    pub(crate) cache: PipelineCache,
    /// What [`first_dispatch`](Self::first_dispatch) has been asked, shared
    /// like the pipelines.
    pub(crate) dispatched: Dispatched,
}

/// A pipeline compiling on a thread of its own
/// ([`visual::Scorer::precompile`](crate::visual::Scorer::precompile)).
/// Dropping it waits for the compile: a command that fails or ends early
/// must not exit while a driver thread still compiles (the driver's
/// clean-up at exit would race it).
#[must_use = "dropping it waits for the compile at once; keep it while preparing the rest"]
pub struct Compiling(Option<std::thread::JoinHandle<()>>);

impl Compiling {
    /// Nothing compiling (the CPU twins need no compile).
    pub fn none() -> Compiling {
        Compiling(None)
    }
}

impl Drop for Compiling {
    fn drop(&mut self) {
        if let Some(handle) = self.0.take() {
            // A compile that panicked left its cell empty: the next caller
            // compiles again and meets the same error in its own thread.
            let _ = handle.join();
        }
    }
}

/// A pipeline of a device's cache, compiled once by whichever thread asks
/// first.
pub(crate) type PipelineCell = Arc<std::sync::OnceLock<Arc<wgpu::ComputePipeline>>>;

/// A device's compiled pipelines by key, shared by its contexts.
pub(crate) type PipelineCache = Arc<std::sync::Mutex<std::collections::HashMap<&'static str, PipelineCell>>>;

/// The pipelines a device has dispatched, each with the sizes of the
/// textures bound to it ([`Context::first_dispatch`]).
pub(crate) type Dispatched = Arc<std::sync::Mutex<std::collections::HashSet<(&'static str, Vec<[u32; 2]>)>>>;

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Context({} on {:?})", self.info.name, self.info.backend)
    }
}

/// Storage buffers the largest kernel binds (score with the plane stage:
/// poses, visibility, records, contact records and support bits; the
/// read-only tables, from triangles to surface samples, are textures).
/// Desktop Vulkan, Metal and DX12 adapters offer far more; WebGPU's
/// default is 8.
const STORAGE_BUFFERS: u32 = 5;

impl Context {
    /// A context on the adapter `opts` names (or the default one). Backends:
    /// `WGPU_BACKEND` when set, otherwise the primary ones (Vulkan, Metal,
    /// DX12): probing GL on a headless server only prints noise, so GL is
    /// used only when asked for. Power preference: `WGPU_POWER_PREF` or the
    /// default. The device is opened once per process and shared by every
    /// context on it ([`shared`]); `opts.limits` applies to this context.
    pub fn new(opts: &GpuOptions) -> Result<Context> {
        let open = shared::device(device_key(opts.adapter.as_deref())?, find_adapter, open_device)?;
        let mut limits = BatchLimits::from_wgpu(&open.required);
        if let Some(l) = opts.limits {
            limits = limits.min(l);
        }
        let info = open.info.clone();
        let subgroup_lanes =
            (open.features.contains(wgpu::Features::SUBGROUP) && info.subgroup_min_size == info.subgroup_max_size && info.subgroup_min_size > 0)
                .then_some(info.subgroup_min_size);
        Ok(Context {
            device: open.device.clone(),
            queue: open.queue.clone(),
            info,
            limits,
            max_texture_dim: open.required.max_texture_dimension_2d,
            timestamps: open.features.contains(wgpu::Features::TIMESTAMP_QUERY),
            subgroup_lanes,
            cache: open.cache.clone(),
            dispatched: open.dispatched.clone(),
        })
    }

    /// A one-line description: adapter name and backend.
    pub fn describe(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }

    /// Whether `other` is on the very device this context is on (one open
    /// device, [`shared`]), not merely on the same adapter. `==` on
    /// `wgpu::Device` compares ids, which a fresh instance (a forked child's)
    /// hands out again.
    pub fn shares_device_with(&self, other: &Context) -> bool {
        Arc::ptr_eq(&self.cache, &other.cache)
    }

    /// True for software adapters (lavapipe/llvmpipe, WARP, SwiftShader).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Lanes per SIMD vector of a software adapter: llvmpipe names its
    /// vector width ("llvmpipe (LLVM 15.0.6, 256 bits)": 8 lanes of 32
    /// bits); 16 (512 bits) when the name does not say.
    pub fn simd_lanes(&self) -> u32 {
        simd_lanes(&self.info.name)
    }

    /// Whether pipeline `key` is dispatched on this device for the first
    /// time with textures of these `sizes` bound (and notes that it now
    /// is). llvmpipe (lavapipe) translates a pipeline to machine code on
    /// its first dispatch, not when the pipeline is made: one machine-code
    /// variant per kind of bound textures (format, and whether each side
    /// is a power of two), so the sizes stand in for that kind.
    pub(crate) fn first_dispatch(&self, key: &'static str, sizes: Vec<[u32; 2]>) -> bool {
        self.dispatched.lock().unwrap_or_else(|e| e.into_inner()).insert((key, sizes))
    }

    /// Compiles (once) the compute pipeline `entry` of `source`.
    pub(crate) fn pipeline(&self, key: &'static str, source: &str, entry: &str) -> Arc<wgpu::ComputePipeline> {
        self.pipeline_with(key, source, entry, &[])
    }

    /// [`pipeline`](Self::pipeline) with values for the module's `override`
    /// constants (`key` must name the values too: the cache goes by it).
    pub(crate) fn pipeline_with(&self, key: &'static str, source: &str, entry: &str, constants: &[(&str, f64)]) -> Arc<wgpu::ComputePipeline> {
        // The lock is held only to find the cell, never over a compile.
        let cell = self.cache.lock().unwrap_or_else(|e| e.into_inner()).entry(key).or_default().clone();
        cell.get_or_init(|| {
            // Naga's translation and the driver's compilation (lavapipe:
            // NIR, then LLVM unless Mesa's shader cache has the code): a
            // fixed cost of the first use, which a trace shows apart.
            let _span = tracing::trace_span!("compile", pipeline = key).entered();
            let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(key),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            Arc::new(self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(key),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
                cache: None,
            }))
        })
        .clone()
    }

    /// Starts compiling a pipeline ([`pipeline_with`](Self::pipeline_with))
    /// on a thread of its own and returns at once, so that the compile
    /// overlaps the caller's own preparation; whoever asks for the pipeline
    /// meanwhile waits for this compile. lavapipe spends 30-50 ms on the
    /// score kernel's NIR even when Mesa's shader cache holds its machine
    /// code. Where no thread can be made, the pipeline is compiled on first
    /// use as usual.
    pub(crate) fn compile_in_background(&self, key: &'static str, source: &'static str, entry: &'static str, constants: Vec<(&'static str, f64)>) -> Compiling {
        let ctx = self.clone();
        let spawned = std::thread::Builder::new().name(format!("compile {key}")).spawn(move || {
            ctx.pipeline_with(key, source, entry, &constants);
        });
        match spawned {
            Ok(handle) => Compiling(Some(handle)),
            Err(e) => {
                tracing::debug!("no thread to compile {key} on ({e}): compiled on first use");
                Compiling(None)
            }
        }
    }

    /// Blocks until the submission `index` is done (and the ones before it
    /// on the queue). The device is shared by every context of the process
    /// ([`shared`]), so waiting for all its work would also wait for other
    /// threads' dispatches.
    pub fn wait_for(&self, index: wgpu::SubmissionIndex) -> Result<()> {
        self.device
            .poll(wgpu::PollType::Wait { submission_index: Some(index), timeout: None })
            .map(|_| ())
            .map_err(|e| Error::Gpu(e.to_string()))
    }

    /// Copies `size` bytes of `src` to the host and returns them (through a
    /// staging buffer made for the call).
    pub fn read_buffer(&self, src: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.read_through(src, &staging, size)
    }

    /// Copies `size` bytes of `src` into `staging` (a MAP_READ buffer the
    /// caller keeps between calls), waits, and returns them: the one
    /// readback path of every kernel.
    pub fn read_through(&self, src: &wgpu::Buffer, staging: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(src, 0, staging, 0, size);
        let index = self.queue.submit([enc.finish()]);
        let slice = staging.slice(..size);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait_for(index)?;
        rx.recv()
            .map_err(|e| Error::Gpu(e.to_string()))?
            .map_err(|e| Error::Gpu(format!("buffer map failed: {e}")))?;
        let out = slice.get_mapped_range().map_err(|e| Error::Gpu(format!("buffer map failed: {e}")))?.to_vec();
        staging.unmap();
        Ok(out)
    }
}

/// What picks the device for `adapter` (a name, or the default adapter):
/// the backends `WGPU_BACKEND` names, otherwise the primary ones (Vulkan,
/// Metal, DX12), and the power preference `WGPU_POWER_PREF` names.
fn device_key(adapter: Option<&str>) -> Result<shared::DeviceKey> {
    Ok(shared::DeviceKey {
        adapter: adapter.map(str::to_lowercase),
        backends: backends_from_env()?.unwrap_or(wgpu::Backends::PRIMARY),
        power: wgpu::PowerPreference::from_env().unwrap_or_default(),
    })
}

/// Opens a device on `adapter` with the limits and features the kernels
/// use.
fn open_device(adapter: wgpu::Adapter) -> Result<shared::SharedDevice> {
    let info = adapter.get_info();
    let required = required_limits(&adapter.limits(), &info.name)?;
    let features = adapter.features() & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::SUBGROUP);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("plausible"),
        required_features: features,
        required_limits: required.clone(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .map_err(|e| Error::Gpu(format!("could not open a device on {}: {e}", info.name)))?;
    tracing::info!("GPU adapter: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    Ok(shared::SharedDevice::new(device, queue, info, required, features))
}

/// The limits a device is opened with: the adapter's own for buffer and
/// texture sizes and workgroup counts, workgroups of at most 256
/// invocations and 16 KiB, and the storage buffers the largest kernel binds.
fn required_limits(alimits: &wgpu::Limits, adapter: &str) -> Result<wgpu::Limits> {
    let mut required = wgpu::Limits::downlevel_defaults();
    required.max_storage_buffer_binding_size = alimits.max_storage_buffer_binding_size;
    required.max_buffer_size = alimits.max_buffer_size;
    required.max_texture_dimension_2d = alimits.max_texture_dimension_2d;
    required.max_compute_workgroups_per_dimension = alimits.max_compute_workgroups_per_dimension;
    required.max_compute_invocations_per_workgroup = alimits.max_compute_invocations_per_workgroup.min(256);
    required.max_compute_workgroup_size_x = alimits.max_compute_workgroup_size_x.min(256);
    if alimits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS {
        return Err(Error::Gpu(format!(
            "{adapter} binds at most {} storage buffers per shader stage; the score kernel with physics needs {STORAGE_BUFFERS}: use the CPU twin (device `cpu`)",
            alimits.max_storage_buffers_per_shader_stage
        )));
    }
    required.max_storage_buffers_per_shader_stage = STORAGE_BUFFERS;
    required.max_compute_workgroup_storage_size = alimits.max_compute_workgroup_storage_size.min(16384);
    Ok(required)
}

/// The first adapter whose name contains `key.adapter`, or the default one.
fn find_adapter(instance: &wgpu::Instance, key: &shared::DeviceKey) -> Result<wgpu::Adapter> {
    let Some(name) = &key.adapter else {
        return pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: key.power,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| Error::NoAdapter { detail: format!(" ({e}; backends tried: {:?})", key.backends) });
    };
    let all = pollster::block_on(instance.enumerate_adapters(key.backends));
    let names: Vec<String> = all.iter().map(|a| a.get_info().name).collect();
    let needle = name.to_lowercase();
    all.into_iter().find(|a| a.get_info().name.to_lowercase().contains(&needle)).ok_or_else(|| Error::NoAdapter {
        detail: format!(" matching '{name}' (available: {})", if names.is_empty() { "none".to_string() } else { names.join(", ") }),
    })
}

/// The backends `WGPU_BACKEND` names (comma-separated), parsed here so
/// that `gl` really selects OpenGL and a misspelt value is an error rather
/// than silently ignored.
fn backends_from_env() -> Result<Option<wgpu::Backends>> {
    let Ok(v) = std::env::var("WGPU_BACKEND") else { return Ok(None) };
    let mut out = wgpu::Backends::empty();
    for name in v.split(',').map(|s| s.trim().to_ascii_lowercase()) {
        out |= match name.as_str() {
            "vulkan" | "vk" => wgpu::Backends::VULKAN,
            "metal" | "mtl" => wgpu::Backends::METAL,
            "dx12" | "d3d12" => wgpu::Backends::DX12,
            "gl" | "gles" | "opengl" => wgpu::Backends::GL,
            "webgpu" => wgpu::Backends::BROWSER_WEBGPU,
            "primary" => wgpu::Backends::PRIMARY,
            _ => {
                return Err(Error::NoAdapter {
                    detail: format!(": WGPU_BACKEND='{v}' names no backend (use vulkan, metal, dx12 or gl, comma-separated)"),
                })
            }
        };
    }
    Ok(Some(out))
}

/// Reads `PLAUSIBLE_REQUIRE_GPU`: tests that need an adapter fail instead of
/// skipping when it is `1`.
pub fn gpu_required() -> bool {
    std::env::var("PLAUSIBLE_REQUIRE_GPU").map(|v| v == "1").unwrap_or(false)
}

/// For tests: a context on the default adapter. A GPU test never passes
/// without running: without an adapter it fails, naming the two remedies
/// (a Vulkan driver, or `cargo test -- --skip gpu`: every test that needs an
/// adapter has `gpu` in its name, and the runner reports them as filtered
/// out).
pub fn test_context() -> Context {
    Context::new(&GpuOptions::default()).unwrap_or_else(|e| {
        panic!(
            "a GPU test found no adapter ({e}). Install a Vulkan driver (apt-get install mesa-vulkan-drivers \
             gives lavapipe) or skip the GPU tests: cargo test -- --skip gpu"
        )
    })
}
