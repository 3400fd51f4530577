//! `tricons bench`: latency of the pose model per object and per frame, with the share of
//! each custom operator (a benchmark, not a test: numbers go to docs/results.md).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use tricons::atomic::write_atomic;
use tricons::ops::profile;
use tricons::pose::PoseEstimator;
use tricons::recording::open_recording;
use tricons::rng::mix_seed;

use crate::common::{DEFAULT_MODEL, DEFAULT_RECORDING};
use crate::progress;

/// Arguments of `tricons bench`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons bench                                        # shipped model, demo recording\n  \
    tricons bench --model data/models/tricons-pose-paper.card.json --runs 5 --json data/bench/paper.json\n  \
    tricons bench --segmenter models/maskrcnn-light.card.json --runs 10\n  \
    tricons bench --segmenter models/maskrcnn-light.card.json --int8 models/maskrcnn-light.int8.json --profile-graph\n  \
    tricons bench --int8 models/tricons-pose.int8.json    # float and int8 side by side\n  \
    tricons bench --threads 1,2 --int8 models/tricons-pose.int8.json\n  \
    tricons bench --pipeline --model models/tricons-pose.int8.json --segmenter models/maskrcnn-light.int8.json --threads 1,2\n\n\
    Per object: the graph on one instance. Per frame: preprocessing plus the graph on every instance\n\
    of a recording frame (ground-truth masks), the instances spread over the worker threads.\n\
    Per object and the operator shares run on one thread; the per-frame graph at each --threads\n\
    count. --pipeline: Mask R-CNN then the pose model on its detections, per frame, at each count.\n\
    Medians over --runs after --warmup.")]
pub struct Args {
    /// Pose model: its card (`*.card.json`) or graph (`*.onnx`, card beside it).
    #[arg(long, default_value = DEFAULT_MODEL)]
    model: PathBuf,
    /// Recording whose frames (with ground-truth masks) give the inputs.
    #[arg(long, default_value = DEFAULT_RECORDING)]
    recording: PathBuf,
    /// Timed repetitions of each measurement.
    #[arg(long, default_value_t = 20)]
    runs: usize,
    /// Untimed repetitions before timing.
    #[arg(long, default_value_t = 2)]
    warmup: usize,
    /// Seed of the point sampling (as `tricons replay --seed`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also time every graph node once (batch 1 and the first frame's batch) and print the
    /// operators taking the most time; with --segmenter, every node of its plan (the int8
    /// one when --int8 is given), by operator and the slowest nodes.
    #[arg(long)]
    profile_graph: bool,
    /// Benchmark this Mask R-CNN (card or graph) on the recording's first frame instead of
    /// the pose model: frame latency, RoiAlign / NMS shares, NMS on 90k candidates.
    #[arg(long)]
    segmenter: Option<PathBuf>,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// int8 profile of the same model (`tricons quantize` output): measured in the same run
    /// on the same inputs, after the float model, and reported side by side.
    #[arg(long)]
    int8: Option<PathBuf>,
    /// Worker thread counts to measure (comma-separated) [default: the cores available].
    #[arg(long, value_name = "N,..", value_delimiter = ',')]
    threads: Vec<usize>,
    /// The whole per-frame work: --segmenter (default the shipped one) then --model on its
    /// detections, at each --threads count.
    #[arg(long)]
    pipeline: bool,
}

/// Latency statistics of one measurement, milliseconds.
#[derive(Serialize)]
pub(crate) struct Stats {
    pub(crate) median_ms: f64,
    pub(crate) p10_ms: f64,
    pub(crate) p90_ms: f64,
    samples: usize,
}

impl Stats {
    pub(crate) fn of(durations: &[Duration]) -> Stats {
        let mut ms: Vec<f64> = durations.iter().map(|d| d.as_secs_f64() * 1e3).collect();
        ms.sort_by(f64::total_cmp);
        let q = |p: f64| ms.get(((ms.len() - 1) as f64 * p).round() as usize).copied().unwrap_or(f64::NAN);
        Stats { median_ms: q(0.5), p10_ms: q(0.1), p90_ms: q(0.9), samples: ms.len() }
    }
}

/// One custom operator's share of the graph time.
#[derive(Serialize)]
pub(crate) struct OpShare {
    pub(crate) node_type: &'static str,
    pub(crate) calls_per_run: f64,
    pub(crate) ms_per_run: f64,
    pub(crate) share_of_graph: f64,
}

