//! Recorded RGB-D frames on disk.
//!
//! Two layouts are read through one [`Recording`] trait:
//! - the tricons recording format ([`TriconsRecording`], written by
//!   [`RecordingWriter`]): a directory with `manifest.json` and per-frame PNGs
//!   and ground truth (docs/formats.md);
//! - the NOCS dataset layout ([`NocsLayout`]): `<frame>_color.png`,
//!   `_depth.png`, `_mask.png`, `_coord.png`, `_meta.txt`.
//!
//! - ROS 2 bags stored as MCAP ([`McapBag`], feature `ros2`): colour, aligned depth and
//!   camera info topics, paired by stamp ([`BagTopics`] names them).
//!
//! [`open_recording`] picks the layout from what the path holds.

pub mod annotations;
pub mod manifest;
#[cfg(feature = "ros2")]
pub mod mcap_bag;
pub mod nocs_layout;
pub mod reader;
pub mod writer;

pub use annotations::{FrameAnnotations, GtInstance};
pub use manifest::{FrameEntry, Manifest, RECORDING_FORMAT, RECORDING_FORMAT_VERSION};
#[cfg(feature = "ros2")]
pub use mcap_bag::McapBag;
pub use nocs_layout::NocsLayout;
pub use reader::TriconsRecording;
pub use writer::{RecordingWriter, WriteMode, write_frame_files};

use crate::capture::pairing::DEFAULT_PAIR_TOLERANCE_S;
use crate::error::{Error, Result};
use crate::frame::{Intrinsics, RgbdFrame};
use std::path::Path;

/// Colour topic of the RealSense ROS 2 wrapper (`realsense2_camera`, namespace `camera`).
pub const DEFAULT_COLOR_TOPIC: &str = "/camera/camera/color/image_raw";
/// Depth registered to colour (`align_depth.enable:=true`).
pub const DEFAULT_DEPTH_TOPIC: &str = "/camera/camera/aligned_depth_to_color/image_raw";
/// Calibration of the colour camera.
pub const DEFAULT_CAMERA_INFO_TOPIC: &str = "/camera/camera/color/camera_info";

/// The topics a bag is read from.
#[derive(Clone, Debug, PartialEq)]
pub struct BagTopics {
    /// Colour images (`sensor_msgs/Image` or `sensor_msgs/CompressedImage`).
    pub color: String,
    /// Depth registered to colour (`sensor_msgs/Image`).
    pub depth: String,
    /// The colour camera's calibration (`sensor_msgs/CameraInfo`).
    pub camera_info: String,
    /// Largest colour/depth stamp difference paired, seconds.
    pub pair_tolerance_s: f64,
}

impl Default for BagTopics {
    fn default() -> BagTopics {
        BagTopics {
            color: DEFAULT_COLOR_TOPIC.into(),
            depth: DEFAULT_DEPTH_TOPIC.into(),
            camera_info: DEFAULT_CAMERA_INFO_TOPIC.into(),
            pair_tolerance_s: DEFAULT_PAIR_TOLERANCE_S,
        }
    }
}

/// A sequence of recorded frames with optional ground truth.
pub trait Recording: Send + Sync {
    /// One line saying what this is (layout, path, frame count).
    fn describe(&self) -> String;
    /// Number of frames.
    fn len(&self) -> usize;
    /// Whether there are no frames.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The id of frame `index` (unique within the recording).
    fn frame_id(&self, index: usize) -> &str;
    /// Intrinsics of the colour camera.
    fn intrinsics(&self) -> Intrinsics;
    /// Reads frame `index` (colour and depth, registered).
    fn read_frame(&self, index: usize) -> Result<RgbdFrame>;
    /// Reads the annotated instances of frame `index`, if it has ground truth.
    fn read_instances(&self, index: usize) -> Result<Option<Vec<GtInstance>>>;
    /// Reads the full ground truth (instances, mask, NOCS map) of frame `index`.
    fn read_annotations(&self, index: usize) -> Result<Option<FrameAnnotations>>;
    /// The capture time of frame `index` in seconds, when known without reading the frame.
    fn timestamp_s(&self, _index: usize) -> Option<f64> {
        None
    }
    /// The colour camera's frame name, when the recording has one (a ROS 2 bag's `frame_id`).
    fn camera_frame_id(&self) -> Option<&str> {
        None
    }
}

/// Opens a recording in any layout: `manifest.json` means the tricons format, `*_color.png`
/// files the NOCS layout, a `.mcap` file a ROS 2 bag (read from the default [`BagTopics`]).
pub fn open_recording(path: &Path) -> Result<Box<dyn Recording>> {
    open_recording_with(path, &BagTopics::default())
}

/// [`open_recording`], reading a ROS 2 bag from `topics`.
pub fn open_recording_with(path: &Path, topics: &BagTopics) -> Result<Box<dyn Recording>> {
    if path.is_file() && path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap")) {
        #[cfg(feature = "ros2")]
        return Ok(Box::new(McapBag::open(path, topics)?));
        #[cfg(not(feature = "ros2"))]
        {
            let _ = topics;
            return Err(Error::parse(path, None, "this build reads no ROS 2 bags (feature `ros2`)"));
        }
    }
    if !path.is_dir() {
        return Err(Error::io(
            path,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "recording not found (a directory, or a .mcap ROS 2 bag)",
            ),
        ));
    }
    if path.join(manifest::MANIFEST_FILE).exists() {
        return Ok(Box::new(TriconsRecording::open(path)?));
    }
    if NocsLayout::looks_like(path)? {
        return Ok(Box::new(NocsLayout::open(path, None)?));
    }
    Err(Error::parse(
        path,
        None,
        "neither a tricons recording (no manifest.json) nor a NOCS layout directory (no *_color.png)",
    ))
}
