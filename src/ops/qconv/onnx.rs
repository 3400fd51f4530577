//! ONNX parsing and shape rules of `QConv`.

use std::sync::Arc;

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use super::kernel::ConvLayer;
use crate::ops::conv_geometry::ConvAttributes;
use crate::ops::qlinear::onnx::{activation_type, parse_layer};
use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `QConv(X (N, C, H, W) f32 or u8) -> (N, Cout, Ho, Wo) f32`.
#[derive(Clone, Debug)]
pub struct QConv {
    /// The node's name (identity for tract's op comparisons).
    pub name: String,
    /// The fused layer (`k = C * kh * kw`), weight rows in the channels-last kernel's order.
    pub conv: Arc<ConvLayer>,
    /// The input arrives as u7 (`u8`).
    pub input_u7: bool,
    /// Kernel, strides, pads, dilations.
    pub attrs: ConvAttributes,
}

impl PartialEq for QConv {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && Arc::ptr_eq(&self.conv, &other.conv)
    }
}
impl Eq for QConv {}
impl std::hash::Hash for QConv {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name.hash(state)
    }
}

/// Build the op from its node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let name = &node.name;
    let (layer, input_u7) = parse_layer(node)?;
    ensure!(layer.output_params().is_none(), "{name}: QConv writes floats only");
    let attrs = ConvAttributes::parse(node)?;
    // ConvLayer refuses weight rows that are not a whole number of kernel taps
    let conv = ConvLayer::new(&layer, attrs.kernel).map_err(|e| format_err!("{name}: {e}"))?;
    expand_op(QConv { name: name.clone(), conv: Arc::new(conv), input_u7, attrs })
}

onnx_rules!(QConv, "QConv", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, activation_type(op.input_u7))?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&inputs[0].shape[0], &outputs[0].shape[0])?;
    let c_in = op.conv.layer().k() / (op.attrs.kernel[0] * op.attrs.kernel[1]);
    s.equals(&inputs[0].shape[1], c_in.to_dim())?;
    s.equals(&outputs[0].shape[1], op.conv.layer().n().to_dim())?;
    op.attrs.spatial_rules(s, &inputs[0], &outputs[0])
});
