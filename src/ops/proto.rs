//! Helpers of the load-time rewrites on the ONNX protobuf (the Mask R-CNN's in
//! `segment::rewrite`, the pose graph's in `pose::rewrite` and `pose::fold`, int8's in
//! `quant::rewrite`): attributes and constants.

use tract_onnx::pb::{AttributeProto, GraphProto, NodeProto, TensorProto, tensor_proto};

/// A node's attribute by name.
pub fn attr<'a>(node: &'a NodeProto, name: &str) -> Option<&'a AttributeProto> {
    node.attribute.iter().find(|a| a.name == name)
}

/// An integer attribute, `default` when absent.
pub fn attr_i(node: &NodeProto, name: &str, default: i64) -> i64 {
    attr(node, name).map_or(default, |a| a.i)
}

/// A float attribute, `default` when absent.
pub fn attr_f(node: &NodeProto, name: &str, default: f32) -> f32 {
    attr(node, name).map_or(default, |a| a.f)
}

/// A string attribute, `default` when absent (or not UTF-8: empty).
pub fn attr_s<'a>(node: &'a NodeProto, name: &str, default: &'a str) -> &'a str {
    attr(node, name).map_or(default, |a| std::str::from_utf8(&a.s).unwrap_or(""))
}

/// A constant tensor by name: an initializer, or the value of the `Constant` node writing it.
pub fn constant<'a>(graph: &'a GraphProto, name: &str) -> Option<&'a TensorProto> {
    graph.initializer.iter().find(|t| t.name == name).or_else(|| {
        graph
            .node
            .iter()
            .find(|n| n.op_type == "Constant" && n.output.first().is_some_and(|o| o == name))
            .and_then(|n| attr(n, "value"))
            .and_then(|a| a.t.as_ref())
    })
}

/// An int64 tensor's values (typed field or little-endian raw data).
pub fn tensor_i64(t: &TensorProto) -> Option<Vec<i64>> {
    if t.data_type != tensor_proto::DataType::Int64 as i32 {
        return None;
    }
    if !t.int64_data.is_empty() {
        return Some(t.int64_data.clone());
    }
    let raw = &t.raw_data;
    raw.len()
        .is_multiple_of(8)
        .then(|| raw.chunks_exact(8).map(|c| i64::from_le_bytes(c.try_into().unwrap_or([0; 8]))).collect())
}

/// A float tensor's values (typed field or little-endian raw data).
pub fn tensor_f32(t: &TensorProto) -> Option<Vec<f32>> {
    if t.data_type != tensor_proto::DataType::Float as i32 {
        return None;
    }
    if !t.float_data.is_empty() {
        return Some(t.float_data.clone());
    }
    let raw = &t.raw_data;
    raw.len()
        .is_multiple_of(4)
        .then(|| raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
}
