//! The evaluation report: per-class AP per metric, means, JSON and a text table.

use super::config::PoseThreshold;
use super::iou::IouMode;
use crate::category::Category;
use serde::ser::{Serialize, SerializeMap, Serializer};
use std::fmt::Write as _;

/// Values per metric in report order; serialises as a JSON object
/// `{"IoU25": 93.1, ..., "5deg2cm": null}` keeping that order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MetricValues(pub Vec<(String, Option<f64>)>);

impl MetricValues {
    /// The value of metric `name`; `None` when the metric is unknown or has no value.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.0.iter().find(|(n, _)| n == name).and_then(|(_, v)| *v)
    }

    /// (name, value) pairs in report order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, Option<f64>)> {
        self.0.iter().map(|(n, v)| (n.as_str(), *v))
    }
}

impl Serialize for MetricValues {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, value) in &self.0 {
            map.serialize_entry(name, value)?;
        }
        map.end()
    }
}

/// Results for one category.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ClassResult {
    /// The category.
    pub class: Category,
    /// Ground-truth instances of this class over all frames.
    pub num_gt: usize,
    /// Predictions of this class over all frames.
    pub num_pred: usize,
    /// Ground-truth instances matched at IoU > 0.10: the recall denominator of
    /// the pose metrics (the reference's gating).
    pub num_gt_pose: usize,
    /// Predictions matched at IoU > 0.10: the only ones the pose metrics rank.
    pub num_pred_pose: usize,
    /// Median rotation error in degrees of the ground-truth objects matched at
    /// IoU > 0.10, each against the prediction that took it (the highest-scoring
    /// one); bottle, bowl, can and mugs with a hidden handle by the angle of their
    /// y axes. `None` when no object passed the gate.
    pub median_rotation_deg: Option<f64>,
    /// Median translation error in centimetres over the same pairs.
    pub median_translation_cm: Option<f64>,
    /// AP in percent per metric; `None` (JSON `null`) when the class has no
    /// ground truth.
    pub ap: MetricValues,
}

/// The outcome of [`evaluate`](super::evaluate): AP per class and metric (in
/// percent, 0..100) and the mean over the classes that have ground truth.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct EvalReport {
    /// The IoU computation used; every number in the report depends on it.
    pub iou_mode: IouMode,
    /// IoU thresholds, in metric order.
    pub iou_thresholds: Vec<f64>,
    /// Pose thresholds, in metric order.
    pub pose_thresholds: Vec<PoseThreshold>,
    /// Metric keys in column order (`IoU25`, ..., `5deg2cm`, ...).
    pub metrics: Vec<String>,
    /// Number of frames evaluated.
    pub frames_evaluated: usize,
    /// One entry per category, in NOCS id order.
    pub classes: Vec<ClassResult>,
    /// Mean AP per metric over the classes with ground truth; `None` when no
    /// class has any.
    pub mean: MetricValues,
}

/// Width of the class-name column of the table.
const CLASS_COLUMN: usize = 8;
/// Width of the count columns of the table.
const COUNT_COLUMN: usize = 8;
/// Minimum width of a metric column of the table.
const METRIC_COLUMN: usize = 8;

impl EvalReport {
    /// Mean AP (percent) of metric `metric_name` over classes with ground
    /// truth; `None` for an unknown metric or when no class has ground truth.
    pub fn mean(&self, metric_name: &str) -> Option<f64> {
        self.mean.get(metric_name)
    }

    /// AP (percent) of `class` for metric `metric_name`; `None` for an
    /// unknown metric or when the class has no ground truth.
    pub fn class_ap(&self, class: Category, metric_name: &str) -> Option<f64> {
        self.classes.iter().find(|c| c.class == class).and_then(|c| c.ap.get(metric_name))
    }

    /// Column labels: IoU keys as they are, pose keys as `5°2cm`.
    fn column_labels(&self) -> Vec<String> {
        let pose_labels = self.pose_thresholds.iter().map(|t| (t.name(), t.label()));
        let pose_labels: Vec<(String, String)> = pose_labels.collect();
        self.metrics
            .iter()
            .map(|m| pose_labels.iter().find(|(n, _)| n == m).map_or_else(|| m.clone(), |(_, l)| l.clone()))
            .collect()
    }

    /// A fixed-width text table: one row per class and a `mean` row, one
    /// column per metric (AP in percent, one decimal; `-` where a class has no
    /// ground truth). The header names the IoU mode.
    pub fn to_table(&self) -> String {
        let labels = self.column_labels();
        let widths: Vec<usize> = labels.iter().map(|l| (l.chars().count() + 1).max(METRIC_COLUMN)).collect();
        let cell = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
        let mut out = String::new();
        // Writing to a String cannot fail.
        let _ = writeln!(
            out,
            "NOCS metrics, AP in %, IoU mode: {} ({}), {} frames",
            self.iou_mode,
            self.iou_mode.description(),
            self.frames_evaluated
        );
        let _ = write!(out, "{:<CLASS_COLUMN$}{:>COUNT_COLUMN$}{:>COUNT_COLUMN$}", "class", "gt", "pred");
        for (label, w) in labels.iter().zip(&widths) {
            let _ = write!(out, "{label:>w$}");
        }
        let _ = write!(out, "{:>METRIC_COLUMN$}{:>METRIC_COLUMN$}", "med°", "med cm");
        out.push('\n');
        for c in &self.classes {
            let _ = write!(
                out,
                "{:<CLASS_COLUMN$}{:>COUNT_COLUMN$}{:>COUNT_COLUMN$}",
                c.class.name(),
                c.num_gt,
                c.num_pred
            );
            for ((_, v), w) in c.ap.iter().zip(&widths) {
                let _ = write!(out, "{:>w$}", cell(v));
            }
            let _ = write!(
                out,
                "{:>METRIC_COLUMN$}{:>METRIC_COLUMN$}",
                cell(c.median_rotation_deg),
                cell(c.median_translation_cm)
            );
            out.push('\n');
        }
        let _ = write!(out, "{:<CLASS_COLUMN$}{:>COUNT_COLUMN$}{:>COUNT_COLUMN$}", "mean", "", "");
        for ((_, v), w) in self.mean.iter().zip(&widths) {
            let _ = write!(out, "{:>w$}", cell(v));
        }
        out.push('\n');
        out.push_str("- : no ground truth for the class (left out of the mean); pose metrics rank only pairs matched at IoU > 0.1\n");
        out.push_str("med°, med cm: median rotation / translation error of the objects matched at IoU > 0.1\n");
        out
    }
}
