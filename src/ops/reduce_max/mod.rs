//! `ReduceMaxAxis`: the maximum over one axis (PointNet++'s max-pool over a centre's
//! neighbours). The pose loader puts it in place of single-axis `ReduceMax` nodes
//! ([`crate::pose::rewrite`]); tract's own `Reduce<Max>` slices the input once per
//! output element.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::ReduceMaxAxis;
