//! The ONNX side of quantization: which nodes can run in int8 ([`candidates`]) and
//! the load-time rewrite that replaces them, with their fused followers, by the
//! `ai.tricons` int8 nodes `QLinear` ([`crate::ops::qlinear`]) and `QConv`
//! ([`crate::ops::qconv`]) ([`apply`]).
//!
//! A candidate is a `MatMul` with a constant rank-2 weight, a `Gemm` with a constant
//! `B` (`transA = 0`), or a 2-D `Conv` with a constant weight and `group = 1`. Its
//! output stage can absorb, while each intermediate tensor has a single consumer and
//! is not a graph output: a constant bias `Add` (linear only), a `BatchNormalization`
//! in inference form (for a linear only on rank-2 inputs, where its channel axis is
//! the last one), then a `Relu`.

use std::collections::HashMap;

use tract_onnx::pb::{AttributeProto, GraphProto, ModelProto, NodeProto, TensorProto, tensor_proto};

use super::params::QParams;
use super::profile::QuantProfile;
use crate::ops::proto::{a_float, a_floats, a_int, a_ints, a_tensor, attr, attr_f, attr_i};

/// ONNX domain of the int8 nodes.
pub const DOMAIN: &str = "ai.tricons";

/// A node that may run in int8.
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    /// Index in `graph.node`.
    pub index: usize,
    /// Node name.
    pub node: String,
    /// ONNX op type (`MatMul`, `Gemm`, `Conv`).
    pub op: String,
    /// The activation input tensor.
    pub input: String,
    /// Fusable followers in order: op type and node index.
    pub chain: Vec<(String, usize)>,
    /// Why it cannot run in int8, if so.
    pub unsupported: Option<String>,
}

impl Candidate {
    /// The tensor after the first `fused` followers.
    pub fn output_after<'g>(&self, graph: &'g GraphProto, fused: usize) -> &'g str {
        let i = if fused == 0 { self.index } else { self.chain[fused - 1].1 };
        &graph.node[i].output[0]
    }
}

/// Float constants of a graph: initializers and `Constant` nodes, by tensor name.
pub struct Constants<'g> {
    tensors: HashMap<&'g str, &'g TensorProto>,
}

impl<'g> Constants<'g> {
    /// Index the constants of `graph`.
    pub fn new(graph: &'g GraphProto) -> Self {
        let mut tensors: HashMap<&str, &TensorProto> = graph.initializer.iter().map(|t| (t.name.as_str(), t)).collect();
        for n in graph.node.iter().filter(|n| n.op_type == "Constant") {
            if let (Some(out), Some(t)) = (n.output.first(), attr(n, "value").and_then(|a| a.t.as_ref())) {
                tensors.insert(out.as_str(), t);
            }
        }
        Constants { tensors }
    }

    /// `(dims, values)` of a constant `f32` tensor.
    pub fn f32(&self, name: &str) -> Option<(Vec<usize>, Vec<f32>)> {
        let t = self.tensors.get(name)?;
        if t.data_type != tensor_proto::DataType::Float as i32 || t.dims.iter().any(|&d| d < 0) {
            return None;
        }
        let dims: Vec<usize> = t.dims.iter().map(|&d| d as usize).collect();
        let values: Vec<f32> = if !t.raw_data.is_empty() {
            t.raw_data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
        } else {
            t.float_data.clone()
        };
        (values.len() == dims.iter().product::<usize>()).then_some((dims, values))
    }
}

