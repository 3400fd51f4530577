//! ONNX side and shape rules of `PixelGather`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `PixelGather(x (B, C, H, W) f32, choose (B, N) i64; upsample2x) -> (B, C, N, 1) f32`:
/// the values of `x` at the row-major pixel indices `choose`; with `upsample2x = 1`, those
/// of its bilinear x2 upsampling (ONNX `Resize` linear, `half_pixel`, scales (1, 1, 2, 2)),
/// `choose` then indexing the `(2H, 2W)` grid.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct PixelGather {
    /// Sample the x2 upsampling of the input instead of the input.
    pub upsample2x: bool,
}

/// Build the op from its node (attribute `upsample2x`, default 0).
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let upsample2x = node.get_attr_opt::<i64>("upsample2x")?.unwrap_or(0);
    ensure!(matches!(upsample2x, 0 | 1), "PixelGather {}: upsample2x must be 0 or 1, got {upsample2x}", node.name);
    expand_op(PixelGather { upsample2x: upsample2x == 1 })
}

onnx_rules!(PixelGather, "PixelGather", inputs: 2, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&inputs[1].datum_type, i64::datum_type())?;
    s.equals(&inputs[1].rank, 2)?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&inputs[1].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    s.equals(&outputs[0].shape[2], &inputs[1].shape[1])?;
    s.equals(&outputs[0].shape[3], 1.to_dim())
});

/// `ResampledPixelGather(x (B, C, h, w) f32, choose (B, N) i64, rows (H, h) f32, cols
/// (w, W) f32) -> (B, C, N, 1) f32`: the values of the resampled map
/// `MatMul(MatMul(rows, x), cols)` (B, C, H, W) at the row-major pixel indices `choose` of
/// its `(H, W)` grid, without computing that map.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ResampledPixelGather;

/// Build the op from its node (no attributes).
pub fn parse_resampled(_ctx: &ParsingContext, _node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    expand_op(ResampledPixelGather)
}

onnx_rules!(ResampledPixelGather, "ResampledPixelGather", inputs: 4, outputs: 1, |_op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&inputs[1].datum_type, i64::datum_type())?;
    s.equals(&inputs[1].rank, 2)?;
    for m in &inputs[2..4] {
        s.equals(&m.datum_type, f32::datum_type())?;
        s.equals(&m.rank, 2)?;
    }
    s.equals(&inputs[2].shape[1], &inputs[0].shape[2])?;
    s.equals(&inputs[3].shape[0], &inputs[0].shape[3])?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&inputs[1].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[0], &inputs[0].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    s.equals(&outputs[0].shape[2], &inputs[1].shape[1])?;
    s.equals(&outputs[0].shape[3], 1.to_dim())
});
