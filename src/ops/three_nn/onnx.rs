//! ONNX parsing and shape rules of `ThreeNN` and `ThreeInterpolate`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules, points_rule};

/// `ThreeNN(unknown (B, n, 3), known (B, m, 3)) -> dist (B, n, 3) f32, idx (B, n, 3) i64`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ThreeNN;

/// `ThreeInterpolate(features (B, C, m), idx (B, n, 3) i64, weight (B, n, 3)) -> (B, C, n)`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ThreeInterpolate;

/// Build `ThreeNN` from its ONNX node.
pub fn parse_three_nn(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(ThreeNN)
}

/// Build `ThreeInterpolate` from its ONNX node.
pub fn parse_three_interpolate(
    _ctx: &ParsingContext,
    _node: &NodeProto,
) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(ThreeInterpolate)
}

onnx_rules!(ThreeNN, "ThreeNN", inputs: 2, outputs: 2, |_op, s, inputs, outputs| {
    points_rule(s, &inputs[0])?;
    points_rule(s, &inputs[1])?;
    s.equals(&inputs[0].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[1].datum_type, i64::datum_type())?;
    for o in outputs {
        s.equals(&o.rank, 3)?;
        s.equals(&o.shape[0], &inputs[0].shape[0])?;
        s.equals(&o.shape[1], &inputs[0].shape[1])?;
        s.equals(&o.shape[2], 3.to_dim())?;
    }
    Ok(())
});

onnx_rules!(ThreeInterpolate, "ThreeInterpolate", inputs: 3, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 3)?;
    s.equals(&inputs[1].datum_type, i64::datum_type())?;
    s.equals(&inputs[2].datum_type, f32::datum_type())?;
    for t in &inputs[1..] {
        s.equals(&t.rank, 3)?;
        s.equals(&t.shape[0], &inputs[0].shape[0])?;
        s.equals(&t.shape[2], 3.to_dim())?;
    }
    s.equals(&inputs[1].shape[1], &inputs[2].shape[1])?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 3)?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    s.equals(&outputs[0].shape[2], &inputs[1].shape[1])
});
