//! 3D IoU between two posed boxes, in the reference ("published") and the
//! corrected variant, and the symmetric search over rotations about y.

use crate::geometry::{Pose, Vec3, rotation_y};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

/// Number of rotations about the prediction's own y axis tried for symmetric
/// objects (`2*pi*i/SYMMETRY_STEPS`, `i = 0..SYMMETRY_STEPS`), as in the reference.
pub const SYMMETRY_STEPS: usize = 20;

/// Sign pattern of the 8 box corners, in the reference's order. The order does
/// not change any result (every formula pairs corners with the same signs), it
/// only keeps the published computation easy to compare by hand.
const CORNER_SIGNS: [[f64; 3]; 8] = [
    [1.0, 1.0, 1.0],
    [1.0, 1.0, -1.0],
    [-1.0, 1.0, 1.0],
    [-1.0, 1.0, -1.0],
    [1.0, -1.0, 1.0],
    [1.0, -1.0, -1.0],
    [-1.0, -1.0, 1.0],
    [-1.0, -1.0, -1.0],
];

/// How the axis-aligned boxes around the 8 transformed corners are formed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum IouMode {
    /// The reference code's computation, flaw included: min and max are taken
    /// per *corner* over its three coordinates (numpy `axis=0` on a 3x8 array),
    /// giving 8 "extents" whose products stand in for volumes. Every published
    /// NOCS table uses this; choose it to compare with papers.
    #[default]
    Published,
    /// The geometrically meaningful version: per-axis min and max over the 8
    /// corners (an axis-aligned box in camera coordinates), 3 extents.
    Corrected,
}

impl IouMode {
    /// The lowercase name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            IouMode::Published => "published",
            IouMode::Corrected => "corrected",
        }
    }

    /// One phrase saying what the mode computes (printed in report headers).
    pub fn description(self) -> &'static str {
        match self {
            IouMode::Published => "reference per-corner min/max, comparable with published tables",
            IouMode::Corrected => "per-axis camera-frame boxes, not comparable with published tables",
        }
    }
}

impl fmt::Display for IouMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for IouMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "published" => Ok(IouMode::Published),
            "corrected" => Ok(IouMode::Corrected),
            _ => Err(format!("unknown IoU mode {s:?} (expected published or corrected)")),
        }
    }
}

/// The 8 corners of the box `[-size/2, size/2]` mapped to the camera frame.
fn camera_corners(pose: &Pose, size: &[f64; 3]) -> [Vec3; 8] {
    CORNER_SIGNS
        .map(|s| pose.transform_point(&Vec3::new(s[0] * size[0] / 2.0, s[1] * size[1] / 2.0, s[2] * size[2] / 2.0)))
}

