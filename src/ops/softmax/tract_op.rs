//! tract runtime of `SoftmaxLastAxis`: the rows are normalised in the input's own buffer.

use tract_onnx::tract_hir::internal::*;

use super::SoftmaxLastAxis;
use super::kernel::softmax_rows;
use crate::ops::tract_glue::TractKernel;

impl TractKernel for SoftmaxLastAxis {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        ensure!(inputs[0].rank() >= 1, "SoftmaxLastAxis: a scalar input");
        let shape: Vec<TDim> = inputs[0].shape.iter().cloned().collect();
        Ok(tvec![f32::fact(shape)])
    }

    fn eval(&self, mut inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = inputs.remove(0);
        ensure!(x.datum_type() == f32::datum_type(), "SoftmaxLastAxis: input is {:?}", x.datum_type());
        let cols = *x.shape().last().ok_or_else(|| format_err!("SoftmaxLastAxis: a scalar input"))?;
        let mut t = x.into_tensor();
        softmax_rows(t.try_as_plain_ram_mut()?.as_slice_mut::<f32>()?, cols)?;
        Ok(tvec![t.into_tvalue()])
    }
}
