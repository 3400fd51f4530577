//! The ROS 2 messages tricons reads and writes, as serde structs whose field order is the
//! wire order (CDR serialises fields in declaration order; names do not travel).
//!
//! Layouts are those of ROS 2 Humble through Rolling (identical on the wire for these types):
//! `sensor_msgs`, `geometry_msgs`, `std_msgs`, `builtin_interfaces`, `visualization_msgs`
//! (with the texture and mesh fields added before Humble) and `vision_msgs` 4.x. The schema
//! texts stored in MCAP files are in [`super::schema`].

use serde::{Deserialize, Serialize};
use serde_big_array::BigArray;
use std::borrow::Cow;

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the epoch of the clock.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds within the second, `0..1e9`.
    pub nanosec: u32,
}

impl Time {
    /// The time `seconds` after the epoch, rounded to the nanosecond (saturating outside i32 seconds).
    pub fn from_seconds(seconds: f64) -> Time {
        Time::from_nanos(if seconds.is_finite() { (seconds * 1e9).round() as i64 } else { 0 })
    }

    /// The time `nanos` nanoseconds after the epoch (saturating outside i32 seconds).
    pub fn from_nanos(nanos: i64) -> Time {
        let sec = nanos.div_euclid(1_000_000_000).clamp(i64::from(i32::MIN), i64::from(i32::MAX));
        let nanosec = nanos.rem_euclid(1_000_000_000);
        Time { sec: sec as i32, nanosec: nanosec as u32 }
    }

    /// Nanoseconds since the epoch.
    pub fn as_nanos(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    /// Seconds since the epoch.
    pub fn as_seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds, `0..1e9`.
    pub nanosec: u32,
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Acquisition time.
    pub stamp: Time,
    /// Coordinate frame the data is in (the camera's optical frame for images).
    pub frame_id: String,
}

/// `sensor_msgs/msg/Image`. `data` borrows from the message buffer when decoded.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Image<'a> {
    /// Acquisition time and optical frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`, `bgr8`, `16UC1`, `32FC1`, ...).
    pub encoding: String,
    /// 1 if multi-byte values are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// `step * height` bytes.
    #[serde(borrow, with = "serde_bytes")]
    pub data: Cow<'a, [u8]>,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage<'a> {
    /// Acquisition time and optical frame.
    pub header: Header,
    /// `jpeg`, `png`, or image_transport's `"rgb8; jpeg compressed bgr8"` forms.
    pub format: String,
    /// The compressed bytes.
    #[serde(borrow, with = "serde_bytes")]
    pub data: Cow<'a, [u8]>,
}

/// `sensor_msgs/msg/RegionOfInterest`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// Left column.
    pub x_offset: u32,
    /// Top row.
    pub y_offset: u32,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Whether the region is to be rectified.
    pub do_rectify: bool,
}

/// `sensor_msgs/msg/CameraInfo`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Acquisition time and optical frame.
    pub header: Header,
    /// Image rows.
    pub height: u32,
    /// Image columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, ...
    pub distortion_model: String,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major: `fx 0 cx; 0 fy cy; 0 0 1`.
    pub k: [f64; 9],
    /// Rectification rotation.
    pub r: [f64; 9],
    /// Projection matrix, 3x4 row-major.
    pub p: [f64; 12],
    /// Horizontal binning.
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}

/// `geometry_msgs/msg/Point`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w (the scalar part).
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Quaternion {
        Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Translation.
    pub position: Point,
    /// Rotation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: Pose,
    /// Row-major 6x6 covariance of (x, y, z, rotation about x, y, z); all zero when unknown.
    #[serde(with = "BigArray")]
    pub covariance: [f64; 36],
}

impl Default for PoseWithCovariance {
    fn default() -> PoseWithCovariance {
        PoseWithCovariance { pose: Pose::default(), covariance: [0.0; 36] }
    }
}

/// `vision_msgs/msg/ObjectHypothesis`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ObjectHypothesis {
    /// The class (tricons: the NOCS category name, e.g. `mug`).
    pub class_id: String,
    /// Confidence.
    pub score: f64,
}

/// `vision_msgs/msg/ObjectHypothesisWithPose`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ObjectHypothesisWithPose {
    /// Class and score.
    pub hypothesis: ObjectHypothesis,
    /// The object's pose in the header's frame.
    pub pose: PoseWithCovariance,
}

/// `vision_msgs/msg/BoundingBox3D`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BoundingBox3D {
    /// Centre and orientation of the box.
    pub center: Pose,
    /// Extent along the box's own axes, metres.
    pub size: Vector3,
}

/// `vision_msgs/msg/Detection3D`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Detection3D {
    /// The frame's stamp and the camera frame.
    pub header: Header,
    /// Class hypotheses (tricons: one).
    pub results: Vec<ObjectHypothesisWithPose>,
    /// The object's 3D box.
    pub bbox: BoundingBox3D,
    /// An id of the detection within the frame.
    pub id: String,
}

/// `vision_msgs/msg/Detection3DArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Detection3DArray {
    /// The frame's stamp and the camera frame.
    pub header: Header,
    /// One per object instance.
    pub detections: Vec<Detection3D>,
}

/// `std_msgs/msg/ColorRGBA`, components in [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRGBA {
    /// Red.
    pub r: f32,
    /// Green.
    pub g: f32,
    /// Blue.
    pub b: f32,
    /// Opacity.
    pub a: f32,
}

/// `visualization_msgs/msg/UVCoordinate`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UVCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name (its extension gives the format).
    pub filename: String,
    /// The file's bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker` (the Humble-through-Rolling layout).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker<'a> {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace (with `id`, the marker's identity).
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// Shape ([`Marker::LINE_LIST`], [`Marker::TEXT_VIEW_FACING`], ...).
    #[serde(rename = "type")]
    pub kind: i32,
    /// [`Marker::ADD`], [`Marker::DELETE`], [`Marker::DELETEALL`].
    pub action: i32,
    /// Pose of the marker's frame.
    pub pose: Pose,
    /// Scale (line width in `x` for lines, text height in `z` for text).
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRGBA,
    /// How long the marker lives (0: until replaced).
    pub lifetime: Duration,
    /// Whether to re-transform the marker into its frame every update.
    pub frame_locked: bool,
    /// Points of line, list and point markers.
    pub points: Vec<Point>,
    /// Per-point colours (empty: `color` for all).
    pub colors: Vec<ColorRGBA>,
    /// Texture URI (mesh markers).
    pub texture_resource: String,
    /// Embedded texture.
    #[serde(borrow)]
    pub texture: CompressedImage<'a>,
    /// Texture coordinates.
    pub uv_coordinates: Vec<UVCoordinate>,
    /// Text of text markers.
    pub text: String,
    /// Mesh URI.
    pub mesh_resource: String,
    /// Embedded mesh.
    pub mesh_file: MeshFile,
    /// Whether to use the mesh's own materials.
    pub mesh_use_embedded_materials: bool,
}

impl Marker<'_> {
    /// Pairs of points, one line segment each.
    pub const LINE_LIST: i32 = 5;
    /// Text that always faces the viewer.
    pub const TEXT_VIEW_FACING: i32 = 9;
    /// Add or replace.
    pub const ADD: i32 = 0;
    /// Remove every marker of the namespace (all namespaces on most viewers).
    pub const DELETEALL: i32 = 3;
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray<'a> {
    /// The markers.
    #[serde(borrow)]
    pub markers: Vec<Marker<'a>>,
}
