//! BOP datasets and results files (Hodaň et al., "BOP: Benchmark for 6D
//! Object Pose Estimation", ECCV 2018): the files as the BOP toolkit reads
//! them, in millimetres, with every malformed entry a clear error.

pub mod dataset;
pub mod results;
pub mod tiff_depth;

pub use dataset::{
    read_models_info, read_scene_camera, read_scene_gt, read_scene_gt_info, read_targets, ContinuousSymmetry, Dataset, DepthMm,
    FrameCamera, GtInstance, Projection, ModelInfo, PoseMm, Scene, SensorRule, Target, TargetSource,
};
pub use results::{read_results, write_results, Estimate};
