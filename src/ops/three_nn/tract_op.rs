//! tract runtime of `ThreeNN` and `ThreeInterpolate`.

use tract_onnx::tract_hir::internal::*;

use super::kernel::{NEIGHBOURS, three_interpolate, three_nn};
use super::{ThreeInterpolate, ThreeNN};
use crate::ops::tract_glue::{OnnxRules, TractKernel, input_slice, output};

impl TractKernel for ThreeNN {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let shape = [inputs[0].shape[0].clone(), inputs[0].shape[1].clone(), NEIGHBOURS.to_dim()];
        Ok(tvec![f32::fact(shape.clone()), i64::fact(shape)])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let unknown = input_slice::<f32>(&inputs[0], Self::NAME, "unknown", 3)?;
        let known = input_slice::<f32>(&inputs[1], Self::NAME, "known", 3)?;
        let (b, n, m) = (inputs[0].shape()[0], inputs[0].shape()[1], inputs[1].shape()[1]);
        ensure!(inputs[1].shape()[0] == b, "ThreeNN: batch of known {} != unknown {b}", inputs[1].shape()[0]);
        let (mut dist, mut idx) = (vec![0f32; b * n * 3], vec![0i64; b * n * 3]);
        for bi in 0..b {
            three_nn(
                &unknown[bi * n * 3..(bi + 1) * n * 3],
                &known[bi * m * 3..(bi + 1) * m * 3],
                &mut dist[bi * n * 3..(bi + 1) * n * 3],
                &mut idx[bi * n * 3..(bi + 1) * n * 3],
            )?;
        }
        Ok(tvec![output(&[b, n, 3], dist)?, output(&[b, n, 3], idx)?])
    }
}

impl TractKernel for ThreeInterpolate {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec![f32::fact([inputs[0].shape[0].clone(), inputs[0].shape[1].clone(), inputs[1].shape[1].clone()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let features = input_slice::<f32>(&inputs[0], Self::NAME, "features", 3)?;
        let idx = input_slice::<i64>(&inputs[1], Self::NAME, "idx", 3)?;
        let weight = input_slice::<f32>(&inputs[2], Self::NAME, "weight", 3)?;
        let (b, c, m) = (inputs[0].shape()[0], inputs[0].shape()[1], inputs[0].shape()[2]);
        let n = inputs[1].shape()[1];
        ensure!(
            inputs[1].shape()[0] == b && inputs[2].shape() == inputs[1].shape(),
            "ThreeInterpolate: idx {:?} and weight {:?} do not match features {:?}",
            inputs[1].shape(),
            inputs[2].shape(),
            inputs[0].shape()
        );
        let mut out = vec![0f32; b * c * n];
        for bi in 0..b {
            three_interpolate(
                &features[bi * c * m..(bi + 1) * c * m],
                m,
                &idx[bi * n * 3..(bi + 1) * n * 3],
                &weight[bi * n * 3..(bi + 1) * n * 3],
                &mut out[bi * c * n..(bi + 1) * c * n],
            )?;
        }
        Ok(tvec![output(&[b, c, n], out)?])
    }
}
