//! BOP pose-error metrics and scoring, defined exactly as the BOP toolkit
//! computes them: pose errors (ADD, ADI, MSSD, MSPD, rotation and
//! translation error), VSD from rendered depth, and the BOP'19 matching,
//! recall and average recall, and the BOP'24 detection average precision.

/// Larger first, as numpy's stable `argsort(-x)` orders them (the toolkit's
/// and pycocotools' score sorts): −0 and 0 tie, which `total_cmp` would
/// not have (NaN is refused on reading).
pub fn falling(a: f64, b: f64) -> std::cmp::Ordering {
    b.partial_cmp(&a).unwrap_or(std::cmp::Ordering::Equal)
}

pub mod pose_error;
pub mod detection;
pub mod recall;
pub mod vsd;
