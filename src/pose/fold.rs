//! Load-time folds on the ONNX protobuf, before tract parses it: algebra tract's own
//! passes never do.
//!
//! **Batch normalisation into the product before it** (tract's einsum declutter runs
//! first and keeps the normalisation as a separate per-channel multiply and add):
//!
//! * `MatMul` (constant rank-2 weight) or `Gemm` (constant `B`, `transA = 0`), with an
//!   optional constant bias `Add`, then `BatchNormalization` -> one `Gemm` whose weight
//!   columns are scaled by `gamma / sqrt(var + eps)` and whose bias is the normalised
//!   bias. `Gemm` only takes rank-2 inputs, where the normalisation's channel axis (1)
//!   is the product's last axis: a graph where the input is not rank 2 fails to type,
//!   and the caller loads it unfolded ([`crate::pose::PoseEstimator`] does).
//! * `Conv` (constant weight, `group = 1`) then `BatchNormalization` -> the `Conv` with
//!   each output channel's filter scaled and its bias normalised.
//!
//! The chains are the ones int8 quantization fuses ([`crate::quant::rewrite::candidates`]),
//! so a node already replaced by an int8 node is not seen again. The folded graph differs
//! from the unfolded one only by rounding (tested on the golden fixtures: relative error
//! <= 1e-5).
//!
//! **A mean taken before the product it follows** ([`move_means_before_products`]): a
//! mean over an axis the product does not contract commutes with it,
//! `mean_a(X W + b) = mean_a(X) W + b`, so the product runs on one row where it ran on
//! every row of the axis. The PIGA geometric encoders end this way (an MLP over each
//! keypoint's 28 or 120 triangles, then their mean): their last product shrinks by that
//! factor. The protobuf does not give ranks, so the moved mean keeps its axis
//! (`keepdims = 1`) and a `Squeeze` drops it after the bias: had the axis been the
//! contracted one, the product of a length-1 axis with a weight of `K > 1` rows fails to
//! type, and the caller loads the graph without the folds (as for a `Gemm` above); a
//! weight of one row is left alone. Rounding only (tested like the batch normalisation).

use std::collections::HashMap;

use tract_onnx::pb::{GraphProto, ModelProto, NodeProto, TensorProto, tensor_proto};

use crate::ops::proto::{self, a_ints, attr, attr_i, constant, i64_tensor, tensor_i64};
use crate::quant::rewrite::{Candidate, Constants, batch_norm, bias_vector, candidates, weight_matrix};

/// What [`fold`] folded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FoldReport {
    /// `BatchNormalization` nodes folded into the weights before them.
    pub batch_norms: usize,
    /// Bias `Add` nodes folded with them.
    pub bias_adds: usize,
    /// `ReduceMean` nodes moved before the product they followed.
    pub means_moved: usize,
}

/// Every fold of this module: batch normalisations, then means.
pub fn fold(model: &mut ModelProto) -> FoldReport {
    let report = fold_batch_norms(model);
    FoldReport { means_moved: move_means_before_products(model), ..report }
}

fn f32_tensor(name: String, dims: &[usize], values: &[f32]) -> TensorProto {
    TensorProto {
        name,
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: tensor_proto::DataType::Float as i32,
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    }
}

/// The followers to fold: the chain up to and including its `BatchNormalization`.
fn folded_prefix(c: &Candidate) -> Option<&[(String, usize)]> {
    let k = c.chain.iter().position(|(op, _)| op == "BatchNormalization")?;
    Some(&c.chain[..=k])
}

