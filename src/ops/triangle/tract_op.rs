//! tract runtime of `TriangleDescriptor`.

use tract_onnx::tract_hir::internal::*;

use super::TriangleDescriptor;
use super::kernel::{triangle_count, triangle_descriptor};
use crate::ops::tract_glue::{OnnxRules, TractKernel, input_slice, output};

impl TractKernel for TriangleDescriptor {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let (b, m) = (inputs[0].shape[0].clone(), inputs[0].shape[1].clone());
        Ok(tvec![
            f32::fact([b.clone(), m.clone(), triangle_count(self.k).to_dim(), 3.to_dim()]),
            i64::fact([b, m, self.k.to_dim()])
        ])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let query = input_slice::<f32>(&inputs[0], Self::NAME, "query", 3)?;
        let points = input_slice::<f32>(&inputs[1], Self::NAME, "points", 3)?;
        let (b, m, n) = (inputs[0].shape()[0], inputs[0].shape()[1], inputs[1].shape()[1]);
        ensure!(inputs[1].shape()[0] == b, "TriangleDescriptor: batch of points {} != query {b}", inputs[1].shape()[0]);
        let (k, t) = (self.k, triangle_count(self.k));
        let (mut phi, mut knn) = (vec![0f32; b * m * t * 3], vec![0i64; b * m * k]);
        for bi in 0..b {
            triangle_descriptor(
                &query[bi * m * 3..(bi + 1) * m * 3],
                &points[bi * n * 3..(bi + 1) * n * 3],
                k,
                &mut phi[bi * m * t * 3..(bi + 1) * m * t * 3],
                &mut knn[bi * m * k..(bi + 1) * m * k],
            )?;
        }
        Ok(tvec![output(&[b, m, t, 3], phi)?, output(&[b, m, k], knn)?])
    }
}
