//! tract runtime of `NonMaxSuppression`: the grid kernel per (batch, class).

use tract_onnx::tract_hir::internal::*;

use super::kernel::{BoxFormat, NmsParams, nms};
use crate::ops::tract_glue::output;

/// The typed NMS op: inputs boxes, scores, then the optional inputs present (`has`:
/// max_output_boxes_per_class, iou_threshold, score_threshold).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct FastNms {
    /// Box layout.
    pub format: BoxFormat,
    /// Which optional inputs follow boxes and scores.
    pub has: [bool; 3],
    /// Symbol of the output length.
    pub selected: Symbol,
}

fn scalar<T: Datum + Copy>(t: &TValue, what: &str) -> TractResult<T> {
    ensure!(t.len() == 1, "NonMaxSuppression: {what} must hold one value, has {}", t.len());
    let t = t.cast_to::<T>()?;
    Ok(t.try_as_plain_ram()?.as_slice::<T>()?[0])
}

impl Op for FastNms {
    fn name(&self) -> StaticName {
        "NonMaxSuppression".into()
    }

    fn mints_runtime_symbols(&self) -> bool {
        true
    }

    op_as_typed_op!();
}

impl EvalOp for FastNms {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        crate::ops::profile::timed("NonMaxSuppression", || self.eval_nms(inputs))
    }
}

impl FastNms {
    fn eval_nms(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let mut rest = inputs.iter().skip(2);
        // Absent means 0 (ONNX default): nothing is selected, as onnxruntime does.
        let mut max_output = 0usize;
        let mut iou_threshold = 0f32;
        let mut score_threshold = None;
        if self.has[0] {
            let v: i64 =
                scalar(rest.next().context("missing max_output_boxes_per_class")?, "max_output_boxes_per_class")?;
            // As onnxruntime (and the ONNX spec): 0 or less selects nothing. torchvision
            // exports i64::MAX. (tract's own op reads 0 as "no limit".)
            max_output = usize::try_from(v.max(0)).unwrap_or(usize::MAX);
        }
        if self.has[1] {
            iou_threshold = scalar(rest.next().context("missing iou_threshold")?, "iou_threshold")?;
        }
        if self.has[2] {
            score_threshold = Some(scalar(rest.next().context("missing score_threshold")?, "score_threshold")?);
        }
        let p = NmsParams { format: self.format, max_output, iou_threshold, score_threshold };
        let boxes = inputs[0].to_plain_array_view::<f32>()?;
        let scores = inputs[1].to_plain_array_view::<f32>()?;
        let (b, n) = (boxes.shape()[0], boxes.shape()[1]);
        let c = scores.shape()[1];
        ensure!(
            scores.shape()[0] == b && scores.shape()[2] == n,
            "NonMaxSuppression: scores {:?} do not match boxes {:?}",
            scores.shape(),
            boxes.shape()
        );
        let boxes = boxes.as_standard_layout();
        let scores = scores.as_standard_layout();
        let (boxes, scores) = (boxes.as_slice().context("boxes")?, scores.as_slice().context("scores")?);
        let mut selected = Vec::new();
        for bi in 0..b {
            let bb = &boxes[bi * n * 4..(bi + 1) * n * 4];
            for ci in 0..c {
                let ss = &scores[(bi * c + ci) * n..(bi * c + ci + 1) * n];
                for k in nms(bb, ss, &p) {
                    selected.extend([bi as i64, ci as i64, k as i64]);
                }
            }
        }
        let k = selected.len() / 3;
        Ok(tvec![output(&[k, 3], selected)?])
    }
}

impl TypedOp for FastNms {
    fn output_facts(&self, _inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![i64::fact([self.selected.to_dim(), 3.to_dim()])])
    }

    as_op!();
}
