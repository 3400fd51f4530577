//! `GatherPoints` and `GroupPoints`: feature gathers by point index.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::{GatherPoints, GroupPoints};
