//! `tricons bench --segmenter`: Mask R-CNN frame latency, with the share of RoiAlign and
//! NMS, and the NMS kernels on a frame with many candidates.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;
use tricons::ops::nms::{BoxFormat, NmsParams, nms, nms_reference};
use tricons::ops::profile;
use tricons::recording::open_recording;
use tricons::rng::Rng;
use tricons::segment::Segmenter;

use crate::bench::{OpShare, Stats, machine, op_shares};

/// Candidates of the synthetic "many boxes" NMS frame (a low-threshold RPN over a
/// 1333-pixel image yields tens of thousands).
const NMS_CANDIDATES: usize = 90_000;

#[derive(Serialize)]
struct SegReport {
    runtime: &'static str,
    model: String,
    machine: String,
    threads: usize,
    width: u32,
    height: u32,
    load_s: f64,
    plan_s: f64,
    /// Detections at the card's score threshold.
    detections: usize,
    /// The card's score threshold, which the graph applies before NMS and the mask head.
    score_threshold: f32,
    /// At the card's threshold (what `segment`, `replay` and `serve` run), one thread.
    per_frame: Stats,
    ops: Vec<OpShare>,
    /// Every detection above the graph's own floor (the work before the floor was raised).
    detections_all: usize,
    per_frame_all: Stats,
    /// The card's threshold at each `--threads` count (float, int8).
    per_frame_by_threads: Vec<SegThreadsRow>,
    nms_candidates: usize,
    nms_kept: usize,
    nms_grid: Stats,
    nms_pairwise: Stats,
    /// The int8 profile on the same frame (`--int8`).
    #[serde(skip_serializing_if = "Option::is_none")]
    int8: Option<SegInt8>,
}

/// Frame latency at one worker-thread count.
#[derive(Serialize)]
struct SegThreadsRow {
    threads: usize,
    float: Stats,
    #[serde(skip_serializing_if = "Option::is_none")]
    int8: Option<Stats>,
}

/// The int8 segmenter in the same run.
#[derive(Serialize)]
struct SegInt8 {
    profile: String,
    int8_nodes: usize,
    load_s: f64,
    plan_s: f64,
    detections: usize,
    per_frame: Stats,
    /// Float median over int8 median.
    speedup: f64,
}

/// Load, plan for `frame` at the card's threshold, warm up, time `runs` frames:
/// (segmenter, load s, plan s, detections, times).
fn timed_segmenter(
    model: &Path,
    frame: &tricons::frame::RgbdFrame,
    runs: usize,
    warmup: usize,
    profiled: bool,
) -> Result<(Segmenter, f64, f64, usize, Vec<Duration>)> {
    let t = Instant::now();
    let seg = Segmenter::load(model).with_context(|| format!("loading the segmenter {}", model.display()))?;
    let load_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    seg.prepare(frame.color.width as usize, frame.color.height as usize)?;
    let plan_s = t.elapsed().as_secs_f64();
    profile::enable(profiled);
    let (detections, times) = time_frames(&seg, frame, runs, warmup)?;
    Ok((seg, load_s, plan_s, detections, times))
}

/// `segment` on `frame`, `runs` times after `warmup` (the profile counters reset after the
/// warm-up): (detections, times).
fn time_frames(
    seg: &Segmenter,
    frame: &tricons::frame::RgbdFrame,
    runs: usize,
    warmup: usize,
) -> Result<(usize, Vec<Duration>)> {
    let mut detections = 0;
    for _ in 0..warmup {
        detections = seg.segment(&frame.color)?.len();
    }
    profile::reset();
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = Instant::now();
        detections = seg.segment(&frame.color)?.len();
        times.push(t.elapsed());
    }
    Ok((detections, times))
}

/// Benchmark `model` on the first frame of `recording`.
/// How `tricons bench --segmenter` measures.
pub struct Options<'a> {
    /// Worker thread counts to measure.
    pub threads: &'a [usize],
    /// Timed repetitions.
    pub runs: usize,
    /// Untimed repetitions first.
    pub warmup: usize,
    /// Also write the report here.
    pub json: Option<&'a Path>,
    /// Also time every node of the plan (`--profile-graph`).
    pub profile_graph: bool,
}

