//! NOCS evaluation metrics: 3D IoU AP and (degrees, cm) pose AP per category,
//! following the reference protocol (the NOCS repo's `compute_degree_cm_mAP`
//! and its copies in DPDN / AG-Pose), quirks included. docs/metrics.md lists
//! what is reproduced and the two deliberate deviations.
//!
//! - [`iou`]: 3D IoU in the [`IouMode::Published`] (reference) and
//!   [`IouMode::Corrected`] variants, with the symmetric search about y;
//! - [`pose_error`]: rotation (degrees) and translation (cm) error;
//! - [`ap`]: VOC all-point average precision;
//! - [`evaluate`] / [`evaluate_recording`]: the per-class, per-image loop,
//!   producing an [`EvalReport`] (JSON via serde, text via
//!   [`EvalReport::to_table`]).

pub mod ap;
pub mod config;
pub mod evaluate;
pub mod iou;
pub mod mask_ap;
mod matching;
pub mod pose_error;
pub mod report;

pub use ap::voc_ap;
pub use config::{DEFAULT_IOU_THRESHOLDS, DEFAULT_POSE_THRESHOLDS, EvalConfig, PoseThreshold, iou_metric_name};
pub use evaluate::{POSE_IOU_GATE, evaluate, evaluate_recording, evaluate_recordings, match_frames_by_timestamp};
pub use iou::{IouMode, SYMMETRY_STEPS, iou_3d, symmetric_iou_3d};
pub use pose_error::pose_error;
pub use report::{ClassResult, EvalReport, MetricValues};
