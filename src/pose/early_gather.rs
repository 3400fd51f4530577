//! Load-time rewrite of the pose graph (ONNX protobuf): run the image decoder's per-pixel
//! layers on the object's `N` pixels instead of the whole crop.
//!
//! The graph computes a dense feature map `F` (B, C, H, W) and then keeps only the pixels
//! `choose` (B, N) of it: `Reshape(F, (B, C, H*W))`, `Transpose(0, 2, 1)`,
//! `Reshape((-1, C))` and a row `Gather` at `choose + b*H*W` (how
//! `tools/tricons_pose/image_encoder.py::gather_pixel_features` exports). The layers just
//! before `F` are per pixel: 1x1 convolutions (float `Conv` or int8 `QConv`), `Relu`,
//! `BatchNormalization`, channel `Concat`. Each pixel of their output depends on that
//! pixel of their input alone, so they give the same values when they run on the
//! gathered pixels as a (B, C, N, 1) map. For the shipped decoder that is its last
//! convolution, its head and the concatenation with the stem: 70 % of its arithmetic,
//! all at crop resolution, for 512 of the crop's 9216 pixels.
//!
//! The rewrite:
//! * walks back from `F` through per-pixel nodes whose outputs feed only each other (in
//!   reverse node order, so every consumer is decided before its producer);
//! * puts a `PixelGather` ([`crate::ops::pixel_gather`]) on each tensor entering that
//!   chain; one made by an x2 bilinear `Resize` feeding only the chain is sampled from
//!   the `Resize`'s input (`upsample2x`, the same bits) and the `Resize` is dropped;
//! * `F` is now (B, C, N, 1), its pixels already the picked ones in order: the tail's
//!   first `Reshape` flattens it keeping (B, C) (shape `(0, 0, -1)`) and the row `Gather`
//!   becomes an `Identity` (the index arithmetic it read is left to tract's pruning).
//!
//! A map with no per-pixel layers before it but made by two constant resampling products,
//! `MatMul(MatMul(rows, x), cols)` (the paper configuration's image encoder: its 14x14
//! patch features brought to the 192x192 crop), is gathered from `x` through the
//! products' weights at the picked pixels (`ResampledPixelGather`) and the two products
//! are dropped: 2 taps a side instead of a 36 864-pixel map and its transpose.
//!
//! The convolutions run as matrix products over other column counts, so results can
//! differ from the unrewritten graph by rounding (tested on the golden fixtures; int8
//! 1x1 `QConv`s compute each pixel alone and give the same bits). A graph without that
//! tail, with `choose` not a graph input, or with offsets other than each item's first
//! row, is left alone.

use std::collections::{HashMap, HashSet};

use tract_onnx::pb::{GraphProto, NodeProto};

use crate::ops::proto::{self, a_int, attr, attr_i};

/// Domain of the inserted nodes.
const DOMAIN: &str = "ai.tricons";

/// Index of the node writing each tensor.
fn producers(graph: &GraphProto) -> HashMap<&str, usize> {
    graph.node.iter().enumerate().flat_map(|(i, n)| n.output.iter().map(move |o| (o.as_str(), i))).collect()
}

fn ints(node: &NodeProto, name: &str) -> Option<Vec<i64>> {
    attr(node, name).map(|a| a.ints.clone())
}

/// A convolution with a 1x1 kernel, unit strides and no padding: per pixel.
fn is_pointwise_conv(graph: &GraphProto, node: &NodeProto) -> bool {
    let kernel = ints(node, "kernel_shape").or_else(|| {
        let w = node.input.get(1)?;
        proto::constant(graph, w).map(|t| t.dims.iter().skip(2).copied().collect())
    });
    kernel.is_some_and(|k| k == [1, 1])
        && ints(node, "strides").is_none_or(|s| s.iter().all(|&v| v == 1))
        && ints(node, "pads").is_none_or(|p| p.iter().all(|&v| v == 0))
        && proto::attr_s(node, "auto_pad", "NOTSET") == "NOTSET"
}

/// The inputs of a per-pixel node that carry the map (the others must be constants), or
/// `None` when the node is not per pixel.
fn pixel_inputs<'a>(graph: &GraphProto, node: &'a NodeProto) -> Option<&'a [String]> {
    let constant_rest =
        |from: usize| node.input.iter().skip(from).all(|s| s.is_empty() || proto::constant(graph, s).is_some());
    let per_pixel = match (node.op_type.as_str(), node.domain.as_str()) {
        ("Conv", "" | "ai.onnx") => is_pointwise_conv(graph, node) && constant_rest(1),
        ("QConv", DOMAIN) => is_pointwise_conv(graph, node) && node.input.len() == 1,
        ("Relu", "" | "ai.onnx") => node.input.len() == 1,
        ("BatchNormalization", "" | "ai.onnx") => node.output.len() == 1 && constant_rest(1),
        ("Concat", "" | "ai.onnx") => return (attr_i(node, "axis", 0) == 1).then_some(&node.input[..]),
        _ => false,
    };
    (per_pixel && !node.input.is_empty()).then(|| &node.input[..1])
}

