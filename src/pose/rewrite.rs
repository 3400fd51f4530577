//! Load-time rewrites of the pose graph (ONNX protobuf, before tract parses it): standard
//! nodes tract runs slowly become `ai.tricons` nodes with the same results.
//!
//! * `ReduceMax` over one (non-negative) axis, f32 (PointNet++'s neighbour max-pool) ->
//!   `ReduceMaxAxis` ([`crate::ops::reduce_max`]): the same fold, bit for bit.
//! * `Resize` with mode `linear`, `half_pixel` coordinates, constant scales (1, 1, 2, 2),
//!   no sizes, no antialiasing or `exclude_outside` -> `BilinearUpsample2x`
//!   ([`crate::ops::upsample`]): the same taps and evaluation order, bit for bit.
//!
//! * `LayerNormalization` over the last axis with scale and bias, f32 statistics, one
//!   output -> `LayerNormLastAxis` ([`crate::ops::layer_norm`]): one pass per row, within
//!   a derived rounding bound of the expansion tract makes of the standard node.
//!
//! * `Softmax` over the last axis (`axis = -1`, or no attribute from opset 13 on) ->
//!   `SoftmaxLastAxis` ([`crate::ops::softmax`]): a vectorised exponential for every row
//!   length, within a derived rounding bound of the exact softmax.
//!
//! * The image decoder's per-pixel layers before the sampling of its map at the object's
//!   pixels run on those pixels only ([`super::early_gather`], `PixelGather`).
//!
//! Anything else is left alone; the report counts what was replaced.

use tract_onnx::pb::{GraphProto, ModelProto, NodeProto};

use crate::ops::proto::{self, a_float, a_int, attr, attr_i, attr_s};

/// Domain of the replacement nodes.
const DOMAIN: &str = "ai.tricons";

/// What [`rewrite`] replaced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RewriteReport {
    /// `ReduceMax` nodes now `ReduceMaxAxis`.
    pub reduce_max: usize,
    /// `Resize` nodes now `BilinearUpsample2x`.
    pub upsample: usize,
    /// Per-pixel decoder nodes now run on the sampled pixels ([`super::early_gather`]).
    pub early_gather: usize,
    /// `LayerNormalization` nodes now `LayerNormLastAxis`.
    pub layer_norm: usize,
    /// `Softmax` nodes now `SoftmaxLastAxis`.
    pub softmax: usize,
}

/// An f32 constant (initializer or `Constant` node) by name.
fn constant_f32(graph: &GraphProto, name: &str) -> Option<Vec<f32>> {
    proto::constant(graph, name).and_then(proto::tensor_f32)
}

/// `ReduceMaxAxis` for a `ReduceMax` with a single non-negative `axes` attribute (opset
/// <= 17 form) and no axes input.
fn reduce_max(node: &NodeProto) -> Option<NodeProto> {
    if node.op_type != "ReduceMax" || node.input.len() != 1 || node.output.len() != 1 {
        return None;
    }
    let axes = &attr(node, "axes")?.ints;
    let [axis] = axes.as_slice() else { return None };
    if *axis < 0 || attr_i(node, "noop_with_empty_axes", 0) != 0 {
        return None;
    }
    Some(NodeProto {
        name: node.name.clone(),
        op_type: "ReduceMaxAxis".into(),
        domain: DOMAIN.into(),
        input: node.input.clone(),
        output: node.output.clone(),
        attribute: vec![a_int("axis", *axis), a_int("keepdims", attr_i(node, "keepdims", 1))],
        ..Default::default()
    })
}

/// `LayerNormLastAxis` for a `LayerNormalization` over the last axis with scale and bias,
/// f32 statistics (`stash_type` 1) and no mean / inverse-deviation outputs.
fn layer_norm(node: &NodeProto) -> Option<NodeProto> {
    let only_y = node.output.len() == 1 || node.output[1..].iter().all(|o| o.is_empty());
    if node.op_type != "LayerNormalization" || node.input.len() != 3 || !only_y {
        return None;
    }
    if attr_i(node, "axis", -1) != -1 || attr_i(node, "stash_type", 1) != 1 {
        return None;
    }
    let epsilon = attr(node, "epsilon").map_or(1e-5, |a| a.f);
    Some(NodeProto {
        name: node.name.clone(),
        op_type: "LayerNormLastAxis".into(),
        domain: DOMAIN.into(),
        input: node.input.clone(),
        output: vec![node.output[0].clone()],
        attribute: vec![a_float("epsilon", epsilon)],
        ..Default::default()
    })
}

/// `SoftmaxLastAxis` for a `Softmax` over the last axis: `axis = -1` (the same in every
/// opset: before 13 the input is flattened to 2-D at the axis, which for the last one is
/// the last-axis softmax too), or no `axis` from opset 13 on (where -1 is the default).
fn softmax(node: &NodeProto, opset: i64) -> Option<NodeProto> {
    if node.op_type != "Softmax" || !node.domain.is_empty() || node.input.len() != 1 || node.output.len() != 1 {
        return None;
    }
    let last = match attr(node, "axis") {
        Some(a) => a.i == -1,
        None => opset >= 13,
    };
    last.then(|| NodeProto {
        name: node.name.clone(),
        op_type: "SoftmaxLastAxis".into(),
        domain: DOMAIN.into(),
        input: node.input.clone(),
        output: node.output.clone(),
        ..Default::default()
    })
}

