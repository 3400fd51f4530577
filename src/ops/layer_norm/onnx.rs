//! ONNX side and shape rules of `LayerNormLastAxis`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `LayerNormLastAxis(x f32 (..., C), scale f32 (C), bias f32 (C); epsilon)`: ONNX
/// `LayerNormalization` with `axis = -1`, f32 statistics and only the normalised output.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct LayerNormLastAxis {
    /// `epsilon` as f32 bits (the op must be `Eq + Hash`).
    pub epsilon_bits: u32,
}

impl LayerNormLastAxis {
    /// The op for this `epsilon`.
    pub fn new(epsilon: f32) -> Self {
        LayerNormLastAxis { epsilon_bits: epsilon.to_bits() }
    }

    /// Added to the variance.
    pub fn epsilon(&self) -> f32 {
        f32::from_bits(self.epsilon_bits)
    }
}

/// Build the op from its node (attribute `epsilon`, default 1e-5 as in ONNX).
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let epsilon = node.get_attr_opt::<f32>("epsilon")?.unwrap_or(1e-5);
    ensure!(epsilon.is_finite() && epsilon >= 0.0, "LayerNormLastAxis {}: epsilon {epsilon}", node.name);
    expand_op(LayerNormLastAxis::new(epsilon))
}

onnx_rules!(LayerNormLastAxis, "LayerNormLastAxis", inputs: 3, outputs: 1, |_op, s, inputs, outputs| {
    for t in inputs.iter().chain(outputs) {
        s.equals(&t.datum_type, f32::datum_type())?;
    }
    s.equals(&inputs[1].rank, 1)?;
    s.equals(&inputs[2].rank, 1)?;
    s.equals(&outputs[0].shape, &inputs[0].shape)?;
    s.given(&inputs[0].rank, move |s, rank| {
        if rank < 1 {
            bail!("LayerNormLastAxis: a scalar input");
        }
        s.equals(&inputs[1].shape[0], &inputs[0].shape[rank as usize - 1])?;
        s.equals(&inputs[2].shape[0], &inputs[0].shape[rank as usize - 1])
    })
});
