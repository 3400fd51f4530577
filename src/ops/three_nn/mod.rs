//! `ThreeNN` and `ThreeInterpolate`: inverse-distance feature propagation.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::{ThreeInterpolate, ThreeNN};
