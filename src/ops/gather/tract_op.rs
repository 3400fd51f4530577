//! tract runtime of `GatherPoints` and `GroupPoints`.

use tract_onnx::tract_hir::internal::*;

use super::kernel::{gather_points, group_points};
use super::{GatherPoints, GroupPoints};
use crate::ops::OpResult;
use crate::ops::tract_glue::{TractKernel, input_slice, output};

type GatherKernel = fn(&[f32], usize, &[i64], &mut [f32]) -> OpResult;

/// Output facts: (B, C) of the features, then the index dims after B.
fn facts(inputs: &[&TypedFact]) -> TVec<TypedFact> {
    let mut shape: TVec<TDim> = tvec![inputs[0].shape[0].clone(), inputs[0].shape[1].clone()];
    shape.extend(inputs[1].shape.iter().skip(1).cloned());
    tvec![f32::fact(shape)]
}

fn eval(op: &str, kernel: GatherKernel, idx_rank: usize, inputs: &TVec<TValue>) -> TractResult<TVec<TValue>> {
    let features = input_slice::<f32>(&inputs[0], op, "features", 3)?;
    let idx = input_slice::<i64>(&inputs[1], op, "idx", idx_rank)?;
    let (b, c, n) = (inputs[0].shape()[0], inputs[0].shape()[1], inputs[0].shape()[2]);
    ensure!(inputs[1].shape()[0] == b, "{op}: batch of idx {} != features {b}", inputs[1].shape()[0]);
    let per_item: usize = inputs[1].shape()[1..].iter().product();
    let mut out = vec![0f32; b * c * per_item];
    for bi in 0..b {
        kernel(
            &features[bi * c * n..(bi + 1) * c * n],
            n,
            &idx[bi * per_item..(bi + 1) * per_item],
            &mut out[bi * c * per_item..(bi + 1) * c * per_item],
        )?;
    }
    let mut shape = vec![b, c];
    shape.extend(&inputs[1].shape()[1..]);
    Ok(tvec![output(&shape, out)?])
}

impl TractKernel for GatherPoints {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(facts(inputs))
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        eval("GatherPoints", gather_points, 2, &inputs)
    }
}

impl TractKernel for GroupPoints {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(facts(inputs))
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        eval("GroupPoints", group_points, 3, &inputs)
    }
}
