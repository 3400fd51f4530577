//! ONNX parsing and shape rules of `TriangleDescriptor`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use super::kernel::triangle_count;
use crate::ops::tract_glue::{expand_op, onnx_rules, points_rule};

/// `TriangleDescriptor(query (B, M, 3), points (B, N, 3)) -> phi (B, M, k(k-1)/2, 3) f32,
/// knn_idx (B, M, k) i64`, attribute `k`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct TriangleDescriptor {
    /// Neighbours per query.
    pub k: usize,
}

/// Build the op from its ONNX node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let k: i64 = node.get_attr("k")?;
    ensure!(k >= 1, "TriangleDescriptor {}: k must be at least 1, got {k}", node.name);
    expand_op(TriangleDescriptor { k: k as usize })
}

onnx_rules!(TriangleDescriptor, "TriangleDescriptor", inputs: 2, outputs: 2, |op, s, inputs, outputs| {
    points_rule(s, &inputs[0])?;
    points_rule(s, &inputs[1])?;
    s.equals(&inputs[0].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&outputs[0].shape[2], triangle_count(op.k).to_dim())?;
    s.equals(&outputs[0].shape[3], 3.to_dim())?;
    s.equals(&outputs[1].datum_type, i64::datum_type())?;
    s.equals(&outputs[1].rank, 3)?;
    s.equals(&outputs[1].shape[2], op.k.to_dim())?;
    for o in outputs {
        s.equals(&o.shape[0], &inputs[0].shape[0])?;
        s.equals(&o.shape[1], &inputs[0].shape[1])?;
    }
    Ok(())
});
