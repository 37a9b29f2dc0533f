//! # plausible
//!
//! Visual and physical plausibility of 6D object poses, for thousands of pose
//! hypotheses at once on any wgpu adapter (including Mesa's lavapipe on a
//! CPU-only server), with a plain-Rust CPU twin of every GPU kernel.
//!
//! The method follows Bauer et al., "Plausibility of object poses" (visual
//! alignment, eq. 3-5; contact-based physical plausibility, eq. 6-13).
//!
//! Conventions: SI units (metres), OpenCV camera (x right, y down, z
//! forward), poses map model to camera coordinates, f32 on the GPU.

pub mod error;
pub mod mesh;
pub mod shapes;
pub mod stable;
pub mod stop;

pub use error::{Error, Input, Result};
pub mod bop;
pub mod camera;
pub mod coco;
pub mod draw;
pub mod eval;
pub mod explain;
pub mod gpu;
pub mod hypotheses;
pub mod io;
pub mod lens;
pub mod kernels;
pub mod metrics;
pub mod observation;
pub mod physical;
pub mod pose;
pub mod refine;
pub mod support_plane;
pub mod synth;
pub mod visual;
