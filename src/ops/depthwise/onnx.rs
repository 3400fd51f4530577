//! ONNX parsing and shape rules of `DepthwiseConv2d`.

use std::sync::Arc;

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `DepthwiseConv2d(X (N, C, H, W) f32) -> (N, C, Ho, Wo) f32`, attributes `weight`
/// (tensor `(C, kh, kw)` f32), `bias` (C floats), `kernel_shape`, `strides`, `pads`
/// (top, left, bottom, right), `dilations`.
#[derive(Clone, Debug)]
pub struct DepthwiseConv2d {
    /// The node's name (identity for tract's op comparisons).
    pub name: String,
    /// Channels.
    pub channels: usize,
    /// `(C, kh, kw)` row-major.
    pub weight: Arc<Vec<f32>>,
    /// Per channel.
    pub bias: Arc<Vec<f32>>,
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Strides.
    pub strides: [usize; 2],
    /// Pads (top, left, bottom, right).
    pub pads: [usize; 4],
    /// Dilations.
    pub dilations: [usize; 2],
}

impl PartialEq for DepthwiseConv2d {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && Arc::ptr_eq(&self.weight, &other.weight)
    }
}
impl Eq for DepthwiseConv2d {}
impl std::hash::Hash for DepthwiseConv2d {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name.hash(state)
    }
}

impl DepthwiseConv2d {
    /// Output size of one axis (`None` if the kernel does not fit).
    pub fn out_len(&self, axis: usize, size: usize) -> Option<usize> {
        let span = self.dilations[axis] * (self.kernel[axis] - 1) + 1;
        let padded = size + self.pads[axis] + self.pads[axis + 2];
        (padded >= span).then(|| (padded - span) / self.strides[axis] + 1)
    }
}

/// Build the op from its node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let name = &node.name;
    let two = |attr: &str| -> TractResult<[usize; 2]> {
        let v: Vec<usize> = node.get_attr_vec(attr)?;
        ensure!(v.len() == 2 && v.iter().all(|&x| x > 0), "{name}: {attr} must be two positive values, got {v:?}");
        Ok([v[0], v[1]])
    };
    let (kernel, strides, dilations) = (two("kernel_shape")?, two("strides")?, two("dilations")?);
    let pads: Vec<usize> = node.get_attr_vec("pads")?;
    ensure!(pads.len() == 4, "{name}: pads must have 4 values, got {pads:?}");
    let w = node.get_attr::<&tract_onnx::pb::TensorProto>("weight")?;
    let weight = crate::ops::proto::tensor_f32(w).ok_or_else(|| format_err!("{name}: weight is not an f32 tensor"))?;
    ensure!(
        w.dims.len() == 3 && w.dims[1] as usize == kernel[0] && w.dims[2] as usize == kernel[1],
        "{name}: weight dims {:?}, expected (C, {}, {})",
        w.dims,
        kernel[0],
        kernel[1]
    );
    let channels = w.dims[0] as usize;
    ensure!(weight.len() == channels * kernel[0] * kernel[1], "{name}: weight holds {} values", weight.len());
    let bias: Vec<f32> = node.get_attr_vec("bias")?;
    ensure!(bias.len() == channels, "{name}: {} bias values for {channels} channels", bias.len());
    expand_op(DepthwiseConv2d {
        name: name.clone(),
        channels,
        weight: Arc::new(weight),
        bias: Arc::new(bias),
        kernel,
        strides,
        pads: [pads[0], pads[1], pads[2], pads[3]],
        dilations,
    })
}

onnx_rules!(DepthwiseConv2d, "DepthwiseConv2d", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&inputs[0].shape[0], &outputs[0].shape[0])?;
    s.equals(&inputs[0].shape[1], op.channels.to_dim())?;
    s.equals(&outputs[0].shape[1], op.channels.to_dim())?;
    for axis in 0..2 {
        let op = op.clone();
        s.given(&inputs[0].shape[2 + axis], move |s, d| {
            if let Some(len) = d.to_usize().ok().and_then(|d| op.out_len(axis, d)) {
                s.equals(&outputs[0].shape[2 + axis], len.to_dim())?;
            }
            Ok(())
        })?;
    }
    Ok(())
});
