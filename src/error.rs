//! The library's error type. Every failure a user can cause (bad files, bad
//! numbers, no GPU) maps to a variant whose message says what is wrong and,
//! where there is one, what to do about it.

use std::path::PathBuf;

/// Errors returned by the `plausible` library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: not found")]
    NotFound { path: PathBuf },

    /// The message already holds the I/O error's text, so it is not also
    /// chained as a source (`{:#}` would print it twice).
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },

    #[error("{path}: unsupported mesh format '{ext}' (expected .obj, .ply, .stl, .gltf or .glb)")]
    UnsupportedFormat { path: PathBuf, ext: String },

    #[error("{path}: malformed mesh: {reason}")]
    MalformedMesh { path: PathBuf, reason: String },

    #[error("{path}: mesh has no triangles")]
    NoTriangles { path: PathBuf },

    #[error("{path}: vertex {index} is not finite ({value:?})")]
    NonFiniteVertex {
        path: PathBuf,
        index: usize,
        value: [f64; 3],
    },

    #[error("{path}: face {face} refers to vertex {index}, but the mesh has only {count} vertices")]
    IndexOutOfRange {
        path: PathBuf,
        face: usize,
        index: u64,
        count: usize,
    },

    #[error("{path}: {reason}")]
    BadImage { path: PathBuf, reason: String },

    #[error("{what}: {reason}")]
    BadCamera { what: String, reason: String },

    #[error("pose {index}: {reason}")]
    BadPose { index: usize, reason: String },

    #[error("{path}: {reason}")]
    BadJson { path: PathBuf, reason: String },

    #[error("{path}, line {line}: {reason}")]
    BadLine { path: PathBuf, line: usize, reason: String },

    #[error("{0}")]
    InvalidInput(String),

    #[error(
        "no GPU adapter found{detail}. Install a Vulkan driver (on Debian/Ubuntu: \
         `apt-get install mesa-vulkan-drivers` gives the lavapipe software adapter) \
         or run the CPU twin (device `cpu`)"
    )]
    NoAdapter { detail: String },

    #[error("GPU error: {0}")]
    Gpu(String),

    #[error("database {path}: {reason}")]
    Database { path: PathBuf, reason: String },

    /// The work stopped early because a [`crate::stop::Stop`] was requested.
    #[error("stopped on request")]
    Stopped,

    /// `error` is about one input of a call that takes several
    /// ([`Input`]); the message is `error`'s. Made by [`Error::about`],
    /// read by [`Error::input`] and [`Error::cause`].
    #[error("{error}")]
    About { input: Input, error: Box<Error> },
}

/// The input of a library call an error is about, where the call takes
/// several and the message alone cannot say which to blame in the caller's
/// own terms (a CLI flag, a Python argument). Callers match on it instead
/// of on the message's words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Input {
    /// The object's mask over the depth image.
    Mask,
    /// The support plane.
    SupportPlane,
    /// Stable poses given as a drop-test database's export.
    StablePoses,
    /// Which sensor's annotations and depth a BOP split annotated per
    /// sensor is read with.
    Sensor,
    /// A setting of the call, by the name its message gives it (e.g. the
    /// evaluation's "ADD threshold").
    Setting(&'static str),
    /// A BOP targets file (`test_targets_bop19.json`), as against the
    /// dataset's scene files it is checked against.
    Targets,
    /// The entry picked from a file of many: a frame of a
    /// `scene_camera.json`, an image (and object) of a `scene_gt.json`.
    Selection,
}

/// Convenience alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Wraps an I/O error, turning "not found" into [`Error::NotFound`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        let path = path.into();
        match source.kind() {
            std::io::ErrorKind::NotFound => Error::NotFound { path },
            // read_to_string on a binary file (a PNG given as the camera
            // JSON): the content is wrong, not the disk.
            std::io::ErrorKind::InvalidData => Error::InvalidInput(format!("{}: not a text file of the expected kind ({source})", path.display())),
            _ => Error::Io { path, error: source },
        }
    }

    /// This error, marked as being about `input` (see [`Input`]). An error
    /// already marked keeps its first, innermost mark, and
    /// [`Error::Stopped`] stays unmarked: a stop is nobody's input.
    pub fn about(self, input: Input) -> Self {
        match self {
            Error::Stopped | Error::About { .. } => self,
            error => Error::About { input, error: Box::new(error) },
        }
    }

    /// The input this error is about, where the call marked one.
    pub fn input(&self) -> Option<Input> {
        match self {
            Error::About { input, .. } => Some(*input),
            _ => None,
        }
    }

    /// The error without its [`Error::About`] mark: the variant to match on.
    pub fn cause(&self) -> &Error {
        match self {
            Error::About { error, .. } => error.cause(),
            e => e,
        }
    }

    /// Wraps an error creating or writing a file: "not found" there means a
    /// folder on the way cannot hold files (e.g. /proc), not a missing input.
    pub fn write(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        let error = std::io::Error::new(source.kind(), format!("cannot create or write the file: {source}"));
        Error::Io { path: path.into(), error }
    }
}

/// `v` for a message: `decimals` places in the usual range, and in
/// scientific notation when its magnitude is 1e6 or more or below 1e-3, so
/// that a value such as 1e300 read from a file is not printed as 300
/// digits (nor 1e-9 as 0.000).
pub fn compact(v: f64, decimals: usize) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-3..1e6).contains(&a) {
        format!("{v:.3e}")
    } else {
        format!("{v:.decimals$}")
    }
}

#[cfg(test)]
mod tests {
    use super::{compact, Error, Input};

    #[test]
    fn a_mark_says_the_input_and_keeps_the_message_and_the_cause() {
        let e = Error::BadJson { path: "gt.json".into(), reason: "no image '7'".into() };
        let text = e.to_string();
        let marked = e.about(Input::Selection);
        assert_eq!(marked.to_string(), text);
        assert_eq!(marked.input(), Some(Input::Selection));
        assert!(matches!(marked.cause(), Error::BadJson { .. }));
        // The innermost mark stays; a stop is never marked.
        assert_eq!(marked.about(Input::Mask).input(), Some(Input::Selection));
        assert!(matches!(Error::Stopped.about(Input::Mask), Error::Stopped));
        assert_eq!(Error::InvalidInput("x".into()).input(), None);
    }

    #[test]
    fn compact_numbers_stay_short() {
        assert_eq!(compact(1e300, 3), "1.000e300");
        assert_eq!(compact(-2.5e-7, 1), "-2.500e-7");
        assert_eq!(compact(0.142, 3), "0.142");
        assert_eq!(compact(999_999.0, 1), "999999.0");
        assert_eq!(compact(0.0, 2), "0.00");
        assert_eq!(compact(f64::INFINITY, 1), "inf");
    }
}
