//! Rotation and translation error between a predicted and a ground-truth pose.

use crate::geometry::{Pose, Vec3, rotation_angle_deg};

/// Centimetres per metre (translation errors are reported in cm).
pub const CM_PER_M: f64 = 100.0;

/// Rotation error in degrees and translation error in centimetres of `pred`
/// against `gt`.
///
/// When `symmetric` (bottle, bowl, can, and mug with its handle hidden), the
/// rotation error is the angle between the two object y axes in the camera
/// frame, `R_pred * y` and `R_gt * y`; otherwise it is the geodesic angle
/// `arccos((trace(R_pred R_gt^T) - 1) / 2)`. The cosine is clipped to
/// [-1, 1] (the reference does not clip and can return NaN for rounding
/// just outside that range). Translation error = `|t_pred - t_gt| * 100`.
pub fn pose_error(pred: &Pose, gt: &Pose, symmetric: bool) -> (f64, f64) {
    let degrees = if symmetric {
        let y_pred = pred.rotation * Vec3::y();
        let y_gt = gt.rotation * Vec3::y();
        let cos = (y_pred.dot(&y_gt) / (y_pred.norm() * y_gt.norm())).clamp(-1.0, 1.0);
        cos.acos().to_degrees()
    } else {
        rotation_angle_deg(&pred.rotation, &gt.rotation)
    };
    let cm = (pred.translation_m - gt.translation_m).norm() * CM_PER_M;
    (degrees, cm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{rotation_axis_angle, rotation_y};

    #[test]
    fn symmetric_ignores_rotation_about_y() {
        let gt = Pose::new(rotation_axis_angle(&Vec3::new(1.0, 0.3, 0.0), 0.6), Vec3::new(0.0, 0.0, 0.5));
        let pred = Pose::new(gt.rotation * rotation_y(2.0), gt.translation_m + Vec3::new(0.03, 0.0, 0.04));
        let (deg, cm) = pose_error(&pred, &gt, true);
        assert!(deg < 1e-6, "{deg}");
        assert!((cm - 5.0).abs() < 1e-9, "{cm}");
        let (deg, _) = pose_error(&pred, &gt, false);
        assert!((deg - 2f64.to_degrees()).abs() < 1e-9, "{deg}");
    }

    #[test]
    fn symmetric_measures_tilt_of_y() {
        let gt = Pose::IDENTITY;
        let pred = Pose::new(rotation_axis_angle(&Vec3::x(), 12f64.to_radians()), Vec3::zeros());
        let (deg, cm) = pose_error(&pred, &gt, true);
        assert!((deg - 12.0).abs() < 1e-9, "{deg}");
        assert_eq!(cm, 0.0);
    }

    #[test]
    fn identical_rotations_give_zero_not_nan() {
        // Rounding can push the cosine just above 1; the clip keeps this at 0.
        let r = rotation_axis_angle(&Vec3::new(0.3, -0.7, 0.2), 1.234);
        let p = Pose::new(r, Vec3::new(0.1, 0.2, 0.3));
        for symmetric in [false, true] {
            let (deg, cm) = pose_error(&p, &p, symmetric);
            assert!(deg.is_finite() && deg < 1e-5, "{deg}");
            assert_eq!(cm, 0.0);
        }
    }
}
