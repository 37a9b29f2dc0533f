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
    match e {
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

/// Runs `work` without the GIL, looking for Ctrl-C (a pending Python
/// signal) about every 50 ms through `look`, which `work` calls at its
/// cancellation points (between drops, chunks, images). On an interrupt
/// `look` returns an error for `work` to stop on, and this returns the
/// `KeyboardInterrupt` (or what the signal handler raised) instead of the
/// work's result: a long call ends at once instead of after all its work.
pub(crate) fn interruptible<T: Send>(py: Python<'_>, work: impl FnOnce(&mut dyn FnMut() -> plausible::Result<()>) -> plausible::Result<T> + Send) -> PyResult<T> {
    let mut raised: Option<PyErr> = None;
    let mut last = std::time::Instant::now();
    let result = py.detach(|| {
        let mut look = || {
            if last.elapsed() < std::time::Duration::from_millis(50) {
                return Ok(());
            }
            last = std::time::Instant::now();
            match Python::attach(|py| py.check_signals()) {
                Ok(()) => Ok(()),
                Err(e) => {
                    raised = Some(e);
                    Err(plausible::Error::InvalidInput("interrupted".into()))
                }
            }
        };
        work(&mut look)
    });
    match raised {
        Some(e) => Err(e),
        None => result.map_err(to_py),
    }
}

/// Runs `work` on a scoped thread without the GIL while this thread looks
/// for Ctrl-C (a pending Python signal) about every 50 ms; on one it
/// requests the [`Stop`] that `work` was given (the library checks it
/// between refinement steps) and returns the `KeyboardInterrupt` once the
/// work has ended. For work whose loops are inside the library, where
/// [`interruptible`]'s callback cannot reach.
pub(crate) fn stoppable<T: Send>(py: Python<'_>, work: impl FnOnce(Stop) -> plausible::Result<T> + Send) -> PyResult<T> {
    let stop = Stop::default();
    let mut raised: Option<PyErr> = None;
    let result = py.detach(|| {
        std::thread::scope(|s| {
            let caller = std::thread::current();
            let worker = {
                let stop = stop.clone();
                s.spawn(move || {
                    let r = work(stop);
                    caller.unpark();
                    r
                })
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
