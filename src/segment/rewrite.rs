//! Load-time rewrites of a torchvision Mask R-CNN ONNX graph for tract.
//!
//! A `torch.onnx.export` of torchvision's Mask R-CNN (opset 11 to 17) holds three
//! patterns tract 0.23 cannot load or run; they are rewritten on the ONNX protobuf,
//! before tract parses it, so the user's file runs unmodified:
//!
//! * **`If` of the batched NMS** (`if boxes.numel() == 0: return empty`): the
//!   then-branch is constants only, the else-branch the real work. The else-branch
//!   is inlined (it gives the same empty result on empty input).
//! * **`Slice` with a constant end on a symbolic axis** (`keep[:1000]`): tract does
//!   not clamp. Such a Slice gets `ends := Min(ends, Shape(data)[axes])`.
//! * **The mask-pasting `Loop`** (`_onnx_paste_masks_in_image_loop`): removed. Its
//!   two inputs from the outer graph, the padded 28x28 mask probabilities and the
//!   integer paste boxes, become graph outputs and [`super::paste`] pastes in Rust.
//!
//! Two more are for speed, not loading: a **depthwise `Conv`** (`group` = input channels =
//! output channels, constant weight and bias; MobileNetV3's) becomes `DepthwiseConv2d`
//! ([`crate::ops::depthwise`]), which tract's generic scalar walk ran at ~2 G
//! multiply-adds/s; a **`Resize` by `sizes`** in the two forms torchvision exports
//! (linear with half-pixel coordinates: the input transform; nearest with asymmetric
//! coordinates and floor: the FPN) becomes `Resize2d` ([`crate::ops::resize`]); a
//! **`ScatterElements` along axis 0 whose indices are `Expand(Reshape(i, [-1, 1, ..]))`**
//! (the multi-scale RoI pooling's merge of its FPN levels) becomes `ScatterRows`
//! ([`crate::ops::scatter_elements`]), which copies whole rows by `i` without the
//! broadcast index tensor.

use std::collections::{HashMap, HashSet};

use tract_onnx::pb::{GraphProto, ModelProto, NodeProto, TensorProto, ValueInfoProto, tensor_proto};

use crate::ops::proto::{self, attr};

/// Graph output added for the padded mask probabilities `(N, 1, M + 2, M + 2)`.
pub const PASTE_MASKS_OUTPUT: &str = "tricons.paste.masks";
/// Graph output added for the integer paste boxes `(N, 4)` (x0, y0, x1, y1).
pub const PASTE_BOXES_OUTPUT: &str = "tricons.paste.boxes";

/// What [`rewrite`] changed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RewriteReport {
    /// `If` nodes replaced by their else-branch.
    pub ifs_inlined: usize,
    /// `Slice` nodes whose ends are now clamped.
    pub slices_clamped: usize,
    /// The graph output the removed mask-pasting `Loop` produced (pasted in Rust now).
    pub pasted_output: Option<String>,
    /// Depthwise `Conv` nodes now `DepthwiseConv2d`.
    pub depthwise: usize,
    /// `Resize` nodes now `Resize2d`.
    pub resize: usize,
    /// `ScatterElements` nodes now `ScatterRows`.
    pub scatter_rows: usize,
}

/// Apply the rewrites to `model` in place. Patterns that are absent are left
/// alone (the report says what was found); anything unexpected in a pattern is an error.
pub fn rewrite(model: &mut ModelProto) -> Result<RewriteReport, String> {
    let graph = model.graph.as_mut().ok_or("the file holds no graph")?;
    let ifs_inlined = inline_empty_guard_ifs(graph)?;
    let pasted_output = cut_paste_loop(graph)?;
    let slices_clamped = clamp_slices(graph);
    let depthwise = replace_nodes(graph, depthwise_conv);
    let resize = replace_nodes(graph, |_, node| resize_by_sizes(node));
    let scatter_rows = replace_nodes(graph, scatter_by_rows);
    if depthwise + resize + scatter_rows > 0 && !model.opset_import.iter().any(|o| o.domain == TRICONS_DOMAIN) {
        model.opset_import.push(tract_onnx::pb::OperatorSetIdProto { domain: TRICONS_DOMAIN.into(), version: 1 });
    }
    Ok(RewriteReport { ifs_inlined, slices_clamped, pasted_output, depthwise, resize, scatter_rows })
}

