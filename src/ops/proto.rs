//! Helpers of the load-time rewrites on the ONNX protobuf (the Mask R-CNN's in
//! `segment::rewrite`, the pose graph's in `pose::rewrite` and `pose::fold`, int8's in
//! `quant::rewrite`): attributes and constants, read and built.

use tract_onnx::pb::{
    AttributeProto, GraphProto, NodeProto, TensorProto, ValueInfoProto, attribute_proto, tensor_proto,
};

/// Indices of the nodes reading each tensor.
pub fn consumers(graph: &GraphProto) -> std::collections::HashMap<&str, Vec<usize>> {
    let mut map: std::collections::HashMap<&str, Vec<usize>> = std::collections::HashMap::new();
    for (i, n) in graph.node.iter().enumerate() {
        for input in n.input.iter().filter(|s| !s.is_empty()) {
            map.entry(input.as_str()).or_default().push(i);
        }
    }
    map
}

/// A rank-1 int64 initializer (little-endian raw data).
pub fn i64_tensor(name: String, values: &[i64]) -> TensorProto {
    TensorProto {
        name,
        dims: vec![values.len() as i64],
        data_type: tensor_proto::DataType::Int64 as i32,
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    }
}

/// A value's declared dimensions: a number where one is declared, `None` for a symbolic
/// or missing one; empty when no tensor shape is declared.
pub fn declared_dims(value: &ValueInfoProto) -> Vec<Option<i64>> {
    use tract_onnx::pb::tensor_shape_proto::dimension;
    use tract_onnx::pb::type_proto;
    match value.r#type.as_ref().and_then(|t| t.value.as_ref()) {
        Some(type_proto::Value::TensorType(t)) => t
            .shape
            .iter()
            .flat_map(|s| &s.dim)
            .map(|d| match d.value {
                Some(dimension::Value::DimValue(v)) => Some(v),
                _ => None,
            })
            .collect(),
        None => Vec::new(),
    }
}

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

/// A string attribute.
pub fn a_string(name: &str, value: &str) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: attribute_proto::AttributeType::String as i32,
        s: value.as_bytes().to_vec(),
        ..Default::default()
    }
}

/// An integer attribute.
pub fn a_int(name: &str, i: i64) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: attribute_proto::AttributeType::Int as i32, i, ..Default::default() }
}

/// A float attribute.
pub fn a_float(name: &str, f: f32) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: attribute_proto::AttributeType::Float as i32, f, ..Default::default() }
}

/// A list-of-floats attribute.
pub fn a_floats(name: &str, floats: Vec<f32>) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: attribute_proto::AttributeType::Floats as i32,
        floats,
        ..Default::default()
    }
}

/// A list-of-integers attribute.
pub fn a_ints(name: &str, ints: Vec<i64>) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: attribute_proto::AttributeType::Ints as i32,
        ints,
        ..Default::default()
    }
}

/// An f32 tensor attribute (little-endian raw data).
pub fn a_tensor(name: &str, dims: &[usize], values: &[f32]) -> AttributeProto {
    let t = TensorProto {
        name: name.into(),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: tensor_proto::DataType::Float as i32,
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    };
    AttributeProto {
        name: name.into(),
        r#type: attribute_proto::AttributeType::Tensor as i32,
        t: Some(t),
        ..Default::default()
    }
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

/// The first graph output (in `graph` or any subgraph of an `If` / `Loop` / `Scan`
/// attribute) that no graph input, initializer or node of its graph defines. tract's
/// ONNX loader indexes outputs by name without a check and panics on such a graph, so
/// the loaders refuse it first with this name.
pub fn undefined_output(graph: &GraphProto) -> Option<String> {
    let defined: std::collections::HashSet<&str> = graph
        .input
        .iter()
        .map(|i| i.name.as_str())
        .chain(graph.initializer.iter().map(|t| t.name.as_str()))
        .chain(graph.node.iter().flat_map(|n| n.output.iter().map(String::as_str)))
        .filter(|n| !n.is_empty())
        .collect();
    if let Some(o) = graph.output.iter().find(|o| !defined.contains(o.name.as_str())) {
        let scope = if graph.name.is_empty() { String::new() } else { format!(" of graph {:?}", graph.name) };
        return Some(format!("output {:?}{scope}", o.name));
    }
    graph.node.iter().flat_map(|n| &n.attribute).flat_map(|a| a.g.iter().chain(&a.graphs)).find_map(undefined_output)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tract_onnx::pb::ValueInfoProto;

    fn value(name: &str) -> ValueInfoProto {
        ValueInfoProto { name: name.into(), ..Default::default() }
    }

    #[test]
    fn outputs_nothing_defines_are_named_in_graphs_and_subgraphs() {
        let relu = NodeProto {
            op_type: "Relu".into(),
            input: vec!["x".into()],
            output: vec!["y".into()],
            ..Default::default()
        };
        let mut g =
            GraphProto { node: vec![relu], input: vec![value("x")], output: vec![value("y")], ..Default::default() };
        assert_eq!(undefined_output(&g), None);
        g.output.push(value("x")); // an input passed through is defined
        assert_eq!(undefined_output(&g), None);
        g.output.push(value("z"));
        assert_eq!(undefined_output(&g).as_deref(), Some("output \"z\""));
        g.output.pop();
        let body = GraphProto { name: "then".into(), output: vec![value("w")], ..Default::default() };
        let attr = AttributeProto { name: "then_branch".into(), g: Some(body), ..Default::default() };
        g.node.push(NodeProto { op_type: "If".into(), attribute: vec![attr], ..Default::default() });
        assert_eq!(undefined_output(&g).as_deref(), Some("output \"w\" of graph \"then\""));
    }
}