/// Every `MatMul`, `Gemm` and `Conv` of `graph`, with its fusable followers.
pub fn candidates(graph: &GraphProto) -> Vec<Candidate> {
    let consts = Constants::new(graph);
    let consumers = crate::ops::proto::consumers(graph);
    let outputs: Vec<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let mut found = Vec::new();
    for (index, node) in graph.node.iter().enumerate() {
        if !matches!(node.op_type.as_str(), "MatMul" | "Gemm" | "Conv") {
            continue;
        }
        let (unsupported, n_out) = match weight_matrix(node, &consts) {
            Ok(Some(w)) => (None, w.n),
            Ok(None) => (Some("the weight is not a constant".to_string()), 0),
            Err(why) => (Some(why), 0),
        };
        let mut chain = Vec::new();
        let mut cur = node.output.first().map(String::as_str).unwrap_or("");
        loop {
            let next = match consumers.get(cur) {
                Some(c) if c.len() == 1 && !outputs.contains(&cur) => c[0],
                _ => break,
            };
            let f = &graph.node[next];
            let seen = |op: &str| chain.iter().any(|(o, _): &(String, usize)| o == op);
            let ok = match f.op_type.as_str() {
                "Add" if node.op_type != "Conv" && !seen("Add") && !seen("BatchNormalization") && !seen("Relu") => {
                    bias_vector(f, cur, &consts, n_out).is_some()
                }
                "BatchNormalization" if !seen("BatchNormalization") && !seen("Relu") => {
                    f.output.len() == 1 && batch_norm(f, &consts, n_out).is_some()
                }
                "Relu" => true,
                _ => false,
            };
            if !ok {
                break;
            }
            chain.push((f.op_type.clone(), next));
            cur = &f.output[0];
            if f.op_type == "Relu" {
                break;
            }
        }
        found.push(Candidate {
            index,
            node: node.name.clone(),
            op: node.op_type.clone(),
            input: node.input.first().cloned().unwrap_or_default(),
            chain,
            unsupported,
        });
    }
    found
}

/// A weight as the int8 kernels take it: row-major `[k][n]`, `n` output channels.
#[derive(Clone, Debug, PartialEq)]
pub struct WeightMatrix {
    /// Reduction length (conv: `Cin * kh * kw`, ordered `(ci, ky, kx)`).
    pub k: usize,
    /// Output channels.
    pub n: usize,
    /// `[k][n]` values.
    pub w: Vec<f32>,
    /// Bias `[n]` (the op's own, e.g. `Conv`'s third input or `Gemm`'s `C`).
    pub bias: Vec<f32>,
    /// Conv kernel height and width (`None` for a linear).
    pub kernel_hw: Option<(usize, usize)>,
}

/// The node's constant weight as a `[k][n]` matrix; `Ok(None)` if it is not constant,
/// `Err` if the node's form is not supported.
pub fn weight_matrix(node: &NodeProto, consts: &Constants) -> Result<Option<WeightMatrix>, String> {
    let Some((dims, w)) = node.input.get(1).and_then(|n| consts.f32(n)) else {
        return Ok(None);
    };
    match node.op_type.as_str() {
        "MatMul" => {
            if dims.len() != 2 {
                return Err(format!("MatMul weight of rank {}", dims.len()));
            }
            Ok(Some(WeightMatrix { k: dims[0], n: dims[1], w, bias: vec![0.0; dims[1]], kernel_hw: None }))
        }
        "Gemm" => {
            if attr_i(node, "transA", 0) != 0 {
                return Err("Gemm with transA".into());
            }
            if dims.len() != 2 {
                return Err(format!("Gemm B of rank {}", dims.len()));
            }
            let alpha = attr_f(node, "alpha", 1.0);
            let beta = attr_f(node, "beta", 1.0);
            let (k, n) = if attr_i(node, "transB", 0) != 0 { (dims[1], dims[0]) } else { (dims[0], dims[1]) };
            let mut m = vec![0f32; k * n];
            for i in 0..k {
                for j in 0..n {
                    let v = if attr_i(node, "transB", 0) != 0 { w[j * k + i] } else { w[i * n + j] };
                    m[i * n + j] = alpha * v;
                }
            }
            let bias = match node.input.get(2).filter(|s| !s.is_empty()) {
                None => vec![0.0; n],
                Some(c) => match consts.f32(c) {
                    Some((_, c)) if c.len() == n => c.iter().map(|v| beta * v).collect(),
                    Some((_, c)) if c.len() == 1 => vec![beta * c[0]; n],
                    _ => return Err("Gemm C is not a constant vector".into()),
                },
            };
            Ok(Some(WeightMatrix { k, n, w: m, bias, kernel_hw: None }))
        }
        "Conv" => {
            if dims.len() != 4 {
                return Err(format!("Conv of rank {} (only 2-D convolutions run in int8)", dims.len()));
            }
            if attr_i(node, "group", 1) != 1 {
                return Err("grouped or depthwise Conv (no int8 kernel)".into());
            }
            if attr(node, "auto_pad").is_some_and(|a| !a.s.is_empty() && a.s != b"NOTSET") {
                return Err("Conv with auto_pad".into());
            }
            let (n, k, kh, kw) = (dims[0], dims[1] * dims[2] * dims[3], dims[2], dims[3]);
            let mut m = vec![0f32; k * n];
            for co in 0..n {
                for r in 0..k {
                    m[r * n + co] = w[co * k + r];
                }
            }
            let bias = match node.input.get(2).filter(|s| !s.is_empty()) {
                None => vec![0.0; n],
                Some(b) => match consts.f32(b) {
                    Some((_, b)) if b.len() == n => b,
                    _ => return Err("Conv bias is not a constant vector".into()),
                },
            };
            Ok(Some(WeightMatrix { k, n, w: m, bias, kernel_hw: Some((kh, kw)) }))
        }
        other => Err(format!("{other} is not quantizable")),
    }
}

