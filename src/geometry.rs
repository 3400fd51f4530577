//! Rigid transforms and small rotation helpers shared by the pipeline.
//!
//! Transforms are named for what they map: `camera_from_object` maps a point
//! in the object's canonical frame to the camera frame (x right, y down,
//! z forward, metres).

use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::{Deserialize, Serialize};

/// 3x3 matrix of f64.
pub type Mat3 = Matrix3<f64>;
/// 3-vector of f64.
pub type Vec3 = Vector3<f64>;

/// Largest deviation from orthonormality accepted for a rotation read from a file.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// A rigid transform: `p_to = rotation * p_from + translation_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PoseWire", into = "PoseWire")]
pub struct Pose {
    /// Proper rotation (orthonormal, det +1).
    pub rotation: Mat3,
    /// Translation in metres.
    pub translation_m: Vec3,
}

impl Default for Pose {
    fn default() -> Self {
        Pose::IDENTITY
    }
}

impl Pose {
    /// The identity transform.
    pub const IDENTITY: Pose = Pose {
        rotation: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation_m: Vector3::new(0.0, 0.0, 0.0),
    };

    /// A transform from a rotation and a translation in metres.
    pub fn new(rotation: Mat3, translation_m: Vec3) -> Pose {
        Pose { rotation, translation_m }
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Vec3) -> Vec3 {
        self.rotation * p + self.translation_m
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Pose {
        let rt = self.rotation.transpose();
        Pose::new(rt, -(rt * self.translation_m))
    }

    /// `self * other`: first `other`, then `self`.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose::new(self.rotation * other.rotation, self.rotation * other.translation_m + self.translation_m)
    }

    /// The 4x4 homogeneous matrix.
    pub fn to_matrix4(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation_m);
        m
    }

    /// Builds a pose from a 4x4 matrix whose upper-left block may be a rotation
    /// scaled by a positive factor (as in NOCS `RTs`); the scale is divided out
    /// with the cube root of the determinant, as the NOCS evaluation does.
    pub fn from_scaled_matrix4(m: &Matrix4<f64>) -> Result<Pose, String> {
        let block: Mat3 = m.fixed_view::<3, 3>(0, 0).into_owned();
        let det = block.determinant();
        if !det.is_finite() || det <= 0.0 {
            return Err(format!("rotation block has determinant {det}, expected > 0"));
        }
        let rotation = block / det.cbrt();
        check_rotation(&rotation)?;
        Ok(Pose::new(rotation, m.fixed_view::<3, 1>(0, 3).into_owned()))
    }
}

/// Checks that `r` is a proper rotation within [`ROTATION_TOLERANCE`].
pub fn check_rotation(r: &Mat3) -> Result<(), String> {
    if r.iter().any(|v| !v.is_finite()) {
        return Err("rotation has non-finite entries".into());
    }
    let err = (r.transpose() * r - Mat3::identity()).abs().max();
    if err > ROTATION_TOLERANCE {
        return Err(format!("rotation is not orthonormal (max |R^T R - I| = {err:.2e})"));
    }
    if r.determinant() < 0.0 {
        return Err("rotation is a reflection (det < 0)".into());
    }
    Ok(())
}

/// Rotation by `angle_rad` about the y axis.
pub fn rotation_y(angle_rad: f64) -> Mat3 {
    let (s, c) = angle_rad.sin_cos();
    Mat3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// Rotation by `angle_rad` about a (not necessarily unit) axis.
pub fn rotation_axis_angle(axis: &Vec3, angle_rad: f64) -> Mat3 {
    let a = axis.normalize();
    let (s, c) = angle_rad.sin_cos();
    let k = Mat3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0);
    Mat3::identity() + k * s + k * k * (1.0 - c)
}

