//! Calibration: observe the float model's activations, then decide per candidate node
//! whether it runs in int8, with which input parameters, which followers it absorbs
//! and whether its output stays int8 ([`build_profile`]).
//!
//! The model-specific drivers (pose: instances through the real preprocessing;
//! segmenter: whole images) live with their runtimes and feed a [`StatsCollector`].

use std::collections::{HashMap, HashSet};

use tract_onnx::pb::{GraphProto, ModelProto, ValueInfoProto};
use tract_onnx::prelude::*;

use super::params::{QParams, RangeMethod, TensorStats, quantize_weights_per_channel, sqnr_db};
use super::profile::{CalibrationInfo, FloatNode, ModelKind, PROFILE_FORMAT, PROFILE_VERSION, QuantNode, QuantProfile};
use super::rewrite::{Candidate, Constants, candidates, weight_matrix};
use crate::error::{Error, Result};

/// Where an observed tensor comes from in a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Slot {
    /// A graph input, by index.
    Input(usize),
    /// A graph output (added for calibration if needed), by index.
    Output(usize),
}

/// Statistics of named tensors over calibration runs of a model.
#[derive(Debug)]
pub struct StatsCollector {
    names: Vec<String>,
    slots: Vec<Slot>,
    stats: Vec<TensorStats>,
    runs: usize,
}

impl StatsCollector {
    /// Make every tensor in `names` observable: a copy of `proto` whose graph outputs
    /// include them (graph inputs are read from the run's inputs), and the collector.
    pub fn new(proto: &ModelProto, names: &[String]) -> Result<(ModelProto, StatsCollector)> {
        let mut proto = proto.clone();
        let graph = proto.graph.as_mut().ok_or_else(|| Error::InvalidArgument("the model holds no graph".into()))?;
        let initializers: HashSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
        let inputs: Vec<String> =
            graph.input.iter().map(|i| i.name.clone()).filter(|n| !initializers.contains(n.as_str())).collect();
        let mut slots = Vec::with_capacity(names.len());
        for name in names {
            if let Some(i) = inputs.iter().position(|n| n == name) {
                slots.push(Slot::Input(i));
            } else if let Some(i) = graph.output.iter().position(|o| &o.name == name) {
                slots.push(Slot::Output(i));
            } else {
                graph.output.push(ValueInfoProto { name: name.clone(), ..Default::default() });
                slots.push(Slot::Output(graph.output.len() - 1));
            }
        }
        let stats = vec![TensorStats::default(); names.len()];
        Ok((proto, StatsCollector { names: names.to_vec(), slots, stats, runs: 0 }))
    }

    /// [`Self::new`] for the activation inputs of every quantizable candidate of `proto`.
    pub fn for_candidates(proto: &ModelProto) -> Result<(ModelProto, StatsCollector)> {
        let graph = proto.graph.as_ref().ok_or_else(|| Error::InvalidArgument("the model holds no graph".into()))?;
        Self::new(proto, &observed_tensors(graph))
    }

    /// Account one run: the inputs given and the outputs returned.
    pub fn observe(&mut self, inputs: &[TValue], outputs: &[TValue]) -> Result<()> {
        for ((name, slot), st) in self.names.iter().zip(&self.slots).zip(&mut self.stats) {
            let t = match *slot {
                Slot::Input(i) => inputs.get(i),
                Slot::Output(i) => outputs.get(i),
            }
            .ok_or_else(|| Error::Inference(format!("calibration: tensor {name:?} missing from the run")))?;
            if t.datum_type() != f32::datum_type() {
                continue;
            }
            let values = t
                .try_as_plain_ram()
                .and_then(|v| v.as_slice::<f32>())
                .map_err(|e| Error::Inference(format!("{e:#}")))?;
            st.observe(values, t.rank());
        }
        self.runs += 1;
        Ok(())
    }

    /// Runs observed so far.
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// The statistics by tensor name.
    pub fn into_stats(self) -> HashMap<String, TensorStats> {
        self.names.into_iter().zip(self.stats).collect()
    }
}

/// The activation inputs of the quantizable candidates of `graph` (what to observe).
pub fn observed_tensors(graph: &GraphProto) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for c in candidates(graph).into_iter().filter(|c| c.unsupported.is_none()) {
        if !names.contains(&c.input) {
            names.push(c.input);
        }
    }
    names
}

