//! ONNX parsing and shape rules of `GatherPoints` and `GroupPoints`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `GatherPoints(features (B, C, N) f32, idx (B, S) i64) -> (B, C, S) f32`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct GatherPoints;

/// `GroupPoints(features (B, C, N) f32, idx (B, S, K) i64) -> (B, C, S, K) f32`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct GroupPoints;

/// Build `GatherPoints` from its ONNX node.
pub fn parse_gather(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(GatherPoints)
}

/// Build `GroupPoints` from its ONNX node.
pub fn parse_group(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(GroupPoints)
}

/// Shared rules: output = features' (B, C) followed by the index dims after B.
fn gather_rules<'r, 'p: 'r>(
    s: &mut Solver<'r>,
    inputs: &'p [TensorProxy],
    outputs: &'p [TensorProxy],
    idx_rank: usize,
) -> InferenceResult {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 3)?;
    s.equals(&inputs[1].datum_type, i64::datum_type())?;
    s.equals(&inputs[1].rank, idx_rank as i64)?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, idx_rank as i64 + 1)?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&inputs[1].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    for d in 1..idx_rank {
        s.equals(&outputs[0].shape[d + 1], &inputs[1].shape[d])?;
    }
    Ok(())
}

onnx_rules!(GatherPoints, "GatherPoints", inputs: 2, outputs: 1, |_op, s, inputs, outputs| {
    gather_rules(s, inputs, outputs, 2)
});

onnx_rules!(GroupPoints, "GroupPoints", inputs: 2, outputs: 1, |_op, s, inputs, outputs| {
    gather_rules(s, inputs, outputs, 3)
});
