//! Python bindings of `plausible` (`plausible._native`): numpy in, numpy
//! out, no files needed. The Python package in `python/plausible` wraps
//! this module: it coerces arguments (meshes from trimesh, 4x4 poses, any
//! numeric dtype, units) and builds structured arrays, so this side takes
//! strictly typed arrays in metres.

use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use plausible::stop::Stop;

mod convert;
mod frame;
mod functions;
mod mesh;
mod scorer;

/// The library's error as the Python exception a user expects, with the
/// same message: bad input is `ValueError`, a missing file
/// `FileNotFoundError`, other I/O `OSError`, no or failing GPU
/// `RuntimeError`.
pub(crate) fn to_py(e: plausible::Error) -> PyErr {
    use plausible::Error as E;
    let msg = e.to_string();
    match e.cause() {
        E::NotFound { .. } => PyFileNotFoundError::new_err(msg),
        E::Io { .. } | E::Database { .. } => PyOSError::new_err(msg),
        E::NoAdapter { .. } | E::Gpu(_) => PyRuntimeError::new_err(msg),
        _ => PyValueError::new_err(msg),
    }
}

/// Emits `msg` as a Python `UserWarning` (what the CLI prints as
/// "warning: ..."); an error only when a warnings filter turns it into one.
pub(crate) fn user_warning(py: Python<'_>, msg: &str) -> PyResult<()> {
    let text = std::ffi::CString::new(msg.replace('\0', " ")).unwrap_or_default();
    PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &text, 1)
}

/// Runs `work` on a scoped thread without the GIL while this thread looks
/// for Ctrl-C (a pending Python signal) about every 50 ms. On one it
/// requests the [`Stop`] that `work` was given, which the library checks
/// between its steps (drops, chunks, images, refinement steps, RANSAC
/// hypotheses), and returns the `KeyboardInterrupt` (or whatever the
/// signal handler raised) once the work has ended: a long call ends
/// promptly instead of after all its work. One mechanism for every long
/// call: the checks in the work are an atomic load, and signals are only
/// looked at from the thread that may run Python.
pub(crate) fn interruptible<T: Send>(py: Python<'_>, work: impl FnOnce(Stop) -> plausible::Result<T> + Send) -> PyResult<T> {
    let stop = Stop::default();
    let mut raised: Option<PyErr> = None;
    let result = py.detach(|| {
        std::thread::scope(|s| {
            let caller = std::thread::current();
            let worker = {
                let stop = stop.clone();
                // The caller's stack size: the work ran on Python's main
                // thread (8 MiB) before it had a thread of its own.
                std::thread::Builder::new().name("plausible".into()).stack_size(WORKER_STACK).spawn_scoped(s, move || {
                    let r = work(stop);
                    caller.unpark();
                    r
                })
            };
            let worker = match worker {
                Ok(w) => w,
                Err(e) => return Err(plausible::Error::Io { path: "(starting a worker thread)".into(), error: e }),
            };
            while !worker.is_finished() {
                std::thread::park_timeout(std::time::Duration::from_millis(50));
                if raised.is_none() && !worker.is_finished() {
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        raised = Some(e);
                        stop.request();
                    }
                }
            }
            worker.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        })
    });
    match raised {
        Some(e) => Err(e),
        None => result.map_err(to_py),
    }
}

/// Stack of the thread [`interruptible`] work runs on.
const WORKER_STACK: usize = 8 << 20;

/// A `ValueError` with `msg`.
pub(crate) fn value_error(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("MAX_POSES", plausible::pose::MAX_POSES)?;
    m.add_class::<mesh::Mesh>()?;
    m.add_class::<scorer::Scorer>()?;
    m.add_function(wrap_pyfunction!(functions::fit_plane, m)?)?;
    m.add_function(wrap_pyfunction!(functions::check, m)?)?;
    m.add_function(wrap_pyfunction!(functions::stable_poses, m)?)?;
    m.add_function(wrap_pyfunction!(functions::hypotheses, m)?)?;
    m.add_function(wrap_pyfunction!(functions::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(functions::device_info, m)?)?;
    m.add_function(wrap_pyfunction!(functions::read_frame, m)?)?;
    m.add_function(wrap_pyfunction!(frame::refine, m)?)?;
    m.add_function(wrap_pyfunction!(frame::estimate, m)?)?;
    Ok(())
}
