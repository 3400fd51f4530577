//! `tricons bench --pipeline`: the whole per-frame work (Mask R-CNN, then the pose model on
//! its detections) at each `--threads` count, on the same frames (a benchmark, not a test).

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;
use tricons::pipeline::stages::{detections_from_segmenter, estimate_detections};
use tricons::pose::PoseEstimator;
use tricons::recording::open_recording;
use tricons::rng::mix_seed;
use tricons::segment::Segmenter;

use crate::bench::{Stats, machine};
use crate::progress;

/// One thread count's measurements.
#[derive(Serialize)]
struct AtThreads {
    threads: usize,
    /// Segmenter + pose, one frame after the other.
    per_frame: Stats,
    segment: Stats,
    pose: Stats,
    /// Detections the pose model received per frame (mean).
    detections_per_frame: f64,
    /// 1000 / median per-frame milliseconds: the rate of one frame at a time (the service
    /// overlaps the two stages on different frames, so it can go faster).
    frames_per_s: f64,
}

#[derive(Serialize)]
struct Report {
    runtime: &'static str,
    model: String,
    segmenter: String,
    recording: String,
    frames: usize,
    machine: String,
    results: Vec<AtThreads>,
}

/// What `tricons bench --pipeline` measures.
pub struct PipelineBench<'a> {
    pub model: &'a Path,
    pub segmenter: &'a Path,
    pub recording: &'a Path,
    pub threads: &'a [usize],
    pub runs: usize,
    pub warmup: usize,
    pub seed: u64,
    pub json: Option<&'a Path>,
}

pub fn run(b: PipelineBench<'_>) -> Result<()> {
    let rec = open_recording(b.recording).with_context(|| "opening the recording (--recording)")?;
    let frames: Vec<_> = (0..rec.len()).map(|i| rec.read_frame(i)).collect::<tricons::Result<_>>()?;
    let Some(first) = frames.first() else {
        anyhow::bail!("{} has no frames", b.recording.display());
    };
    let mut estimator = PoseEstimator::load(b.model).with_context(|| "loading the pose model (--model)")?;
    let mut segmenter = Segmenter::load(b.segmenter).with_context(|| "loading the segmenter (--segmenter)")?;
    segmenter.prepare(first.color.width as usize, first.color.height as usize)?;
    let bar = progress::bar(b.threads.len() * (b.warmup + b.runs) * frames.len(), "bench pipeline");
    let mut results = Vec::new();
    for &threads in b.threads {
        estimator.set_threads(threads)?;
        segmenter.set_threads(threads)?;
        let (mut total, mut seg, mut pose, mut detections) = (Vec::new(), Vec::new(), Vec::new(), 0usize);
        for run in 0..b.warmup + b.runs {
            for (i, frame) in frames.iter().enumerate() {
                let t0 = Instant::now();
                let dets = detections_from_segmenter(&segmenter, frame)?;
                let t1 = Instant::now();
                estimate_detections(&estimator, frame, &dets, mix_seed(&[b.seed, i as u64]))?;
                let t2 = Instant::now();
                if run >= b.warmup {
                    seg.push(t1 - t0);
                    pose.push(t2 - t1);
                    total.push(t2 - t0);
                    detections += dets.len();
                }
                bar.inc(1);
            }
        }
        let per_frame = Stats::of(&total);
        results.push(AtThreads {
            threads,
            frames_per_s: 1e3 / per_frame.median_ms,
            per_frame,
            segment: Stats::of(&seg),
            pose: Stats::of(&pose),
            detections_per_frame: detections as f64 / total.len().max(1) as f64,
        });
    }
    bar.finish_and_clear();
    let report = Report {
        runtime: "tricons",
        model: b.model.display().to_string(),
        segmenter: b.segmenter.display().to_string(),
        recording: b.recording.display().to_string(),
        frames: frames.len(),
        machine: machine(),
        results,
    };
    println!(
        "pipeline: {} + {} on {} ({} frames), {}",
        report.segmenter, report.model, report.recording, report.frames, report.machine
    );
    println!(
        "{:>7} {:>12} {:>12} {:>12} {:>11} {:>10}",
        "threads", "frame ms", "segment ms", "pose ms", "detections", "frames/s"
    );
    for r in &report.results {
        println!(
            "{:>7} {:>12.1} {:>12.1} {:>12.1} {:>11.2} {:>10.2}",
            r.threads,
            r.per_frame.median_ms,
            r.segment.median_ms,
            r.pose.median_ms,
            r.detections_per_frame,
            r.frames_per_s
        );
    }
    if let Some(path) = b.json {
        crate::bench::write_report(path, &report)?;
    }
    Ok(())
}
