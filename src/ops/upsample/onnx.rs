//! ONNX side and shape rules of `BilinearUpsample2x`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `BilinearUpsample2x(x (N, C, H, W) f32) -> (N, C, 2H, 2W)`: ONNX `Resize` with mode
/// `linear`, `half_pixel` coordinates and scales (1, 1, 2, 2).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct BilinearUpsample2x;

/// Build the op from its node (no attributes).
pub fn parse(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(BilinearUpsample2x)
}

onnx_rules!(BilinearUpsample2x, "BilinearUpsample2x", inputs: 1, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    s.equals(&outputs[0].shape[2], 2 * inputs[0].shape[2].bex())?;
    s.equals(&outputs[0].shape[3], 2 * inputs[0].shape[3].bex())
});
