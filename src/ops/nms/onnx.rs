//! ONNX parsing and shape rules of `NonMaxSuppression` (replaces tract's).

use tract_onnx::model::{ParsingContext, optional_inputs};
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use super::kernel::BoxFormat;
use super::tract_op::FastNms;

/// `NonMaxSuppression(boxes (B, N, 4), scores (B, C, N), [max_output_boxes_per_class],
/// [iou_threshold], [score_threshold]) -> selected_indices (K, 3) i64`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct NonMaxSuppression {
    /// Input slot of each optional input, when present.
    pub optional: [Option<usize>; 3],
    /// `center_point_box`.
    pub format: BoxFormat,
    /// The symbol naming the (data-dependent) number of selected boxes.
    pub selected: Symbol,
}

/// Build the op from its ONNX node.
pub fn parse(ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let format = match node.get_attr_opt::<i64>("center_point_box")?.unwrap_or(0) {
        0 => BoxFormat::Corners,
        1 => BoxFormat::Center,
        v => bail!("NonMaxSuppression {}: center_point_box must be 0 or 1, got {v}", node.name),
    };
    let mut opt = optional_inputs(node).skip(2);
    let optional = [opt.next().flatten(), opt.next().flatten(), opt.next().flatten()];
    let selected = ctx.template.symbols.new_with_prefix("nms");
    Ok((expand(NonMaxSuppression { optional, format, selected }), vec![]))
}

impl Expansion for NonMaxSuppression {
    fn name(&self) -> StaticName {
        "NonMaxSuppression".into()
    }

    fn rules<'r, 'p: 'r, 's: 'r>(
        &'s self,
        s: &mut Solver<'r>,
        inputs: &'p [TensorProxy],
        outputs: &'p [TensorProxy],
    ) -> InferenceResult {
        check_input_arity(inputs, 2 + self.optional.iter().flatten().count())?;
        check_output_arity(outputs, 1)?;
        s.equals(&outputs[0].datum_type, i64::datum_type())?;
        s.equals(&outputs[0].rank, 2)?;
        s.equals(&outputs[0].shape[0], self.selected.to_dim())?;
        s.equals(&outputs[0].shape[1], 3.to_dim())?;
        s.equals(&inputs[0].datum_type, f32::datum_type())?;
        s.equals(&inputs[0].rank, 3)?;
        s.equals(&inputs[0].shape[2], 4.to_dim())?;
        s.equals(&inputs[1].datum_type, f32::datum_type())?;
        s.equals(&inputs[1].rank, 3)?;
        s.equals(&inputs[0].shape[0], &inputs[1].shape[0])?;
        s.equals(&inputs[0].shape[1], &inputs[1].shape[2])
    }

    fn wire(&self, prefix: &str, model: &mut TypedModel, inputs: &[OutletId]) -> TractResult<TVec<OutletId>> {
        let mut wired = tvec![inputs[0], inputs[1]];
        let mut has = [false; 3];
        for (k, slot) in self.optional.iter().enumerate() {
            if let Some(i) = slot {
                wired.push(inputs[*i]);
                has[k] = true;
            }
        }
        model.wire_node(prefix, FastNms { format: self.format, has, selected: self.selected.clone() }, &wired)
    }
}
