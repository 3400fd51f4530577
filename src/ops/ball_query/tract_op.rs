//! tract runtime of `BallQuery`.

use tract_onnx::tract_hir::internal::*;

use super::BallQuery;
use super::kernel::ball_query;
use crate::ops::tract_glue::{OnnxRules, TractKernel, input_slice, output};

impl TractKernel for BallQuery {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![i64::fact([inputs[1].shape[0].clone(), inputs[1].shape[1].clone(), self.nsample.to_dim()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let xyz = input_slice::<f32>(&inputs[0], Self::NAME, "xyz", 3)?;
        let centres = input_slice::<f32>(&inputs[1], Self::NAME, "new_xyz", 3)?;
        let (b, n, s) = (inputs[0].shape()[0], inputs[0].shape()[1], inputs[1].shape()[1]);
        ensure!(inputs[1].shape()[0] == b, "BallQuery: batch of new_xyz {} != xyz {b}", inputs[1].shape()[0]);
        let mut idx = vec![0i64; b * s * self.nsample];
        for bi in 0..b {
            ball_query(
                &xyz[bi * n * 3..(bi + 1) * n * 3],
                &centres[bi * s * 3..(bi + 1) * s * 3],
                self.radius(),
                self.nsample,
                &mut idx[bi * s * self.nsample..(bi + 1) * s * self.nsample],
            )?;
        }
        Ok(tvec![output(&[b, s, self.nsample], idx)?])
    }
}
