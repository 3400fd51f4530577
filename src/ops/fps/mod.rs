//! `FurthestPointSample`: greedy farthest point sampling.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::FurthestPointSample;
