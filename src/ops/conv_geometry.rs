//! [`ConvGeometry`]: the shape of one 2-D convolution (ONNX `Conv` attributes on one
//! image), shared by the int8 convolution ([`super::qconv`]) and the depthwise one
//! ([`super::depthwise`]).

use crate::ops::{OpError, OpResult};

/// Geometry of a 2-D convolution on one `(c_in, h, w)` image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ConvGeometry {
    /// Input channels.
    pub c_in: usize,
    /// Input height.
    pub h: usize,
    /// Input width.
    pub w: usize,
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Strides (y, x).
    pub strides: [usize; 2],
    /// Padding (top, left, bottom, right), ONNX order.
    pub pads: [usize; 4],
    /// Dilations (y, x).
    pub dilations: [usize; 2],
}

impl ConvGeometry {
    /// Output height and width, or an error when the kernel does not fit.
    pub fn output_hw(&self) -> OpResult<(usize, usize)> {
        let axis = |size: usize, pad: usize, k: usize, s: usize, d: usize| -> OpResult<usize> {
            // checked before `k - 1`: a zero kernel, stride or dilation is refused, not wrapped
            let span = if k == 0 || s == 0 || d == 0 { usize::MAX } else { d * (k - 1) + 1 };
            let padded = size + pad;
            if padded < span {
                return Err(OpError::BadLength { op: "Conv", what: "input spatial size", got: size, expected: span });
            }
            Ok((padded - span) / s + 1)
        };
        let [kh, kw] = self.kernel;
        Ok((
            axis(self.h, self.pads[0] + self.pads[2], kh, self.strides[0], self.dilations[0])?,
            axis(self.w, self.pads[1] + self.pads[3], kw, self.strides[1], self.dilations[1])?,
        ))
    }

    /// Patch length `c_in * kh * kw`.
    pub fn patch_len(&self) -> usize {
        self.c_in * self.kernel[0] * self.kernel[1]
    }
}