#[derive(Serialize)]
struct Report {
    runtime: &'static str,
    model: String,
    config_name: String,
    n_points: usize,
    crop_size: usize,
    threads: usize,
    machine: String,
    load_s: f64,
    per_object: Stats,
    per_object_ops: Vec<OpShare>,
    per_object_custom_share: f64,
    frames: usize,
    instances_per_frame: f64,
    per_frame: Stats,
    per_frame_preprocess: Stats,
    per_frame_graph: Stats,
    /// The same frames' instances run one at a time (batch 1 each), summed per frame.
    per_frame_graph_one_by_one: Stats,
    per_frame_ops: Vec<OpShare>,
    per_frame_custom_share: f64,
    /// The int8 profile's measurements on the same inputs (`--int8`).
    #[serde(skip_serializing_if = "Option::is_none")]
    int8: Option<Int8Report>,
    /// The per-frame graph (every instance of a frame) at each `--threads` count.
    per_frame_graph_by_threads: Vec<ThreadsRow>,
}

/// The per-frame graph time at one worker-thread count.
#[derive(Serialize)]
struct ThreadsRow {
    threads: usize,
    float: Stats,
    #[serde(skip_serializing_if = "Option::is_none")]
    int8: Option<Stats>,
}

/// The int8 model in the same run.
#[derive(Serialize)]
struct Int8Report {
    profile: String,
    int8_nodes: usize,
    load_s: f64,
    per_object: Stats,
    per_frame_graph: Stats,
    /// Float median over int8 median, per object (batch 1).
    speedup_per_object: f64,
    /// The same per frame (graph, batched).
    speedup_per_frame_graph: f64,
}

