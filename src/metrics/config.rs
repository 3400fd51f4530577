//! What to evaluate: IoU mode, IoU thresholds and (degrees, cm) thresholds.

use super::iou::IouMode;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::fmt;
use std::str::FromStr;

/// The standard IoU thresholds of NOCS tables (IoU25, IoU50, IoU75).
pub const DEFAULT_IOU_THRESHOLDS: [f64; 3] = [0.25, 0.50, 0.75];

/// The standard pose thresholds of NOCS tables, (degrees, cm):
/// 5°2cm, 5°5cm, 10°2cm, 10°5cm.
pub const DEFAULT_POSE_THRESHOLDS: [(f64, f64); 4] = [(5.0, 2.0), (5.0, 5.0), (10.0, 2.0), (10.0, 5.0)];

/// A pose-accuracy threshold: a match needs rotation error <= `degrees` and
/// translation error <= `cm` (both inclusive).
///
/// Parsed from `"5deg2cm"`, `"5°2cm"` or `"5:2"`; displayed as `"5°2cm"`; its
/// metric key ([`PoseThreshold::name`]) is ASCII, `"5deg2cm"`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseThreshold {
    /// Largest accepted rotation error in degrees.
    pub degrees: f64,
    /// Largest accepted translation error in centimetres.
    pub cm: f64,
}

impl PoseThreshold {
    /// The metric key, e.g. `"5deg2cm"` (`"7.5deg1cm"` for fractions).
    pub fn name(&self) -> String {
        format!("{}deg{}cm", self.degrees, self.cm)
    }

    /// The table label, e.g. `"5°2cm"`.
    pub fn label(&self) -> String {
        format!("{}°{}cm", self.degrees, self.cm)
    }

    fn check(&self) -> std::result::Result<(), String> {
        if !(self.degrees.is_finite() && self.degrees >= 0.0 && self.cm.is_finite() && self.cm >= 0.0) {
            return Err(format!(
                "pose threshold {}deg {}cm: degrees and cm must be finite and non-negative",
                self.degrees, self.cm
            ));
        }
        Ok(())
    }
}

impl fmt::Display for PoseThreshold {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.label())
    }
}

impl FromStr for PoseThreshold {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        let text = s.trim();
        let bad = || format!("bad pose threshold {s:?} (expected e.g. 5deg2cm, 5°2cm or 5:2)");
        let (deg, cm) = if let Some((d, c)) = text.split_once(':') {
            (d, c)
        } else {
            let body = text.strip_suffix("cm").ok_or_else(bad)?;
            body.split_once("deg").or_else(|| body.split_once('°')).ok_or_else(bad)?
        };
        let number = |v: &str| v.trim().parse::<f64>().map_err(|_| bad());
        let t = PoseThreshold { degrees: number(deg)?, cm: number(cm)? };
        t.check()?;
        Ok(t)
    }
}

/// The metric key of an IoU threshold: `"IoU"` followed by the threshold in
/// percent, e.g. `"IoU25"` for 0.25 (`"IoU12.5"` for 0.125).
pub fn iou_metric_name(threshold: f64) -> String {
    let pct = threshold * 100.0;
    if (pct - pct.round()).abs() < 1e-9 {
        format!("IoU{}", pct.round())
    } else {
        let text = format!("{pct:.6}");
        format!("IoU{}", text.trim_end_matches('0').trim_end_matches('.'))
    }
}

/// What [`evaluate`](super::evaluate) computes.
///
/// `Default` is the standard NOCS report: [`IouMode::Published`] (so numbers
/// are comparable with published tables, which all use the reference's IoU),
/// IoU 0.25/0.50/0.75 and 5°2cm, 5°5cm, 10°2cm, 10°5cm. Pass
/// [`IouMode::Corrected`] for the geometrically meaningful IoU.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    /// How 3D IoU is computed.
    pub iou_mode: IouMode,
    /// IoU thresholds in [0, 1]; each gives a metric `IoU{percent}`.
    pub iou_thresholds: Vec<f64>,
    /// Pose thresholds; each gives a metric like `5deg2cm`.
    pub pose_thresholds: Vec<PoseThreshold>,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig::standard(IouMode::Published)
    }
}

impl EvalConfig {
    /// The standard thresholds with the given IoU mode.
    pub fn standard(iou_mode: IouMode) -> EvalConfig {
        EvalConfig {
            iou_mode,
            iou_thresholds: DEFAULT_IOU_THRESHOLDS.to_vec(),
            pose_thresholds: DEFAULT_POSE_THRESHOLDS
                .iter()
                .map(|&(degrees, cm)| PoseThreshold { degrees, cm })
                .collect(),
        }
    }

    /// Metric keys in report order: IoU metrics, then pose metrics.
    pub fn metric_names(&self) -> Vec<String> {
        self.iou_thresholds
            .iter()
            .map(|&t| iou_metric_name(t))
            .chain(self.pose_thresholds.iter().map(PoseThreshold::name))
            .collect()
    }

    /// Checks thresholds (IoU in [0, 1], pose values finite and non-negative)
    /// and that no two metrics share a name; [`Error::InvalidArgument`] otherwise.
    pub fn validate(&self) -> Result<()> {
        for &t in &self.iou_thresholds {
            if !(t.is_finite() && (0.0..=1.0).contains(&t)) {
                return Err(Error::InvalidArgument(format!("IoU threshold {t} is not in [0, 1]")));
            }
        }
        for t in &self.pose_thresholds {
            t.check().map_err(Error::InvalidArgument)?;
        }
        let mut seen = HashSet::new();
        for name in self.metric_names() {
            if !seen.insert(name.clone()) {
                return Err(Error::InvalidArgument(format!("metric {name} is requested twice")));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_threshold_parsing() {
        let t = PoseThreshold { degrees: 5.0, cm: 2.0 };
        assert_eq!("5deg2cm".parse::<PoseThreshold>(), Ok(t));
        assert_eq!("5:2".parse::<PoseThreshold>(), Ok(t));
        assert_eq!("5°2cm".parse::<PoseThreshold>(), Ok(t));
        assert_eq!(t.to_string(), "5°2cm");
        assert_eq!(t.name(), "5deg2cm");
        assert_eq!(t.to_string().parse::<PoseThreshold>(), Ok(t));
        let f: PoseThreshold = "7.5deg0.5cm".parse().unwrap_or(t);
        assert_eq!((f.degrees, f.cm, f.name()), (7.5, 0.5, "7.5deg0.5cm".to_string()));
        for bad in ["5deg", "5cm", "deg2cm", "5:x", "-1:2", "5:inf", ""] {
            assert!(bad.parse::<PoseThreshold>().is_err(), "{bad}");
        }
    }

    #[test]
    fn names_and_validation() {
        assert_eq!(iou_metric_name(0.25), "IoU25");
        assert_eq!(iou_metric_name(0.1), "IoU10");
        assert_eq!(iou_metric_name(0.125), "IoU12.5");
        let cfg = EvalConfig::default();
        assert_eq!(cfg.iou_mode, IouMode::Published);
        assert_eq!(cfg.metric_names(), ["IoU25", "IoU50", "IoU75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm"]);
        assert!(cfg.validate().is_ok());
        let mut dup = cfg.clone();
        dup.iou_thresholds.push(0.5);
        assert!(dup.validate().is_err());
        let mut out = cfg;
        out.iou_thresholds = vec![1.5];
        assert!(out.validate().is_err());
    }
}
