//! tract runtime of `Resize2d`.

use tract_onnx::tract_hir::internal::*;

use super::Resize2d;
use super::kernel::{resize_columns, resize_plane};
use crate::ops::tract_glue::{TractKernel, input_slice, output};

impl TractKernel for Resize2d {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let s = &inputs[0].shape;
        ensure!(s.rank() == 4, "Resize2d: input of rank {}", s.rank());
        Ok(tvec![f32::fact([s[0].clone(), s[1].clone(), self.out_h.to_dim(), self.out_w.to_dim()])])
    }

    fn eval(&self, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = input_slice::<f32>(&inputs[0], "Resize2d", "x", 4)?;
        let shape = inputs[0].shape();
        let (planes, h, w) = (shape[0] * shape[1], shape[2], shape[3]);
        let (ho, wo) = (self.out_h, self.out_w);
        let mut out = vec![0f32; planes * ho * wo];
        if h * w > 0 && ho * wo > 0 {
            let columns = resize_columns(self.mode, w, wo);
            for (src, dst) in x.chunks_exact(h * w).zip(out.chunks_exact_mut(ho * wo)) {
                resize_plane(self.mode, src, [h, w], dst, [ho, wo], &columns)?;
            }
        }
        Ok(tvec![output(&[shape[0], shape[1], ho, wo], out)?])
    }
}