/// `Resize2d` for a `Resize(X, roi, scales, sizes)` with only `sizes` given and the
/// attributes of one of its two forms (defaults as ONNX's); `None` for anything else.
fn resize_by_sizes(node: &NodeProto) -> Option<NodeProto> {
    if node.op_type != "Resize" || node.input.len() != 4 || node.output.len() != 1 {
        return None;
    }
    let empty = |i: usize| node.input[i].is_empty();
    if !empty(1) || !empty(2) || empty(3) {
        return None;
    }
    let plain = proto::attr_i(node, "antialias", 0) == 0
        && proto::attr_i(node, "exclude_outside", 0) == 0
        && proto::attr_s(node, "keep_aspect_ratio_policy", "stretch") == "stretch"
        && proto::attr(node, "axes").is_none();
    let coordinates = proto::attr_s(node, "coordinate_transformation_mode", "half_pixel");
    let mode = match proto::attr_s(node, "mode", "nearest") {
        "linear" if coordinates == "half_pixel" => "linear",
        "nearest"
            if coordinates == "asymmetric" && proto::attr_s(node, "nearest_mode", "round_prefer_floor") == "floor" =>
        {
            "nearest"
        }
        _ => return None,
    };
    plain.then(|| NodeProto {
        name: node.name.clone(),
        op_type: "Resize2d".into(),
        domain: TRICONS_DOMAIN.into(),
        input: vec![node.input[0].clone(), node.input[3].clone()],
        output: node.output.clone(),
        attribute: vec![proto::a_string("mode", mode)],
        ..Default::default()
    })
}

const TRICONS_DOMAIN: &str = "ai.tricons";

/// `ScatterRows(data, i, updates)` for a `ScatterElements(data, Expand(Reshape(i, s), _),
/// updates)` along axis 0 without reduction, where `s` is a constant `[-1 or n, 1, .., 1]`
/// of rank at least 2: every element of update row `r` then has index `i[r]` (ONNX
/// requires the indices' shape to be the updates'); `None` for anything else.
fn scatter_by_rows(graph: &GraphProto, node: &NodeProto) -> Option<NodeProto> {
    if node.op_type != "ScatterElements" || !node.domain.is_empty() || node.input.len() != 3 {
        return None;
    }
    if proto::attr_i(node, "axis", 0) != 0 || proto::attr_s(node, "reduction", "none") != "none" {
        return None;
    }
    let producer = |name: &str| graph.node.iter().find(|n| n.output.iter().any(|o| o == name));
    let expand = producer(&node.input[1]).filter(|n| n.op_type == "Expand" && n.input.len() == 2)?;
    let reshape = producer(&expand.input[0]).filter(|n| n.op_type == "Reshape" && n.input.len() == 2)?;
    if proto::attr_i(reshape, "allowzero", 0) != 0 {
        return None;
    }
    let shape = constant_i64(graph, &reshape.input[1])?;
    let rows_only = shape.len() >= 2 && (shape[0] == -1 || shape[0] > 0) && shape[1..].iter().all(|&d| d == 1);
    rows_only.then(|| NodeProto {
        name: node.name.clone(),
        op_type: "ScatterRows".into(),
        domain: TRICONS_DOMAIN.into(),
        input: vec![node.input[0].clone(), reshape.input[0].clone(), node.input[2].clone()],
        output: node.output.clone(),
        ..Default::default()
    })
}

