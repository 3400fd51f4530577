//! `BilinearUpsample2x`: the small CNN decoder's bilinear x2 upsampling (ONNX `Resize`,
//! linear, `half_pixel`, scales (1, 1, 2, 2)) with its fixed taps. The pose loader puts
//! it in place of such `Resize` nodes ([`crate::pose::rewrite`]); tract's `Resize` builds a
//! general per-axis plan and accumulates tap by tap.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::BilinearUpsample2x;
