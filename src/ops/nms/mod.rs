//! `NonMaxSuppression` (ONNX standard op) with a fast kernel.
//!
//! tract's own NonMaxSuppression compares every candidate with every kept box
//! (22 s on a frame with ~90k candidates). This one registers under the same
//! node type and keeps kept boxes in a sparse uniform grid, so a candidate is
//! only compared with the kept boxes that share a cell with it; the selection
//! is identical to the pairwise scalar reference ([`kernel::nms_reference`]),
//! which follows onnxruntime (strict `iou > threshold`, strict
//! `score > score_threshold`, ties in score to the lower index).

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{BoxFormat, NmsParams, nms, nms_reference};
pub use onnx::NonMaxSuppression;
