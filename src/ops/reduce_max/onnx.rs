//! ONNX side and shape rules of `ReduceMaxAxis`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `ReduceMaxAxis(x f32, axis, keepdims)`: `ReduceMax` over the single axis `axis`
/// (non-negative), the axis kept as 1 when `keepdims`, removed otherwise.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ReduceMaxAxis {
    /// The reduced axis.
    pub axis: usize,
    /// Keep the reduced axis (length 1).
    pub keepdims: bool,
}

/// Build the op from its node (attributes `axis`, `keepdims`).
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let axis: i64 = node.get_attr("axis")?;
    let keepdims = node.get_attr_opt::<i64>("keepdims")?.unwrap_or(1) != 0;
    ensure!(axis >= 0, "ReduceMaxAxis {}: axis must be non-negative, got {axis}", node.name);
    expand_op(ReduceMaxAxis { axis: axis as usize, keepdims })
}

onnx_rules!(ReduceMaxAxis, "ReduceMaxAxis", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    let (axis, keepdims) = (op.axis, op.keepdims);
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, inputs[0].rank.bex() - (!keepdims) as i64)?;
    s.given(&inputs[0].shape, move |s, shape| {
        if axis >= shape.len() {
            bail!("ReduceMaxAxis: axis {axis} of a rank-{} input", shape.len());
        }
        let mut out = shape.clone();
        if keepdims {
            out[axis] = 1.to_dim();
        } else {
            out.remove(axis);
        }
        s.equals(&outputs[0].shape, out)
    })
});
