//! tricons results as ROS 2 messages: one `vision_msgs/Detection3DArray` per frame, RViz
//! boxes and labels as a `visualization_msgs/MarkerArray`, overlays as `sensor_msgs/Image`.
//!
//! Every pose is `camera_from_object` in the colour camera's optical frame (x right, y down,
//! z forward), the header's `frame_id`; the box is centred on the object frame's origin
//! (the NOCS convention), so `bbox.center` equals the hypothesis pose.

use super::msg::{
    BoundingBox3D, ColorRGBA, Detection3D, Detection3DArray, Header, Image, Marker, MarkerArray, ObjectHypothesis,
    ObjectHypothesisWithPose, Point, Pose, PoseWithCovariance, Quaternion, Time, Vector3,
};
use crate::frame::ColorImage;
use crate::geometry;
use crate::output::overlay::{box_corners, box_edges, class_color};
use crate::output::predictions::{FramePredictions, PredInstance};
use nalgebra::{Rotation3, UnitQuaternion};
use std::borrow::Cow;

/// Marker namespace of the boxes and labels.
pub const MARKER_NS: &str = "tricons";
/// Line width of the box markers, metres.
const LINE_WIDTH_M: f64 = 0.004;
/// Height of the label text, metres.
const TEXT_HEIGHT_M: f64 = 0.03;

/// The header of a frame's messages: its capture time and the camera's optical frame.
pub fn header(frame: &FramePredictions, frame_id: &str) -> Header {
    Header { stamp: Time::from_seconds(frame.timestamp_s.unwrap_or(0.0)), frame_id: frame_id.to_string() }
}

/// A tricons pose as a `geometry_msgs/Pose` (the rotation as a unit quaternion, w >= 0).
pub fn ros_pose(pose: &geometry::Pose) -> Pose {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(pose.rotation));
    let q = if q.w < 0.0 { -q.into_inner() } else { q.into_inner() };
    let t = pose.translation_m;
    Pose { position: Point { x: t.x, y: t.y, z: t.z }, orientation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w } }
}

/// The rotation matrix of a `geometry_msgs/Quaternion` (normalised first).
pub fn rotation_of(q: &Quaternion) -> geometry::Mat3 {
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z));
    *q.to_rotation_matrix().matrix()
}

/// One `Detection3D` per instance, ids `0, 1, ...` in the order of the JSON Lines output.
pub fn detections(frame: &FramePredictions, frame_id: &str) -> Detection3DArray {
    let header = header(frame, frame_id);
    let detections = frame
        .instances
        .iter()
        .enumerate()
        .map(|(k, inst)| {
            let pose = ros_pose(&inst.camera_from_object);
            Detection3D {
                header: header.clone(),
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis { class_id: inst.class.name().to_string(), score: inst.score },
                    pose: PoseWithCovariance { pose, covariance: [0.0; 36] },
                }],
                bbox: BoundingBox3D {
                    center: pose,
                    size: Vector3 { x: inst.size_m[0], y: inst.size_m[1], z: inst.size_m[2] },
                },
                id: k.to_string(),
            }
        })
        .collect();
    Detection3DArray { header, detections }
}

fn rgba(inst: &PredInstance) -> ColorRGBA {
    let [r, g, b] = class_color(inst.class);
    ColorRGBA { r: f32::from(r) / 255.0, g: f32::from(g) / 255.0, b: f32::from(b) / 255.0, a: 1.0 }
}

/// RViz markers of a frame: a DELETEALL (the previous frame's markers go), then per instance
/// `k` a line list of the box's 12 edges (id `2k`) and a label `class score` above the box
/// (id `2k + 1`), in the class colours of the overlay images.
pub fn markers(frame: &FramePredictions, frame_id: &str) -> MarkerArray<'static> {
    let header = header(frame, frame_id);
    let mut markers =
        vec![Marker { header: header.clone(), ns: MARKER_NS.into(), action: Marker::DELETEALL, ..Marker::default() }];
    for (k, inst) in frame.instances.iter().enumerate() {
        let corners = box_corners(inst);
        let points =
            box_edges().flat_map(|(a, b)| [corners[a], corners[b]]).map(|p| Point { x: p.x, y: p.y, z: p.z }).collect();
        markers.push(Marker {
            header: header.clone(),
            ns: MARKER_NS.into(),
            id: 2 * k as i32,
            kind: Marker::LINE_LIST,
            action: Marker::ADD,
            scale: Vector3 { x: LINE_WIDTH_M, y: 0.0, z: 0.0 },
            color: rgba(inst),
            points,
            ..Marker::default()
        });
        // above the box: the camera's up is -y
        let top = corners.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        let t = inst.camera_from_object.translation_m;
        markers.push(Marker {
            header: header.clone(),
            ns: MARKER_NS.into(),
            id: 2 * k as i32 + 1,
            kind: Marker::TEXT_VIEW_FACING,
            action: Marker::ADD,
            pose: Pose { position: Point { x: t.x, y: top - TEXT_HEIGHT_M, z: t.z }, ..Pose::default() },
            scale: Vector3 { x: 0.0, y: 0.0, z: TEXT_HEIGHT_M },
            color: rgba(inst),
            text: format!("{} {:.2}", inst.class.name(), inst.score),
            ..Marker::default()
        });
    }
    MarkerArray { markers }
}

