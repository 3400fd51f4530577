//! `tricons segment`: run the Mask R-CNN over frames; masks and overlays out.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use tricons::atomic::{write_atomic, write_atomic_with};
use tricons::image_io::{SizeLimit, read_color_png, write_label_png};
use tricons::output::segments::{SegRecord, draw_segments, label_image};
use tricons::recording::open_recording;
use tricons::segment::Segmenter;

use crate::common::{DEFAULT_RECORDING, DEFAULT_SEGMENTER, detections_2d, ground_truth_2d, segmentation_ap};
use crate::progress;

/// Reads one frame's colour image on demand.
type FrameLoader = Box<dyn Fn() -> Result<tricons::ColorImage>>;

/// Arguments of `tricons segment`.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    tricons segment                                   # shipped Mask R-CNN on the shipped demo recording\n  \
    tricons segment --image photo.png --out data/segment/photo --overlays\n  \
    tricons segment --model maskrcnn_resnet50_fpn.onnx --min-score 0 --recording data/synthnocs-test\n  \
    tricons segment --recording data/synthnocs-val --keep-duplicates --json data/segment/val-dups.json\n\n\
    Writes <out>/segments.jsonl (one line per frame: label, class, score, box, run-length mask)\n\
    and <out>/<frame>_labels.png (8-bit, pixel = 1 + instance index); --overlays adds\n\
    <out>/<frame>_segments.png. Any torchvision Mask R-CNN ONNX export loads; without a\n\
    card beside it, labels stay numeric and the score threshold is 0.5. On a recording with\n\
    ground truth it prints box and mask AP (COCO 101-point, mean over the NOCS classes) and\n\
    detections per object.")]
