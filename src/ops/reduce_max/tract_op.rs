//! tract runtime of `ReduceMaxAxis`.

use tract_onnx::tract_hir::internal::*;

use super::ReduceMaxAxis;
use super::kernel::reduce_max_axis;
use crate::ops::tract_glue::{TractKernel, output};

impl ReduceMaxAxis {
    fn out_shape<D: Clone + From<usize>>(&self, shape: &[D]) -> TVec<D> {
        let mut out: TVec<D> = shape.into();
        if self.keepdims {
            out[self.axis] = D::from(1);
        } else {
            out.remove(self.axis);
        }
        out
    }
}

impl TractKernel for ReduceMaxAxis {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        ensure!(self.axis < inputs[0].rank(), "ReduceMaxAxis: axis {} of a rank-{} input", self.axis, inputs[0].rank());
        let shape: Vec<TDim> = inputs[0].shape.iter().cloned().collect();
        Ok(tvec![f32::fact(self.out_shape(&shape))])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        ensure!(x.datum_type() == f32::datum_type(), "ReduceMaxAxis: input is {:?}", x.datum_type());
        let shape = x.shape();
        ensure!(self.axis < shape.len(), "ReduceMaxAxis: axis {} of a rank-{} input", self.axis, shape.len());
        let outer: usize = shape[..self.axis].iter().product();
        let inner: usize = shape[self.axis + 1..].iter().product();
        let mut out = vec![0f32; outer * inner];
        reduce_max_axis(x.try_as_plain_ram()?.as_slice::<f32>()?, outer, shape[self.axis], inner, &mut out)?;
        Ok(tvec![output(&self.out_shape(shape), out)?])
    }
}
