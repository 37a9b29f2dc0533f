//! The machine a benchmark ran on: CPU model and SIMD features, core and
//! thread counts, adapter and driver (Mesa and LLVM versions on lavapipe),
//! so figures from different machines are never compared blindly. Every
//! `bench` JSON row carries it and every table starts with its line.

use plausible::visual::Device;
use serde::Serialize;

#[derive(Serialize, Clone, Debug)]
pub struct Machine {
    pub cpu_model: String,
    /// The SIMD features that matter to lavapipe and the CPU twins, as the
    /// running CPU reports them (x86: sse4.2, avx, avx2, fma, avx512f, …).
    pub cpu_features: Vec<&'static str>,
    /// Logical CPUs the process may use.
    pub logical_cpus: usize,
    /// Threads of the CPU twins (rayon).
    pub threads: usize,
    pub os: String,
    /// The wgpu adapter, its backend and driver (`None` on the CPU twin).
    pub adapter: Option<String>,
    pub backend: Option<String>,
    pub driver: Option<String>,
    /// `GALLIUM_OVERRIDE_CPU_CAPS` when set: Mesa's software adapters then
    /// compile for fewer SIMD features than `cpu_features` lists (`avx`:
    /// AVX2 without AVX-512, how an AVX-512 machine measures lavapipe as
    /// an AVX2-only one would run it).
    pub mesa_cpu_caps_override: Option<String>,
}

impl Machine {
    /// This machine, with the adapter of `device` when it is a GPU.
    pub fn detect(device: Option<&Device>) -> Machine {
        let gpu = device.and_then(|d| match d {
            Device::Gpu(ctx) => Some(&ctx.info),
            Device::Cpu => None,
        });
        Machine {
            cpu_model: cpu_model(),
            cpu_features: cpu_features(),
            logical_cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            threads: rayon::current_num_threads(),
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
            adapter: gpu.map(|i| i.name.clone()),
            backend: gpu.map(|i| format!("{:?}", i.backend)),
            driver: gpu.map(|i| format!("{} {}", i.driver, i.driver_info).trim().to_string()),
            mesa_cpu_caps_override: gpu.and_then(|_| std::env::var("GALLIUM_OVERRIDE_CPU_CAPS").ok()),
        }
    }

    /// One line for the head of a table.
    pub fn line(&self) -> String {
        let simd = if self.cpu_features.is_empty() { "no SIMD features detected".to_string() } else { self.cpu_features.join(" ") };
        let gpu = match (&self.adapter, &self.driver) {
            (Some(a), Some(d)) => format!("; adapter {a} ({}), driver {d}", self.backend.as_deref().unwrap_or("?")),
            _ => String::new(),
        };
        let caps = match &self.mesa_cpu_caps_override {
            Some(c) => format!(" (Mesa's CPU features capped: GALLIUM_OVERRIDE_CPU_CAPS={c})"),
            None => String::new(),
        };
        format!("{} [{simd}], {} logical CPUs, {} threads, {}{gpu}{caps}", self.cpu_model, self.logical_cpus, self.threads, self.os)
    }
}

/// The CPU's model name (Linux `/proc/cpuinfo`; "unknown" elsewhere).
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|m| m.trim().to_string()))
        .unwrap_or_else(|| "unknown".into())
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
fn cpu_features() -> Vec<&'static str> {
    let mut f = Vec::new();
    macro_rules! probe {
        ($($name:tt),*) => {$(
            if std::arch::is_x86_feature_detected!($name) {
                f.push($name);
            }
        )*};
    }
    probe!("sse4.2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl");
    f
}

#[cfg(target_arch = "aarch64")]
fn cpu_features() -> Vec<&'static str> {
    let mut f = Vec::new();
    if std::arch::is_aarch64_feature_detected!("neon") {
        f.push("neon");
    }
    if std::arch::is_aarch64_feature_detected!("sve") {
        f.push("sve");
    }
    f
}

#[cfg(not(any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64")))]
fn cpu_features() -> Vec<&'static str> {
    Vec::new()
}
