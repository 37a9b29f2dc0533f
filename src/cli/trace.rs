//! Logging and `--trace`: the log lines on stderr, and when asked for a
//! Chrome trace (JSON Trace Event Format, opens in https://ui.perfetto.dev
//! and chrome://tracing) of the stage spans the library and the commands
//! open.
//!
//! The stage spans are at TRACE level, so the log filter (`warn,
//! plausible=<level>`, at most debug from `-vv`) never enables them: without
//! `--trace` the subscriber is exactly the log formatter and every span is
//! switched off at its call site. With `--trace` the trace layer has its own
//! filter (everything of `plausible` down to TRACE) beside the log filter.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{bail, Result};
use tracing_subscriber::filter::{EnvFilter, LevelFilter, Targets};
use tracing_subscriber::prelude::*;

/// The trace being written: the writer thread's guard and the first write
/// error, if any. Kept in a static so that the panic hook's exit path can
/// finish the file too.
struct TraceFile {
    path: PathBuf,
    /// Where the trace is written until it is complete (beside `path`):
    /// a killed run leaves `path` as it was, never empty or cut off.
    partial: PathBuf,
    guard: tracing_chrome::FlushGuard,
    error: Arc<Mutex<Option<std::io::Error>>>,
}

static TRACE: Mutex<Option<TraceFile>> = Mutex::new(None);

/// The `--trace` file of this run, if any: an output like the command's
/// own, which no other output or input may name.
pub fn path() -> Option<PathBuf> {
    TRACE.lock().unwrap_or_else(|e| e.into_inner()).as_ref().map(|t| t.path.clone())
}

/// Installs the subscriber: the log formatter, and with `trace` a Chrome
/// trace written to that file. The file is created here, before any work,
/// so a bad path fails at once with a clear message.
pub fn init(verbose: u8, trace: Option<&Path>) -> Result<()> {
    let level = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let env = || EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(format!("warn,plausible={level}")));
    let Some(path) = trace else {
        tracing_subscriber::fmt().with_env_filter(env()).with_writer(std::io::stderr).with_ansi(colour()).without_time().init();
        return Ok(());
    };
    #[cfg(unix)]
    finish_on_signal()?;
    let partial = partial_path(path);
    let file = create(path, &partial)?;
    let error = Arc::new(Mutex::new(None));
    let writer = Recording { inner: file, error: error.clone() };
    let (chrome, guard) = tracing_chrome::ChromeLayerBuilder::new()
        .writer(writer)
        .include_args(true)
        .name_fn(Box::new(|item| match item {
            tracing_chrome::EventOrSpan::Event(e) => event_name(e),
            tracing_chrome::EventOrSpan::Span(s) => s.name().to_string(),
        }))
        .build();
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr).with_ansi(colour()).without_time().with_filter(env());
    let traced = Targets::new().with_target("plausible", LevelFilter::TRACE);
    tracing_subscriber::registry().with(fmt).with(chrome.with_filter(traced)).init();
    *TRACE.lock().unwrap_or_else(|e| e.into_inner()) = Some(TraceFile { path: path.to_path_buf(), partial, guard, error });
    flush_every_second()?;
    Ok(())
}

/// Has the writer thread flush its buffer once a second until the trace
/// is finished, so a run killed with SIGKILL (which no handler sees)
/// leaves a partial file holding all but its last second: tracing-chrome
/// writes through an 8 KiB buffer, and the stage spans of a long run fill
/// it rarely (a killed run's file was empty). Each event is written whole
/// after its separator, so a flushed file ends on a complete event.
fn flush_every_second() -> Result<()> {
    std::thread::Builder::new()
        .name("trace flush".into())
        .spawn(|| loop {
            std::thread::sleep(std::time::Duration::from_secs(1));
            match TRACE.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
                Some(t) => t.guard.flush(),
                None => return,
            }
        })
        .map_err(|e| anyhow::anyhow!("--trace: cannot start the thread that flushes the trace: {e}"))?;
    Ok(())
}

/// Makes Ctrl-C, SIGTERM and SIGHUP finish the trace before the process
/// ends (exit status 128 + the signal), so an interrupted run leaves its
/// trace so far at the path asked for, not a hidden `.partial` file. The
/// signals are blocked in this thread before any other exists (threads
/// inherit the mask) and taken by one thread in `sigwait`: no work is done
/// in a signal handler. Only with `--trace`: without it the signals keep
/// their default action. The command's own files are left as a kill leaves
/// them (each is resumable or written whole by a rename).
#[cfg(unix)]
fn finish_on_signal() -> Result<()> {
    // SAFETY: sigset_t is plain data, initialised by sigemptyset before use;
    // called from init, before the trace writer, rayon or wgpu start a
    // thread.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::sigaddset(&mut set, sig);
        }
        if libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut()) != 0 {
            bail!("--trace: cannot block the interrupt signals");
        }
        set
    };
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            let mut sig = 0;
            // SAFETY: `set` is a valid signal set, `sig` a valid out pointer.
            if unsafe { libc::sigwait(&set, &mut sig) } != 0 {
                return;
            }
            match finish() {
                Ok(()) => eprintln!("interrupted: the trace holds the run so far"),
                Err(e) => eprintln!("interrupted; error: {e:#}"),
            }
            std::process::exit(128 + sig);
        })
        .map_err(|e| anyhow::anyhow!("--trace: cannot start the signal thread: {e}"))?;
    Ok(())
}

