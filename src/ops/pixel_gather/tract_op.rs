//! tract runtime of `PixelGather` and `ResampledPixelGather`.

use tract_onnx::tract_hir::internal::*;

use super::kernel::{gather_pixels, gather_resampled_pixels, gather_upsampled_pixels};
use super::{PixelGather, ResampledPixelGather};
use crate::ops::tract_glue::{TractKernel, input_slice, output};

impl TractKernel for PixelGather {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let (x, choose) = (&inputs[0].shape, &inputs[1].shape);
        ensure!(x.rank() == 4 && choose.rank() == 2, "PixelGather: inputs of rank {} and {}", x.rank(), choose.rank());
        Ok(tvec![f32::fact([x[0].clone(), x[1].clone(), choose[1].clone(), 1.to_dim()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = input_slice::<f32>(&inputs[0], "PixelGather", "x", 4)?;
        let choose = input_slice::<i64>(&inputs[1], "PixelGather", "choose", 2)?;
        let (s, cs) = (inputs[0].shape(), inputs[1].shape());
        let (b, c, h, w, n) = (s[0], s[1], s[2], s[3], cs[1]);
        ensure!(cs[0] == b, "PixelGather: batch of choose {} != x {b}", cs[0]);
        let kernel = if self.upsample2x { gather_upsampled_pixels } else { gather_pixels };
        let mut out = vec![0f32; b * c * n];
        for bi in 0..b {
            kernel(
                &x[bi * c * h * w..(bi + 1) * c * h * w],
                c,
                h,
                w,
                &choose[bi * n..(bi + 1) * n],
                &mut out[bi * c * n..(bi + 1) * c * n],
            )?;
        }
        Ok(tvec![output(&[b, c, n, 1], out)?])
    }
}

impl TractKernel for ResampledPixelGather {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let (x, choose) = (&inputs[0].shape, &inputs[1].shape);
        ensure!(
            x.rank() == 4 && choose.rank() == 2,
            "ResampledPixelGather: inputs of rank {} and {}",
            x.rank(),
            choose.rank()
        );
        Ok(tvec![f32::fact([x[0].clone(), x[1].clone(), choose[1].clone(), 1.to_dim()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        const OP: &str = "ResampledPixelGather";
        let x = input_slice::<f32>(&inputs[0], OP, "x", 4)?;
        let choose = input_slice::<i64>(&inputs[1], OP, "choose", 2)?;
        let rows = input_slice::<f32>(&inputs[2], OP, "rows", 2)?;
        let cols = input_slice::<f32>(&inputs[3], OP, "cols", 2)?;
        let (s, cs) = (inputs[0].shape(), inputs[1].shape());
        let (b, c, h, w, n) = (s[0], s[1], s[2], s[3], cs[1]);
        let (big_h, big_w) = (inputs[2].shape()[0], inputs[3].shape()[1]);
        ensure!(cs[0] == b, "{OP}: batch of choose {} != x {b}", cs[0]);
        let mut out = vec![0f32; b * c * n];
        for bi in 0..b {
            gather_resampled_pixels(
                &x[bi * c * h * w..(bi + 1) * c * h * w],
                (c, h, w),
                rows,
                cols,
                (big_h, big_w),
                &choose[bi * n..(bi + 1) * n],
                &mut out[bi * c * n..(bi + 1) * c * n],
            )?;
        }
        Ok(tvec![output(&[b, c, n, 1], out)?])
    }
}
