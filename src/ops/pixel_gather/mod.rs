//! `PixelGather`: a dense feature map's values at the object's pixels. The pose loader
//! puts it in front of the image decoder's per-pixel layers, which then run on the `N`
//! sampled pixels instead of the whole crop ([`crate::pose::rewrite`]); with
//! `upsample2x` it samples the bilinear x2 upsampling of its input at those pixels
//! without computing the upsampled map. `ResampledPixelGather` does the same for a map
//! made by two constant resampling products (`MatMul(MatMul(rows, x), cols)`, how the
//! paper configuration's image encoder brings its patch features to the crop).

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use onnx::{PixelGather, ResampledPixelGather};
