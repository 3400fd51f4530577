//! tract runtime of `RoiAlign`.

use tract_onnx::tract_hir::internal::*;

use super::RoiAlign;
use super::kernel::roi_align;
use crate::ops::tract_glue::{OnnxRules, TractKernel, input_slice, output};

impl TractKernel for RoiAlign {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![f32::fact([
            inputs[1].shape[0].clone(),
            inputs[0].shape[1].clone(),
            self.output_height.to_dim(),
            self.output_width.to_dim(),
        ])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let features = input_slice::<f32>(&inputs[0], Self::NAME, "X", 4)?;
        let rois = input_slice::<f32>(&inputs[1], Self::NAME, "rois", 2)?;
        let batch_indices = inputs[2].cast_to::<i64>()?;
        let batch_indices =
            input_slice::<i64>(&batch_indices.into_owned().into_tvalue(), Self::NAME, "batch_indices", 1)?.to_vec();
        let x = inputs[0].shape();
        let (n, c, h, w) = (x[0], x[1], x[2], x[3]);
        let r = batch_indices.len();
        let shape = [r, c, self.output_height, self.output_width];
        let mut out = vec![0f32; shape.iter().product()];
        roi_align(features, (n, c, h, w), rois, &batch_indices, &self.params(), &mut out)?;
        Ok(tvec![output(&shape, out)?])
    }
}
