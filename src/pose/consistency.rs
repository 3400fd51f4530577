//! How well the pose head agrees with the network's own keypoints: a confidence for the
//! reported score (tools/MODEL.md, E11).
//!
//! The graph predicts, besides `R`, `t`, `s`, M keypoints in the camera frame (`kpt_3d`)
//! and each keypoint's NOCS coordinate (`kpt_nocs`, object frame over the box diagonal).
//! On an object the network knows, carrying the NOCS coordinates by the head's pose
//! (`d R n + t`, `d` the diagonal of `s`) lands them on the keypoints; on a distractor or a
//! mask that missed its object the two disagree. [`keypoint_residual`] measures that, in
//! units of the box diagonal so that one scale serves every size of object;
//! [`consistency_score`] turns it into the factor of the reported score.

use crate::geometry::{Pose, Vec3};

/// Root mean square, over the keypoints, of `|d R n_k + t - p_k|`, over `d`: the distance
/// between keypoint `k`'s camera-frame position `p_k` and its NOCS coordinate `n_k` carried
/// by `camera_from_object` at the scale `d` of the box diagonal of `size_m`. `None` without
/// keypoints, for lists of different lengths, a diagonal that is not positive or a
/// non-finite result.
pub fn keypoint_residual(
    camera_from_object: &Pose,
    size_m: [f64; 3],
    keypoints_nocs: &[[f32; 3]],
    keypoints_camera_m: &[[f32; 3]],
) -> Option<f64> {
    let n = keypoints_nocs.len();
    if n == 0 || n != keypoints_camera_m.len() {
        return None;
    }
    let diagonal_m = size_m.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(diagonal_m > 0.0 && diagonal_m.is_finite()) {
        return None;
    }
    let v = |p: &[f32; 3]| Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let mut sum_sq_m2 = 0.0;
    for (nocs, camera_m) in keypoints_nocs.iter().zip(keypoints_camera_m) {
        let carried_m = diagonal_m * (camera_from_object.rotation * v(nocs)) + camera_from_object.translation_m;
        sum_sq_m2 += (carried_m - v(camera_m)).norm_squared();
    }
    let residual = (sum_sq_m2 / n as f64).sqrt() / diagonal_m;
    residual.is_finite().then_some(residual)
}

/// The factor `exp(-residual / scale)` in (0, 1]: 1 for a pose that agrees with its
/// keypoints exactly, `1/e` at a residual of `scale` box diagonals. A missing residual
/// (see [`keypoint_residual`]) gives 0: a pose the keypoints cannot vouch for ranks last.
pub fn consistency_score(residual: Option<f64>, scale: f64) -> f64 {
    residual.map_or(0.0, |r| (-r / scale).exp())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Mat3, rotation_axis_angle};

    fn keypoints(pose: &Pose, size_m: [f64; 3], nocs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let d = size_m.iter().map(|v| v * v).sum::<f64>().sqrt();
        nocs.iter()
            .map(|n| {
                let p = d * (pose.rotation * Vec3::new(n[0] as f64, n[1] as f64, n[2] as f64)) + pose.translation_m;
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect()
    }

    const NOCS: [[f32; 3]; 4] = [[0.2, -0.1, 0.05], [-0.3, 0.2, 0.1], [0.0, 0.0, -0.25], [0.1, 0.3, 0.0]];

    #[test]
    fn keypoints_on_the_pose_give_zero_and_one() {
        let pose =
            Pose::new(rotation_axis_angle(&Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7), Vec3::new(0.1, -0.2, 0.9));
        let size_m = [0.08, 0.2, 0.08];
        let r = keypoint_residual(&pose, size_m, &NOCS, &keypoints(&pose, size_m, &NOCS)).unwrap();
        assert!(r < 1e-6, "{r}");
        assert!((consistency_score(Some(r), 0.3) - 1.0).abs() < 1e-5);
    }

    #[test]
    fn a_known_offset_gives_its_length_over_the_diagonal() {
        // every keypoint moved by the same 3-4-0 cm vector: RMS 5 cm over a 0.5 m diagonal
        let pose = Pose::new(Mat3::identity(), Vec3::new(0.0, 0.0, 1.0));
        let size_m = [0.3, 0.4, 0.0];
        let moved: Vec<[f32; 3]> =
            keypoints(&pose, size_m, &NOCS).iter().map(|p| [p[0] + 0.03, p[1] + 0.04, p[2]]).collect();
        let r = keypoint_residual(&pose, size_m, &NOCS, &moved).unwrap();
        assert!((r - 0.1).abs() < 1e-6, "{r}");
        assert!((consistency_score(Some(r), 0.1) - (-1.0f64).exp()).abs() < 1e-6);
    }

    #[test]
    fn the_residual_does_not_depend_on_where_or_how_large_the_object_is() {
        // the same disagreement at twice the size, elsewhere and turned: the same residual
        let pose = Pose::new(Mat3::identity(), Vec3::new(0.0, 0.0, 1.0));
        let size_m = [0.1, 0.2, 0.1];
        let wrong = keypoints(&Pose::new(rotation_axis_angle(&Vec3::y(), 0.2), pose.translation_m), size_m, &NOCS);
        let r = keypoint_residual(&pose, size_m, &NOCS, &wrong).unwrap();
        assert!(r > 0.01);
        let turn = rotation_axis_angle(&Vec3::new(0.3, -1.0, 0.2).normalize(), 1.1);
        let shift = Vec3::new(-0.4, 0.1, 0.6);
        let big = [0.2, 0.4, 0.2];
        let moved = |p: &Pose| Pose::new(turn * p.rotation, turn * p.translation_m * 2.0 + shift);
        let pose2 = moved(&pose);
        let wrong2 =
            keypoints(&moved(&Pose::new(rotation_axis_angle(&Vec3::y(), 0.2), pose.translation_m)), big, &NOCS);
        let r2 = keypoint_residual(&pose2, big, &NOCS, &wrong2).unwrap();
        assert!((r - r2).abs() < 1e-5, "{r} vs {r2}");
        // and a larger disagreement scores lower
        assert!(consistency_score(Some(r), 0.3) < 1.0);
        assert!(consistency_score(Some(2.0 * r), 0.3) < consistency_score(Some(r), 0.3));
    }

    #[test]
    fn no_keypoints_or_no_size_give_no_residual_and_a_zero_score() {
        let pose = Pose::new(Mat3::identity(), Vec3::zeros());
        assert_eq!(keypoint_residual(&pose, [0.1, 0.1, 0.1], &[], &[]), None);
        assert_eq!(keypoint_residual(&pose, [0.1, 0.1, 0.1], &NOCS, &NOCS[..3]), None);
        assert_eq!(keypoint_residual(&pose, [0.0; 3], &NOCS, &NOCS), None);
        assert_eq!(keypoint_residual(&pose, [f64::NAN, 0.1, 0.1], &NOCS, &NOCS), None);
        assert_eq!(consistency_score(None, 0.3), 0.0);
    }
}