/// Geodesic angle between two rotations in degrees, `arccos((tr(R1 R2^T) - 1) / 2)`
/// with the cosine clipped to [-1, 1].
pub fn rotation_angle_deg(r1: &Mat3, r2: &Mat3) -> f64 {
    let cos = (((r1 * r2.transpose()).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    cos.acos().to_degrees()
}

/// The weighted chordal L2 mean of rotations: the proper rotation nearest (Frobenius) to
/// `sum_i w_i R_i`, by SVD with the sign of the smallest singular direction fixed. For two
/// rotations it lies on the geodesic between them, nearer the heavier one. Weights should be
/// non-negative with a positive sum; a sum of rank below 2 (e.g. two rotations 180 degrees
/// apart, equal weights) has no unique answer and gives one of the nearest.
pub fn weighted_chordal_mean(rotations: &[(Mat3, f64)]) -> Mat3 {
    let sum = rotations.iter().fold(Mat3::zeros(), |acc, (r, w)| acc + r * *w);
    match nearest_rotation(&sum) {
        Some((rotation, _)) => rotation,
        // nalgebra computes U and V when asked; keep a rotation regardless
        None => rotations.first().map_or(Mat3::identity(), |(r, _)| *r),
    }
}

/// The proper rotation `R` nearest (Frobenius) to `m`: `U diag(1, 1, +-1) V^T` from its SVD,
/// the last sign chosen so that `det R = +1`, with `tr(R^T m)` (the singular values summed
/// under that sign). `None` when nalgebra returns no `U` or `V`.
fn nearest_rotation(m: &Mat3) -> Option<(Mat3, f64)> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut sign = Mat3::identity();
    if (u * v_t).determinant() < 0.0 {
        sign[(2, 2)] = -1.0;
    }
    let trace = svd.singular_values.component_mul(&sign.diagonal()).sum();
    Some((u * sign * v_t, trace))
}

/// How a pose is written in JSON: `R` (3x3, row-major) and `t` (metres), or a
/// 4x4 `RT` whose rotation block may be scaled (NOCS style).
/// A pose is read flattened into its parent (an instance), where serde loses the field
/// path of an error; each field therefore names itself in its errors.
#[derive(Serialize, Deserialize)]
struct PoseWire {
    #[serde(rename = "R", default, skip_serializing_if = "Option::is_none", deserialize_with = "named_r")]
    r: Option<[[f64; 3]; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "named_t")]
    t: Option<[f64; 3]>,
    #[serde(rename = "RT", default, skip_serializing, deserialize_with = "named_rt")]
    rt: Option<[[f64; 4]; 4]>,
}

macro_rules! named_field {
    ($fn:ident, $name:literal, $ty:ty) => {
        fn $fn<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<$ty>, D::Error> {
            <Option<$ty>>::deserialize(d).map_err(|e| serde::de::Error::custom(format!("field {}: {e}", $name)))
        }
    };
}
named_field!(named_r, "R", [[f64; 3]; 3]);
named_field!(named_t, "t", [f64; 3]);
named_field!(named_rt, "RT", [[f64; 4]; 4]);

impl TryFrom<PoseWire> for Pose {
    type Error = String;

    fn try_from(w: PoseWire) -> Result<Pose, String> {
        match (w.r, w.t, w.rt) {
            (Some(r), Some(t), None) => {
                let rotation = Mat3::from_fn(|i, j| r[i][j]);
                check_rotation(&rotation).map_err(|e| format!("field R: {e}"))?;
                let translation_m = Vec3::new(t[0], t[1], t[2]);
                if translation_m.iter().any(|v| !v.is_finite()) {
                    return Err("field t: non-finite entries".into());
                }
                Ok(Pose::new(rotation, translation_m))
            }
            (None, None, Some(rt)) => {
                let m = Matrix4::from_fn(|i, j| rt[i][j]);
                Pose::from_scaled_matrix4(&m).map_err(|e| format!("field RT: {e}"))
            }
            (_, _, Some(_)) => Err("give either RT or R and t, not both".into()),
            (None, _, None) => Err("missing field R (or RT)".into()),
            (Some(_), None, None) => Err("missing field t".into()),
        }
    }
}

