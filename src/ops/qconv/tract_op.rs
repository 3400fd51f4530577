//! tract runtime of `QConv`.

use tract_onnx::tract_hir::internal::*;

use super::QConv;
use super::kernel::{ConvGeometry, qconv};
use crate::ops::tract_glue::{OnnxRules, TractKernel, output};
use crate::quant::LayerInput;

impl QConv {
    fn geometry(&self, c_in: usize, h: usize, w: usize) -> ConvGeometry {
        ConvGeometry {
            c_in,
            h,
            w,
            kernel: self.kernel,
            strides: self.strides,
            pads: self.pads,
            dilations: self.dilations,
        }
    }
}

impl TractKernel for QConv {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let s = &inputs[0].shape;
        ensure!(s.len() == 4, "QConv {}: input rank {}, expected 4", self.name, s.len());
        let spatial = |axis: usize| -> TractResult<TDim> {
            let d = s[2 + axis].to_usize().map_err(|_| format_err!("QConv {}: symbolic spatial size", self.name))?;
            let len =
                self.out_len(axis, d).ok_or_else(|| format_err!("QConv {}: kernel larger than input", self.name))?;
            Ok(len.to_dim())
        };
        Ok(tvec![f32::fact([s[0].clone(), self.conv.layer().n().to_dim(), spatial(0)?, spatial(1)?])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        ensure!(x.rank() == 4, "{}: input rank {}, expected 4", Self::NAME, x.rank());
        let (b, c, h, w) = (x.shape()[0], x.shape()[1], x.shape()[2], x.shape()[3]);
        let g = self.geometry(c, h, w);
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