/// Choices of `tricons quantize`.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantizeOptions {
    /// How activation ranges are chosen.
    pub range: RangeMethod,
    /// Nodes whose input or weight SQNR (dB) is below this stay float.
    pub min_sqnr_db: f64,
    /// Nodes whose name contains one of these stay float.
    pub keep_float: Vec<String>,
    /// Let consecutive int8 linear layers pass u7 activations (no float round trip).
    pub chain: bool,
    /// Keep this many nodes float: those whose quantization alone changes the model's
    /// outputs most on calibration samples (pose models; one model build per int8 node).
    pub sensitivity: usize,
}

impl Default for QuantizeOptions {
    fn default() -> Self {
        QuantizeOptions {
            range: RangeMethod::MinMax,
            min_sqnr_db: 20.0,
            keep_float: Vec::new(),
            chain: true,
            sensitivity: 0,
        }
    }
}

/// The model a profile is for: kind, path relative to the profile, graph sha256.
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileTarget {
    /// Pose or segmenter.
    pub kind: ModelKind,
    /// The float model (card or ONNX) relative to the profile's directory.
    pub model: std::path::PathBuf,
    /// sha256 of the float ONNX.
    pub onnx_sha256: String,
}

/// Decide the int8 nodes of `graph` from calibration `stats` (see the module docs).
/// A model where nothing can be quantized is an error.
pub fn build_profile(
    target: ProfileTarget,
    graph: &GraphProto,
    stats: &HashMap<String, TensorStats>,
    opts: &QuantizeOptions,
    calibration: CalibrationInfo,
) -> Result<QuantProfile> {
    let consts = Constants::new(graph);
    let mut nodes: Vec<QuantNode> = Vec::new();
    let mut float: Vec<FloatNode> = Vec::new();
    let all = candidates(graph);
    for c in &all {
        let keep = |reason: String, float: &mut Vec<FloatNode>| {
            float.push(FloatNode { node: c.node.clone(), op: c.op.clone(), reason })
        };
        if let Some(why) = &c.unsupported {
            keep(why.clone(), &mut float);
            continue;
        }
        if let Some(p) = opts.keep_float.iter().find(|p| c.node.contains(p.as_str())) {
            keep(format!("--keep-float {p}"), &mut float);
            continue;
        }
        let Some((st, (lo, hi))) = stats.get(&c.input).and_then(|s| Some((s, s.range(opts.range)?))) else {
            keep("no calibration value reached its input".into(), &mut float);
            continue;
        };
        let input_q = QParams::from_range(lo, hi);
        let input_sqnr_db = st.sqnr_db(&input_q);
        let weight_sqnr_db = match weight_matrix(&graph.node[c.index], &consts) {
            Ok(Some(w)) => {
                let (q, s) = quantize_weights_per_channel(&w.w, w.k, w.n);
                sqnr_db(w.w.iter().enumerate().map(|(i, &x)| (x, q[i] as f32 * s[i % w.n])))
            }
            _ => f64::NAN,
        };
        if !(input_sqnr_db >= opts.min_sqnr_db && weight_sqnr_db >= opts.min_sqnr_db) {
            keep(
                format!(
                    "SQNR input {input_sqnr_db:.1} dB, weight {weight_sqnr_db:.1} dB, below {} dB",
                    opts.min_sqnr_db
                ),
                &mut float,
            );
            continue;
        }
        let mut fuse: Vec<String> = c.chain.iter().map(|(op, _)| op.clone()).collect();
        if c.op != "Conv" && st.rank != 2 {
            // A normalisation over axis 1 is the output channel only for rank-2 inputs.
            if let Some(i) = fuse.iter().position(|f| f == "BatchNormalization") {
                fuse.truncate(i);
            }
        }
        nodes.push(QuantNode {
            node: c.node.clone(),
            op: c.op.clone(),
            input: c.input.clone(),
            input_q,
            input_u7: false,
            fuse,
            output_u7: None,
            input_sqnr_db: round2(input_sqnr_db),
            weight_sqnr_db: round2(weight_sqnr_db),
        });
    }
    if nodes.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "no node of the model can run in int8 ({} candidates: {})",
            all.len(),
            if float.is_empty() {
                "the graph has no MatMul, Gemm or Conv with a constant weight".to_string()
            } else {
                float.iter().map(|f| format!("{}: {}", f.node, f.reason)).take(5).collect::<Vec<_>>().join("; ")
            }
        )));
    }
    if opts.chain {
        chain_u7(graph, &all, &mut nodes);
    }
    Ok(QuantProfile {
        format: PROFILE_FORMAT.into(),
        version: PROFILE_VERSION,
        kind: target.kind,
        model: target.model,
        onnx_sha256: target.onnx_sha256,
        range: opts.range,
        min_sqnr_db: opts.min_sqnr_db,
        calibration,
        nodes,
        float,
    })
}

