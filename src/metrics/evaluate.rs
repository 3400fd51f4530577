//! The per-class, per-image evaluation loop and AP accumulation.

use super::ap::voc_ap;
use super::config::EvalConfig;
use super::iou::symmetric_iou_3d;
use super::matching::{match_by_iou, match_by_pose};
use super::pose_error::pose_error;
use super::report::{ClassResult, EvalReport, MetricValues};
use crate::category::Category;
use crate::error::{Error, Result};
use crate::output::predictions::{FramePredictions, PredInstance};
use crate::recording::{GtInstance, Recording};
use std::collections::HashMap;
use std::path::Path;

/// IoU a prediction / ground-truth pair must exceed (strictly) for the pair to
/// enter the pose metrics (the reference's `use_matches_for_pose` with
/// `iou_pose_thres = 0.1`).
pub const POSE_IOU_GATE: f64 = 0.10;

/// Percent per unit fraction (AP is reported in percent).
const PERCENT: f64 = 100.0;

/// Scored detections of one class for one metric, pooled over frames.
type Ranked = Vec<(f64, bool)>;

/// Everything gathered for one class over all frames.
struct ClassAccumulator {
    num_gt: usize,
    num_pred: usize,
    num_gt_pose: usize,
    num_pred_pose: usize,
    /// Per IoU threshold.
    iou: Vec<Ranked>,
    /// Per pose threshold.
    pose: Vec<Ranked>,
    /// (degrees, cm) of each ground-truth object matched at the pose gate, against the
    /// prediction that took it there.
    gate_errors: Vec<(f64, f64)>,
}

impl ClassAccumulator {
    fn new(cfg: &EvalConfig) -> Self {
        ClassAccumulator {
            num_gt: 0,
            num_pred: 0,
            num_gt_pose: 0,
            num_pred_pose: 0,
            iou: vec![Vec::new(); cfg.iou_thresholds.len()],
            pose: vec![Vec::new(); cfg.pose_thresholds.len()],
            gate_errors: Vec::new(),
        }
    }

    /// Adds one frame's ground truth and predictions of this class.
    fn add(&mut self, gts: &[&GtInstance], preds: &[&PredInstance], cfg: &EvalConfig) {
        self.num_gt += gts.len();
        self.num_pred += preds.len();
        if gts.is_empty() && preds.is_empty() {
            return;
        }
        // Score order, highest first; stable, so ties keep the frame's order.
        let mut preds = preds.to_vec();
        preds.sort_by(|a, b| b.score.total_cmp(&a.score));
        let symmetric: Vec<bool> = gts.iter().map(|g| g.class.is_symmetric(g.handle_visible)).collect();

        let ious: Vec<Vec<f64>> = preds
            .iter()
            .map(|p| {
                gts.iter()
                    .zip(&symmetric)
                    .map(|(g, &sym)| {
                        symmetric_iou_3d(
                            (&p.camera_from_object, &p.size_m),
                            (&g.camera_from_object, &g.size_m),
                            sym,
                            cfg.iou_mode,
                        )
                    })
                    .collect()
            })
            .collect();

        for (ranked, &threshold) in self.iou.iter_mut().zip(&cfg.iou_thresholds) {
            let m = match_by_iou(&ious, gts.len(), threshold);
            ranked.extend(preds.iter().zip(&m.pred_to_gt).map(|(p, g)| (p.score, g.is_some())));
        }

        // Pose metrics see only predictions and ground truth matched at the gate.
        let gate = match_by_iou(&ious, gts.len(), POSE_IOU_GATE);
        let pose_preds: Vec<&PredInstance> =
            preds.iter().zip(&gate.pred_to_gt).filter(|(_, g)| g.is_some()).map(|(p, _)| *p).collect();
        let pose_gts: Vec<(&GtInstance, bool)> = gts
            .iter()
            .zip(&symmetric)
            .zip(&gate.gt_to_pred)
            .filter(|(_, p)| p.is_some())
            .map(|((g, &sym), _)| (*g, sym))
            .collect();
        self.num_gt_pose += pose_gts.len();
        self.num_pred_pose += pose_preds.len();
        for ((g, &sym), p) in gts.iter().zip(&symmetric).zip(&gate.gt_to_pred) {
            if let Some(p) = p {
                self.gate_errors.push(pose_error(&preds[*p].camera_from_object, &g.camera_from_object, sym));
            }
        }
        let errors: Vec<Vec<(f64, f64)>> = pose_preds
            .iter()
            .map(|p| {
                pose_gts.iter().map(|(g, sym)| pose_error(&p.camera_from_object, &g.camera_from_object, *sym)).collect()
            })
            .collect();
        for (ranked, threshold) in self.pose.iter_mut().zip(&cfg.pose_thresholds) {
            let m = match_by_pose(&errors, pose_gts.len(), threshold);
            ranked.extend(pose_preds.iter().zip(&m.pred_to_gt).map(|(p, g)| (p.score, g.is_some())));
        }
    }

