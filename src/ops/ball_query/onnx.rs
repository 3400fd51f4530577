//! ONNX parsing and shape rules of `BallQuery`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules, points_rule};

/// `BallQuery(xyz (B, N, 3), new_xyz (B, S, 3)) -> idx (B, S, nsample) i64`, attributes
/// `radius` (metres) and `nsample`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct BallQuery {
    /// Bits of the `f32` radius (kept as bits so the op is `Eq` and `Hash`).
    pub radius_bits: u32,
    /// Neighbours per centre.
    pub nsample: usize,
}

impl BallQuery {
    /// Ball radius.
    pub fn radius(&self) -> f32 {
        f32::from_bits(self.radius_bits)
    }
}

/// Build the op from its ONNX node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let radius: f32 = node.get_attr("radius")?;
    let nsample: i64 = node.get_attr("nsample")?;
    ensure!(radius.is_finite() && radius > 0.0, "BallQuery {}: radius must be positive, got {radius}", node.name);
    ensure!(nsample > 0, "BallQuery {}: nsample must be positive, got {nsample}", node.name);
    expand_op(BallQuery { radius_bits: radius.to_bits(), nsample: nsample as usize })
}

onnx_rules!(BallQuery, "BallQuery", inputs: 2, outputs: 1, |op, s, inputs, outputs| {
    points_rule(s, &inputs[0])?;
    points_rule(s, &inputs[1])?;
    s.equals(&inputs[0].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].datum_type, i64::datum_type())?;
    s.equals(&outputs[0].rank, 3)?;
    s.equals(&outputs[0].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[1].shape[1])?;
    s.equals(&outputs[0].shape[2], op.nsample.to_dim())
});
