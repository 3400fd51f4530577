//! RGB-D capture: where frames come from.
//!
//! - [`decode`]: raw V4L2 buffers (YUYV, MJPG, RGB3 colour; Z16 depth) to images, pure Rust.
//! - [`v4l2`] (feature `v4l`, Linux): device enumeration and memory-mapped streaming.
//! - [`pairing`]: colour and depth come from separate nodes with their own
//!   timestamps; pairs are formed by timestamp within a tolerance.
//! - [`registration`]: the camera config (intrinsics of both sensors,
//!   extrinsics, depth scale) and depth-to-colour registration.
//! - [`source`]: the [`FrameSource`] trait the pipeline reads from, with
//!   recording replay ([`RecordingSource`]).
//! - `camera` (feature `v4l`, Linux): `CameraSource`, live frames from two V4L2 nodes.

#[cfg(all(feature = "v4l", target_os = "linux"))]
pub mod camera;
pub mod decode;
pub mod pairing;
pub mod registration;
pub mod source;
#[cfg(all(feature = "v4l", target_os = "linux"))]
pub mod v4l2;

#[cfg(all(feature = "v4l", target_os = "linux"))]
pub use camera::{CameraSettings, CameraSource};
pub use pairing::{FramePairer, Pair, PairingStats, Timed};
pub use registration::{CameraConfig, DEFAULT_FRAME_ID, register_depth};
pub use source::{FrameSource, Pace, RecordingSource, SourceFrame};
