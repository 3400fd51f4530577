//! `tricons replay`: run the pose model over a recorded sequence.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tricons::atomic::write_atomic;
use tricons::metrics::{EvalConfig, IouMode, evaluate_recording};
use tricons::output::overlay::draw_overlay;
use tricons::output::predictions::{FramePredictions, write_predictions};
use tricons::pipeline::stages::{
    Detection, NotReported, detections_from_annotations, detections_from_segmenter, estimate_detections,
};
use tricons::pose::PoseEstimator;
use tricons::recording::open_recording_with;
use tricons::segment::Segmenter;
use tricons::segment::card::MAX_POSE_MASK_ERODE_PX;

use tricons::segment::published::PublishedDetections;

use crate::common::{DEFAULT_MODEL, DEFAULT_RECORDING, DEFAULT_SEGMENTER, MaskSource};
use crate::progress;
use crate::source_args::BagTopicArgs;

/// Arguments of `tricons replay`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons replay                                   # shipped model on the shipped demo recording\n  \
    tricons replay --recording data/synthnocs-test --out data/replay/test.jsonl\n  \
    tricons replay --recording data/synthnocs-test --overlays data/overlays --iou corrected\n  \
    tricons replay --masks gt                        # ground-truth masks: the pose model alone\n  \
    tricons replay --pose-mask-erode 0 --keep-depth-outliers  # the segmenter's masks as predicted\n  \
    tricons replay --keep-low-scores                 # every pose, whatever the pose card's min_score\n  \
    tricons replay --recording NOCS/Real/test/scene_1 --masks results:NOCS/segmentation_results/real_test\n  \
    tricons replay --recording bag.mcap --mcap poses.mcap  # a ROS 2 bag in (RealSense topics), MCAP out\n  \
    tricons replay --recording bag.mcap --color-topic /cam/color/image_raw/compressed --depth-topic /cam/depth\n\n\
    Raw RGB-D -> Mask R-CNN (--segmenter) -> TriCons-Pose -> predictions. With ground truth,\n\
    the NOCS metrics are printed at the end.")]
pub struct Args {
    /// Recording directory (tricons format or NOCS dataset layout) or ROS 2 bag (`.mcap`).
    #[arg(long, default_value = DEFAULT_RECORDING, value_name = "DIR|BAG.mcap")]
    recording: PathBuf,
    #[command(flatten)]
    bag: BagTopicArgs,
    /// Pose model: its card (`*.card.json`) or graph (`*.onnx`, card beside it).
    #[arg(long, default_value = DEFAULT_MODEL)]
    model: PathBuf,
    /// Instance masks: `model` (the Mask R-CNN, --segmenter), `gt` (the recording's ground
    /// truth: the pose model alone) or `results:DIR` (published Mask R-CNN result pickles,
    /// `results_*_<scene>_<frame>.pkl`, as distributed with SPD / DualPoseNet / AG-Pose).
    #[arg(long, default_value = "model", value_parser = clap::value_parser!(MaskSource), value_name = "model|gt|results:DIR")]
    masks: MaskSource,
    /// Mask R-CNN for `--masks model`: its card or graph (any torchvision export).
    #[arg(long, default_value = DEFAULT_SEGMENTER)]
    segmenter: PathBuf,
    /// Erode each of the segmenter's masks by PX pixels before the pose stage samples its
    /// points (0: off) [default: the segmenter card's `pose_mask_erode_px`].
    #[arg(long, value_name = "PX", value_parser = clap::value_parser!(u16).range(0..=MAX_POSE_MASK_ERODE_PX as i64))]
    pose_mask_erode: Option<u16>,
    /// Leave the depth outliers in the segmenter's masks, whatever its card's
    /// `pose_mask_max_radius_m` says.
    #[arg(long)]
    keep_depth_outliers: bool,
    /// Report every pose, also those scored below the pose card's `min_score` (always so
    /// with `--masks gt`).
    #[arg(long)]
    keep_low_scores: bool,
    /// Predictions to write (JSON Lines) [default: data/replay/<recording name>.jsonl].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write one overlay PNG per frame (3D boxes, axes, labels) into this directory.
    #[arg(long)]
    overlays: Option<PathBuf>,
    /// Also write the results as a ROS 2 bag: /tricons/detections (vision_msgs/Detection3DArray),
    /// /tricons/markers (visualization_msgs/MarkerArray) and /tricons/overlay (sensor_msgs/Image).
    #[cfg(feature = "ros2")]
    #[arg(long, value_name = "OUT.mcap")]
    mcap: Option<PathBuf>,
    /// Seed of the point sampling (frame i, instance j draw from (seed, i, j)).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// IoU variant of the evaluation at the end.
    #[arg(long, default_value = "published")]
    iou: IouMode,
    /// Do not evaluate against the ground truth at the end.
    #[arg(long)]
    no_eval: bool,
    /// Worker threads a frame's objects run on [default: the cores available].
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Worker threads of the Mask R-CNN's matrix products.
    #[arg(long, value_name = "N", default_value_t = crate::common::DEFAULT_SEGMENTER_THREADS)]
    segmenter_threads: usize,
}

