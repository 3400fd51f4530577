//! `RoiAlign` (ONNX standard op, opset 10 and 16): the region pooling of Mask R-CNN,
//! which tract does not implement. Semantics follow onnxruntime's CPU kernel,
//! including its sample clamping and the `output_half_pixel` minimum ROI size of 1.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{PoolMode, RoiAlignParams, roi_align, roi_align_reference};
pub use onnx::RoiAlign;