/// The constant `[n]` addend of `add` (whose other input is `x`).
pub fn bias_vector(add: &NodeProto, x: &str, consts: &Constants, n: usize) -> Option<Vec<f32>> {
    let other = add.input.iter().find(|i| i.as_str() != x)?;
    let (dims, v) = consts.f32(other)?;
    (v.len() == n && dims.iter().rev().skip(1).all(|&d| d == 1)).then_some(v)
}

/// `(multiplier, offset)` per channel of an inference-mode `BatchNormalization`.
pub fn batch_norm(bn: &NodeProto, consts: &Constants, n: usize) -> Option<(Vec<f32>, Vec<f32>)> {
    let get = |i: usize| consts.f32(bn.input.get(i)?).map(|(_, v)| v).filter(|v| v.len() == n);
    let (gamma, beta, mean, var) = (get(1)?, get(2)?, get(3)?, get(4)?);
    let eps = attr_f(bn, "epsilon", 1e-5);
    let g: Vec<f32> = gamma.iter().zip(&var).map(|(g, v)| g / (v + eps).sqrt()).collect();
    let off = beta.iter().zip(&mean).zip(&g).map(|((b, m), g)| b - m * g).collect();
    Some((g, off))
}

/// What [`apply`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ApplyReport {
    /// Nodes now running in int8.
    pub quantized: usize,
    /// Follower nodes folded into them.
    pub fused: usize,
}

fn q_attrs(prefix: &str, q: QParams) -> [AttributeProto; 2] {
    [a_float(&format!("{prefix}_scale"), q.scale), a_int(&format!("{prefix}_zero_point"), q.zero_point as i64)]
}