/// A linear half-pixel `Resize` by constant scales (1, 1, 2, 2), no sizes.
pub(crate) fn is_bilinear_upsample2x(graph: &GraphProto, node: &NodeProto) -> bool {
    if node.op_type != "Resize" || node.output.len() != 1 {
        return false;
    }
    let plain = attr_s(node, "mode", "nearest") == "linear"
        && attr_s(node, "coordinate_transformation_mode", "half_pixel") == "half_pixel"
        && attr_i(node, "antialias", 0) == 0
        && attr_i(node, "exclude_outside", 0) == 0
        && attr_s(node, "keep_aspect_ratio_policy", "stretch") == "stretch"
        && attr(node, "axes").is_none();
    // inputs: X, roi (unused outside tf_crop_and_resize), scales, [sizes]
    let Some(scales) = node.input.get(2).filter(|s| !s.is_empty()) else { return false };
    let no_sizes = node.input.get(3).is_none_or(|s| s.is_empty());
    plain && no_sizes && constant_f32(graph, scales).is_some_and(|v| v == [1.0, 1.0, 2.0, 2.0])
}

/// `BilinearUpsample2x` for a linear half-pixel `Resize` by constant scales (1, 1, 2, 2).
fn upsample(graph: &GraphProto, node: &NodeProto) -> Option<NodeProto> {
    is_bilinear_upsample2x(graph, node).then(|| NodeProto {
        name: node.name.clone(),
        op_type: "BilinearUpsample2x".into(),
        domain: DOMAIN.into(),
        input: vec![node.input[0].clone()],
        output: node.output.clone(),
        ..Default::default()
    })
}

/// Apply the rewrites to `model` in place: the early pixel gather first (it drops the
/// `Resize` it samples through), then the layer normalisations and the node replacements.
pub fn rewrite(model: &mut ModelProto) -> RewriteReport {
    let early_gather = model.graph.as_mut().map_or(0, super::early_gather::gather_pixels_early);
    let layer_norm = replace_layer_norms(model);
    let softmax = replace_softmaxes(model);
    let report = RewriteReport { early_gather, layer_norm, softmax, ..replace_nodes(model) };
    if report != RewriteReport::default() {
        import_domain(model);
    }
    report
}

fn import_domain(model: &mut ModelProto) {
    if !model.opset_import.iter().any(|o| o.domain == DOMAIN) {
        model.opset_import.push(tract_onnx::pb::OperatorSetIdProto { domain: DOMAIN.into(), version: 1 });
    }
}

/// `LayerNormalization` -> `LayerNormLastAxis` where it applies; returns the count. The
/// results differ from tract's expansion of the standard node by rounding only
/// ([`crate::ops::layer_norm::kernel::error_bound`]).
pub fn replace_layer_norms(model: &mut ModelProto) -> usize {
    let Some(graph) = model.graph.as_mut() else { return 0 };
    let mut n = 0;
    for node in graph.node.iter_mut() {
        if let Some(new) = layer_norm(node) {
            *node = new;
            n += 1;
        }
    }
    if n > 0 {
        import_domain(model);
    }
    n
}

/// `Softmax` -> `SoftmaxLastAxis` where it applies; returns the count. The results are
/// within [`crate::ops::softmax::kernel::error_bounds`] of the exact softmax.
pub fn replace_softmaxes(model: &mut ModelProto) -> usize {
    let opset = model.opset_import.iter().find(|o| o.domain.is_empty()).map_or(1, |o| o.version);
    let Some(graph) = model.graph.as_mut() else { return 0 };
    let mut n = 0;
    for node in graph.node.iter_mut() {
        if let Some(new) = softmax(node, opset) {
            *node = new;
            n += 1;
        }
    }
    if n > 0 {
        import_domain(model);
    }
    n
}

/// Only the node-for-node replacements that keep the bits (`ReduceMaxAxis`,
/// `BilinearUpsample2x`).
pub fn replace_nodes(model: &mut ModelProto) -> RewriteReport {
    let mut report = RewriteReport::default();
    let Some(graph) = model.graph.as_mut() else { return report };
    let replaced: Vec<Option<NodeProto>> = graph
        .node
        .iter()
        .map(|n| {
            reduce_max(n)
                .inspect(|_| report.reduce_max += 1)
                .or_else(|| upsample(graph, n).inspect(|_| report.upsample += 1))
        })
        .collect();
    for (node, new) in graph.node.iter_mut().zip(replaced) {
        if let Some(new) = new {
            *node = new;
        }
    }
    if report != RewriteReport::default() {
        import_domain(model);
    }
    report
}
