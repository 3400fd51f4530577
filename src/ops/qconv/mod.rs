//! `QConv` (`ai.tricons`, written by the load-time quantization rewrite,
//! [`crate::quant::rewrite`]): a 2-D `Conv` (`group = 1`) with a constant weight and
//! its fused normalisation and ReLU, run in int8: the input is quantized once,
//! unfolded to u7 patches ([`kernel::im2col_u7`], padding with the zero point) and
//! multiplied by the packed weights ([`crate::quant::Int8Layer`]), writing NCHW floats.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{ConvGeometry, im2col_u7, im2col_u7_reference, qconv};
pub use onnx::QConv;
