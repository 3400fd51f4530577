//! tract runtime of `QConv`.

use tract_onnx::tract_hir::internal::*;

use super::QConv;
use super::kernel::qconv;
use crate::ops::tract_glue::{OnnxRules, TractKernel, output};
use crate::quant::LayerInput;

impl TractKernel for QConv {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let s = &inputs[0].shape;
        let [ho, wo] = self.attrs.output_spatial(&format!("QConv {}", self.name), s)?;
        Ok(tvec![f32::fact([s[0].clone(), self.conv.layer().n().to_dim(), ho, wo])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        ensure!(x.rank() == 4, "{}: input rank {}, expected 4", Self::NAME, x.rank());
        let (b, c, h, w) = (x.shape()[0], x.shape()[1], x.shape()[2], x.shape()[3]);
        let g = self.attrs.geometry(c, h, w);
        let (ho, wo) = g.output_hw()?;
        let n = self.conv.layer().n();
        let mut out = vec![0f32; b * n * ho * wo];
        let image = c * h * w;
        for (bi, o) in out.chunks_exact_mut(n * ho * wo).enumerate() {
            let input = if self.input_u7 {
                LayerInput::U7(&x.try_as_plain_ram()?.as_slice::<u8>()?[bi * image..(bi + 1) * image])
            } else {
                LayerInput::F32(&x.try_as_plain_ram()?.as_slice::<f32>()?[bi * image..(bi + 1) * image])
            };
            qconv(&self.conv, input, &g, o)?;
        }
        Ok(tvec![output(&[b, n, ho, wo], out)?])
    }
}
