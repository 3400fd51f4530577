//! What several commands share: the shipped files they default to, the thread count, the
//! mask source, the ground truth and AP of the segmenter commands.

use tricons::metrics::mask_ap::Object2d;

/// The shipped demo recording (four SynthNOCS-test frames).
pub const DEFAULT_RECORDING: &str = "tests/data/synthnocs-demo";
/// The shipped pose model's card.
pub const DEFAULT_MODEL: &str = "models/tricons-pose.card.json";
/// The shipped Mask R-CNN's card.
pub const DEFAULT_SEGMENTER: &str = "models/maskrcnn-light.card.json";

/// The cores this process may run on (affinity and cgroup limits included).
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// Worker threads of the Mask R-CNN's matrix products when `--segmenter-threads` is not
/// given: tract's threaded products made the shipped graph slower at 2 threads than at 1
/// (docs/results.md, "Speed"), so the segmenter runs on one and the cores go to the pose
/// instances (and, in the service, to the stages running side by side).
pub const DEFAULT_SEGMENTER_THREADS: usize = 1;

/// `--threads`, or the cores available when it is not given (at least 1).
pub fn threads(flag: Option<usize>) -> usize {
    flag.unwrap_or_else(available_threads).max(1)
}

/// Where the instance masks come from: `model`, `gt` or `results:DIR` (flags and configs).
#[derive(Clone, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(try_from = "String")]
pub enum MaskSource {
    /// The Mask R-CNN (--segmenter) on the colour image: the full pipeline.
    Model,
    /// The recording's ground-truth instance masks (isolates the pose model).
    Gt,
    /// Published Mask R-CNN result pickles (`results_*_<scene>_<frame>.pkl`), as distributed
    /// with SPD / DualPoseNet / AG-Pose: the detections of every published REAL275 table.
    Results(std::path::PathBuf),
}

impl std::str::FromStr for MaskSource {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<MaskSource, String> {
        match s {
            "model" => Ok(MaskSource::Model),
            "gt" => Ok(MaskSource::Gt),
            _ => match s.strip_prefix("results:") {
                Some(dir) if !dir.is_empty() => Ok(MaskSource::Results(dir.into())),
                _ => Err(format!("{s:?}: expected model, gt or results:DIR")),
            },
        }
    }
}

impl TryFrom<String> for MaskSource {
    type Error = String;
    fn try_from(s: String) -> std::result::Result<MaskSource, String> {
        s.parse()
    }
}

/// Frame `i`'s ground truth: its instances and their full-image masks (an error naming
/// the frame when it has none).
pub fn ground_truth(
    rec: &dyn tricons::recording::Recording,
    i: usize,
) -> anyhow::Result<(Vec<tricons::recording::GtInstance>, Vec<Vec<bool>>)> {
    let Some(ann) = rec.read_annotations(i)? else {
        anyhow::bail!("frame {} of {} has no ground truth", rec.frame_id(i), rec.describe());
    };
    let Some(masks) = ann.instance_masks() else {
        anyhow::bail!("frame {} of {} has no instance mask", rec.frame_id(i), rec.describe());
    };
    Ok((ann.instances, masks))
}

/// Frame `i`'s ground-truth objects as 2-D detections (class, the mask's tight box, mask).
pub fn ground_truth_2d(rec: &dyn tricons::recording::Recording, i: usize) -> anyhow::Result<Vec<Object2d>> {
    let width = rec.intrinsics().width as usize;
    let (gt, masks) = ground_truth(rec, i)?;
    Ok(gt
        .iter()
        .zip(masks)
        .map(|(g, m)| Object2d { class: g.class, score: 1.0, box_xyxy: Object2d::mask_box(&m, width), mask: m })
        .collect())
}

/// A segmenter's detections of NOCS categories as 2-D objects (other labels left out).
pub fn detections_2d(dets: &[tricons::segment::SegInstance]) -> Vec<Object2d> {
    dets.iter()
        .filter_map(|d| {
            Some(Object2d {
                class: d.category?,
                score: d.score as f64,
                box_xyxy: d.box_xyxy.map(f64::from),
                mask: d.mask.clone(),
            })
        })
        .collect()
}

/// Box and mask AP at IoU 0.5 and 0.75, percent, named `bbox_AP50` ... `mask_AP75`.
pub fn segmentation_ap(frames: &[(Vec<Object2d>, Vec<Object2d>)]) -> Vec<(String, Option<f64>)> {
    use tricons::metrics::mask_ap::{Overlap, average_precision_2d};
    let mut rows = Vec::new();
    for (overlap, name) in [(Overlap::Box, "bbox"), (Overlap::Mask, "mask")] {
        for thr in [0.5, 0.75] {
            let ap = average_precision_2d(frames, overlap, thr).map(|v| 100.0 * v);
            rows.push((format!("{name}_AP{}", (thr * 100.0) as u32), ap));
        }
    }
    rows
}
