//! ONNX parsing and shape rules of `DepthwiseConv2d`.

use std::sync::Arc;

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::conv_geometry::ConvAttributes;
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
    /// Kernel, strides, pads, dilations.
    pub attrs: ConvAttributes,
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

/// Build the op from its node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let name = &node.name;
    let attrs = ConvAttributes::parse(node)?;
    let kernel = attrs.kernel;
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
    expand_op(DepthwiseConv2d { name: name.clone(), channels, weight: Arc::new(weight), bias: Arc::new(bias), attrs })
}

onnx_rules!(DepthwiseConv2d, "DepthwiseConv2d", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&inputs[0].shape[0], &outputs[0].shape[0])?;
    s.equals(&inputs[0].shape[1], op.channels.to_dim())?;
    s.equals(&outputs[0].shape[1], op.channels.to_dim())?;
    op.attrs.spatial_rules(s, &inputs[0], &outputs[0])
});
