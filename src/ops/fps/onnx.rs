//! ONNX parsing and shape rules of `FurthestPointSample`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules, points_rule};

/// `FurthestPointSample(xyz (B, N, 3) f32) -> idx (B, npoint) i64`, attribute `npoint`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct FurthestPointSample {
    /// Number of points to pick.
    pub npoint: usize,
}

/// Build the op from its ONNX node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let npoint: i64 = node.get_attr("npoint")?;
    ensure!(npoint > 0, "FurthestPointSample {}: npoint must be positive, got {npoint}", node.name);
    expand_op(FurthestPointSample { npoint: npoint as usize })
}

onnx_rules!(FurthestPointSample, "FurthestPointSample", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    points_rule(s, &inputs[0])?;
    s.equals(&outputs[0].datum_type, i64::datum_type())?;
    s.equals(&outputs[0].rank, 2)?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], op.npoint.to_dim())
});
