//! `DepthwiseConv2d` (`ai.tricons`, written by the Mask R-CNN loader's rewrite,
//! [`crate::segment::rewrite`]): a 2-D `Conv` with `group` = input channels = output
//! channels and a constant weight `(C, 1, kh, kw)` and bias, as MobileNetV3's depthwise
//! layers. tract runs it through a generic scalar zone walk; [`kernel::depthwise`] copies
//! each channel plane once into a zero-padded buffer split into stride phases, so every
//! kernel tap is one contiguous multiply-add over an output row (vectorised by the
//! compiler; on x86_64 built again with AVX-512F and AVX2, `x86.rs`, chosen at run time),
//! in the reference's order: the bits of [`kernel::depthwise_reference`].

pub mod kernel;
pub mod onnx;
pub mod tract_op;
#[cfg(target_arch = "x86_64")]
mod x86;

pub use kernel::{depthwise, depthwise_reference, depthwise_rows};
pub use onnx::DepthwiseConv2d;