pub fn run(model: &Path, int8: Option<&Path>, recording: &Path, opts: &Options<'_>) -> Result<()> {
    let Options { threads, runs, warmup, json, profile_graph } = *opts;
    let rec = open_recording(recording).with_context(|| "opening the recording (--recording)")?;
    let frame = rec.read_frame(0)?;
    let (mut seg, load_s, plan_s, detections, times) = timed_segmenter(model, &frame, runs, warmup, true)?;
    let (ops, _) = op_shares(runs, &times);
    profile::enable(false);
    let score_threshold = seg.card().score_threshold;
    seg.set_score_threshold(0.0);
    let (detections_all, times_all) = time_frames(&seg, &frame, runs, warmup)?;
    seg.set_score_threshold(score_threshold);

    let (boxes, scores) = many_boxes(NMS_CANDIDATES);
    let p = NmsParams { format: BoxFormat::Corners, max_output: usize::MAX, iou_threshold: 0.7, score_threshold: None };
    let time = |f: &dyn Fn() -> Vec<usize>, n: usize| -> (Vec<Duration>, usize) {
        let mut v = Vec::new();
        let mut kept = 0;
        for _ in 0..n {
            let t = Instant::now();
            kept = f().len();
            v.push(t.elapsed());
        }
        (v, kept)
    };
    let (grid, nms_kept) = time(&|| nms(&boxes, &scores, &p), runs.max(3));
    let (pairwise, kept_ref) = time(&|| nms_reference(&boxes, &scores, &p), 3);
    anyhow::ensure!(kept_ref == nms_kept, "grid NMS kept {nms_kept}, pairwise {kept_ref}");
    let mut quantized = None;
    let int8 = match int8 {
        None => None,
        Some(path) => {
            let (q, load_s, plan_s, detections, q_times) = timed_segmenter(path, &frame, runs, warmup, false)?;
            let per_frame = Stats::of(&q_times);
            let int8_nodes = q.quantized().map_or(0, |r| r.quantized);
            quantized = Some(q);
            Some(SegInt8 {
                profile: path.display().to_string(),
                int8_nodes,
                load_s,
                plan_s,
                detections,
                speedup: Stats::of(&times).median_ms / per_frame.median_ms,
                per_frame,
            })
        }
    };
    let mut per_frame_by_threads = Vec::new();
    for &t in threads {
        seg.set_threads(t)?;
        let float = Stats::of(&time_frames(&seg, &frame, runs, warmup)?.1);
        let int8 = match quantized.as_mut() {
            None => None,
            Some(q) => {
                q.set_threads(t)?;
                Some(Stats::of(&time_frames(q, &frame, runs, warmup)?.1))
            }
        };
        per_frame_by_threads.push(SegThreadsRow { threads: t, float, int8 });
    }
    let report = SegReport {
        runtime: "tract",
        model: seg.onnx_path().display().to_string(),
        machine: machine(),
        threads: 1,
        width: frame.color.width,
        height: frame.color.height,
        load_s,
        plan_s,
        detections,
        score_threshold,
        per_frame: Stats::of(&times),
        ops,
        detections_all,
        per_frame_all: Stats::of(&times_all),
        per_frame_by_threads,
        nms_candidates: NMS_CANDIDATES,
        nms_kept,
        nms_grid: Stats::of(&grid),
        nms_pairwise: Stats::of(&pairwise),
        int8,
    };
    println!(
        "segmenter {} on {}x{} ({} detections at score >= {}): median {:.1} ms/frame (p10 {:.1}, p90 {:.1}), \
         load {:.2} s + plan {:.2} s",
        report.model,
        report.width,
        report.height,
        detections,
        score_threshold,
        report.per_frame.median_ms,
        report.per_frame.p10_ms,
        report.per_frame.p90_ms,
        load_s,
        plan_s
    );
    for o in &report.ops {
        println!(
            "  {:<18} {:>6.1} calls  {:>8.2} ms/frame  {:>5.1}%",
            o.node_type,
            o.calls_per_run,
            o.ms_per_run,
            100.0 * o.share_of_graph
        );
    }
    println!(
        "every detection above the graph's floor ({detections_all}): median {:.1} ms/frame",
        report.per_frame_all.median_ms
    );
    for row in &report.per_frame_by_threads {
        println!(
            "{} thread(s): float {:.1} ms/frame{}",
            row.threads,
            row.float.median_ms,
            row.int8.as_ref().map(|q| format!(", int8 {:.1} ms/frame", q.median_ms)).unwrap_or_default()
        );
    }
    println!(
        "NMS on {NMS_CANDIDATES} candidates ({nms_kept} kept): grid {:.1} ms, pairwise {:.1} ms",
        report.nms_grid.median_ms, report.nms_pairwise.median_ms
    );
    if let Some(q) = &report.int8 {
        println!(
            "int8 ({}, {} int8 nodes, {} detections): median {:.1} ms/frame (p10 {:.1}, p90 {:.1}), {:.2}x float",
            q.profile,
            q.int8_nodes,
            q.detections,
            q.per_frame.median_ms,
            q.per_frame.p10_ms,
            q.per_frame.p90_ms,
            q.speedup
        );
    }
    if profile_graph {
        print_node_profile(quantized.as_ref().unwrap_or(&seg), &frame.color, runs.max(1))?;
    }
    if let Some(path) = json {
        crate::bench::write_report(path, &report)?;
    }
    Ok(())
}

