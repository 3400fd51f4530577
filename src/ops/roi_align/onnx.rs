//! ONNX parsing and shape rules of `RoiAlign`.

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use super::kernel::{PoolMode, RoiAlignParams};
use crate::ops::tract_glue::{expand_op, onnx_rules};

/// `RoiAlign(X (N, C, H, W), rois (R, 4), batch_indices (R,) i64) -> (R, C, oh, ow)`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct RoiAlign {
    /// Output bins, vertically.
    pub output_height: usize,
    /// Output bins, horizontally.
    pub output_width: usize,
    /// Samples per bin and axis (0 = adaptive).
    pub sampling_ratio: usize,
    /// Bits of the `f32` spatial scale (bits so the op is `Eq` and `Hash`).
    pub spatial_scale_bits: u32,
    /// `coordinate_transformation_mode == "half_pixel"`.
    pub half_pixel: bool,
    /// `mode`.
    pub mode: PoolMode,
}

impl RoiAlign {
    /// The kernel's parameters.
    pub fn params(&self) -> RoiAlignParams {
        RoiAlignParams {
            output_height: self.output_height,
            output_width: self.output_width,
            sampling_ratio: self.sampling_ratio,
            spatial_scale: f32::from_bits(self.spatial_scale_bits),
            half_pixel: self.half_pixel,
            mode: self.mode,
        }
    }
}

/// Build the op from its ONNX node. Before opset 16 there is no
/// `coordinate_transformation_mode` and the behaviour is `output_half_pixel`;
/// from 16 the default is `half_pixel`.
pub fn parse(ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let positive = |name: &str, default: i64| -> TractResult<usize> {
        let v: i64 = node.get_attr_opt(name)?.unwrap_or(default);
        ensure!(v >= 0, "RoiAlign {}: attribute {name} must be >= 0, got {v}", node.name);
        Ok(v as usize)
    };
    let output_height = positive("output_height", 1)?;
    let output_width = positive("output_width", 1)?;
    let sampling_ratio = positive("sampling_ratio", 0)?;
    ensure!(output_height > 0 && output_width > 0, "RoiAlign {}: output size must be positive", node.name);
    let spatial_scale: f32 = node.get_attr_opt("spatial_scale")?.unwrap_or(1.0);
    ensure!(spatial_scale.is_finite(), "RoiAlign {}: spatial_scale is not finite", node.name);
    let default_mode = if ctx.onnx_operator_set_version >= 16 { "half_pixel" } else { "output_half_pixel" };
    let ctm: String = node.get_attr_opt("coordinate_transformation_mode")?.unwrap_or_else(|| default_mode.to_string());
    let half_pixel = match ctm.as_str() {
        "half_pixel" => true,
        "output_half_pixel" => false,
        other => bail!("RoiAlign {}: unknown coordinate_transformation_mode {other:?}", node.name),
    };
    let mode: String = node.get_attr_opt("mode")?.unwrap_or_else(|| "avg".to_string());
    let mode = match mode.as_str() {
        "avg" => PoolMode::Avg,
        "max" => PoolMode::Max,
        other => bail!("RoiAlign {}: unknown mode {other:?}", node.name),
    };
    expand_op(RoiAlign {
        output_height,
        output_width,
        sampling_ratio,
        spatial_scale_bits: spatial_scale.to_bits(),
        half_pixel,
        mode,
    })
}

onnx_rules!(RoiAlign, "RoiAlign", inputs: 3, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, f32::datum_type())?;
    s.equals(&inputs[0].rank, 4)?;
    s.equals(&inputs[1].datum_type, f32::datum_type())?;
    s.equals(&inputs[1].rank, 2)?;
    s.equals(&inputs[1].shape[1], 4.to_dim())?;
    // batch_indices: int64 in the file; tract may type a shape-derived Cast as TDim.
    s.equals(&inputs[2].rank, 1)?;
    s.equals(&inputs[2].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].datum_type, f32::datum_type())?;
    s.equals(&outputs[0].rank, 4)?;
    s.equals(&outputs[0].shape[0], &inputs[1].shape[0])?;
    s.equals(&outputs[0].shape[1], &inputs[0].shape[1])?;
    s.equals(&outputs[0].shape[2], op.output_height.to_dim())?;
    s.equals(&outputs[0].shape[3], op.output_width.to_dim())
});