    fn finish(self, class: Category, cfg: &EvalConfig) -> ClassResult {
        let has_gt = self.num_gt > 0;
        let iou_aps = self.iou.iter().map(|r| voc_ap(r, self.num_gt));
        // A class with ground truth of which none passed the gate has no pose
        // candidates at all: AP 0, as the reference computes it.
        let pose_aps = self.pose.iter().map(|r| has_gt.then(|| voc_ap(r, self.num_gt_pose).unwrap_or(0.0)));
        let values = iou_aps.chain(pose_aps).map(|ap| ap.map(|v| v * PERCENT));
        let degrees: Vec<f64> = self.gate_errors.iter().map(|e| e.0).collect();
        let cm: Vec<f64> = self.gate_errors.iter().map(|e| e.1).collect();
        ClassResult {
            class,
            num_gt: self.num_gt,
            num_pred: self.num_pred,
            num_gt_pose: self.num_gt_pose,
            num_pred_pose: self.num_pred_pose,
            median_rotation_deg: median(degrees),
            median_translation_cm: median(cm),
            ap: MetricValues(cfg.metric_names().into_iter().zip(values).collect()),
        }
    }
}

/// The median of `values` (the mean of the middle two for an even count); `None` when empty.
fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) })
}

/// Evaluates frames of (ground truth, predictions) with the NOCS protocol
/// (see docs/metrics.md) and returns AP per class and metric in percent.
///
/// For every class and frame: predictions are ranked by score and matched
/// greedily to ground truth by 3D IoU (strictly above each threshold); pose
/// metrics use only the pairs matched at IoU > [`POSE_IOU_GATE`], matched by
/// degrees + cm within each threshold (inclusive). AP is VOC all-point over
/// all frames. A class without ground truth has no AP (`None`) and is left out
/// of the mean. Each class also gets the median rotation and translation error
/// of its ground-truth objects matched at the gate (against the prediction
/// that took each one there, the protocol's symmetry rules applied). Thresholds are not checked here: call
/// [`EvalConfig::validate`] on user input.
pub fn evaluate<'a>(
    frames: impl IntoIterator<Item = (&'a [GtInstance], &'a [PredInstance])>,
    cfg: &EvalConfig,
) -> EvalReport {
    let mut classes: Vec<ClassAccumulator> = Category::ALL.iter().map(|_| ClassAccumulator::new(cfg)).collect();
    let mut frames_evaluated = 0;
    for (gts, preds) in frames {
        frames_evaluated += 1;
        for (acc, class) in classes.iter_mut().zip(Category::ALL) {
            let cls_gts: Vec<&GtInstance> = gts.iter().filter(|g| g.class == class).collect();
            let cls_preds: Vec<&PredInstance> = preds.iter().filter(|p| p.class == class).collect();
            acc.add(&cls_gts, &cls_preds, cfg);
        }
    }
    let classes: Vec<ClassResult> =
        classes.into_iter().zip(Category::ALL).map(|(acc, class)| acc.finish(class, cfg)).collect();
    let metrics = cfg.metric_names();
    let mean = metrics
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let values: Vec<f64> = classes.iter().filter_map(|c| c.ap.0.get(k).and_then(|(_, v)| *v)).collect();
            let mean = (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
            (name.clone(), mean)
        })
        .collect();
    EvalReport {
        iou_mode: cfg.iou_mode,
        iou_thresholds: cfg.iou_thresholds.clone(),
        pose_thresholds: cfg.pose_thresholds.clone(),
        metrics,
        frames_evaluated,
        classes,
        mean: MetricValues(mean),
    }
}

