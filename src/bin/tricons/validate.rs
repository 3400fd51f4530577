//! `tricons validate`: a float model and its int8 profile on the same frames, side by
//! side: accuracy metrics (NOCS for pose, box and mask AP for the segmenter), their
//! differences, per-output error statistics and latency.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use serde::Serialize;
use tricons::atomic::write_atomic;
use tricons::metrics::mask_ap::{box_iou, mask_iou};
use tricons::metrics::{EvalConfig, IouMode, evaluate};
use tricons::output::PredInstance;
use tricons::pose::{InstanceOutcome, PoseEstimator};
use tricons::quant::{ModelKind, QuantProfile};
use tricons::recording::{Recording, open_recording};
use tricons::segment::Segmenter;

use crate::common::{detections_2d, ground_truth, ground_truth_2d, segmentation_ap};
use crate::progress;

/// Arguments of `tricons validate`.
#[derive(ClapArgs, Debug)]
#[command(after_help = "Examples:\n  \
    tricons validate --float models/tricons-pose.card.json --int8 models/tricons-pose.int8.json \\\n      \
    --data data/synthnocs-test --max-drop 1.0 --json data/validate/pose.json\n  \
    tricons validate --float models/maskrcnn-light.card.json --int8 models/maskrcnn-light.int8.json \\\n      \
    --data tests/data/synthnocs-demo\n\n\
    Pose models run on the recording's ground-truth masks (the pose model alone); segmenters are scored \
    with box and mask AP against the ground-truth instance masks. Exit status 1 when --max-drop is \
    exceeded.")]
pub struct Args {
    /// The float model (card or graph).
    #[arg(long)]
    float: PathBuf,
    /// Its int8 quantization profile (`tricons quantize` output).
    #[arg(long)]
    int8: PathBuf,
    /// Recording with ground truth.
    #[arg(long)]
    data: PathBuf,
    /// Use at most this many frames.
    #[arg(long)]
    frames: Option<usize>,
    /// Fail (exit 1) when any metric of the int8 model is more than this many points below float.
    #[arg(long)]
    max_drop: Option<f64>,
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Pose: 3D IoU variant of the NOCS metrics.
    #[arg(long, default_value = "published")]
    iou: IouMode,
    /// Pose: seed of the point sampling (the same for both models).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads of each model: a pose model's objects in parallel [default: the cores
    /// available]; a Mask R-CNN's matrix products [default: 1, see `replay --segmenter-threads`].
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
}

/// One metric of both models.
#[derive(Serialize, Debug)]
struct MetricRow {
    name: String,
    float: Option<f64>,
    int8: Option<f64>,
    /// int8 minus float, points.
    diff: Option<f64>,
}

/// Error statistics of one output, int8 against float, over matched results.
#[derive(Serialize, Debug, Default)]
struct OutputRow {
    name: String,
    values: usize,
    max_abs: f64,
    cosine: f64,
}

/// Latency of one model.
#[derive(Serialize, Debug)]
struct Latency {
    per_frame_median_ms: f64,
    /// Pose: per object (frame time / objects); segmenter: per image.
    per_item_median_ms: f64,
}

/// The JSON report.
#[derive(Serialize, Debug)]
struct Report {
    kind: ModelKind,
    float: String,
    int8: String,
    data: String,
    frames: usize,
    /// Pose: instances estimated by both; segmenter: detections of the float model.
    items: usize,
    int8_nodes: usize,
    metrics: Vec<MetricRow>,
    outputs: Vec<OutputRow>,
    latency_float: Latency,
    latency_int8: Latency,
    /// Float time over int8 time (medians per item).
    speedup: f64,
    max_drop: Option<f64>,
    /// Largest drop (float minus int8), points.
    worst_drop: f64,
    passed: bool,
}

/// Accumulates max |a - b| and the cosine of the flattened vectors.
#[derive(Default)]
struct ErrorAcc {
    n: usize,
    max_abs: f64,
    dot: f64,
    aa: f64,
    bb: f64,
}

impl ErrorAcc {
    fn add(&mut self, a: &[f64], b: &[f64]) {
        for (&x, &y) in a.iter().zip(b) {
            self.n += 1;
            self.max_abs = self.max_abs.max((x - y).abs());
            self.dot += x * y;
            self.aa += x * x;
            self.bb += y * y;
        }
    }

