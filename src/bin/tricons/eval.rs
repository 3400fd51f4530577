//! `tricons eval`: NOCS metrics of predictions against ground truth.

use anyhow::{Context, Result};
use std::path::PathBuf;
use tricons::atomic::write_atomic;
use tricons::metrics::{EvalConfig, IouMode, PoseThreshold, evaluate_recordings, match_frames_by_timestamp};
use tricons::output::read_predictions;
use tricons::recording::open_recording;

/// Arguments of `tricons eval`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons eval --gt data/synthnocs-test --pred pred.jsonl\n  \
    tricons eval --gt data/synthnocs-test --pred pred.jsonl --iou corrected --json report.json\n  \
    tricons eval --gt scene_1 --pred pred.jsonl --iou-threshold 0.1 --pose-threshold 15deg5cm\n  \
    tricons eval --gt tests/data/synthnocs-demo --pred bag.jsonl --match timestamp\n  \
    tricons eval --gt Real/test/scene_1 --pred s1.jsonl --gt Real/test/scene_2 --pred s2.jsonl  # one AP over both\n\n\
    The table always names the IoU variant: `published` reproduces the per-corner box extents of the\n\
    NOCS reference code that every published table uses; `corrected` takes per-axis extents.")]
pub struct Args {
    /// Recording with ground truth (tricons format or NOCS dataset layout); repeat it with
    /// --pred for several scenes scored together (one AP over all their frames).
    #[arg(long, required = true)]
    gt: Vec<PathBuf>,
    /// Predictions, JSON Lines (one line per frame; see docs/formats.md); one per --gt, in order.
    #[arg(long, required = true)]
    pred: Vec<PathBuf>,
    /// 3D IoU variant: `published` (the reference code's per-corner extents) or `corrected` (per-axis).
    #[arg(long, default_value = "published")]
    iou: IouMode,
    /// Extra 3D IoU thresholds beside 0.25, 0.50, 0.75 (comma-separated or repeated).
    #[arg(long = "iou-threshold", value_delimiter = ',')]
    iou_thresholds: Vec<f64>,
    /// Extra pose thresholds beside 5deg2cm, 5deg5cm, 10deg2cm, 10deg5cm, e.g. `15deg5cm`.
    #[arg(long = "pose-threshold", value_delimiter = ',')]
    pose_thresholds: Vec<PoseThreshold>,
    /// Where to write the JSON report [default: the (first) PRED with extension .eval.json].
    #[arg(long)]
    json: Option<PathBuf>,
    /// How prediction frames find their ground truth: `id` (the frame ids) or `timestamp`
    /// (the nearest frame within 1 ms: predictions of a ROS 2 bag made from the recording).
    #[arg(long = "match", value_enum, default_value = "id")]
    match_by: MatchBy,
}

/// How `eval` pairs prediction frames with ground-truth frames.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum MatchBy {
    Id,
    Timestamp,
}

/// Largest timestamp difference of `--match timestamp`, seconds.
const MATCH_TOLERANCE_S: f64 = 1e-3;

pub fn run(args: Args) -> Result<()> {
    anyhow::ensure!(
        args.gt.len() == args.pred.len(),
        "{} --gt but {} --pred: give one predictions file per recording, in the same order",
        args.gt.len(),
        args.pred.len()
    );
    let mut sets = Vec::with_capacity(args.gt.len());
    for (gt, pred) in args.gt.iter().zip(&args.pred) {
        let rec = open_recording(gt)?;
        let mut preds = read_predictions(pred)?;
        if let MatchBy::Timestamp = args.match_by {
            preds = match_frames_by_timestamp(rec.as_ref(), &preds, pred, MATCH_TOLERANCE_S)?;
        }
        sets.push((rec, preds, pred.clone()));
    }
    let mut cfg = EvalConfig { iou_mode: args.iou, ..EvalConfig::default() };
    for t in args.iou_thresholds {
        anyhow::ensure!((0.0..1.0).contains(&t), "--iou-threshold {t} must be in [0, 1)");
        if !cfg.iou_thresholds.contains(&t) {
            cfg.iou_thresholds.push(t);
        }
    }
    for t in args.pose_thresholds {
        if !cfg.pose_thresholds.contains(&t) {
            cfg.pose_thresholds.push(t);
        }
    }
    let refs: Vec<_> = sets.iter().map(|(r, p, path)| (r.as_ref(), p.as_slice(), path.as_path())).collect();
    let report = evaluate_recordings(&refs, &cfg)?;
    println!("{}", report.to_table());
    let json_path = args.json.unwrap_or_else(|| args.pred[0].with_extension("eval.json"));
    let json = serde_json::to_string_pretty(&report)?;
    write_atomic(&json_path, json.as_bytes()).with_context(|| "writing the JSON report")?;
    log::info!("report written to {}", json_path.display());
    Ok(())
}
