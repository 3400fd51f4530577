//! V4L2 capture (Linux, feature `v4l`): device enumeration and memory-mapped
//! streaming with plain `libc` ioctls.
//!
//! - [`list_devices`]: every `/dev/video*` node with its driver, card, bus and,
//!   for capture nodes, its formats and frame sizes.
//! - [`V4l2Stream`]: one node streaming one format; [`V4l2Stream::next_buffer`]
//!   returns copies of raw buffers for [`crate::capture::decode`].
//! - [`sys`]: the kernel ABI mirrors (structs, constants, request numbers).

mod device;
pub mod sys;

pub use device::{DeviceInfo, FormatInfo, FrameSize, RawBuffer, V4l2Stream, list_devices, list_devices_in};
