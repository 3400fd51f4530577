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

/// A convolution node's attributes (`kernel_shape`, `strides`, `pads` top-left-bottom-right,
/// `dilations`; all required), as the `ai.tricons` convolutions carry them: their parsing,
/// output sizes and shape rules in one place.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ConvAttributes {
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Strides.
    pub strides: [usize; 2],
    /// Pads (top, left, bottom, right).
    pub pads: [usize; 4],
    /// Dilations.
    pub dilations: [usize; 2],
}

impl ConvAttributes {
    /// From a node's attributes; errors name the node and attribute.
    pub fn parse(node: &tract_onnx::pb::NodeProto) -> tract_onnx::prelude::TractResult<Self> {
        use tract_onnx::tract_hir::internal::*;
        let name = &node.name;
        let two = |attr: &str| -> TractResult<[usize; 2]> {
            let v: Vec<usize> = node.get_attr_vec(attr)?;
            ensure!(v.len() == 2 && v.iter().all(|&x| x > 0), "{name}: {attr} must be two positive values, got {v:?}");
            Ok([v[0], v[1]])
        };
        let pads: Vec<usize> = node.get_attr_vec("pads")?;
        ensure!(pads.len() == 4, "{name}: pads must have 4 values, got {pads:?}");
        Ok(Self {
            kernel: two("kernel_shape")?,
            strides: two("strides")?,
            pads: [pads[0], pads[1], pads[2], pads[3]],
            dilations: two("dilations")?,
        })
    }

    /// Output size of spatial axis `axis` (0: height, 1: width) for an input of `size`;
    /// `None` if the kernel does not fit.
    pub fn out_len(&self, axis: usize, size: usize) -> Option<usize> {
        let span = self.dilations[axis] * (self.kernel[axis] - 1) + 1;
        let padded = size + self.pads[axis] + self.pads[axis + 2];
        (padded >= span).then(|| (padded - span) / self.strides[axis] + 1)
    }

    /// The geometry of one `(c_in, h, w)` image.
    pub fn geometry(&self, c_in: usize, h: usize, w: usize) -> ConvGeometry {
        ConvGeometry {
            c_in,
            h,
            w,
            kernel: self.kernel,
            strides: self.strides,
            pads: self.pads,
            dilations: self.dilations,
        }
    }

    /// The output's `(ho, wo)` for an `(N, C, H, W)` input shape whose spatial sizes are
    /// concrete (tract's typed facts); `op` names the node in errors.
    pub fn output_spatial(
        &self,
        op: &str,
        shape: &tract_onnx::prelude::ShapeFact,
    ) -> tract_onnx::prelude::TractResult<[tract_onnx::prelude::TDim; 2]> {
        use tract_onnx::tract_hir::internal::*;
        ensure!(shape.len() == 4, "{op}: input rank {}, expected 4", shape.len());
        let axis = |a: usize| -> TractResult<TDim> {
            let d = shape[2 + a].to_usize().map_err(|_| format_err!("{op}: symbolic spatial size"))?;
            Ok(self.out_len(a, d).ok_or_else(|| format_err!("{op}: kernel larger than input"))?.to_dim())
        };
        Ok([axis(0)?, axis(1)?])
    }

    /// The inference rules of the output's spatial sizes, from the input's once known.
    pub fn spatial_rules<'r, 'p: 'r>(
        self,
        s: &mut tract_onnx::tract_hir::internal::Solver<'r>,
        input: &'p tract_onnx::tract_hir::internal::TensorProxy,
        output: &'p tract_onnx::tract_hir::internal::TensorProxy,
    ) -> tract_onnx::tract_hir::internal::InferenceResult {
        use tract_onnx::tract_hir::internal::*;
        for axis in 0..2 {
            s.given(&input.shape[2 + axis], move |s, d| {
                if let Some(len) = d.to_usize().ok().and_then(|d| self.out_len(axis, d)) {
                    s.equals(&output.shape[2 + axis], len.to_dim())?;
                }
                Ok(())
            })?;
        }
        Ok(())
    }
}