pub fn run(args: Args) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    if args.threads.contains(&0) {
        bail!("--threads: counts must be at least 1");
    }
    let threads = if args.threads.is_empty() { vec![crate::common::available_threads()] } else { args.threads.clone() };
    if args.pipeline {
        let segmenter = args.segmenter.clone().unwrap_or_else(|| PathBuf::from(crate::common::DEFAULT_SEGMENTER));
        return crate::bench_pipeline::run(crate::bench_pipeline::PipelineBench {
            model: &args.model,
            segmenter: &segmenter,
            recording: &args.recording,
            threads: &threads,
            runs: args.runs,
            warmup: args.warmup,
            seed: args.seed,
            json: args.json.as_deref(),
        });
    }
    if let Some(seg) = &args.segmenter {
        let int8 = args.int8.as_deref();
        let opts = crate::bench_segment::Options {
            threads: &threads,
            runs: args.runs,
            warmup: args.warmup,
            json: args.json.as_deref(),
            profile_graph: args.profile_graph,
        };
        return crate::bench_segment::run(seg, int8, &args.recording, &opts);
    }
    let rec = open_recording(&args.recording).with_context(|| "opening the recording (--recording)")?;
    let t_load = Instant::now();
    let mut estimator = PoseEstimator::load(&args.model).with_context(|| "loading the pose model (--model)")?;
    let load_s = t_load.elapsed().as_secs_f64();
    let cfg = estimator.preprocess_config().clone();
    log::info!("model {} ({}) loaded in {load_s:.2} s", estimator.card_path().display(), estimator.card().config_name);

    let mut frames = Vec::new();
    for i in 0..rec.len() {
        let frame = rec.read_frame(i)?;
        let masks = rec.read_annotations(i)?.and_then(|a| a.instance_masks()).unwrap_or_default();
        if !masks.is_empty() {
            frames.push((i, frame, masks));
        }
    }
    let first_input = frames
        .iter()
        .find_map(|(i, frame, masks)| {
            let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
            estimator.prepare(frame, &refs, mix_seed(&[args.seed, *i as u64])).ok()?.inputs.into_iter().next()
        })
        .with_context(|| format!("{} has no frame with a usable instance mask", args.recording.display()))?;

    profile::enable(true);
    let bar = progress::bar((args.warmup + args.runs) * (1 + frames.len()), "bench");
    // per object: batch of one
    let one = [first_input];
    for _ in 0..args.warmup {
        estimator.run_inputs(&one)?;
        bar.inc(1);
    }
    profile::reset();
    let mut object_times = Vec::with_capacity(args.runs);
    for _ in 0..args.runs {
        let t = Instant::now();
        estimator.run_inputs(&one)?;
        object_times.push(t.elapsed());
        bar.inc(1);
    }
    let (per_object_ops, per_object_custom_share) = op_shares(args.runs, &object_times);

    // per frame: preprocessing + one batched run
    let (mut frame_times, mut prep_times, mut graph_times, mut instances) = (vec![], vec![], vec![], 0usize);
    for (i, frame, masks) in &frames {
        let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
        for _ in 0..args.warmup {
            estimator.estimate(frame, &refs, mix_seed(&[args.seed, *i as u64]))?;
            bar.inc(1);
        }
    }
    profile::reset();
    for (i, frame, masks) in &frames {
        let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
        for _ in 0..args.runs {
            let t0 = Instant::now();
            let prepared = estimator.prepare(frame, &refs, mix_seed(&[args.seed, *i as u64]))?;
            let t1 = Instant::now();
            estimator.run_inputs(&prepared.inputs)?;
            let t2 = Instant::now();
            prep_times.push(t1 - t0);
            graph_times.push(t2 - t1);
            frame_times.push(t2 - t0);
            instances += prepared.inputs.len();
            bar.inc(1);
        }
    }
    let (per_frame_ops, per_frame_custom_share) = op_shares(frame_times.len(), &graph_times);
    profile::enable(false);
    let mut one_by_one = Vec::new();
    for (i, frame, masks) in &frames {
        let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
        let prepared = estimator.prepare(frame, &refs, mix_seed(&[args.seed, *i as u64]))?;
        for _ in 0..args.runs {
            let t = Instant::now();
            for x in &prepared.inputs {
                estimator.run_inputs(std::slice::from_ref(x))?;
            }
            one_by_one.push(t.elapsed());
        }
    }
    bar.finish_and_clear();

    let mut quantized = None;
    let int8 = match &args.int8 {
        None => None,
        Some(path) => {
            let t = Instant::now();
            let q = PoseEstimator::load(path).with_context(|| "loading the int8 profile (--int8)")?;
            let load_s = t.elapsed().as_secs_f64();
            let (obj, graph) = time_graph(&q, &one, &frames, &args)?;
            let (obj, graph) = (Stats::of(&obj), Stats::of(&graph));
            let int8_nodes = q.quantized().map_or(0, |r| r.quantized);
            quantized = Some(q);
            Some(Int8Report {
                profile: path.display().to_string(),
                int8_nodes,
                load_s,
                speedup_per_object: Stats::of(&object_times).median_ms / obj.median_ms,
                speedup_per_frame_graph: Stats::of(&graph_times).median_ms / graph.median_ms,
                per_object: obj,
                per_frame_graph: graph,
            })
        }
    };

    let mut per_frame_graph_by_threads = Vec::new();
    for &t in &threads {
        estimator.set_threads(t)?;
        let float = Stats::of(&frame_graph_times(&estimator, &frames, &args)?);
        let int8 = match quantized.as_mut() {
            None => None,
            Some(q) => {
                q.set_threads(t)?;
                Some(Stats::of(&frame_graph_times(q, &frames, &args)?))
            }
        };
        per_frame_graph_by_threads.push(ThreadsRow { threads: t, float, int8 });
    }
    let card = estimator.card();
    let report = Report {
        runtime: "tract",
        model: estimator.card_path().display().to_string(),
        config_name: card.config_name.clone(),
        n_points: cfg.n_points,
        crop_size: cfg.crop_size,
        threads: 1,
        machine: machine(),
        load_s,
        per_object: Stats::of(&object_times),
        per_object_ops,
        per_object_custom_share,
        frames: frames.len(),
        instances_per_frame: instances as f64 / frame_times.len().max(1) as f64,
        per_frame: Stats::of(&frame_times),
        per_frame_preprocess: Stats::of(&prep_times),
        per_frame_graph: Stats::of(&graph_times),
        per_frame_graph_one_by_one: Stats::of(&one_by_one),
        per_frame_ops,
        per_frame_custom_share,
        int8,
        per_frame_graph_by_threads,
    };
    print_report(&report);
    if args.profile_graph {
        print_node_profile(&estimator, &one[0], &frames, args.seed)?;
    }
    if let Some(path) = &args.json {
        write_report(path, &report)?;
    }
    Ok(())
}

/// Write a benchmark report as pretty JSON (atomically, creating the directory).
pub(crate) fn write_report(path: &std::path::Path, report: &impl Serialize) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_atomic(path, serde_json::to_string_pretty(report)?.as_bytes())?;
    log::info!("report written to {}", path.display());
    Ok(())
}

/// Per-object (batch 1) and per-frame graph (batched) times of `estimator` on the inputs
/// the float model was measured on.
fn time_graph(
    estimator: &PoseEstimator,
    one: &[tricons::pose::preprocess::PoseInput],
    frames: &[(usize, tricons::frame::RgbdFrame, Vec<Vec<bool>>)],
    args: &Args,
) -> Result<(Vec<Duration>, Vec<Duration>)> {
    for _ in 0..args.warmup {
        estimator.run_inputs(one)?;
    }
    let mut object = Vec::with_capacity(args.runs);
    for _ in 0..args.runs {
        let t = Instant::now();
        estimator.run_inputs(one)?;
        object.push(t.elapsed());
    }
    Ok((object, frame_graph_times(estimator, frames, args)?))
}