/// The masks of a run, opened.
enum MaskInput {
    Segmenter(Box<Segmenter>),
    GroundTruth,
    Published(PublishedDetections),
}

pub fn run(args: Args) -> Result<()> {
    let rec = open_recording_with(&args.recording, &args.bag.topics(None))
        .with_context(|| "opening the recording (--recording)")?;
    let t_load = Instant::now();
    let threads = crate::common::threads(args.threads);
    let mut estimator = PoseEstimator::load(&args.model)
        .and_then(|e| e.with_threads(threads))
        .with_context(|| "loading the pose model (--model)")?;
    // Ground-truth masks evaluate the pose model alone: every mask is an object.
    if args.keep_low_scores || matches!(args.masks, MaskSource::Gt) {
        estimator.set_min_score(None);
    }
    log::info!(
        "model {} ({}) loaded in {:.2} s, {threads} thread(s); {}",
        estimator.card_path().display(),
        estimator.card().config_name,
        t_load.elapsed().as_secs_f64(),
        rec.describe()
    );
    let masks = match &args.masks {
        MaskSource::Model => {
            let mut seg = Segmenter::load(&args.segmenter)
                .and_then(|s| s.with_threads(args.segmenter_threads))
                .with_context(|| "loading the segmenter (--segmenter)")?;
            if let Some(px) = args.pose_mask_erode {
                seg.set_pose_mask_erode_px(usize::from(px));
            }
            if args.keep_depth_outliers {
                seg.clear_pose_mask_max_radius();
            }
            let radii = &seg.card().pose_mask_max_radius_m;
            log::info!(
                "masks from {}; for the pose stage eroded by {} px, depth outliers {}",
                seg.onnx_path().display(),
                seg.card().pose_mask_erode_px,
                if radii.is_empty() { "kept".to_string() } else { format!("dropped beyond {radii:?} m") }
            );
            MaskInput::Segmenter(Box::new(seg))
        }
        MaskSource::Gt => MaskInput::GroundTruth,
        MaskSource::Results(dir) => {
            let published = PublishedDetections::open(dir).with_context(|| "opening --masks results:DIR")?;
            log::info!("masks from the result pickles in {}", dir.display());
            MaskInput::Published(published)
        }
    };
    // the scene name of published result files: the recording directory's name
    let scene = args.recording.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
    let out = args.out.clone().unwrap_or_else(|| default_out(&args.recording));
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    if let Some(dir) = &args.overlays {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    #[cfg(feature = "ros2")]
    let mut mcap = match &args.mcap {
        Some(path) => {
            let frame_id = rec.camera_frame_id().unwrap_or(tricons::capture::DEFAULT_FRAME_ID);
            Some(tricons::output::mcap_sink::McapSink::create(path, frame_id).with_context(|| "creating --mcap")?)
        }
        None => None,
    };
    let bar = progress::bar(rec.len(), "replay");
    let (mut frames, mut skipped, mut low_scores, mut estimated) = (Vec::with_capacity(rec.len()), 0, 0, 0usize);
    let t_run = Instant::now();
    for i in 0..rec.len() {
        let frame = rec.read_frame(i)?;
        let detections: Vec<Detection> = match &masks {
            MaskInput::Segmenter(seg) => detections_from_segmenter(seg, &frame)
                .with_context(|| format!("segmenting frame {}", rec.frame_id(i)))?,
            MaskInput::Published(published) => {
                let path = published.file_for(&scene, rec.frame_id(i))?;
                PublishedDetections::read(&path, frame.color.width, frame.color.height)?
            }
            MaskInput::GroundTruth => {
                let Some(ann) = rec.read_annotations(i)? else {
                    bail!(
                        "frame {} of {} has no instance masks: use --masks model (the default)",
                        rec.frame_id(i),
                        rec.describe()
                    );
                };
                let Some(detections) = detections_from_annotations(&ann) else {
                    bail!("frame {} of {} has annotations but no instance mask", rec.frame_id(i), rec.describe());
                };
                detections
            }
        };
        let seed = tricons::rng::mix_seed(&[args.seed, i as u64]);
        let (instances, skips) = estimate_detections(&estimator, &frame, &detections, seed)?;
        estimated += instances.len();
        for (k, why) in skips {
            match why {
                NotReported::BelowMinScore(_) => low_scores += 1,
                NotReported::Skipped(_) => skipped += 1,
            }
            log::debug!("frame {} instance {k}: not reported ({why})", rec.frame_id(i));
        }
        if let Some(dir) = &args.overlays {
            let png = draw_overlay(&frame, &instances)?;
            let path = dir.join(format!("{}_overlay.png", rec.frame_id(i)));
            write_atomic(&path, &png)?;
        }
        let predictions =
            FramePredictions { frame: rec.frame_id(i).to_string(), timestamp_s: Some(frame.timestamp_s), instances };
        #[cfg(feature = "ros2")]
        if let Some(sink) = mcap.as_mut() {
            use tricons::output::sink::Sink;
            sink.publish_with_image(&predictions, "", &frame)?;
        }
        frames.push(predictions);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let secs = t_run.elapsed().as_secs_f64();
    write_predictions(&out, &frames)?;
    #[cfg(feature = "ros2")]
    if let Some(mut sink) = mcap {
        use tricons::output::sink::Sink;
        sink.close()?;
    }
    let min_score = estimator.card().min_score.map_or_else(|| "off".to_string(), |m| format!("{m}"));
    log::info!(
        "{} frames, {estimated} instances reported, {skipped} skipped (too few valid pixels), {low_scores} below the \
         pose card's min_score ({min_score}), {:.1} ms/frame -> {}",
        frames.len(),
        1e3 * secs / frames.len().max(1) as f64,
        out.display()
    );
    if let MaskInput::Segmenter(seg) = &masks {
        let others = seg.card().non_nocs_classes();
        let others = if others.is_empty() { "none on its card".to_string() } else { others.join(", ") };
        log::info!(
            "segmenter: {} detections dropped as duplicates, {} of no NOCS class ({others}) left out",
            seg.duplicates_dropped(),
            seg.not_nocs_dropped(),
        );
    }
    if !args.no_eval {
        let has_gt = (0..rec.len()).any(|i| matches!(rec.read_instances(i), Ok(Some(_))));
        if has_gt {
            let cfg = EvalConfig { iou_mode: args.iou, ..EvalConfig::default() };
            let report = evaluate_recording(rec.as_ref(), &frames, &out, &cfg)?;
            println!("{}", report.to_table());
            let json_path = out.with_extension("eval.json");
            write_atomic(&json_path, serde_json::to_string_pretty(&report)?.as_bytes())?;
            log::info!("report written to {}", json_path.display());
        }
    }
    Ok(())
}

fn default_out(recording: &Path) -> PathBuf {
    // a bag file: its name without .mcap
    let name = if recording.is_file() { recording.file_stem() } else { recording.file_name() };
    let name = name.map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "replay".into());
    PathBuf::from("data/replay").join(format!("{name}.jsonl"))
}