/// Replace the profile's nodes in `model` by int8 nodes. Every profile node must be
/// found with the same op type and fusable followers (else the profile belongs to
/// another graph: an error naming the node).
pub fn apply(model: &mut ModelProto, profile: &QuantProfile) -> Result<ApplyReport, String> {
    let graph = model.graph.as_mut().ok_or("the file holds no graph")?;
    let found = candidates(graph);
    let by_name: HashMap<&str, &Candidate> = found.iter().map(|c| (c.node.as_str(), c)).collect();
    let consts = Constants::new(graph);
    let mut replace: Vec<(usize, NodeProto)> = Vec::new();
    let mut remove: Vec<usize> = Vec::new();
    for q in &profile.nodes {
        let c = by_name.get(q.node.as_str()).ok_or_else(|| format!("profile node {:?} is not in the graph", q.node))?;
        if c.op != q.op || c.input != q.input {
            return Err(format!("profile node {:?}: the graph has {} on {:?}", q.node, c.op, c.input));
        }
        if let Some(why) = &c.unsupported {
            return Err(format!("profile node {:?}: {why}", q.node));
        }
        let ops: Vec<&str> = c.chain.iter().take(q.fuse.len()).map(|(o, _)| o.as_str()).collect();
        if ops != q.fuse.iter().map(String::as_str).collect::<Vec<_>>() {
            return Err(format!("profile node {:?}: fuses {:?}, the graph allows {ops:?}", q.node, q.fuse));
        }
        let node = &graph.node[c.index];
        let wm = weight_matrix(node, &consts)?.ok_or_else(|| format!("node {:?}: weight not constant", q.node))?;
        let mut post_scale = vec![1f32; wm.n];
        let mut bias = wm.bias.clone();
        let mut relu = false;
        for (op, i) in c.chain.iter().take(q.fuse.len()) {
            let f = &graph.node[*i];
            match op.as_str() {
                "Add" => {
                    // A bias Add is always the first follower.
                    let x = c.output_after(graph, 0);
                    let b = bias_vector(f, x, &consts, wm.n).ok_or("bias Add changed")?;
                    bias.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                }
                "BatchNormalization" => {
                    let (g, off) = batch_norm(f, &consts, wm.n).ok_or("BatchNormalization changed")?;
                    for j in 0..wm.n {
                        post_scale[j] *= g[j];
                        bias[j] = bias[j] * g[j] + off[j];
                    }
                }
                _ => relu = true,
            }
            remove.push(*i);
        }
        let output = c.output_after(graph, q.fuse.len()).to_string();
        let mut attribute = vec![
            a_floats("post_scale", post_scale),
            a_floats("bias", bias),
            a_int("input_u7", q.input_u7 as i64),
            a_int("relu", relu as i64),
        ];
        attribute.extend(q_attrs("x", q.input_q));
        if let Some(yq) = q.output_u7 {
            attribute.extend(q_attrs("y", yq));
        }
        let op_type = match wm.kernel_hw {
            None => {
                attribute.push(a_tensor("weight", &[wm.k, wm.n], &wm.w));
                attribute.push(a_int("rank2", q.fuse.iter().any(|f| f == "BatchNormalization") as i64));
                "QLinear"
            }
            Some((kh, kw)) => {
                attribute.push(a_tensor("weight", &[wm.k, wm.n], &wm.w));
                attribute.push(a_ints("kernel_shape", vec![kh as i64, kw as i64]));
                for (name, default) in [("strides", 1), ("dilations", 1)] {
                    let v = attr(node, name).map(|a| a.ints.clone()).unwrap_or_else(|| vec![default; 2]);
                    attribute.push(a_ints(name, v));
                }
                let pads = attr(node, "pads").map(|a| a.ints.clone()).unwrap_or_else(|| vec![0; 4]);
                attribute.push(a_ints("pads", pads));
                "QConv"
            }
        };
        replace.push((
            c.index,
            NodeProto {
                name: format!("{}.int8", q.node),
                op_type: op_type.into(),
                domain: DOMAIN.into(),
                input: vec![q.input.clone()],
                output: vec![output],
                attribute,
                ..Default::default()
            },
        ));
    }
    let report = ApplyReport { quantized: replace.len(), fused: remove.len() };
    for (i, n) in replace {
        graph.node[i] = n;
    }
    remove.sort_unstable();
    for i in remove.into_iter().rev() {
        graph.node.remove(i);
    }
    if !model.opset_import.iter().any(|o| o.domain == DOMAIN) {
        model.opset_import.push(tract_onnx::pb::OperatorSetIdProto { domain: DOMAIN.into(), version: 1 });
    }
    Ok(report)
}