pub struct Args {
    /// Recording directory (ignored when --image is given).
    #[arg(long, default_value = DEFAULT_RECORDING)]
    recording: PathBuf,
    /// Colour PNG(s) to segment instead of a recording.
    #[arg(long, num_args = 1..)]
    image: Vec<PathBuf>,
    /// Mask R-CNN: its card (`*.card.json`) or graph (`*.onnx`).
    #[arg(long, default_value = DEFAULT_SEGMENTER)]
    model: PathBuf,
    /// Output directory [default: data/segment/<recording or image name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write mask overlays.
    #[arg(long)]
    overlays: bool,
    /// Keep detections scoring at least this (default: the card's threshold).
    #[arg(long)]
    min_score: Option<f32>,
    /// Only the first N frames of the recording.
    #[arg(long)]
    limit: Option<usize>,
    /// Keep detections the card's duplicate suppression (`duplicate_mask_iou`, `duplicate_mask_inside`) would drop.
    #[arg(long)]
    keep_duplicates: bool,
    /// Write the ground-truth evaluation (AP, detection counts) as JSON here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// What `tricons segment` measured against a recording's ground truth.
#[derive(serde::Serialize)]
struct Evaluation {
    recording: String,
    model: String,
    frames: usize,
    objects: usize,
    /// Detections of the NOCS classes (what the AP and the per-object ratio count).
    detections: usize,
    detections_per_object: f64,
    /// Detections of labels the card maps to no NOCS class (e.g. "other"), kept in
    /// segments.jsonl but not scored.
    other_detections: usize,
    duplicate_mask_iou: Option<f32>,
    duplicate_mask_inside: Option<f32>,
    duplicates_dropped: u64,
    /// bbox_AP50 .. mask_AP75, percent.
    ap: std::collections::BTreeMap<String, Option<f64>>,
}

pub fn run(args: Args) -> Result<()> {
    let t_load = Instant::now();
    let mut seg = Segmenter::load(&args.model).with_context(|| "loading the segmenter (--model)")?;
    if let Some(s) = args.min_score {
        anyhow::ensure!((0.0..=1.0).contains(&s), "--min-score must lie in [0, 1], got {s}");
        seg.set_score_threshold(s);
    }
    if args.keep_duplicates {
        seg.set_duplicate_mask_iou(None);
        seg.set_duplicate_mask_inside(None);
    }
    log::info!("segmenter {} loaded in {:.2} s", seg.onnx_path().display(), t_load.elapsed().as_secs_f64());
    // (frame id, loader) pairs: images or recording frames.
    let mut recording = None;
    let frames: Vec<(String, FrameLoader)> = if args.image.is_empty() {
        let rec =
            std::rc::Rc::new(open_recording(&args.recording).with_context(|| "opening the recording (--recording)")?);
        recording = Some(rec.clone());
        let n = args.limit.unwrap_or(usize::MAX).min(rec.len());
        (0..n)
            .map(|i| {
                let rec = rec.clone();
                let id = rec.frame_id(i).to_string();
                let load: FrameLoader = Box::new(move || Ok(rec.read_frame(i)?.color));
                (id, load)
            })
            .collect()
    } else {
        args.image
            .iter()
            .map(|p| {
                let id = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "image".into());
                let p = p.clone();
                let load: FrameLoader = Box::new(move || Ok(read_color_png(&p, SizeLimit::Capped)?));
                (id, load)
            })
            .collect()
    };
    let name = match args.image.first() {
        Some(p) => p.file_stem().map(|s| s.to_string_lossy().into_owned()),
        None => args.recording.file_name().map(|s| s.to_string_lossy().into_owned()),
    };
    let out =
        args.out.clone().unwrap_or_else(|| PathBuf::from("data/segment").join(name.unwrap_or_else(|| "frames".into())));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    // Evaluate against the ground truth when the recording has it.
    let evaluate = match &recording {
        Some(rec) if !rec.is_empty() => rec.read_annotations(0)?.is_some_and(|a| a.mask.is_some()),
        _ => false,
    };
    if args.json.is_some() && !evaluate {
        anyhow::bail!("--json needs a recording with ground-truth masks (--recording)");
    }
    let bar = progress::bar(frames.len(), "segment");
    let (mut records, mut total, mut secs) = (Vec::new(), 0usize, 0f64);
    let (mut eval_frames, mut other_detections) = (Vec::new(), 0usize);
    for (index, (id, load)) in frames.iter().enumerate() {
        let image = load().with_context(|| format!("reading frame {id}"))?;
        let t = Instant::now();
        let instances = seg.segment(&image).with_context(|| format!("segmenting frame {id}"))?;
        secs += t.elapsed().as_secs_f64();
        total += instances.len();
        write_label_png(&out.join(format!("{id}_labels.png")), &label_image(image.width, image.height, &instances))?;
        if args.overlays {
            write_atomic(&out.join(format!("{id}_segments.png")), &draw_segments(&image, &instances)?)?;
        }
        records.push(SegRecord::new(id, image.width, image.height, &instances));
        if let (true, Some(rec)) = (evaluate, &recording) {
            let nocs = detections_2d(&instances);
            other_detections += instances.len() - nocs.len();
            eval_frames.push((nocs, ground_truth_2d(rec.as_ref().as_ref(), index)?));
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let jsonl = out.join("segments.jsonl");
    write_atomic_with(&jsonl, |f| {
        use std::io::Write;
        for r in &records {
            writeln!(f, "{}", serde_json::to_string(r).map_err(std::io::Error::other)?)?;
        }
        Ok(())
    })?;
    log::info!(
        "{} frames, {total} instances, {:.1} ms/frame (first frame includes planning) -> {}",
        records.len(),
        1e3 * secs / records.len().max(1) as f64,
        jsonl.display()
    );
    if evaluate {
        let objects: usize = eval_frames.iter().map(|(_, g)| g.len()).sum();
        let detections: usize = eval_frames.iter().map(|(d, _)| d.len()).sum();
        let eval = Evaluation {
            recording: args.recording.display().to_string(),
            model: seg.onnx_path().display().to_string(),
            frames: eval_frames.len(),
            objects,
            detections,
            detections_per_object: detections as f64 / objects.max(1) as f64,
            other_detections,
            duplicate_mask_iou: seg.card().duplicate_mask_iou,
            duplicate_mask_inside: seg.card().duplicate_mask_inside,
            duplicates_dropped: seg.duplicates_dropped(),
            ap: segmentation_ap(&eval_frames).into_iter().collect(),
        };
        let dup = match (eval.duplicate_mask_iou, eval.duplicate_mask_inside) {
            (None, None) => "off".to_string(),
            (iou, inside) => [iou.map(|t| format!("mask IoU > {t}")), inside.map(|t| format!("inside > {t}"))]
                .into_iter()
                .flatten()
                .collect::<Vec<_>>()
                .join(" or "),
        };
        println!(
            "{} frames: {} detections of NOCS classes for {} objects ({:.2} per object), {} of no NOCS class; \
             duplicate suppression {dup}: {} dropped",
            eval.frames,
            eval.detections,
            eval.objects,
            eval.detections_per_object,
            eval.other_detections,
            eval.duplicates_dropped
        );
        for (name, ap) in &eval.ap {
            println!("{name:<10}{:>8}", ap.map_or_else(|| "-".to_string(), |v| format!("{v:.1}")));
        }
        if let Some(path) = &args.json {
            let text = serde_json::to_string_pretty(&eval)?;
            write_atomic(path, format!("{text}\n").as_bytes())?;
        }
    }
    Ok(())
}