impl From<Pose> for PoseWire {
    fn from(p: Pose) -> PoseWire {
        let r = p.rotation;
        PoseWire {
            r: Some([
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ]),
            t: Some([p.translation_m.x, p.translation_m.y, p.translation_m.z]),
            rt: None,
        }
    }
}

/// In [`fit_similarity_robust`], residuals above this multiple of the median
/// are dropped before the refit.
pub const OUTLIER_MEDIAN_FACTOR: f64 = 3.0;

/// A similarity transform `y = scale * pose.rotation * x + pose.translation_m`.
#[derive(Clone, Copy, Debug)]
pub struct SimilarityFit {
    /// Scale factor.
    pub scale: f64,
    /// Rotation and translation.
    pub pose: Pose,
}

/// Least-squares similarity transform mapping `src` onto `dst` (Umeyama's
/// closed form). `None` when fewer than 3 points or a degenerate spread.
pub fn fit_similarity(src: &[Vec3], dst: &[Vec3]) -> Option<SimilarityFit> {
    let n = src.len();
    if n < 3 || n != dst.len() {
        return None;
    }
    let nf = n as f64;
    let mu_s = src.iter().sum::<Vec3>() / nf;
    let mu_d = dst.iter().sum::<Vec3>() / nf;
    let mut cov = Mat3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (a, b) = (s - mu_s, d - mu_d);
        cov += b * a.transpose();
        var_s += a.norm_squared();
    }
    cov /= nf;
    var_s /= nf;
    if var_s <= f64::EPSILON {
        return None;
    }
    let (rotation, trace) = nearest_rotation(&cov)?;
    let scale = trace / var_s;
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let translation_m = mu_d - scale * rotation * mu_s;
    Some(SimilarityFit { scale, pose: Pose::new(rotation, translation_m) })
}

