//! tract runtime of `DepthwiseConv2d`.

use tract_onnx::tract_hir::internal::*;

use super::DepthwiseConv2d;
use super::kernel::depthwise;
use crate::ops::tract_glue::{TractKernel, input_slice, output};

impl TractKernel for DepthwiseConv2d {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let s = &inputs[0].shape;
        let [ho, wo] = self.attrs.output_spatial(&format!("DepthwiseConv2d {}", self.name), s)?;
        Ok(tvec![f32::fact([s[0].clone(), self.channels.to_dim(), ho, wo])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = input_slice::<f32>(&inputs[0], "DepthwiseConv2d", "x", 4)?;
        let shape = inputs[0].shape();
        let (b, c, h, w) = (shape[0], shape[1], shape[2], shape[3]);
        ensure!(c == self.channels, "DepthwiseConv2d {}: {c} input channels, expected {}", self.name, self.channels);
        let g = self.attrs.geometry(self.channels, h, w);
        let (ho, wo) = g.output_hw()?;
        let mut out = vec![0f32; b * c * ho * wo];
        if c * h * w > 0 && c * ho * wo > 0 {
            for (src, dst) in x.chunks_exact(c * h * w).zip(out.chunks_exact_mut(c * ho * wo)) {
                depthwise(src, &self.weight, &self.bias, &g, dst)?;
            }
        }
        Ok(tvec![output(&[b, c, ho, wo], out)?])
    }
}