/// An RGB image as a `sensor_msgs/Image` (`rgb8`).
pub fn image<'a>(img: &'a ColorImage, header: Header) -> Image<'a> {
    Image {
        header,
        height: img.height,
        width: img.width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: img.width * 3,
        data: Cow::Borrowed(&img.data),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::category::Category;
    use crate::geometry::{Vec3, rotation_axis_angle};

    fn instance(rotation: geometry::Mat3) -> PredInstance {
        PredInstance {
            class: Category::Mug,
            score: 0.75,
            camera_from_object: geometry::Pose::new(rotation, Vec3::new(0.1, -0.2, 0.8)),
            size_m: [0.1, 0.2, 0.3],
            box2d: None,
            mask: None,
        }
    }

    /// The quaternion gives back the rotation for angles all around (near 180 degrees too).
    #[test]
    fn poses_round_trip_through_quaternions() {
        for (axis, angle) in [
            (Vec3::new(1.0, 0.0, 0.0), 0.0),
            (Vec3::new(0.3, -0.5, 0.8), 1.0),
            (Vec3::new(0.0, 1.0, 0.0), std::f64::consts::PI - 1e-9),
            (Vec3::new(-0.7, 0.1, 0.2), 3.0),
        ] {
            let r = rotation_axis_angle(&axis.normalize(), angle);
            let pose = ros_pose(&geometry::Pose::new(r, Vec3::new(1.0, 2.0, 3.0)));
            let q = pose.orientation;
            assert!(q.w >= 0.0);
            assert!(((q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1.0).abs() < 1e-12);
            assert!((rotation_of(&q) - r).abs().max() < 1e-9, "angle {angle}");
            assert_eq!((pose.position.x, pose.position.y, pose.position.z), (1.0, 2.0, 3.0));
        }
    }

    #[test]
    fn a_frame_becomes_one_detection_per_instance() {
        let frame = FramePredictions {
            frame: "000007".into(),
            timestamp_s: Some(12.25),
            instances: vec![instance(geometry::Mat3::identity()), instance(rotation_axis_angle(&Vec3::z(), 0.5))],
        };
        let msg = detections(&frame, "cam");
        assert_eq!(msg.header.stamp, Time { sec: 12, nanosec: 250_000_000 });
        assert_eq!(msg.detections.len(), 2);
        let d = &msg.detections[1];
        assert_eq!((d.id.as_str(), d.header.frame_id.as_str()), ("1", "cam"));
        assert_eq!(d.results[0].hypothesis, ObjectHypothesis { class_id: "mug".into(), score: 0.75 });
        assert_eq!(d.bbox.center, d.results[0].pose.pose);
        assert_eq!((d.bbox.size.x, d.bbox.size.y, d.bbox.size.z), (0.1, 0.2, 0.3));
        let m = markers(&frame, "cam");
        assert_eq!(m.markers.len(), 1 + 2 * 2);
        assert_eq!(m.markers[0].action, Marker::DELETEALL);
        assert_eq!(m.markers[1].points.len(), 24);
        assert_eq!(m.markers[2].text, "mug 0.75");
    }

    #[test]
    fn times_split_into_seconds_and_nanoseconds() {
        assert_eq!(Time::from_seconds(-0.5), Time { sec: -1, nanosec: 500_000_000 });
        assert_eq!(Time::from_nanos(1_700_000_000_123_456_789).as_nanos(), 1_700_000_000_123_456_789);
        assert_eq!(Time::from_seconds(f64::NAN), Time::default());
    }
}