/// Per-axis (x, y, z) minima and maxima of the corners.
fn per_axis_bounds(corners: &[Vec3; 8]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for c in corners {
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    (lo, hi)
}

/// The reference's per-corner "bounds": for each corner, the min and the max
/// of its three camera coordinates.
fn per_corner_bounds(corners: &[Vec3; 8]) -> ([f64; 8], [f64; 8]) {
    (corners.map(|c| c.min()), corners.map(|c| c.max()))
}

/// IoU of two "boxes" given as `N` lower and upper bounds, with the
/// reference's arithmetic: the intersection is 0 when any overlap extent is
/// negative, otherwise the product of the extents; union = product of the
/// extents of each box minus the intersection.
fn bounds_iou<const N: usize>(a: ([f64; N], [f64; N]), b: ([f64; N], [f64; N])) -> f64 {
    let (lo_a, hi_a) = a;
    let (lo_b, hi_b) = b;
    let mut overlap = [0.0; N];
    for k in 0..N {
        overlap[k] = hi_a[k].min(hi_b[k]) - lo_a[k].max(lo_b[k]);
    }
    let intersection = if overlap.iter().any(|&e| e < 0.0) { 0.0 } else { overlap.iter().product() };
    let volume = |lo: &[f64; N], hi: &[f64; N]| (0..N).map(|k| hi[k] - lo[k]).product::<f64>();
    let union = volume(&lo_a, &hi_a) + volume(&lo_b, &hi_b) - intersection;
    intersection / union
}

/// 3D IoU of box `a` (size `size_a` in metres along the object axes, centred,
/// posed by `pose_a` = camera_from_object) and box `b`, using axis-aligned
/// boxes in camera coordinates formed as `mode` says.
///
/// Sizes must be positive. In [`IouMode::Published`] the value is NaN when
/// both boxes have a corner whose three camera coordinates are equal (0/0, as
/// in the reference); the matching treats NaN as "no match".
pub fn iou_3d(pose_a: &Pose, size_a: &[f64; 3], pose_b: &Pose, size_b: &[f64; 3], mode: IouMode) -> f64 {
    let ca = camera_corners(pose_a, size_a);
    let cb = camera_corners(pose_b, size_b);
    match mode {
        IouMode::Published => bounds_iou(per_corner_bounds(&ca), per_corner_bounds(&cb)),
        IouMode::Corrected => bounds_iou(per_axis_bounds(&ca), per_axis_bounds(&cb)),
    }
}

/// IoU of a prediction with a ground-truth box. When `symmetric`, the
/// prediction's pose is rotated about its own y axis by `2*pi*i/SYMMETRY_STEPS`
/// (`pose * rot_y`) and the best IoU is kept, starting from 0 as the reference
/// does (so a NaN step never wins); otherwise this is [`iou_3d`].
pub fn symmetric_iou_3d(pred: (&Pose, &[f64; 3]), gt: (&Pose, &[f64; 3]), symmetric: bool, mode: IouMode) -> f64 {
    let (pred_pose, pred_size) = pred;
    let (gt_pose, gt_size) = gt;
    if !symmetric {
        return iou_3d(pred_pose, pred_size, gt_pose, gt_size, mode);
    }
    let mut best = 0.0;
    for i in 0..SYMMETRY_STEPS {
        let angle = 2.0 * PI * i as f64 / SYMMETRY_STEPS as f64;
        let rotated = Pose::new(pred_pose.rotation * rotation_y(angle), pred_pose.translation_m);
        let iou = iou_3d(&rotated, pred_size, gt_pose, gt_size, mode);
        // Python's max(best, iou): keeps `best` unless `iou` is strictly larger.
        if iou > best {
            best = iou;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::rotation_axis_angle;

    fn at(t: [f64; 3]) -> Pose {
        Pose::new(crate::geometry::Mat3::identity(), Vec3::new(t[0], t[1], t[2]))
    }

    #[test]
    fn corrected_half_overlap_is_exact() {
        // Extent 3 along x, shifted by 1: overlap 2, union 4 -> 0.5 exactly.
        let s = [3.0, 1.0, 1.0];
        let iou = iou_3d(&at([0.0, 0.0, 4.0]), &s, &at([1.0, 0.0, 4.0]), &s, IouMode::Corrected);
        assert_eq!(iou, 0.5);
        let apart = iou_3d(&at([0.0, 0.0, 4.0]), &s, &at([3.5, 0.0, 4.0]), &s, IouMode::Corrected);
        assert_eq!(apart, 0.0);
    }

    #[test]
    fn published_uses_per_corner_bounds() {
        // Identity box of size (2, 4, 2) at z = 5: corner (+,+,+) is (1, 2, 6),
        // whose per-corner min/max are 1 and 6.
        let corners = camera_corners(&at([0.0, 0.0, 5.0]), &[2.0, 4.0, 2.0]);
        let (lo, hi) = per_corner_bounds(&corners);
        assert_eq!((lo[0], hi[0]), (1.0, 6.0));
        assert_eq!((lo[7], hi[7]), (-2.0, 4.0));
    }

    #[test]
    fn symmetric_search_recovers_y_rotation() {
        let gt = Pose::new(rotation_axis_angle(&Vec3::new(0.2, 1.0, 0.1), 0.5), Vec3::new(0.05, -0.02, 0.8));
        let size = [0.1, 0.25, 0.06];
        // A rotation by a multiple of 18 degrees about the object's y is found exactly.
        let pred = Pose::new(gt.rotation * rotation_y(54f64.to_radians()), gt.translation_m);
        for mode in [IouMode::Published, IouMode::Corrected] {
            let plain = iou_3d(&pred, &size, &gt, &size, mode);
            let sym = symmetric_iou_3d((&pred, &size), (&gt, &size), true, mode);
            assert!(plain < 0.9, "{mode}: {plain}");
            assert!((sym - 1.0).abs() < 1e-9, "{mode}: {sym}");
            assert_eq!(symmetric_iou_3d((&pred, &size), (&gt, &size), false, mode), plain);
        }
    }

    #[test]
    fn mode_parsing_and_display() {
        assert_eq!("published".parse::<IouMode>(), Ok(IouMode::Published));
        assert_eq!(" Corrected ".parse::<IouMode>(), Ok(IouMode::Corrected));
        assert!("per-axis".parse::<IouMode>().is_err());
        assert_eq!(IouMode::Corrected.to_string(), "corrected");
        assert_eq!(serde_json::to_string(&IouMode::Published).ok().as_deref(), Some("\"published\""));
    }
}
