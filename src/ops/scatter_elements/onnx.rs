//! ONNX parsing of `ScatterElements` and the choice between this kernel and tract's.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_core::ops::array::ScatterReduction;
use tract_onnx::tract_hir::internal::*;
use tract_onnx::tract_hir::ops::array::ScatterElements as TractScatterElements;

use crate::ops::tract_glue::{TypedWrapper, expand_op, onnx_rules};

/// The typed op: `ScatterElements(data, indices, updates)` along a non-negative `axis`,
/// no reduction, data and updates of one [`ScatterElements::is_fast_type`] type.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ScatterElements {
    /// The scattered axis (normalised, `0..rank`).
    pub axis: usize,
}

impl ScatterElements {
    /// Element types this kernel runs (the rest go to tract's op).
    pub fn is_fast_type(dt: DatumType) -> bool {
        use DatumType::*;
        matches!(dt, F32 | F64 | I64 | I32 | I16 | I8 | U64 | U32 | U16 | U8 | Bool)
    }
}

/// The ONNX node as parsed: tract's shape rules; at wiring, this kernel when it applies,
/// tract's op otherwise.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct ScatterElementsNode {
    axis: i64,
    reduction: ScatterReduction,
    tract: TractScatterElements,
}

/// Build the node (attributes `axis`, default 0, and `reduction`, default `"none"`).
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let axis: i64 = node.get_attr_opt("axis")?.unwrap_or(0);
    let reduction = ScatterReduction::parse(node.get_attr_opt("reduction")?.unwrap_or("none"))?;
    Ok((expand(ScatterElementsNode { axis, reduction, tract: TractScatterElements::new(axis, reduction) }), vec![]))
}

impl Expansion for ScatterElementsNode {
    fn name(&self) -> StaticName {
        "ScatterElements".into()
    }

    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult {
        self.tract.rules(s, inputs, outputs)
    }

    fn wire(&self, prefix: &str, model: &mut TypedModel, inputs: &[OutletId]) -> TractResult<TVec<OutletId>> {
        let data = model.outlet_fact(inputs[0])?.clone();
        let updates = model.outlet_fact(inputs[2])?.datum_type;
        let rank = data.rank() as i64;
        ensure!(
            (-rank..rank).contains(&self.axis),
            "ScatterElements {prefix}: axis {} out of range for rank {rank}",
            self.axis
        );
        let fast = self.reduction == ScatterReduction::None
            && data.datum_type == updates
            && ScatterElements::is_fast_type(data.datum_type);
        if !fast {
            return self.tract.wire(prefix, model, inputs);
        }
        let axis = if self.axis < 0 { self.axis + rank } else { self.axis } as usize;
        model.wire_node(prefix, TypedWrapper(ScatterElements { axis }), inputs)
    }
}

onnx_rules!(ScatterElements, "ScatterElements", inputs: 3, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].rank, &inputs[1].rank)?;
    s.equals(&inputs[1].shape, &inputs[2].shape)?;
    s.equals(&outputs[0].datum_type, &inputs[0].datum_type)?;
    s.equals(&outputs[0].shape, &inputs[0].shape)
});

/// `ScatterRows(data, indices, updates) -> data'` (domain `ai.tricons`): rows of `updates`
/// written over rows `indices` of `data` along axis 0 ([`super::kernel::scatter_rows`]).
/// The Mask R-CNN loader puts it in for a `ScatterElements` along axis 0 whose indices
/// are a row index vector broadcast over each row ([`crate::segment::rewrite`]).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ScatterRows;

/// Build the op (no attributes).
pub fn parse_rows(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(ScatterRows)
}

onnx_rules!(ScatterRows, "ScatterRows", inputs: 3, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, &inputs[2].datum_type)?;
    s.equals(&inputs[0].rank, &inputs[2].rank)?;
    s.equals(&outputs[0].datum_type, &inputs[0].datum_type)?;
    s.equals(&outputs[0].shape, &inputs[0].shape)
});