fn round2(x: f64) -> f64 {
    if x.is_finite() { (x * 100.0).round() / 100.0 } else { 999.0 }
}

/// A linear int8 node whose (fused) output feeds only int8 linear nodes that read it
/// as their input writes u7 for them.
fn chain_u7(graph: &GraphProto, all: &[Candidate], nodes: &mut [QuantNode]) {
    let by_name: HashMap<&str, &Candidate> = all.iter().map(|c| (c.node.as_str(), c)).collect();
    let mut consumers: HashMap<&str, Vec<&str>> = HashMap::new();
    for n in &graph.node {
        for i in &n.input {
            consumers.entry(i.as_str()).or_default().push(n.name.as_str());
        }
    }
    let outputs: HashSet<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let index: HashMap<String, usize> = nodes.iter().enumerate().map(|(i, n)| (n.node.clone(), i)).collect();
    let mut links: Vec<(usize, Vec<usize>)> = Vec::new();
    for (i, q) in nodes.iter().enumerate() {
        if q.op == "Conv" {
            continue;
        }
        let Some(c) = by_name.get(q.node.as_str()) else { continue };
        let out = c.output_after(graph, q.fuse.len());
        if outputs.contains(out) {
            continue;
        }
        let Some(users) = consumers.get(out) else { continue };
        let targets: Option<Vec<usize>> = users
            .iter()
            .map(|u| index.get(*u).copied().filter(|&j| nodes[j].op != "Conv" && nodes[j].input == out))
            .collect();
        if let Some(t) = targets.filter(|t| !t.is_empty()) {
            links.push((i, t));
        }
    }
    for (producer, users) in links {
        let q = nodes[users[0]].input_q;
        nodes[producer].output_u7 = Some(q);
        for u in users {
            nodes[u].input_u7 = true;
        }
    }
}

/// `profile` with only its node `index` in int8 (no u7 hand-over), for sensitivity runs.
pub fn single_node_profile(profile: &QuantProfile, index: usize) -> QuantProfile {
    let mut node = profile.nodes[index].clone();
    node.input_u7 = false;
    node.output_u7 = None;
    QuantProfile { nodes: vec![node], float: Vec::new(), ..profile.clone() }
}

/// Move the `count` nodes with the largest `errors` (one per profile node: the output
/// error when it alone runs in int8) to float, then re-link the u7 hand-overs.
pub fn keep_most_sensitive_float(
    profile: &mut QuantProfile,
    graph: &GraphProto,
    errors: &[f64],
    count: usize,
    chain: bool,
) {
    let mut order: Vec<usize> = (0..profile.nodes.len().min(errors.len())).collect();
    order.sort_by(|&a, &b| errors[b].total_cmp(&errors[a]).then(a.cmp(&b)));
    let drop: HashSet<usize> = order.iter().take(count.min(order.len().saturating_sub(1))).copied().collect();
    let mut kept = Vec::new();
    for (i, mut n) in std::mem::take(&mut profile.nodes).into_iter().enumerate() {
        if drop.contains(&i) {
            let rank = order.iter().position(|&j| j == i).unwrap_or(0) + 1;
            profile.float.push(FloatNode {
                node: n.node,
                op: n.op,
                reason: format!("sensitivity: alone in int8 it changes the outputs by {:.2e} (rank {rank})", errors[i]),
            });
        } else {
            n.input_u7 = false;
            n.output_u7 = None;
            kept.push(n);
        }
    }
    if chain {
        chain_u7(graph, &candidates(graph), &mut kept);
    }
    profile.nodes = kept;
}

/// Relative squared error of `got` against `want`, averaged over the f32 outputs whose
/// shapes agree.
pub fn output_error(want: &[TValue], got: &[TValue]) -> f64 {
    let mut total = 0f64;
    let mut n = 0;
    for (a, b) in want.iter().zip(got) {
        let (Ok(a), Ok(b)) = (a.try_as_plain_ram(), b.try_as_plain_ram()) else { continue };
        let (Ok(a), Ok(b)) = (a.as_slice::<f32>(), b.as_slice::<f32>()) else { continue };
        if a.len() != b.len() {
            continue;
        }
        let num: f64 = a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
        let den: f64 = a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().max(1e-30);
        total += num / den;
        n += 1;
    }
    if n == 0 { 0.0 } else { total / n as f64 }
}