/// The replacement node and its two new constants, or `None` to leave the chain alone.
fn fold_one(graph: &GraphProto, consts: &Constants, c: &Candidate) -> Option<(NodeProto, [TensorProto; 2])> {
    if c.unsupported.is_some() {
        return None;
    }
    let chain = folded_prefix(c)?;
    let node = &graph.node[c.index];
    let wm = weight_matrix(node, consts).ok()??;
    let mut bias = wm.bias.clone();
    let mut scale = vec![1f32; wm.n];
    for (op, i) in chain {
        let f = &graph.node[*i];
        if op == "Add" {
            let b = bias_vector(f, c.output_after(graph, 0), consts, wm.n)?;
            bias.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
        } else {
            let (g, off) = batch_norm(f, consts, wm.n)?;
            for j in 0..wm.n {
                scale[j] *= g[j];
                bias[j] = bias[j] * g[j] + off[j];
            }
        }
    }
    let output = c.output_after(graph, chain.len()).to_string();
    let (w_name, b_name) = (format!("{output}.folded_weight"), format!("{output}.folded_bias"));
    let (op_type, weight, attribute) = match wm.kernel_hw {
        None => {
            // [k][n] columns scaled: Gemm(X, W, b) with the defaults (alpha = beta = 1, no transposes)
            let w: Vec<f32> =
                wm.w.chunks_exact(wm.n).flat_map(|row| row.iter().zip(&scale).map(|(w, s)| w * s)).collect();
            ("Gemm", f32_tensor(w_name.clone(), &[wm.k, wm.n], &w), Vec::new())
        }
        Some(_) => {
            // the original [co][ci][kh][kw] layout, each output channel's filter scaled
            let (dims, w) = consts.f32(node.input.get(1)?)?;
            let w: Vec<f32> =
                w.chunks_exact(wm.k).zip(&scale).flat_map(|(f, s)| f.iter().map(move |v| v * s)).collect();
            ("Conv", f32_tensor(w_name.clone(), &dims, &w), node.attribute.clone())
        }
    };
    let replacement = NodeProto {
        name: node.name.clone(),
        op_type: op_type.into(),
        domain: String::new(),
        input: vec![c.input.clone(), w_name, b_name.clone()],
        output: vec![output],
        attribute,
        ..Default::default()
    };
    Some((replacement, [weight, f32_tensor(b_name, &[wm.n], &bias)]))
}

/// Fold every foldable `BatchNormalization` of `model` in place.
pub fn fold_batch_norms(model: &mut ModelProto) -> FoldReport {
    let mut report = FoldReport::default();
    let Some(graph) = model.graph.as_mut() else { return report };
    let found = candidates(graph);
    let consts = Constants::new(graph);
    let mut replace = Vec::new();
    let mut remove = Vec::new();
    let mut initializers = Vec::new();
    for c in &found {
        let Some((node, tensors)) = fold_one(graph, &consts, c) else { continue };
        let chain = folded_prefix(c).unwrap_or_default();
        report.batch_norms += 1;
        report.bias_adds += chain.iter().filter(|(op, _)| op == "Add").count();
        remove.extend(chain.iter().map(|(_, i)| *i));
        replace.push((c.index, node));
        initializers.extend(tensors);
    }
    drop(consts);
    for (i, n) in replace {
        graph.node[i] = n;
    }
    remove.sort_unstable();
    for i in remove.into_iter().rev() {
        graph.node.remove(i);
    }
    graph.initializer.extend(initializers);
    report
}

/// The single axis of a `ReduceMean` (attribute before opset 18, constant input from it).
fn mean_axis(graph: &GraphProto, node: &NodeProto) -> Option<i64> {
    let axes = match node.input.get(1).filter(|s| !s.is_empty()) {
        Some(name) => tensor_i64(constant(graph, name)?)?,
        None => attr(node, "axes")?.ints.clone(),
    };
    match axes[..] {
        [a] => Some(a),
        _ => None,
    }
}

