//! `QLinear` (`ai.tricons`, written by the load-time quantization rewrite,
//! [`crate::quant::rewrite`]): a `MatMul`/`Gemm` with a constant weight and its fused
//! bias, normalisation and ReLU, run in int8 on the last axis of its input.
//! The kernel is [`crate::quant::Int8Layer`] (pure, on slices).

pub mod onnx;
pub mod tract_op;

pub use onnx::QLinear;