    fn row(&self, name: &str) -> OutputRow {
        let cosine = if self.aa > 0.0 && self.bb > 0.0 { self.dot / (self.aa.sqrt() * self.bb.sqrt()) } else { 1.0 };
        OutputRow { name: name.into(), values: self.n, max_abs: self.max_abs, cosine }
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Run `tricons validate`.
pub fn run(args: Args) -> Result<()> {
    let profile = QuantProfile::read(&args.int8).with_context(|| "reading the int8 profile (--int8)")?;
    let rec = open_recording(&args.data).with_context(|| "opening the recording (--data)")?;
    let frames = args.frames.map_or(rec.len(), |f| f.min(rec.len()));
    if frames == 0 {
        bail!("{}: no frames", rec.describe());
    }
    let report = match profile.kind {
        ModelKind::Pose => validate_pose(&args, rec.as_ref(), frames, &profile)?,
        ModelKind::Segmenter => validate_segmenter(&args, rec.as_ref(), frames, &profile)?,
    };
    print_report(&report);
    if let Some(path) = &args.json {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        write_atomic(path, format!("{}\n", serde_json::to_string_pretty(&report)?).as_bytes())?;
        log::info!("report written to {}", path.display());
    }
    if !report.passed {
        bail!(
            "int8 drops {:.2} points on a metric, more than --max-drop {}",
            report.worst_drop,
            report.max_drop.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}

fn check_same_graph(profile: &QuantProfile, float_sha: &str, float: &Path) -> Result<()> {
    if !profile.onnx_sha256.eq_ignore_ascii_case(float_sha) {
        bail!(
            "--int8 was made from another graph than --float {} (sha256 {} vs {float_sha})",
            float.display(),
            profile.onnx_sha256
        );
    }
    Ok(())
}

/// What a validation measured, before the summary.
struct Measured {
    kind: ModelKind,
    frames: usize,
    items: usize,
    int8_nodes: usize,
    metrics: Vec<MetricRow>,
    outputs: Vec<OutputRow>,
    /// (per frame, per item) milliseconds, float then int8.
    times: [(Vec<f64>, Vec<f64>); 2],
}

fn finish(args: &Args, m: Measured) -> Report {
    let Measured { kind, frames, items, int8_nodes, metrics, outputs, mut times } = m;
    let [(ff, fi), (qf, qi)] = &mut times;
    let latency_float = Latency { per_frame_median_ms: median(ff), per_item_median_ms: median(fi) };
    let latency_int8 = Latency { per_frame_median_ms: median(qf), per_item_median_ms: median(qi) };
    let worst_drop = metrics.iter().filter_map(|m| m.diff).map(|d| -d).fold(0.0, f64::max);
    Report {
        kind,
        float: args.float.display().to_string(),
        int8: args.int8.display().to_string(),
        data: args.data.display().to_string(),
        frames,
        items,
        int8_nodes,
        speedup: latency_float.per_item_median_ms / latency_int8.per_item_median_ms,
        metrics,
        outputs,
        latency_float,
        latency_int8,
        max_drop: args.max_drop,
        worst_drop,
        passed: args.max_drop.is_none_or(|m| worst_drop <= m),
    }
}

fn metric_row(name: &str, float: Option<f64>, int8: Option<f64>) -> MetricRow {
    let diff = float.zip(int8).map(|(f, q)| q - f);
    MetricRow { name: name.into(), float, int8, diff }
}

fn validate_pose(args: &Args, rec: &dyn Recording, frames: usize, profile: &QuantProfile) -> Result<Report> {
    let threads = crate::common::threads(args.threads);
    let float = PoseEstimator::load(&args.float)
        .and_then(|m| m.with_threads(threads))
        .with_context(|| "loading the float model (--float)")?;
    let int8 = PoseEstimator::load(&args.int8)
        .and_then(|m| m.with_threads(threads))
        .with_context(|| "loading the int8 model (--int8)")?;
    check_same_graph(profile, &float.card().onnx.sha256, &args.float)?;
    let bar = progress::bar(frames, "validate");
    let (mut gts, mut preds_f, mut preds_q) = (Vec::new(), Vec::new(), Vec::new());
    let mut acc: [ErrorAcc; 4] = Default::default();
    let mut times: [(Vec<f64>, Vec<f64>); 2] = Default::default();
    let mut items = 0;
    for i in 0..frames {
        let frame = rec.read_frame(i)?;
        let (gt, masks) = ground_truth(rec, i)?;
        let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
        let prepared = float.prepare(&frame, &refs, tricons::rng::mix_seed(&[args.seed, i as u64]))?;
        let mut outcomes: Vec<Vec<InstanceOutcome>> = Vec::new();
        for (model, t) in [&float, &int8].into_iter().zip(&mut times) {
            let start = Instant::now();
            let out = model.run_inputs(&prepared.inputs)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            if !prepared.inputs.is_empty() {
                t.0.push(ms);
                t.1.push(ms / prepared.inputs.len() as f64);
            }
            outcomes.push(out);
        }
        let to_preds = |model: &PoseEstimator, out: &[InstanceOutcome]| -> Vec<PredInstance> {
            let mut it = out.iter();
            prepared
                .slots
                .iter()
                .zip(&gt)
                .filter_map(|(slot, g)| {
                    let e = match slot {
                        Ok(_) => it.next()?.as_ref().ok()?,
                        Err(_) => return None,
                    };
                    Some(PredInstance {
                        class: g.class,
                        score: model.score(e, 1.0),
                        camera_from_object: model.camera_from_object(e, g.class),
                        size_m: e.size_m,
                        box2d: None,
                        mask: None,
                    })
                })
                .collect()
        };
        for (a, b) in outcomes[0].iter().zip(&outcomes[1]) {
            if let (Ok(a), Ok(b)) = (a, b) {
                items += 1;
                let r = |e: &tricons::pose::PoseEstimate| {
                    e.camera_from_object.rotation.iter().copied().collect::<Vec<f64>>()
                };
                let t = |e: &tricons::pose::PoseEstimate| {
                    e.camera_from_object.translation_m.iter().copied().collect::<Vec<f64>>()
                };
                let k = |e: &tricons::pose::PoseEstimate| {
                    e.keypoints_camera_m.iter().flatten().map(|&v| v as f64).collect::<Vec<f64>>()
                };
                acc[0].add(&r(a), &r(b));
                acc[1].add(&t(a), &t(b));
                acc[2].add(&a.size_m, &b.size_m);
                acc[3].add(&k(a), &k(b));
            }
        }
        preds_f.push(to_preds(&float, &outcomes[0]));
        preds_q.push(to_preds(&int8, &outcomes[1]));
        gts.push(gt);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let cfg = EvalConfig::standard(args.iou);
    let report_f = evaluate(gts.iter().zip(&preds_f).map(|(g, p)| (g.as_slice(), p.as_slice())), &cfg);
    let report_q = evaluate(gts.iter().zip(&preds_q).map(|(g, p)| (g.as_slice(), p.as_slice())), &cfg);
    let metrics = cfg.metric_names().iter().map(|m| metric_row(m, report_f.mean(m), report_q.mean(m))).collect();
    let names = ["R", "t_m", "s_m", "keypoints_m"];
    let outputs = acc.iter().zip(names).map(|(a, n)| a.row(n)).collect();
    let nodes = int8.quantized().map_or(0, |q| q.quantized);
    let int8_nodes = nodes;
    Ok(finish(args, Measured { kind: ModelKind::Pose, frames, items, int8_nodes, metrics, outputs, times }))
}

fn validate_segmenter(args: &Args, rec: &dyn Recording, frames: usize, profile: &QuantProfile) -> Result<Report> {
    let threads = args.threads.unwrap_or(crate::common::DEFAULT_SEGMENTER_THREADS).max(1);
    let float = Segmenter::load(&args.float)
        .and_then(|m| m.with_threads(threads))
        .with_context(|| "loading the float model (--float)")?;
    let int8 = Segmenter::load(&args.int8)
        .and_then(|m| m.with_threads(threads))
        .with_context(|| "loading the int8 model (--int8)")?;
    check_same_graph(profile, float.onnx_sha256(), &args.float)?;
    // Plans are built per image size on first use: build them before timing.
    let first = rec.read_frame(0)?;
    for seg in [&float, &int8] {
        seg.prepare(first.color.width as usize, first.color.height as usize)?;
    }
    let bar = progress::bar(frames, "validate");
    let (mut eval_f, mut eval_q) = (Vec::new(), Vec::new());
    let (mut boxes, mut scores, mut masks_iou) = (ErrorAcc::default(), ErrorAcc::default(), Vec::new());
    let mut times: [(Vec<f64>, Vec<f64>); 2] = Default::default();
    let (mut items, mut unmatched) = (0usize, 0usize);
    for i in 0..frames {
        let frame = rec.read_frame(i)?;
        let gt_objects = ground_truth_2d(rec, i)?;
        let mut dets = Vec::new();
        for (model, t) in [&float, &int8].into_iter().zip(&mut times) {
            let start = Instant::now();
            let d = model.segment(&frame.color)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            t.0.push(ms);
            t.1.push(ms);
            dets.push(d);
        }
        // Match int8 detections to float ones: same label, best box IoU >= 0.5, greedy.
        let mut used = vec![false; dets[1].len()];
        for a in &dets[0] {
            items += 1;
            let best = dets[1]
                .iter()
                .enumerate()
                .filter(|(j, b)| !used[*j] && b.label == a.label)
                .map(|(j, b)| (j, box_iou(&a.box_xyxy.map(f64::from), &b.box_xyxy.map(f64::from))))
                .fold(None::<(usize, f64)>, |acc, x| match acc {
                    Some(p) if p.1 >= x.1 => Some(p),
                    _ => Some(x),
                });
            match best {
                Some((j, iou)) if iou >= 0.5 => {
                    used[j] = true;
                    let b = &dets[1][j];
                    boxes.add(&a.box_xyxy.map(f64::from), &b.box_xyxy.map(f64::from));
                    scores.add(&[a.score as f64], &[b.score as f64]);
                    masks_iou.push(mask_iou(&a.mask, &b.mask));
                }
                _ => unmatched += 1,
            }
        }
        unmatched += used.iter().filter(|u| !**u).count();
        eval_f.push((detections_2d(&dets[0]), gt_objects.clone()));
        eval_q.push((detections_2d(&dets[1]), gt_objects));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let metrics = segmentation_ap(&eval_f)
        .into_iter()
        .zip(segmentation_ap(&eval_q))
        .map(|((name, f), (_, q))| metric_row(&name, f, q))
        .collect();
    let mean_iou = masks_iou.iter().sum::<f64>() / masks_iou.len().max(1) as f64;
    let min_iou = masks_iou.iter().copied().fold(f64::INFINITY, f64::min);
    let outputs = vec![
        boxes.row("boxes_px"),
        scores.row("scores"),
        OutputRow { name: "mask_iou_mean".into(), values: masks_iou.len(), max_abs: 1.0 - min_iou, cosine: mean_iou },
        OutputRow { name: "unmatched_detections".into(), values: unmatched, max_abs: 0.0, cosine: 0.0 },
    ];
    let nodes = int8.quantized().map_or(0, |q| q.quantized);
    let int8_nodes = nodes;
    Ok(finish(args, Measured { kind: ModelKind::Segmenter, frames, items, int8_nodes, metrics, outputs, times }))
}

fn print_report(r: &Report) {
    let cell = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.2}"));
    println!("{:?} model, {} frames, {} items, {} int8 nodes", r.kind, r.frames, r.items, r.int8_nodes);
    println!("{:<14}{:>10}{:>10}{:>10}", "metric", "float", "int8", "diff");
    for m in &r.metrics {
        println!("{:<14}{:>10}{:>10}{:>10}", m.name, cell(m.float), cell(m.int8), cell(m.diff));
    }
    println!("{:<22}{:>10}{:>14}{:>12}", "output (int8 vs float)", "values", "max |diff|", "cosine");
    for o in &r.outputs {
        println!("{:<22}{:>10}{:>14.6}{:>12.6}", o.name, o.values, o.max_abs, o.cosine);
    }
    let item = if r.kind == ModelKind::Pose { "object" } else { "image" };
    println!(
        "latency, median ms: float {:.2}/{item} ({:.1}/frame), int8 {:.2}/{item} ({:.1}/frame): {:.2}x",
        r.latency_float.per_item_median_ms,
        r.latency_float.per_frame_median_ms,
        r.latency_int8.per_item_median_ms,
        r.latency_int8.per_frame_median_ms,
        r.speedup
    );
}