/// Time every node of the plan `segment` runs (mean of `runs` runs): the operators and
/// the single nodes taking the most time.
fn print_node_profile(seg: &Segmenter, image: &tricons::frame::ColorImage, runs: usize) -> Result<()> {
    let mut per_node: Vec<(String, String, Duration)> = Vec::new();
    for _ in 0..runs {
        for (i, (op, node, t)) in seg.profile_nodes(image)?.into_iter().enumerate() {
            match per_node.get_mut(i) {
                Some(slot) => slot.2 += t,
                None => per_node.push((op, node, t)),
            }
        }
    }
    let total: Duration = per_node.iter().map(|x| x.2).sum();
    let ms = |t: Duration| t.as_secs_f64() * 1e3 / runs as f64;
    println!(
        "node profile of {} ({} nodes, {:.1} ms/frame in nodes), by operator:",
        seg.onnx_path().display(),
        per_node.len(),
        ms(total)
    );
    for (op, n, t) in crate::bench::by_operator(&per_node).iter().take(16) {
        println!(
            "  {op:<28} {n:>4} nodes  {:>8.2} ms  {:>5.1}%",
            ms(*t),
            100.0 * t.as_secs_f64() / total.as_secs_f64()
        );
    }
    println!("slowest nodes:");
    per_node.sort_by_key(|x| std::cmp::Reverse(x.2));
    for (op, node, t) in per_node.iter().take(20) {
        println!("  {:>8.2} ms  {op:<24} {node}", ms(*t));
    }
    Ok(())
}

/// RPN-like candidates: clustered boxes of 8-300 px over a 1333 x 800 image, random scores.
fn many_boxes(n: usize) -> (Vec<f32>, Vec<f32>) {
    let mut rng = Rng::new(42);
    let mut u = || (rng.next_u64() >> 11) as f32 / (1u64 << 53) as f32;
    let mut boxes = Vec::with_capacity(n * 4);
    let mut scores = Vec::with_capacity(n);
    for _ in 0..n {
        let (cx, cy) = (u() * 1333.0, u() * 800.0);
        let (w, h) = (8.0 + u() * u() * 300.0, 8.0 + u() * u() * 300.0);
        boxes.extend([cy - h / 2.0, cx - w / 2.0, cy + h / 2.0, cx + w / 2.0]);
        scores.push(u());
    }
    (boxes, scores)
}
