//! `QConv` (`ai.tricons`, written by the load-time quantization rewrite,
//! [`crate::quant::rewrite`]): a 2-D `Conv` (`group = 1`) with a constant weight and
//! its fused normalisation and ReLU, run in int8: the input is quantized once and turned
//! channels-last, unfolded block by block to u7 patches ([`kernel::im2col_hwc_u7`],
//! padding with the zero point; none for a 1x1 convolution) and multiplied by the packed
//! weights ([`crate::quant::Int8Layer`], rows reordered to the patches' order), writing
//! NCHW floats. [`kernel::qconv_reference`] (the ONNX row order, the whole image unfolded
//! by [`kernel::im2col_u7`]) is the definition it is tested against, bit for bit.

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{
    CHANNELS_LAST_MIN_C_IN, ConvGeometry, ConvLayer, PatchOrder, chw_to_hwc_u8, im2col_hwc_u7, im2col_u7,
    im2col_u7_reference, qconv, qconv_reference,
};
pub use onnx::QConv;
