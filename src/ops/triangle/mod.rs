//! `TriangleDescriptor`: the triangle-based geometric descriptor of PIGA.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::TriangleDescriptor;
