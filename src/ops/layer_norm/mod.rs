//! `LayerNormLastAxis`: ONNX `LayerNormalization` over the last axis (every transformer
//! block of the pose graph: PIGA, SCKD, the ViT). The pose loader puts it in place of the
//! standard node ([`crate::pose::rewrite`]); tract expands that node into a chain of
//! reductions and broadcast arithmetic (`Reduce<Sum>`, `Sub`, `RmsNorm`, `Mul`, `Add`), each
//! a pass over the tensor, where this is one pass per row for the statistics and one for
//! the result.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::LayerNormLastAxis;