/// An x2 bilinear half-pixel upsampling (`Resize` of the form [`super::rewrite`] replaces,
/// or the replacement itself): its input.
fn upsampled_from<'a>(graph: &GraphProto, node: &'a NodeProto) -> Option<&'a str> {
    let resize = node.op_type == "Resize" && super::rewrite::is_bilinear_upsample2x(graph, node);
    let replaced = node.op_type == "BilinearUpsample2x" && node.domain == DOMAIN;
    if resize || replaced { node.input.first().map(String::as_str) } else { None }
}

/// A map made by two constant resampling products, `MatMul(MatMul(rows, x), cols)` with
/// `rows` and `cols` f32 matrices and the inner product read by the outer one only (how
/// the paper configuration's image encoder brings its patch grid to the crop): the two
/// nodes, `x`, `rows` and `cols`.
fn resampled_from<'a>(
    graph: &'a GraphProto,
    outer: usize,
    prod: &HashMap<&str, usize>,
    cons: &HashMap<&str, Vec<usize>>,
) -> Option<([usize; 2], [&'a str; 3])> {
    let matrix =
        |t: &str| proto::constant(graph, t).is_some_and(|c| c.dims.len() == 2 && proto::tensor_f32(c).is_some());
    let o = &graph.node[outer];
    let [t, cols] = o.input.as_slice() else { return None };
    if o.op_type != "MatMul" || !matrix(cols) {
        return None;
    }
    let inner = *prod.get(t.as_str())?;
    let i = &graph.node[inner];
    let [rows, x] = i.input.as_slice() else { return None };
    let read_once = cons.get(t.as_str()).is_some_and(|c| c == &[outer]);
    (i.op_type == "MatMul" && matrix(rows) && read_once && !graph.output.iter().any(|g| &g.name == t))
        .then_some(([inner, outer], [x.as_str(), rows.as_str(), cols.as_str()]))
}

/// The matched tail: the dense map `F`, its `Reshape` (B, C, H*W), the row `Gather`, the
/// tail's nodes and `choose`.
struct Tail {
    map: String,
    flatten: usize,
    gather: usize,
    nodes: Vec<usize>,
    choose: String,
}

/// `Gather(axis 0)` of `Reshape(Transpose(Reshape(F), perm (0, 2, 1)))` at
/// `Reshape(Add(choose, offsets))`, every intermediate read once, `choose` a graph input
/// and `offsets` each item's first row: `Range(0, B, 1)` (unsqueezed) times the row
/// count, or zero where the declared batch is 1.
fn match_tail(
    graph: &GraphProto,
    gather: usize,
    prod: &HashMap<&str, usize>,
    cons: &HashMap<&str, Vec<usize>>,
) -> Option<Tail> {
    let node = |i: usize| &graph.node[i];
    let g = node(gather);
    if g.op_type != "Gather" || attr_i(g, "axis", 0) != 0 || g.input.len() != 2 {
        return None;
    }
    let only_reader = |t: &str, reader: usize| cons.get(t).is_some_and(|c| c == &[reader]);
    let from = |t: &str, op: &str, reader: usize| -> Option<usize> {
        let i = *prod.get(t)?;
        (node(i).op_type == op && only_reader(t, reader)).then_some(i)
    };
    let first = |i: usize| node(i).input.first().map(String::as_str);
    let r1 = from(&g.input[0], "Reshape", gather)?;
    let tr = from(first(r1)?, "Transpose", r1)?;
    if ints(node(tr), "perm")? != [0, 2, 1] {
        return None;
    }
    let r0 = from(first(tr)?, "Reshape", tr)?;
    let idx = from(&g.input[1], "Reshape", gather)?;
    let add = from(first(idx)?, "Add", idx)?;
    let [x, y] = node(add).input.as_slice() else { return None };
    let is_input = |s: &str| graph.input.iter().any(|i| i.name == s) && proto::constant(graph, s).is_none();
    let (choose, offsets) = if is_input(x) { (x, y) } else { (y, x) };
    if !is_input(choose) || !item_offsets(graph, offsets, choose, prod) {
        return None;
    }
    Some(Tail {
        map: first(r0)?.to_string(),
        flatten: r0,
        gather,
        nodes: vec![r0, tr, r1, gather],
        choose: choose.clone(),
    })
}

/// Whether `offsets` is `Unsqueeze(Range(0, _, 1)) * _` (in either order), or a constant
/// of zeros with `choose` declared of batch 1.
fn item_offsets(graph: &GraphProto, offsets: &str, choose: &str, prod: &HashMap<&str, usize>) -> bool {
    if let Some(values) = proto::constant(graph, offsets).and_then(proto::tensor_i64) {
        return values.iter().all(|&v| v == 0) && declared_batch(graph, choose) == Some(1);
    }
    let node = |t: &str| prod.get(t).map(|&i| &graph.node[i]);
    let const_is = |t: &str, v: i64| proto::constant(graph, t).and_then(proto::tensor_i64).is_some_and(|x| x == [v]);
    let range_from_zero = |t: &str| {
        node(t).filter(|u| u.op_type == "Unsqueeze").and_then(|u| node(u.input.first()?)).is_some_and(|r| {
            r.op_type == "Range" && r.input.len() == 3 && const_is(&r.input[0], 0) && const_is(&r.input[2], 1)
        })
    };
    node(offsets).is_some_and(|m| m.op_type == "Mul" && m.input.iter().any(|t| range_from_zero(t)))
}

/// The first (batch) dimension of a graph input, when declared as a number.
fn declared_batch(graph: &GraphProto, name: &str) -> Option<i64> {
    let input = graph.input.iter().find(|i| i.name == name)?;
    proto::declared_dims(input).first().copied().flatten()
}

/// Apply the rewrite wherever the tail matches; the number of per-pixel nodes moved
/// behind a `PixelGather`, plus one per resampled map gathered at its source grid.
pub fn gather_pixels_early(graph: &mut GraphProto) -> usize {
    let mut moved = 0;
    // one tail at a time (each rewrite changes the indices); a rewritten tail ends in an
    // Identity and does not match again
    for _ in 0..graph.node.len() {
        match rewrite_one(graph) {
            Some(n) => moved += n,
            None => break,
        }
    }
    moved
}

fn rewrite_one(graph: &mut GraphProto) -> Option<usize> {
    let prod = producers(graph);
    let cons = proto::consumers(graph);
    let outputs: HashSet<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let (tail, chain, sources) = (0..graph.node.len()).find_map(|g| {
        let tail = match_tail(graph, g, &prod, &cons)?;
        // F may also be read by Shape nodes (the tail's sizes) and nothing else
        let tail_reader = |i: usize| i == tail.nodes[0] || graph.node[i].op_type == "Shape";
        if outputs.contains(tail.map.as_str()) || !cons.get(tail.map.as_str())?.iter().all(|&i| tail_reader(i)) {
            return None;
        }
        match per_pixel_chain(graph, &tail.map, &prod, &cons, &outputs) {
            Some((chain, sources)) => Some((tail, chain, sources)),
            // no per-pixel layers, but a resampled map: gathered from its source grid
            None => {
                resampled_from(graph, *prod.get(tail.map.as_str())?, &prod, &cons)?;
                let map = tail.map.clone();
                Some((tail, HashSet::new(), vec![map]))
            }
        }
    })?;
    // the gathers go where the chain starts, or where the resampled map was made
    let first = match chain.iter().min() {
        Some(&i) => i,
        None => *prod.get(tail.map.as_str())?,
    };
    // the gathers of what enters the chain; a Resize read only by the chain is dropped
    let choose = tail.choose.clone();
    let mut inserted = Vec::new();
    let mut dropped = HashSet::new();
    let mut renamed: HashMap<String, String> = HashMap::new();
    for source in &sources {
        let producer = prod.get(source.as_str()).copied();
        // the map itself (no chain): the gather writes it under its own name, which the
        // tail and its Shape readers read
        let is_map = chain.is_empty();
        let read_by_chain_only =
            is_map || cons.get(source.as_str()).is_some_and(|c| c.iter().all(|i| chain.contains(i)));
        let out = if is_map { source.clone() } else { format!("{source}.pixels") };
        let made = producer.filter(|_| read_by_chain_only);
        if let Some((nodes, [x, rows, cols])) = made.and_then(|p| resampled_from(graph, p, &prod, &cons)) {
            dropped.extend(nodes);
            inserted.push(NodeProto {
                name: format!("{source}.ResampledPixelGather"),
                op_type: "ResampledPixelGather".into(),
                domain: DOMAIN.into(),
                input: vec![x.to_string(), choose.clone(), rows.to_string(), cols.to_string()],
                output: vec![out.clone()],
                ..Default::default()
            });
        } else {
            let upsampled = made.and_then(|p| upsampled_from(graph, &graph.node[p]).map(|x| (p, x)));
            let (x, up) = match upsampled {
                Some((p, x)) => {
                    dropped.insert(p);
                    (x.to_string(), 1)
                }
                None => (source.clone(), 0),
            };
            inserted.push(NodeProto {
                name: format!("{source}.PixelGather"),
                op_type: "PixelGather".into(),
                domain: DOMAIN.into(),
                input: vec![x, choose.clone()],
                output: vec![out.clone()],
                attribute: vec![a_int("upsample2x", up)],
                ..Default::default()
            });
        }
        if !is_map {
            renamed.insert(source.clone(), out);
        }
    }
    // chain nodes read the gathered maps
    for &i in &chain {
        for input in graph.node[i].input.iter_mut() {
            if let Some(new) = renamed.get(input) {
                *input = new.clone();
            }
        }
    }
    // F is now (B, C, N, 1): its rows are the picked ones, in order; the flattening keeps
    // (B, C) and the row gather becomes an Identity
    let keep_bc = format!("{}.keep_bc_flatten", graph.node[tail.flatten].name);
    graph.initializer.push(proto::i64_tensor(keep_bc.clone(), &[0, 0, -1]));
    let flatten = &mut graph.node[tail.flatten];
    flatten.input.truncate(1);
    flatten.input.push(keep_bc);
    flatten.attribute.retain(|a| a.name != "allowzero");
    let gather = &mut graph.node[tail.gather];
    gather.op_type = "Identity".into();
    gather.input.truncate(1);
    gather.attribute.clear();
    // shapes recorded for the crop-sized tensors no longer hold
    let mut stale: HashSet<String> =
        chain.iter().chain(&tail.nodes).flat_map(|&i| graph.node[i].output.iter().cloned()).collect();
    stale.insert(tail.map.clone());
    graph.value_info.retain(|v| !stale.contains(&v.name));
    // the per-pixel nodes moved, and each resampled map's two products replaced by a gather
    let moved = chain.len() + inserted.iter().filter(|n| n.op_type == "ResampledPixelGather").count();
    let mut nodes: Vec<NodeProto> = Vec::with_capacity(graph.node.len() + inserted.len());
    for (i, node) in std::mem::take(&mut graph.node).into_iter().enumerate() {
        if i == first {
            nodes.append(&mut inserted);
        }
        if !dropped.contains(&i) {
            nodes.push(node);
        }
    }
    graph.node = nodes;
    Some(moved)
}

/// The per-pixel nodes producing `map` (in reverse node order, each taken only when every
/// reader of its outputs is taken) and the tensors entering them; `None` when `map` is
/// not made by a per-pixel node.
fn per_pixel_chain(
    graph: &GraphProto,
    map: &str,
    prod: &HashMap<&str, usize>,
    cons: &HashMap<&str, Vec<usize>>,
    outputs: &HashSet<&str>,
) -> Option<(HashSet<usize>, Vec<String>)> {
    let last = *prod.get(map)?;
    let mut chain: HashSet<usize> = HashSet::new();
    let mut wanted: HashSet<String> = HashSet::from([map.to_string()]);
    let mut sources: Vec<String> = Vec::new();
    for i in (0..=last).rev() {
        let node = &graph.node[i];
        let wanted_here: Vec<&String> = node.output.iter().filter(|o| wanted.contains(*o)).collect();
        if wanted_here.is_empty() {
            continue;
        }
        let readers_taken = node.output.iter().all(|o| {
            !outputs.contains(o.as_str())
                && cons.get(o.as_str()).is_none_or(|c| c.iter().all(|r| chain.contains(r) || (o == map && *r > last)))
        });
        match pixel_inputs(graph, node).filter(|_| readers_taken) {
            Some(inputs) => {
                chain.insert(i);
                wanted.extend(inputs.iter().cloned());
            }
            None => sources.extend(wanted_here.into_iter().cloned()),
        }
    }
    // what is still wanted and made by no node: graph inputs
    let made: HashSet<&str> = chain.iter().flat_map(|&i| graph.node[i].output.iter().map(String::as_str)).collect();
    for t in &wanted {
        if !made.contains(t.as_str()) && !sources.contains(t) && !prod.contains_key(t.as_str()) {
            sources.push(t.clone());
        }
    }
    sources.sort();
    (!chain.is_empty()).then_some((chain, sources))
}