/// Renames each frame of `preds` to the recording's frame nearest in time, within
/// `tolerance_s`: for predictions of a stream whose frame ids are not the recording's (a ROS 2
/// bag made from it, a camera recorded alongside). Every prediction frame needs a timestamp and
/// a match; two prediction frames may not match one recording frame.
pub fn match_frames_by_timestamp(
    rec: &dyn Recording,
    preds: &[FramePredictions],
    pred_path: &Path,
    tolerance_s: f64,
) -> Result<Vec<FramePredictions>> {
    let mut times: Vec<(f64, usize)> = Vec::with_capacity(rec.len());
    for i in 0..rec.len() {
        let Some(t) = rec.timestamp_s(i) else {
            return Err(Error::InvalidArgument(format!(
                "{}: frame {:?} has no timestamp to match predictions by (use --match id)",
                rec.describe(),
                rec.frame_id(i)
            )));
        };
        times.push((t, i));
    }
    times.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut taken: HashMap<usize, usize> = HashMap::new();
    let mut out = Vec::with_capacity(preds.len());
    for (k, frame) in preds.iter().enumerate() {
        let line = Some(k + 1);
        let Some(t) = frame.timestamp_s else {
            return Err(Error::parse(pred_path, line, format!("frame {:?} has no timestamp_s", frame.frame)));
        };
        let at = times.partition_point(|(x, _)| *x < t);
        let nearest = [at.checked_sub(1), Some(at)]
            .into_iter()
            .flatten()
            .filter_map(|j| times.get(j))
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()));
        let Some(&(tr, i)) = nearest.filter(|(tr, _)| (tr - t).abs() <= tolerance_s) else {
            return Err(Error::parse(
                pred_path,
                line,
                format!("frame {:?} at {t} s: no frame of {} within {tolerance_s} s", frame.frame, rec.describe()),
            ));
        };
        if let Some(first) = taken.insert(i, k) {
            return Err(Error::parse(
                pred_path,
                line,
                format!(
                    "frame {:?} at {t} s matches recording frame {:?} ({tr} s), as line {} did",
                    frame.frame,
                    rec.frame_id(i),
                    first + 1
                ),
            ));
        }
        out.push(FramePredictions { frame: rec.frame_id(i).to_string(), ..frame.clone() });
    }
    Ok(out)
}

/// Evaluates a predictions file's frames against a recording's ground truth.
///
/// `preds` are matched to recording frames by frame id; `pred_path` is only
/// used in error messages. A prediction frame id that is not in the recording,
/// or that appears twice, is an [`Error::Parse`] naming `pred_path` and line
/// `index + 1`. Recording frames without a prediction line count as frames
/// with no predictions. Every recording frame must have ground truth
/// ([`Error::InvalidArgument`] otherwise, naming the frame), and the
/// configuration must pass [`EvalConfig::validate`].
pub fn evaluate_recording(
    rec: &dyn Recording,
    preds: &[FramePredictions],
    pred_path: &Path,
    cfg: &EvalConfig,
) -> Result<EvalReport> {
    evaluate_recordings(&[(rec, preds, pred_path)], cfg)
}

/// [`evaluate_recording`] over several recordings at once, each with its predictions file:
/// one average precision over all their frames, as the NOCS reference code computes it over
/// a dataset's scenes (REAL275's six test scenes), not a mean of per-scene results.
pub fn evaluate_recordings(
    sets: &[(&dyn Recording, &[FramePredictions], &Path)],
    cfg: &EvalConfig,
) -> Result<EvalReport> {
    cfg.validate()?;
    let mut gts: Vec<Vec<GtInstance>> = Vec::new();
    let mut pred_of_frame: Vec<&[PredInstance]> = Vec::new();
    for &(rec, preds, pred_path) in sets {
        let (g, lines) = ground_truth_and_lines(rec, preds, pred_path)?;
        gts.extend(g);
        pred_of_frame.extend(lines.iter().map(|k| k.map_or(&[][..], |k| preds[k].instances.as_slice())));
    }
    if gts.is_empty() {
        return Err(Error::InvalidArgument("no recording to evaluate".into()));
    }
    Ok(evaluate(gts.iter().map(Vec::as_slice).zip(pred_of_frame), cfg))
}

