//! `Resize2d` (`ai.tricons`, written by the Mask R-CNN loader's rewrite,
//! [`crate::segment::rewrite`]): the two ONNX `Resize` forms of a torchvision Mask R-CNN,
//! on `(N, C, H, W)` f32 with output sizes known when the plan is made:
//!
//! * `linear` with `half_pixel` coordinates (the input transform's resize of the image);
//! * `nearest` with `asymmetric` coordinates and `floor` rounding (the FPN's top-down x2).
//!
//! tract evaluates `Resize` element by element through generic coordinate transforms;
//! [`kernel`] computes each output row's and column's source taps once.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{ResizeMode, resize_columns, resize_plane, resize_plane_reference};
pub use onnx::Resize2d;
