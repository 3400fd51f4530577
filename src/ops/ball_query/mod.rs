//! `BallQuery`: the first neighbours within a radius.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::BallQuery;
