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

/// How a pose is written in JSON: `R` (3x3, row-major) and `t` (metres), or a
/// 4x4 `RT` whose rotation block may be scaled (NOCS style).
#[derive(Serialize, Deserialize)]
struct PoseWire {
    #[serde(rename = "R", skip_serializing_if = "Option::is_none")]
    r: Option<[[f64; 3]; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    t: Option<[f64; 3]>,
    #[serde(rename = "RT", default, skip_serializing)]
    rt: Option<[[f64; 4]; 4]>,
}

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
}