/// `MatMul(X, W) -> Add(b) -> ReduceMean(axis a)` (constant `W` of `K > 1` rows and
/// bias, each intermediate used once) -> `ReduceMean(X, a, keepdims 1) -> MatMul(W) ->
/// Add(b) [-> Squeeze(a)]`, in place; returns how many means moved.
pub fn move_means_before_products(model: &mut ModelProto) -> usize {
    let opset =
        model.opset_import.iter().find(|o| o.domain.is_empty() || o.domain == "ai.onnx").map_or(17, |o| o.version);
    let Some(graph) = model.graph.as_mut() else { return 0 };
    let consumers = proto::consumers(graph);
    let is_output = |name: &str| graph.output.iter().any(|o| o.name == name);
    let consts = Constants::new(graph);
    // (product, bias add, mean, its axis)
    let mut found = Vec::new();
    for c in candidates(graph) {
        let [(op, add)] = &c.chain[..] else { continue };
        if c.op != "MatMul" || op != "Add" || c.unsupported.is_some() {
            continue;
        }
        match weight_matrix(&graph.node[c.index], &consts) {
            Ok(Some(w)) if w.k > 1 && w.kernel_hw.is_none() => {}
            _ => continue,
        }
        // a bias of rank 1 (a higher one could add axes, and move the mean's axis)
        let node_add = &graph.node[*add];
        let bias = node_add.input.iter().find(|i| **i != graph.node[c.index].output[0]);
        if bias.and_then(|b| consts.f32(b)).is_none_or(|(dims, _)| dims.len() != 1) {
            continue;
        }
        let y = node_add.output[0].as_str();
        let mean = match consumers.get(y).map(Vec::as_slice) {
            Some(&[m]) if !is_output(y) && graph.node[m].op_type == "ReduceMean" => m,
            _ => continue,
        };
        if let Some(axis) = mean_axis(graph, &graph.node[mean]) {
            found.push((c.index, *add, mean, axis));
        }
    }
    drop(consts);
    let mut replace: HashMap<usize, Vec<NodeProto>> = HashMap::new();
    let mut initializers = Vec::new();
    for &(product, add, mean, axis) in &found {
        let (p, a, m) = (&graph.node[product], &graph.node[add], &graph.node[mean]);
        let out = m.output[0].clone();
        let keep = attr_i(m, "keepdims", 1) != 0;
        let mut reduced = m.clone();
        reduced.name = format!("{}.before_product", m.name);
        reduced.input[0] = p.input[0].clone();
        reduced.output = vec![format!("{out}.mean_first")];
        reduced.attribute.retain(|at| at.name != "keepdims");
        reduced.attribute.push(crate::ops::proto::a_int("keepdims", 1));
        let mut product_node = p.clone();
        product_node.input[0] = reduced.output[0].clone();
        let mut add_node = a.clone();
        let mut tail = Vec::new();
        if keep {
            add_node.output = vec![out];
        } else {
            add_node.output = vec![format!("{out}.kept_axis")];
            let mut squeeze = NodeProto {
                name: format!("{}.squeeze", m.name),
                op_type: "Squeeze".into(),
                input: vec![add_node.output[0].clone()],
                output: vec![out.clone()],
                ..Default::default()
            };
            if opset >= 13 {
                let axes = format!("{out}.squeeze_axes");
                squeeze.input.push(axes.clone());
                initializers.push(i64_tensor(axes, &[axis]));
            } else {
                squeeze.attribute.push(a_ints("axes", vec![axis]));
            }
            tail.push(squeeze);
        }
        replace.insert(product, vec![reduced]);
        replace.insert(add, vec![product_node]);
        replace.insert(mean, std::iter::once(add_node).chain(tail).collect());
    }
    let nodes = std::mem::take(&mut graph.node);
    graph.node =
        nodes.into_iter().enumerate().flat_map(|(i, n)| replace.remove(&i).unwrap_or_else(|| vec![n])).collect();
    graph.initializer.extend(initializers);
    found.len()
}

#[cfg(test)]
mod tests {
    use tract_onnx::pb::{AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, ValueInfoProto};
    use tract_onnx::prelude::*;

    use super::*;

    fn node(op: &str, input: &[&str], output: &str) -> NodeProto {
        NodeProto {
            name: format!("{op}_{output}"),
            op_type: op.into(),
            input: input.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            ..Default::default()
        }
    }

