//! `SoftmaxLastAxis`: ONNX `Softmax` over the last axis (the attention weights of every
//! transformer block of the pose graph: the ViT's 197 tokens, PIGA's and SCKD's keys). The
//! pose loader puts it in place of the standard node ([`crate::pose::rewrite`]). tract's own
//! `Softmax` has a vectorised row kernel only for rows whose length is a multiple of 4; the
//! ViT's 197-token rows take its per-row generic path at about 10 ns an element, where this
//! kernel (max, polynomial exponential and sum in 8 lanes, one scaling pass) vectorises
//! every row length.
//!
//! Layers: [`onnx`] (node, shape rules), [`tract_op`] (runtime, in place), [`kernel`] (pure
//! kernel on slices, its f64 reference and the derived error bound) and, on x86_64, `x86.rs`
//! (the same kernel compiled with AVX-512F / AVX2, chosen at run time, bit for bit equal).

pub mod kernel;
pub mod onnx;
pub mod tract_op;
#[cfg(target_arch = "x86_64")]
mod x86;

pub use onnx::SoftmaxLastAxis;
