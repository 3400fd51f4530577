//! tract runtime of `LayerNormLastAxis`.

use tract_onnx::tract_hir::internal::*;

use super::LayerNormLastAxis;
use super::kernel::layer_norm_rows;
use crate::ops::tract_glue::{TractKernel, output};

impl TractKernel for LayerNormLastAxis {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        ensure!(inputs[0].rank() >= 1, "LayerNormLastAxis: a scalar input");
        let shape: Vec<TDim> = inputs[0].shape.iter().cloned().collect();
        Ok(tvec![f32::fact(shape)])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        for (what, t) in [("input", x), ("scale", &inputs[1]), ("bias", &inputs[2])] {
            ensure!(t.datum_type() == f32::datum_type(), "LayerNormLastAxis: {what} is {:?}", t.datum_type());
        }
        let shape = x.shape();
        let cols = *shape.last().ok_or_else(|| format_err!("LayerNormLastAxis: a scalar input"))?;
        let rows = x.len().checked_div(cols).unwrap_or(0);
        let mut out = vec![0f32; x.len()];
        layer_norm_rows(
            x.try_as_plain_ram()?.as_slice::<f32>()?,
            rows,
            cols,
            inputs[1].try_as_plain_ram()?.as_slice::<f32>()?,
            inputs[2].try_as_plain_ram()?.as_slice::<f32>()?,
            self.epsilon(),
            &mut out,
        )?;
        Ok(tvec![output(shape, out)?])
    }
}