/// `DepthwiseConv2d` for a 2-D `Conv` with explicit (or no) padding, `group` = C and a
/// constant weight `(C, 1, kh, kw)` (and bias, if any); `None` for anything else.
fn depthwise_conv(graph: &GraphProto, node: &NodeProto) -> Option<NodeProto> {
    if node.op_type != "Conv" || !(2..=3).contains(&node.input.len()) || node.output.len() != 1 {
        return None;
    }
    let group = proto::attr_i(node, "group", 1);
    let auto_pad = proto::attr_s(node, "auto_pad", "NOTSET");
    let w = proto::constant(graph, &node.input[1])?;
    let [c, 1, kh, kw] = w.dims[..] else { return None };
    if group < 2 || group != c || kh < 1 || kw < 1 || !(auto_pad == "NOTSET" || auto_pad.is_empty()) {
        return None;
    }
    let weight = proto::tensor_f32(w)?;
    let bias = match node.input.get(2).filter(|b| !b.is_empty()) {
        Some(b) => proto::tensor_f32(proto::constant(graph, b)?)?,
        None => vec![0.0; c as usize],
    };
    let ints = |name: &str, len: usize, default: i64| -> Option<Vec<i64>> {
        let v = proto::attr(node, name).map_or_else(|| vec![default; len], |a| a.ints.clone());
        // kernel sizes, strides and dilations positive, pads not negative
        let least = default.min(1);
        (v.len() == len && v.iter().all(|&x| x >= least)).then_some(v)
    };
    let kernel = ints("kernel_shape", 2, 1)?;
    if kernel != [kh, kw] || weight.len() != (c * kh * kw) as usize || bias.len() != c as usize {
        return None;
    }
    Some(NodeProto {
        name: node.name.clone(),
        op_type: "DepthwiseConv2d".into(),
        domain: TRICONS_DOMAIN.into(),
        input: vec![node.input[0].clone()],
        output: node.output.clone(),
        attribute: vec![
            proto::a_tensor("weight", &[c as usize, kh as usize, kw as usize], &weight),
            proto::a_floats("bias", bias),
            proto::a_ints("kernel_shape", kernel),
            proto::a_ints("strides", ints("strides", 2, 1)?),
            proto::a_ints("pads", ints("pads", 4, 0)?),
            proto::a_ints("dilations", ints("dilations", 2, 1)?),
        ],
        ..Default::default()
    })
}

/// Replace every node `with` gives a replacement for; the count.
fn replace_nodes(graph: &mut GraphProto, with: impl Fn(&GraphProto, &NodeProto) -> Option<NodeProto>) -> usize {
    let replaced: Vec<Option<NodeProto>> = graph.node.iter().map(|n| with(graph, n)).collect();
    let mut count = 0;
    for (node, new) in graph.node.iter_mut().zip(replaced) {
        if let Some(new) = new {
            *node = new;
            count += 1;
        }
    }
    count
}

/// Replace `If(cond) then {constants} else {work}` by the else-branch's nodes.
fn inline_empty_guard_ifs(graph: &mut GraphProto) -> Result<usize, String> {
    let mut count = 0;
    let mut nodes = Vec::with_capacity(graph.node.len());
    for node in std::mem::take(&mut graph.node) {
        if node.op_type != "If" {
            nodes.push(node);
            continue;
        }
        let (Some(then_g), Some(else_g)) = (
            attr(&node, "then_branch").and_then(|a| a.g.as_ref()),
            attr(&node, "else_branch").and_then(|a| a.g.as_ref()),
        ) else {
            nodes.push(node);
            continue;
        };
        let guard = then_g.node.iter().all(|n| n.op_type == "Constant")
            && else_g.output.len() == node.output.len()
            && else_g.input.is_empty();
        if !guard {
            nodes.push(node);
            continue;
        }
        graph.initializer.extend(else_g.initializer.iter().cloned());
        nodes.extend(else_g.node.iter().cloned());
        for (inner, outer) in else_g.output.iter().zip(&node.output) {
            nodes.push(NodeProto {
                name: format!("{}.inlined.{}", node.name, outer),
                op_type: "Identity".into(),
                input: vec![inner.name.clone()],
                output: vec![outer.clone()],
                ..Default::default()
            });
        }
        count += 1;
    }
    graph.node = nodes;
    Ok(count)
}

/// Names a subgraph reads from its enclosing scope.
fn outer_references(body: &GraphProto) -> Vec<String> {
    let mut local: HashSet<&str> = body.input.iter().map(|i| i.name.as_str()).collect();
    local.extend(body.initializer.iter().map(|i| i.name.as_str()));
    let mut refs = Vec::new();
    for n in &body.node {
        for i in &n.input {
            if !i.is_empty() && !local.contains(i.as_str()) && !refs.contains(i) {
                refs.push(i.clone());
            }
        }
        local.extend(n.output.iter().map(String::as_str));
    }
    refs
}