/// The graph on every instance of each frame (at the estimator's thread count), `--runs`
/// times per frame after `--warmup`.
fn frame_graph_times(
    estimator: &PoseEstimator,
    frames: &[(usize, tricons::frame::RgbdFrame, Vec<Vec<bool>>)],
    args: &Args,
) -> Result<Vec<Duration>> {
    let mut graph = Vec::new();
    for (i, frame, masks) in frames {
        let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
        let prepared = estimator.prepare(frame, &refs, mix_seed(&[args.seed, *i as u64]))?;
        for _ in 0..args.warmup {
            estimator.run_inputs(&prepared.inputs)?;
        }
        for _ in 0..args.runs {
            let t = Instant::now();
            estimator.run_inputs(&prepared.inputs)?;
            graph.push(t.elapsed());
        }
    }
    Ok(graph)
}

/// Time per tract operator over one run at batch 1 and one over the first frame's batch.
fn print_node_profile(
    estimator: &PoseEstimator,
    one: &tricons::pose::preprocess::PoseInput,
    frames: &[(usize, tricons::frame::RgbdFrame, Vec<Vec<bool>>)],
    seed: u64,
) -> Result<()> {
    let (i, frame, masks) = &frames[0];
    let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
    let batch = estimator.prepare(frame, &refs, mix_seed(&[seed, *i as u64]))?.inputs;
    let single_nodes = estimator.profile_nodes(std::slice::from_ref(one))?;
    let (single, batched) = (by_operator(&single_nodes), by_operator(&estimator.profile_nodes(&batch)?));
    let total = |v: &[(String, usize, Duration)]| v.iter().map(|x| x.2.as_secs_f64()).sum::<f64>() * 1e3;
    println!(
        "graph profile: batch 1 {:.1} ms, batch {} {:.1} ms (one run each)",
        total(&single),
        batch.len(),
        total(&batched)
    );
    println!("{:<28} {:>10} {:>14}", "operator", "batch 1 ms", format!("batch {} ms", batch.len()));
    for (name, _, d) in single.iter().take(15) {
        let b = batched.iter().find(|x| &x.0 == name).map(|x| x.2.as_secs_f64() * 1e3).unwrap_or(f64::NAN);
        println!("{name:<28} {:>10.2} {:>14.2}", d.as_secs_f64() * 1e3, b);
    }
    println!("{:<44} {:>6} {:>10}", "module (batch 1; repeated blocks summed)", "nodes", "ms");
    for (module, n, d) in by_module(&single_nodes).iter().take(15) {
        println!("{module:<44} {n:>6} {:>10.2}", d.as_secs_f64() * 1e3);
    }
    let mut slowest = single_nodes;
    slowest.sort_by_key(|x| std::cmp::Reverse(x.2));
    println!("slowest nodes (batch 1):");
    for (op, node, t) in slowest.iter().take(20) {
        println!("  {:>8.3} ms  {op:<24} {node}", t.as_secs_f64() * 1e3);
    }
    Ok(())
}

/// Node times summed per operator name, with the node count, largest first.
pub(crate) fn by_operator(nodes: &[(String, String, Duration)]) -> Vec<(String, usize, Duration)> {
    let mut per_op: std::collections::BTreeMap<&str, (usize, Duration)> = Default::default();
    for (op, _, t) in nodes {
        let e = per_op.entry(op.as_str()).or_default();
        e.0 += 1;
        e.1 += *t;
    }
    let mut v: Vec<_> = per_op.into_iter().map(|(op, (n, t))| (op.to_string(), n, t)).collect();
    v.sort_by_key(|x| std::cmp::Reverse(x.2));
    v
}

/// The module a node belongs to, from its exported name: the path without its last part,
/// at most five parts deep, with numbered repeats merged (`/model/vit/blocks.3/attn/MatMul`
/// -> `model/vit/blocks.*/attn`).
fn module_of(node: &str) -> String {
    let parts: Vec<&str> = node.trim_start_matches('/').split('/').collect();
    let keep = &parts[..parts.len().saturating_sub(1).clamp(1, 5)];
    let merged: Vec<String> = keep
        .iter()
        .map(|p| match p.rsplit_once('.') {
            Some((stem, n)) if !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) => format!("{stem}.*"),
            _ => p.to_string(),
        })
        .collect();
    merged.join("/")
}