/// Each frame's ground-truth instances, and the index of its predictions line (if any).
type GroundTruthAndLines = (Vec<Vec<GtInstance>>, Vec<Option<usize>>);

/// Every frame's ground truth, and the predictions line of each frame (if any): the checks
/// [`evaluate_recording`] documents.
fn ground_truth_and_lines(
    rec: &dyn Recording,
    preds: &[FramePredictions],
    pred_path: &Path,
) -> Result<GroundTruthAndLines> {
    if rec.is_empty() {
        return Err(Error::InvalidArgument(format!("{}: the recording has no frames to evaluate", rec.describe())));
    }
    let index: HashMap<&str, usize> = (0..rec.len()).map(|i| (rec.frame_id(i), i)).collect();
    let mut line_of_frame: Vec<Option<usize>> = vec![None; rec.len()];
    for (k, frame) in preds.iter().enumerate() {
        let Some(&i) = index.get(frame.frame.as_str()) else {
            return Err(Error::parse(
                pred_path,
                Some(k + 1),
                format!("frame {:?} is not in the recording ({})", frame.frame, rec.describe()),
            ));
        };
        if let Some(first) = line_of_frame[i] {
            return Err(Error::parse(
                pred_path,
                Some(k + 1),
                format!("frame {:?} is given twice (first on line {})", frame.frame, first + 1),
            ));
        }
        line_of_frame[i] = Some(k);
    }
    let mut gts = Vec::with_capacity(rec.len());
    for i in 0..rec.len() {
        match rec.read_instances(i)? {
            Some(instances) => gts.push(instances),
            None => {
                return Err(Error::InvalidArgument(format!(
                    "{}: frame {:?} has no ground truth; evaluation needs ground truth for every frame",
                    rec.describe(),
                    rec.frame_id(i)
                )));
            }
        }
    }
    Ok((gts, line_of_frame))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose, Vec3, rotation_axis_angle};

    fn gt(class: Category, pose: Pose, size: [f64; 3]) -> GtInstance {
        GtInstance { id: 1, class, camera_from_object: pose, size_m: size, handle_visible: true }
    }

    fn pred(class: Category, score: f64, pose: Pose, size: [f64; 3]) -> PredInstance {
        PredInstance { class, score, camera_from_object: pose, size_m: size, box2d: None, mask: None }
    }

    #[test]
    fn gate_drops_unmatched_predictions_and_ground_truth_from_pose() {
        let size = [0.1, 0.08, 0.12];
        let p0 = Pose::new(rotation_axis_angle(&Vec3::new(0.1, 1.0, 0.2), 0.4), Vec3::new(0.0, 0.0, 0.7));
        let far = Pose::new(p0.rotation, Vec3::new(0.5, 0.0, 0.7));
        let gts = vec![gt(Category::Camera, p0, size), gt(Category::Camera, far, size)];
        // Only the first GT is detected; a high-scoring FP sits elsewhere.
        let nowhere = Pose::new(p0.rotation, Vec3::new(-0.5, 0.0, 0.7));
        let preds = vec![pred(Category::Camera, 0.5, p0, size), pred(Category::Camera, 0.9, nowhere, size)];
        let report =
            evaluate([(gts.as_slice(), preds.as_slice())], &EvalConfig::standard(super::super::IouMode::Corrected));
        let cam = &report.classes[2];
        assert_eq!((cam.num_gt, cam.num_pred, cam.num_gt_pose, cam.num_pred_pose), (2, 2, 1, 1));
        // IoU: FP first, then TP: precision 1/2 up to recall 1/2.
        assert_eq!(report.class_ap(Category::Camera, "IoU50"), Some(25.0));
        // Pose: the FP and the missed GT are gone: 100.
        assert_eq!(report.class_ap(Category::Camera, "5deg2cm"), Some(100.0));
    }
}