/// [`fit_similarity`], refitted once without points whose residual exceeds
/// [`OUTLIER_MEDIAN_FACTOR`] times the median (depth noise and mask edges).
pub fn fit_similarity_robust(src: &[Vec3], dst: &[Vec3]) -> Option<SimilarityFit> {
    let fit = fit_similarity(src, dst)?;
    let residual = |s: &Vec3, d: &Vec3| (fit.scale * fit.pose.rotation * s + fit.pose.translation_m - d).norm();
    let mut res: Vec<f64> = src.iter().zip(dst).map(|(s, d)| residual(s, d)).collect();
    let mut sorted = res.clone();
    sorted.sort_by(f64::total_cmp);
    let limit = OUTLIER_MEDIAN_FACTOR * sorted[sorted.len() / 2] + 1e-9;
    let (mut s2, mut d2) = (Vec::new(), Vec::new());
    for ((s, d), r) in src.iter().zip(dst).zip(res.drain(..)) {
        if r <= limit {
            s2.push(*s);
            d2.push(*d);
        }
    }
    fit_similarity(&s2, &d2).or(Some(fit))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_and_compose_cancel() {
        let p = Pose::new(rotation_axis_angle(&Vec3::new(1.0, 2.0, 3.0), 0.7), Vec3::new(0.1, -0.2, 0.9));
        let id = p.compose(&p.inverse());
        assert!((id.rotation - Mat3::identity()).abs().max() < 1e-12);
        assert!(id.translation_m.norm() < 1e-12);
    }

    #[test]
    fn json_round_trip_and_scaled_rt() {
        let p = Pose::new(rotation_y(0.3), Vec3::new(0.0, 0.1, 0.5));
        let s = serde_json::to_string(&p).unwrap();
        let q: Pose = serde_json::from_str(&s).unwrap();
        assert!((p.rotation - q.rotation).abs().max() < 1e-15);
        let mut m = p.to_matrix4();
        for i in 0..3 {
            for j in 0..3 {
                m[(i, j)] *= 0.25;
            }
        }
        let rows: Vec<Vec<f64>> = (0..4).map(|i| (0..4).map(|j| m[(i, j)]).collect()).collect();
        let q: Pose = serde_json::from_value(serde_json::json!({ "RT": rows })).unwrap();
        assert!((p.rotation - q.rotation).abs().max() < 1e-12);
        let bad = serde_json::from_str::<Pose>(r#"{"R":[[1,0,0],[0,1,0],[0,0,2]],"t":[0,0,0]}"#);
        assert!(bad.unwrap_err().to_string().contains("field R"));
    }

    #[test]
    fn angle_between_rotations() {
        let a = rotation_axis_angle(&Vec3::new(0.3, 1.0, -0.2), 0.4);
        let b = a * rotation_axis_angle(&Vec3::x(), 7f64.to_radians());
        assert!((rotation_angle_deg(&a, &b) - 7.0).abs() < 1e-9);
    }

    #[test]
    fn weighted_chordal_mean_lies_on_the_geodesic() {
        let base = rotation_axis_angle(&Vec3::new(0.3, 1.0, -0.2), 0.9);
        let axis = Vec3::new(-0.5, 0.2, 1.0).normalize();
        let theta = 40f64.to_radians();
        let other = base * rotation_axis_angle(&axis, theta);
        // about one axis, R(0) and R(theta) weighted 1-w, w give the angle
        // atan2(w sin theta, 1 - w + w cos theta) (the midpoint for w = 1/2)
        for w in [0.0, 0.25, 0.5, 0.8, 1.0] {
            let mean = weighted_chordal_mean(&[(base, 1.0 - w), (other, w)]);
            let want = base * rotation_axis_angle(&axis, (w * theta.sin()).atan2(1.0 - w + w * theta.cos()));
            assert!((mean - want).abs().max() < 1e-12, "w {w}");
            assert!((mean.determinant() - 1.0).abs() < 1e-12);
        }
        let half = weighted_chordal_mean(&[(base, 1.0), (other, 1.0)]);
        assert!((rotation_angle_deg(&half, &base) - 20.0).abs() < 1e-9);
        // many rotations: a proper rotation, invariant to a common left factor
        let rs: Vec<(Mat3, f64)> = (0..5)
            .map(|i| (rotation_axis_angle(&Vec3::new(1.0, i as f64, 0.5), 0.2 * i as f64), 1.0 + i as f64))
            .collect();
        let mean = weighted_chordal_mean(&rs);
        assert!((mean * mean.transpose() - Mat3::identity()).abs().max() < 1e-12);
        assert!((mean.determinant() - 1.0).abs() < 1e-12);
        let left = rotation_axis_angle(&Vec3::new(0.0, 0.4, 1.0), 2.0);
        let moved: Vec<(Mat3, f64)> = rs.iter().map(|(r, w)| (left * r, *w)).collect();
        assert!((weighted_chordal_mean(&moved) - left * mean).abs().max() < 1e-12);
    }

    #[test]
    fn similarity_fit_recovers_a_known_transform() {
        let r = rotation_axis_angle(&Vec3::new(0.2, 1.0, -0.4), 1.1);
        let t = Vec3::new(0.05, -0.1, 0.8);
        let scale = 0.23;
        let src: Vec<Vec3> = (0..50)
            .map(|i| {
                let f = i as f64;
                Vec3::new((f * 0.37).sin() * 0.4, (f * 0.91).cos() * 0.3, ((f * 0.13).sin() - 0.5) * 0.2)
            })
            .collect();
        let mut dst: Vec<Vec3> = src.iter().map(|p| scale * r * p + t).collect();
        dst[3] += Vec3::new(0.5, 0.0, 0.0); // one gross outlier
        let fit = fit_similarity_robust(&src, &dst).unwrap();
        assert!((fit.scale - scale).abs() < 1e-9);
        assert!((fit.pose.rotation - r).abs().max() < 1e-9);
        assert!((fit.pose.translation_m - t).norm() < 1e-9);
    }
}