/// Remove torchvision's mask-pasting Loop and expose its inputs as graph outputs.
///
/// Recognised by shape: a `Loop` whose first output feeds an `Unsqueeze` that is a
/// graph output, whose body reads a `Pad` output (the masks) and an int64 `Cast`
/// output (the boxes) from the outer graph.
fn cut_paste_loop(graph: &mut GraphProto) -> Result<Option<String>, String> {
    let producers: HashMap<&str, &NodeProto> =
        graph.node.iter().flat_map(|n| n.output.iter().map(move |o| (o.as_str(), n))).collect();
    let outputs: HashSet<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let mut found = None;
    for (li, node) in graph.node.iter().enumerate() {
        if node.op_type != "Loop" || node.output.is_empty() {
            continue;
        }
        let Some(body) = attr(node, "body").and_then(|a| a.g.as_ref()) else { continue };
        let Some((ui, unsqueeze)) = graph
            .node
            .iter()
            .enumerate()
            .find(|(_, n)| n.op_type == "Unsqueeze" && n.input.first() == Some(&node.output[0]))
        else {
            continue;
        };
        if unsqueeze.output.len() != 1 || !outputs.contains(unsqueeze.output[0].as_str()) {
            continue;
        }
        let refs = outer_references(body);
        let masks = refs.iter().find(|r| producers.get(r.as_str()).is_some_and(|p| p.op_type == "Pad"));
        let boxes = refs.iter().find(|r| {
            producers.get(r.as_str()).is_some_and(|p| {
                p.op_type == "Cast"
                    && attr(p, "to").is_some_and(|a| a.i == tensor_proto::DataType::Int64 as i64)
                    && p.input.first().and_then(|i| producers.get(i.as_str())).is_some_and(|q| q.op_type == "Concat")
            })
        });
        let (Some(masks), Some(boxes)) = (masks, boxes) else {
            return Err(format!(
                "Loop {:?} feeds output {:?} but does not read padded masks and int64 boxes; \
                 is this a torchvision Mask R-CNN export?",
                node.name, unsqueeze.output[0]
            ));
        };
        found = Some((li, ui, masks.clone(), boxes.clone(), unsqueeze.output[0].clone()));
        break;
    }
    let Some((li, ui, masks, boxes, out)) = found else { return Ok(None) };
    let (first, second) = if li > ui { (li, ui) } else { (ui, li) };
    graph.node.remove(first);
    graph.node.remove(second);
    let pos = graph.output.iter().position(|o| o.name == out).ok_or("pasted output vanished")?;
    graph.output.remove(pos);
    for (name, src) in [(PASTE_MASKS_OUTPUT, masks), (PASTE_BOXES_OUTPUT, boxes)] {
        graph.node.push(NodeProto {
            name: name.into(),
            op_type: "Identity".into(),
            input: vec![src],
            output: vec![name.into()],
            ..Default::default()
        });
        graph.output.push(ValueInfoProto { name: name.into(), ..Default::default() });
    }
    Ok(Some(out))
}

/// An int64 constant (initializer or `Constant` node) by name.
fn constant_i64(graph: &GraphProto, name: &str) -> Option<Vec<i64>> {
    proto::constant(graph, name).and_then(proto::tensor_i64)
}

/// Constant slice ends at or above this mean "to the end" (torch writes `i64::MAX`) and
/// are left alone; tract handles those.
const MAX_CLAMPED_END: i64 = 1 << 31;

/// `ends := Min(ends, Gather(Shape(data), axes))` on every Slice with constant positive
/// ends below [`MAX_CLAMPED_END`], explicit axes and positive (or absent) steps.
fn clamp_slices(graph: &mut GraphProto) -> usize {
    let forward: Vec<bool> = graph
        .node
        .iter()
        .map(|node| {
            node.op_type == "Slice"
                && node.input.len() >= 4
                && !node.input[3].is_empty()
                && constant_i64(graph, &node.input[2]).is_some_and(|e| e.iter().all(|&v| v > 0 && v < MAX_CLAMPED_END))
                && match node.input.get(4).filter(|s| !s.is_empty()) {
                    None => true,
                    Some(steps) => constant_i64(graph, steps).is_some_and(|s| s.iter().all(|&v| v > 0)),
                }
        })
        .collect();
    let mut count = 0;
    let mut nodes = Vec::with_capacity(graph.node.len());
    for (mut node, forward) in std::mem::take(&mut graph.node).into_iter().zip(forward) {
        if !forward {
            nodes.push(node);
            continue;
        }
        let base = format!("{}.clamp{count}", if node.name.is_empty() { &node.output[0] } else { &node.name });
        let (shape, dims, ends) = (format!("{base}.shape"), format!("{base}.dims"), format!("{base}.ends"));
        nodes.push(NodeProto {
            name: shape.clone(),
            op_type: "Shape".into(),
            input: vec![node.input[0].clone()],
            output: vec![shape.clone()],
            ..Default::default()
        });
        nodes.push(NodeProto {
            name: dims.clone(),
            op_type: "Gather".into(),
            input: vec![shape, node.input[3].clone()],
            output: vec![dims.clone()],
            attribute: vec![proto::a_int("axis", 0)],
            ..Default::default()
        });
        nodes.push(NodeProto {
            name: ends.clone(),
            op_type: "Min".into(),
            input: vec![node.input[2].clone(), dims],
            output: vec![ends.clone()],
            ..Default::default()
        });
        node.input[2] = ends;
        nodes.push(node);
        count += 1;
    }
    graph.node = nodes;
    count
}

