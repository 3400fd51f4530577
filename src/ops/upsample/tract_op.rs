//! tract runtime of `BilinearUpsample2x`.

use tract_onnx::tract_hir::internal::*;

use super::BilinearUpsample2x;
use super::kernel::upsample2x_plane;
use crate::ops::tract_glue::{TractKernel, input_slice, output};

impl TractKernel for BilinearUpsample2x {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let s = &inputs[0].shape;
        ensure!(s.rank() == 4, "BilinearUpsample2x: input of rank {}", s.rank());
        Ok(tvec![f32::fact([s[0].clone(), s[1].clone(), s[2].clone() * 2, s[3].clone() * 2])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = input_slice::<f32>(&inputs[0], "BilinearUpsample2x", "x", 4)?;
        let shape = inputs[0].shape();
        let (planes, h, w) = (shape[0] * shape[1], shape[2], shape[3]);
        let mut out = vec![0f32; planes * 4 * h * w];
        let mut scratch = Vec::new();
        if h * w > 0 {
            for (src, dst) in x.chunks_exact(h * w).zip(out.chunks_exact_mut(4 * h * w)) {
                upsample2x_plane(src, h, w, &mut scratch, dst)?;
            }
        }
        Ok(tvec![output(&[shape[0], shape[1], 2 * h, 2 * w], out)?])
    }
}