    /// Deterministic values in [-1, 1) (a small LCG; nothing here needs more).
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// `X -> op(X, W[, b]) [-> Add(bias)] -> BatchNormalization(c channels) -> Relu -> Y`.
    fn model(op: &str, w_dims: &[usize], c: usize, bias_add: bool, op_bias: bool) -> ModelProto {
        let mut inits = vec![f32_tensor("W".into(), w_dims, &values(w_dims.iter().product(), 1))];
        let mut first = vec!["X", "W"];
        if op_bias {
            inits.push(f32_tensor("B".into(), &[c], &values(c, 2)));
            first.push("B");
        }
        let mut nodes = vec![node(op, &first, "p")];
        let mut x = "p";
        if bias_add {
            inits.push(f32_tensor("bias".into(), &[c], &values(c, 3)));
            nodes.push(node("Add", &[x, "bias"], "a"));
            x = "a";
        }
        let var: Vec<f32> = values(c, 7).iter().map(|v| v.abs() + 0.1).collect();
        for (name, v) in [("gamma", values(c, 4)), ("beta", values(c, 5)), ("mean", values(c, 6)), ("var", var)] {
            inits.push(f32_tensor(name.into(), &[c], &v));
        }
        let mut bn = node("BatchNormalization", &[x, "gamma", "beta", "mean", "var"], "n");
        bn.attribute.push(AttributeProto {
            name: "epsilon".into(),
            r#type: tract_onnx::pb::attribute_proto::AttributeType::Float as i32,
            f: 1e-3,
            ..Default::default()
        });
        nodes.push(bn);
        nodes.push(node("Relu", &["n"], "Y"));
        let io = |name: &str| ValueInfoProto { name: name.into(), ..Default::default() };
        ModelProto {
            ir_version: 8,
            opset_import: vec![OperatorSetIdProto { domain: String::new(), version: 17 }],
            graph: Some(GraphProto {
                node: nodes,
                initializer: inits,
                input: vec![io("X")],
                output: vec![io("Y")],
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    fn run(model: &ModelProto, x_dims: &[usize]) -> TractResult<Vec<f32>> {
        use tract_onnx::pb::tensor_shape_proto::{Dimension, dimension};
        use tract_onnx::pb::{TensorShapeProto, TypeProto, type_proto};
        let x = tract_ndarray::ArrayD::from_shape_vec(x_dims, values(x_dims.iter().product(), 9))?;
        let mut model = model.clone();
        let dim = x_dims
            .iter()
            .map(|&d| Dimension { value: Some(dimension::Value::DimValue(d as i64)), ..Default::default() })
            .collect();
        let tensor = type_proto::Tensor {
            elem_type: tensor_proto::DataType::Float as i32,
            shape: Some(TensorShapeProto { dim }),
        };
        let input = &mut model.graph.as_mut().expect("a graph").input[0];
        input.r#type = Some(TypeProto { value: Some(type_proto::Value::TensorType(tensor)), ..Default::default() });
        let plan = tract_onnx::onnx().model_for_proto_model(&model)?.into_optimized()?.into_runnable()?;
        let out = plan.run(tvec!(Tensor::from(x).into_tvalue()))?;
        Ok(out[0].try_as_plain_ram()?.as_slice::<f32>()?.to_vec())
    }

    /// Fold, check what was folded, and compare with the unfolded graph in tract.
    fn check(mut m: ModelProto, x_dims: &[usize], want: FoldReport) {
        let plain = run(&m, x_dims).unwrap();
        assert_eq!(fold_batch_norms(&mut m), want);
        let g = m.graph.as_ref().unwrap();
        assert!(!g.node.iter().any(|n| n.op_type == "BatchNormalization" || n.op_type == "Add"), "{:?}", g.node);
        let folded = run(&m, x_dims).unwrap();
        let scale = plain.iter().fold(0f32, |a, v| a.max(v.abs()));
        assert!(scale > 0.1, "the test graph has non-trivial outputs");
        for (a, b) in plain.iter().zip(&folded) {
            assert!((a - b).abs() <= 1e-5 * scale, "{a} vs {b}");
        }
    }

    #[test]
    fn matmul_bias_and_batch_norm_fold_into_one_gemm() {
        check(
            model("MatMul", &[6, 5], 5, true, false),
            &[7, 6],
            FoldReport { batch_norms: 1, bias_adds: 1, ..Default::default() },
        );
        check(
            model("MatMul", &[6, 5], 5, false, false),
            &[7, 6],
            FoldReport { batch_norms: 1, bias_adds: 0, ..Default::default() },
        );
    }

    #[test]
    fn gemm_with_transposed_weight_and_bias_folds() {
        let mut m = model("Gemm", &[5, 6], 5, false, true);
        let g = m.graph.as_mut().unwrap();
        g.node[0].attribute.push(crate::ops::proto::a_int("transB", 1));
        check(m, &[3, 6], FoldReport { batch_norms: 1, bias_adds: 0, ..Default::default() });
    }

    #[test]
    fn conv_and_batch_norm_fold_into_the_filters() {
        check(
            model("Conv", &[4, 3, 3, 3], 4, false, true),
            &[1, 3, 6, 5],
            FoldReport { batch_norms: 1, bias_adds: 0, ..Default::default() },
        );
        check(
            model("Conv", &[4, 3, 1, 1], 4, false, false),
            &[2, 3, 4, 4],
            FoldReport { batch_norms: 1, bias_adds: 0, ..Default::default() },
        );
    }

    /// On a rank-3 product the normalisation's channel axis is not the product's last axis:
    /// the folded `Gemm` must refuse to type (the estimator then loads the graph unfolded),
    /// never compute something else.
    #[test]
    fn a_rank3_product_fails_to_type_once_folded() {
        let mut m = model("MatMul", &[4, 4], 4, false, false);
        run(&m, &[2, 4, 4]).unwrap();
        assert_eq!(fold_batch_norms(&mut m).batch_norms, 1);
        assert!(run(&m, &[2, 4, 4]).is_err());
    }

    #[test]
    fn a_product_with_two_consumers_is_left_alone() {
        let mut m = model("MatMul", &[6, 5], 5, false, false);
        let g = m.graph.as_mut().unwrap();
        g.node.push(node("Relu", &["p"], "Z"));
        g.output.push(ValueInfoProto { name: "Z".into(), ..Default::default() });
        let before = m.clone();
        assert_eq!(fold_batch_norms(&mut m), FoldReport::default());
        assert_eq!(m, before);
    }

    /// `X -> MatMul(W [k, n]) -> Add(bias) -> ReduceMean(axis, keepdims) -> Y`, opset 17.
    fn mean_model(k: usize, n: usize, axis: i64, keepdims: i64) -> ModelProto {
        let mut m = model("MatMul", &[k, n], n, true, false);
        let g = m.graph.as_mut().unwrap();
        g.node.truncate(2);
        g.initializer.retain(|t| t.name == "W" || t.name == "bias");
        let mut mean = node("ReduceMean", &["a"], "Y");
        mean.attribute.push(crate::ops::proto::a_ints("axes", vec![axis]));
        mean.attribute.push(crate::ops::proto::a_int("keepdims", keepdims));
        g.node.push(mean);
        m
    }

    fn check_mean(mut m: ModelProto, x_dims: &[usize]) {
        let plain = run(&m, x_dims).unwrap();
        assert_eq!(move_means_before_products(&mut m), 1);
        let ops: Vec<&str> = m.graph.as_ref().unwrap().node.iter().map(|n| n.op_type.as_str()).collect();
        assert_eq!(&ops[..3], ["ReduceMean", "MatMul", "Add"]);
        let moved = run(&m, x_dims).unwrap();
        assert_eq!(plain.len(), moved.len());
        let scale = plain.iter().fold(0f32, |a, v| a.max(v.abs()));
        assert!(scale > 0.1, "the test graph has non-trivial outputs");
        for (a, b) in plain.iter().zip(&moved) {
            assert!((a - b).abs() <= 1e-5 * scale, "{a} vs {b}");
        }
    }

    #[test]
    fn a_mean_after_a_product_moves_before_it() {
        check_mean(mean_model(4, 6, 2, 0), &[2, 5, 7, 4]);
        check_mean(mean_model(4, 6, 2, 1), &[2, 5, 7, 4]);
        check_mean(mean_model(4, 6, -2, 0), &[3, 9, 4]);
        check_mean(mean_model(4, 6, 0, 0), &[3, 9, 4]);
    }

    /// A mean over the product's own output axis does not commute with it: once moved it
    /// must refuse to type (the estimator then loads the graph unfolded), never compute
    /// something else; a one-row weight, where that test cannot work, is left alone.
    #[test]
    fn a_mean_over_the_output_axis_fails_to_type_once_moved() {
        for axis in [3, -1] {
            let mut m = mean_model(4, 6, axis, 0);
            run(&m, &[2, 5, 7, 4]).unwrap();
            assert_eq!(move_means_before_products(&mut m), 1);
            assert!(run(&m, &[2, 5, 7, 4]).is_err());
        }
        let mut m = mean_model(1, 6, 2, 0);
        let before = m.clone();
        assert_eq!(move_means_before_products(&mut m), 0);
        assert_eq!(m, before);
    }

    #[test]
    fn a_mean_whose_sum_is_used_elsewhere_is_left_alone() {
        let mut m = mean_model(4, 6, 2, 0);
        let g = m.graph.as_mut().unwrap();
        g.node.push(node("Relu", &["a"], "Z"));
        g.output.push(ValueInfoProto { name: "Z".into(), ..Default::default() });
        let before = m.clone();
        assert_eq!(move_means_before_products(&mut m), 0);
        assert_eq!(m, before);
    }
}
