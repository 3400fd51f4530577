//! ONNX side and shape rules of `SoftmaxLastAxis`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `SoftmaxLastAxis(x f32 (..., C)) -> y f32 (..., C)`: ONNX `Softmax` with `axis = -1`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct SoftmaxLastAxis;

/// Build the op from its node (no attributes).
pub fn parse(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(SoftmaxLastAxis)
}

onnx_rules!(SoftmaxLastAxis, "SoftmaxLastAxis", inputs: 1, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].shape, &inputs[0].shape)?;
    s.given(&inputs[0].rank, move |_s, rank| {
        if rank < 1 {
            bail!("SoftmaxLastAxis: a scalar input");
        }
        Ok(())
    })
});
