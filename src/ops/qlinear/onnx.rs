//! ONNX parsing and shape rules of `QLinear` and the attributes it shares with `QConv`.

use std::sync::Arc;

use tract_onnx::model::ParsingContext;
use tract_onnx::pb::NodeProto;
use tract_onnx::tract_hir::internal::*;

use crate::ops::tract_glue::{expand_op, onnx_rules};
use crate::quant::{Int8Layer, OutputFold, QParams};

/// `QLinear(X (..., K) f32 or u8) -> (..., N) f32 or u8`.
#[derive(Clone, Debug)]
pub struct QLinear {
    /// The node's name (identity for tract's op comparisons).
    pub name: String,
    /// The fused layer.
    pub layer: Arc<Int8Layer>,
    /// The input arrives as u7 (`u8`).
    pub input_u7: bool,
    /// The input must be rank 2 (a normalisation over axis 1 was folded).
    pub rank2: bool,
}

impl PartialEq for QLinear {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && Arc::ptr_eq(&self.layer, &other.layer)
    }
}
impl Eq for QLinear {}
impl std::hash::Hash for QLinear {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name.hash(state)
    }
}

/// The layer attributes common to `QLinear` and `QConv`: `weight` (float tensor
/// `[k, n]`), `post_scale` and `bias` (floats `[n]`), `relu`, `x_scale`/`x_zero_point`,
/// optional `y_scale`/`y_zero_point` (u7 output), `input_u7`.
pub fn parse_layer(node: &NodeProto) -> TractResult<(Int8Layer, bool)> {
    let name = &node.name;
    let w = node.get_attr::<&tract_onnx::pb::TensorProto>("weight")?;
    ensure!(w.dims.len() == 2, "{name}: weight must be [k, n], has dims {:?}", w.dims);
    let (k, n) = (w.dims[0] as usize, w.dims[1] as usize);
    ensure!(w.raw_data.len() == 4 * k * n, "{name}: weight holds {} bytes, expected {}", w.raw_data.len(), 4 * k * n);
    let weight: Vec<f32> = w.raw_data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    let post_scale: Vec<f32> = node.get_attr_vec("post_scale")?;
    let bias: Vec<f32> = node.get_attr_vec("bias")?;
    let q = |prefix: &str| -> TractResult<Option<QParams>> {
        let scale: Option<f32> = node.get_attr_opt(&format!("{prefix}_scale"))?;
        let zp: Option<i64> = node.get_attr_opt(&format!("{prefix}_zero_point"))?;
        Ok(match (scale, zp) {
            (Some(scale), Some(zp)) => {
                ensure!(scale.is_finite() && scale > 0.0 && (0..=127).contains(&zp), "{name}: bad {prefix} params");
                Some(QParams { scale, zero_point: zp as i32 })
            }
            _ => None,
        })
    };
    let input = q("x")?.ok_or_else(|| format_err!("{name}: x_scale and x_zero_point are required"))?;
    let output = q("y")?;
    let relu = node.get_attr_opt::<i64>("relu")?.unwrap_or(0) != 0;
    let input_u7 = node.get_attr_opt::<i64>("input_u7")?.unwrap_or(0) != 0;
    let fold = OutputFold { post_scale: &post_scale, bias: &bias, relu };
    let layer = Int8Layer::new(&weight, k, n, &fold, input, output).map_err(|e| format_err!("{name}: {e}"))?;
    Ok((layer, input_u7))
}

/// Build the op from its node.
pub fn parse(_ctx: &ParsingContext, node: &NodeProto) -> TractResult<(Box<dyn InferenceOp>, Vec<String>)> {
    let (layer, input_u7) = parse_layer(node)?;
    let rank2 = node.get_attr_opt::<i64>("rank2")?.unwrap_or(0) != 0;
    expand_op(QLinear { name: node.name.clone(), layer: Arc::new(layer), input_u7, rank2 })
}

/// `f32`, or `u8` for u7 activations.
pub fn activation_type(u7: bool) -> DatumType {
    if u7 { u8::datum_type() } else { f32::datum_type() }
}

onnx_rules!(QLinear, "QLinear", inputs: 1, outputs: 1, |op, s, inputs, outputs| {
    s.equals(&inputs[0].datum_type, activation_type(op.input_u7))?;
    s.equals(&outputs[0].datum_type, activation_type(op.layer.output_params().is_some()))?;
    s.equals(&inputs[0].rank, &outputs[0].rank)?;
    if op.rank2 {
        s.equals(&inputs[0].rank, 2)?;
    }
    let (k, n) = (op.layer.k(), op.layer.n());
    s.given(&inputs[0].rank, move |s, rank| {
        let r = rank as usize;
        s.equals(&inputs[0].shape[r - 1], k.to_dim())?;
        for i in 0..r - 1 {
            s.equals(&inputs[0].shape[i], &outputs[0].shape[i])?;
        }
        s.equals(&outputs[0].shape[r - 1], n.to_dim())
    })
});