/// Node times summed per module (see [`module_of`]), with the node count, largest first.
fn by_module(nodes: &[(String, String, Duration)]) -> Vec<(String, usize, Duration)> {
    let mut per: std::collections::BTreeMap<String, (usize, Duration)> = Default::default();
    for (_, node, t) in nodes {
        let e = per.entry(module_of(node)).or_default();
        e.0 += 1;
        e.1 += *t;
    }
    let mut v: Vec<_> = per.into_iter().map(|(m, (n, t))| (m, n, t)).collect();
    v.sort_by_key(|x| std::cmp::Reverse(x.2));
    v
}

/// Per-op time per run and share of the total graph time, from the profile counters.
pub(crate) fn op_shares(runs: usize, graph_times: &[Duration]) -> (Vec<OpShare>, f64) {
    let graph_s: f64 = graph_times.iter().map(Duration::as_secs_f64).sum();
    let ops: Vec<OpShare> = profile::snapshot()
        .into_iter()
        .filter(|o| o.calls > 0)
        .map(|o| OpShare {
            node_type: o.node_type,
            calls_per_run: o.calls as f64 / runs as f64,
            ms_per_run: o.total.as_secs_f64() * 1e3 / runs as f64,
            share_of_graph: o.total.as_secs_f64() / graph_s,
        })
        .collect();
    let total = ops.iter().map(|o| o.share_of_graph).sum();
    (ops, total)
}

fn print_report(r: &Report) {
    println!(
        "tract, {} config (N {}, crop {}), 1 thread, {}; model loaded in {:.2} s",
        r.config_name, r.n_points, r.crop_size, r.machine, r.load_s
    );
    println!(
        "per object (batch 1): median {:.2} ms (p10 {:.2}, p90 {:.2}); custom ops {:.1}% of it",
        r.per_object.median_ms,
        r.per_object.p10_ms,
        r.per_object.p90_ms,
        100.0 * r.per_object_custom_share
    );
    println!(
        "per frame ({} frames, {:.2} instances/frame): median {:.2} ms = preprocessing {:.2} + graph {:.2} (one instance at a time: {:.2}); custom ops {:.1}% of the graph",
        r.frames,
        r.instances_per_frame,
        r.per_frame.median_ms,
        r.per_frame_preprocess.median_ms,
        r.per_frame_graph.median_ms,
        r.per_frame_graph_one_by_one.median_ms,
        100.0 * r.per_frame_custom_share
    );
    println!(
        "{:<20} {:>10} {:>12} {:>8}   {:>10} {:>8}",
        "custom op", "calls/obj", "ms/object", "share", "ms/frame", "share"
    );
    for (o, f) in r.per_object_ops.iter().zip(&r.per_frame_ops) {
        println!(
            "{:<20} {:>10.0} {:>12.3} {:>7.1}%   {:>10.3} {:>7.1}%",
            o.node_type,
            o.calls_per_run,
            o.ms_per_run,
            100.0 * o.share_of_graph,
            f.ms_per_run,
            100.0 * f.share_of_graph
        );
    }
    for row in &r.per_frame_graph_by_threads {
        println!(
            "per frame graph, {} thread(s): float {:.2} ms{}",
            row.threads,
            row.float.median_ms,
            row.int8.as_ref().map(|q| format!(", int8 {:.2} ms", q.median_ms)).unwrap_or_default()
        );
    }
    if let Some(q) = &r.int8 {
        println!(
            "int8 ({}, {} int8 nodes, loaded in {:.2} s): per object median {:.2} ms (p10 {:.2}, p90 {:.2}), \
             {:.2}x float; per frame graph {:.2} ms, {:.2}x float",
            q.profile,
            q.int8_nodes,
            q.load_s,
            q.per_object.median_ms,
            q.per_object.p10_ms,
            q.per_object.p90_ms,
            q.speedup_per_object,
            q.per_frame_graph.median_ms,
            q.speedup_per_frame_graph
        );
    }
}

/// CPU model name and core count, for the report.
pub(crate) fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    format!("{cpu}, {cores} cores")
}

#[cfg(test)]
mod tests {
    use super::module_of;

    #[test]
    fn modules_merge_numbered_repeats_and_drop_the_node_name() {
        assert_eq!(
            module_of("/model/image_encoder/vit/blocks.10/mlp/fc1/MatMul"),
            "model/image_encoder/vit/blocks.*/mlp"
        );
        assert_eq!(module_of("/model/piga.4/wk/Add.prefused"), "model/piga.*/wk");
        assert_eq!(module_of("/model/TriangleDescriptor"), "model");
        assert_eq!(module_of("output_R"), "output_R");
        assert_eq!(module_of("/model/sckd/Mul_3.split-over-1.1..197"), "model/sckd");
    }
}
