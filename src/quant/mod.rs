//! int8 post-training quantization, done in Rust.
//!
//! [`params`] holds the numerics (u7 activations, per-channel i8 weights, calibration
//! statistics and ranges), [`gemm`] the int8 GEMM kernels with their fused output
//! stage, [`layer`] one fused int8 layer on slices, [`profile`] the artifact
//! `tricons quantize` writes, [`rewrite`] the ONNX rewrite that applies it at load and
//! [`calibrate`] the statistics and decisions behind it, [`quantize`] the calibration
//! run over a recording.

pub mod calibrate;
pub mod gemm;
pub mod layer;
pub mod params;
pub mod profile;
pub mod quantize;
pub mod rewrite;

pub use layer::{Int8Layer, LayerInput, LayerOutput, OutputFold};
pub use params::{QParams, RangeMethod};
pub use profile::{ModelKind, QuantProfile, is_profile};
pub use quantize::{QuantizeJob, quantize};
