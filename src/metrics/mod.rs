//! BOP pose-error metrics and scoring, defined exactly as the BOP toolkit
//! computes them: pose errors (ADD, ADI, MSSD, MSPD, rotation and
//! translation error), VSD from rendered depth, and the BOP'19 matching,
//! recall and average recall, and the BOP'24 detection average precision.

pub mod pose_error;
pub mod detection;
pub mod recall;
pub mod vsd;