/// An event's name in the trace: its message ("gpu pass", a warning's
/// text), where tracing would call it "event file:line".
fn event_name(e: &tracing::Event<'_>) -> String {
    struct Message(Option<String>);
    impl tracing::field::Visit for Message {
        fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
            if field.name() == "message" {
                self.0 = Some(format!("{value:?}"));
            }
        }
    }
    let mut m = Message(None);
    e.record(&mut m);
    m.0.unwrap_or_else(|| e.metadata().name().to_string())
}

/// The file the trace is written to before it is renamed to `path`.
fn partial_path(path: &Path) -> PathBuf {
    // A device or pipe (/dev/stdout, a FIFO) is written as it is.
    if path.exists() && !path.is_file() && !path.is_dir() {
        return path.to_path_buf();
    }
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.partial", std::process::id()))
}

/// Whether `path` holds something other than a trace: the trace must not
/// replace a command's input or output. A trace is a JSON array of Chrome
/// trace events, each with a `"ph"` (phase) key; pose lists and score
/// outputs are JSON arrays too, so the first element must be an event. An
/// empty file or a bare `[` (a trace cut off at its start) holds nothing.
fn holds_other_data(path: &Path) -> bool {
    use std::io::Read;
    if !path.is_file() {
        return false;
    }
    let mut head = Vec::with_capacity(4096);
    let Ok(_) = std::fs::File::open(path).and_then(|f| f.take(4096).read_to_end(&mut head)) else { return false };
    !is_trace_start(&head)
}

/// Whether `head` (a file's first bytes) starts like a trace: see
/// [`holds_other_data`].
fn is_trace_start(head: &[u8]) -> bool {
    let text = String::from_utf8_lossy(head);
    let Some(rest) = text.trim_start().strip_prefix('[') else { return text.trim().is_empty() };
    let rest = rest.trim_start();
    if rest.is_empty() {
        return true;
    }
    // The writer puts one event on a line.
    rest.starts_with('{') && rest.lines().next().is_some_and(|event| event.contains("\"ph\":"))
}

/// Creates the partial trace file, saying which flag a bad path came from.
fn create(path: &Path, partial: &Path) -> Result<std::fs::File> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!("--trace {}: the folder {} does not exist", path.display(), dir.display());
    }
    if path.is_dir() {
        bail!("--trace {}: is a folder, expected a file name (e.g. trace.json)", path.display());
    }
    if holds_other_data(path) {
        bail!("--trace {}: the file exists and is not a trace (an input or output of the command?): give another path", path.display());
    }
    if partial == path {
        return std::fs::OpenOptions::new().write(true).open(path).map_err(|e| anyhow::anyhow!("--trace {}: {e}", path.display()));
    }
    std::fs::File::create(partial).map_err(|e| anyhow::anyhow!("--trace {}: cannot create the file: {e}", path.display()))
}

/// Finishes the trace, when one is being written: stops the writer thread
/// (which closes the JSON array) and reports a write error. Call it before
/// every `std::process::exit`, or the file is cut off.
pub fn finish() -> Result<()> {
    let Some(t) = TRACE.lock().unwrap_or_else(|e| e.into_inner()).take() else { return Ok(()) };
    drop(t.guard);
    if let Some(e) = t.error.lock().unwrap_or_else(|e| e.into_inner()).take() {
        if t.partial != t.path {
            let _ = std::fs::remove_file(&t.partial);
        }
        bail!("cannot write the trace {}: {e}", t.path.display());
    }
    // The command may have written `path` itself meanwhile (an output of
    // the same name): that is kept, and the trace left beside it.
    if t.partial == t.path {
        return Ok(());
    }
    if holds_other_data(&t.path) {
        bail!("--trace {}: the command wrote a file of that name; the trace is in {}", t.path.display(), t.partial.display());
    }
    std::fs::rename(&t.partial, &t.path).map_err(|e| anyhow::anyhow!("cannot write the trace {}: {e}", t.path.display()))
}

/// The trace file's writer (tracing-chrome buffers in front of it): its
/// writer thread panics on a write error (a full disk), so the first error
/// is kept here for [`finish`] to report, and what follows is dropped.
struct Recording {
    inner: std::fs::File,
    error: Arc<Mutex<Option<std::io::Error>>>,
}

impl Recording {
    /// Runs `op` unless an earlier write failed; a failure is kept and
    /// turned into success for the writer thread.
    fn guarded(&mut self, op: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>) {
        let mut error = self.error.lock().unwrap_or_else(|e| e.into_inner());
        if error.is_none() {
            if let Err(e) = op(&mut self.inner) {
                *error = Some(e);
            }
        }
    }
}

impl Write for Recording {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.guarded(|w| w.write_all(buf));
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.guarded(|w| w.flush());
        Ok(())
    }
}

/// Colours only on a terminal: a log piped to a file stays plain text.
fn colour() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none()
}

#[cfg(test)]
mod tests {
    use super::is_trace_start;

    #[test]
    fn only_traces_count_as_traces() {
        assert!(is_trace_start(b"[\n{\"args\":{\"name\":\"main\"},\"name\":\"thread_name\",\"ph\":\"M\",\"pid\":1,\"tid\":0},\n"));
        assert!(is_trace_start(b""));
        assert!(is_trace_start(b"  [\n"));
        // Pose lists and score outputs are JSON arrays too.
        assert!(!is_trace_start(b"[{\"cam_R_m2c\": [1, 0, 0, 0, 1, 0, 0, 0, 1], \"cam_t_m2c\": [0, 0, 700]}]"));
        assert!(!is_trace_start(b"[\n  {\n    \"rank\": 1,\n    \"score\": 0.8\n  }\n]"));
        assert!(!is_trace_start(b"[]"));
        assert!(!is_trace_start(b"{\"point\": [0, 0, 1]}"));
        assert!(!is_trace_start(b"\x89PNG\r\n"));
    }
}
