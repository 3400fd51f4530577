//! tract runtime of `FurthestPointSample`.

use tract_onnx::tract_hir::internal::*;

use super::FurthestPointSample;
use super::kernel::furthest_point_sample;
use crate::ops::tract_glue::{OnnxRules, TractKernel, input_slice, output};

impl TractKernel for FurthestPointSample {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![i64::fact([inputs[0].shape[0].clone(), self.npoint.to_dim()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let xyz = input_slice::<f32>(&inputs[0], Self::NAME, "xyz", 3)?;
        let (b, n) = (inputs[0].shape()[0], inputs[0].shape()[1]);
        let mut idx = vec![0i64; b * self.npoint];
        if n > 0 {
            for (x, o) in xyz.chunks_exact(n * 3).zip(idx.chunks_exact_mut(self.npoint)) {
                furthest_point_sample(x, self.npoint, o)?;
            }
        }
        Ok(tvec![output(&[b, self.npoint], idx)?])
    }
}
