//! tract runtime of `QLinear`.

use tract_onnx::tract_hir::internal::*;

use super::QLinear;
use super::onnx::activation_type;
use crate::ops::tract_glue::{OnnxRules, TractKernel, output};
use crate::quant::{LayerInput, LayerOutput};

impl TractKernel for QLinear {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let mut shape: TVec<TDim> = inputs[0].shape.iter().cloned().collect();
        ensure!(!shape.is_empty(), "QLinear {}: scalar input", self.name);
        ensure!(!self.rank2 || shape.len() == 2, "QLinear {}: a folded normalisation needs a rank-2 input", self.name);
        *shape.last_mut().unwrap_or(&mut TDim::from(0)) = self.layer.n().to_dim();
        Ok(tvec![activation_type(self.layer.output_params().is_some()).fact(shape)])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        let (k, n) = (self.layer.k(), self.layer.n());
        ensure!(
            x.rank() >= 1 && x.shape()[x.rank() - 1] == k,
            "{}: input {:?}, expected (..., {k})",
            Self::NAME,
            x.shape()
        );
        let m = x.len() / k;
        let mut shape: Vec<usize> = x.shape().to_vec();
        shape[x.rank() - 1] = n;
        let input = if self.input_u7 {
            LayerInput::U7(x.try_as_plain_ram()?.as_slice::<u8>()?)
        } else {
            LayerInput::F32(x.try_as_plain_ram()?.as_slice::<f32>()?)
        };
        let err = |e| format_err!("QLinear {}: {e}", self.name);
        if self.layer.output_params().is_some() {
            let mut out = vec![0u8; m * n];
            self.layer.run(input, m, LayerOutput::U7(&mut out)).map_err(err)?;
            Ok(tvec![output(&shape, out)?])
        } else {
            let mut out = vec![0f32; m * n];
            self.layer.run(input, m, LayerOutput::F32(&mut out)).map_err(err)?;
            Ok(tvec![output(&shape, out)?])
        }
    }
}