/// Ops a score tensor may pass through between the class `Softmax` and the score floor.
const SCORE_PATH_OPS: [&str; 7] = ["Reshape", "Slice", "Flatten", "Gather", "Squeeze", "Unsqueeze", "Identity"];

/// A scalar f32 constant (initializer or `Constant` node) by name.
fn constant_f32_scalar(graph: &GraphProto, name: &str) -> Option<f32> {
    let t = proto::constant(graph, name)?;
    if t.dims.iter().product::<i64>() != 1 {
        return None;
    }
    proto::tensor_f32(t)?.first().copied()
}

/// The graph's detection score floor: the one `Greater(scores, c)` with a scalar f32
/// constant `c` whose scores come from a `Softmax` (torchvision's
/// `postprocess_detections`: `scores > box_score_thresh`, before NMS, the top-k and the
/// mask head). Returns the node index and `c`.
fn find_score_floor(graph: &GraphProto) -> Result<Option<(usize, f32)>, String> {
    let producers: HashMap<&str, &NodeProto> =
        graph.node.iter().flat_map(|n| n.output.iter().map(move |o| (o.as_str(), n))).collect();
    let from_softmax = |start: &str| {
        let mut name = start.to_string();
        for _ in 0..16 {
            match producers.get(name.as_str()) {
                Some(p) if p.op_type == "Softmax" => return true,
                Some(p) if SCORE_PATH_OPS.contains(&p.op_type.as_str()) && !p.input.is_empty() => {
                    name = p.input[0].clone()
                }
                _ => return false,
            }
        }
        false
    };
    let found: Vec<(usize, f32)> = graph
        .node
        .iter()
        .enumerate()
        .filter(|(_, n)| n.op_type == "Greater" && n.input.len() == 2 && from_softmax(&n.input[0]))
        .filter_map(|(i, n)| constant_f32_scalar(graph, &n.input[1]).map(|c| (i, c)))
        .collect();
    match found.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(*one)),
        many => {
            Err(format!("{} score floors (Greater of softmax scores and a constant) found; expected one", many.len()))
        }
    }
}

/// Raise the graph's detection score floor to `min_score` so that everything after it
/// (per-class NMS, the top-k, the box decoding of the kept ones and the mask head) only
/// sees detections the card keeps. Detections scoring at least `min_score` are exactly
/// those of the unchanged graph: a lower-scoring box never suppresses a higher one in
/// NMS, and the top-k is by score. `Greater(s, c)` becomes `Greater(s, next_down(min_score))`,
/// which is `s >= min_score`, the card's rule. Returns the floor found (`None`: no floor
/// in the graph, nothing changed); a floor already at or above `min_score` is kept.
pub fn raise_score_floor(model: &mut ModelProto, min_score: f32) -> Result<Option<f32>, String> {
    let graph = model.graph.as_mut().ok_or("the file holds no graph")?;
    let Some((index, floor)) = find_score_floor(graph)? else { return Ok(None) };
    let raised = min_score.next_down();
    if !raised.is_finite() || raised <= floor {
        return Ok(Some(floor));
    }
    let name = format!("tricons.score_floor.{index}");
    graph.initializer.push(TensorProto {
        name: name.clone(),
        data_type: tensor_proto::DataType::Float as i32,
        float_data: vec![raised],
        ..Default::default()
    });
    graph.node[index].input[1] = name;
    Ok(Some(floor))
}

/// The graph's detection score floor (see [`raise_score_floor`]), if it has one.
pub fn score_floor(model: &ModelProto) -> Result<Option<f32>, String> {
    let graph = model.graph.as_ref().ok_or("the file holds no graph")?;
    Ok(find_score_floor(graph)?.map(|(_, c)| c))
}
