//! Recorded RGB-D frames on disk.
//!
//! Two layouts are read through one [`Recording`] trait:
//! - the tricons recording format ([`TriconsRecording`], written by
//!   [`RecordingWriter`]): a directory with `manifest.json` and per-frame PNGs
//!   and ground truth (docs/formats.md);
//! - the NOCS dataset layout ([`NocsLayout`]): `<frame>_color.png`,
//!   `_depth.png`, `_mask.png`, `_coord.png`, `_meta.txt`.
//!
//! [`open_recording`] picks the layout from what the directory holds.

pub mod annotations;
pub mod manifest;
pub mod nocs_layout;
pub mod reader;
pub mod writer;

pub use annotations::{FrameAnnotations, GtInstance};
pub use manifest::{FrameEntry, Manifest, RECORDING_FORMAT, RECORDING_FORMAT_VERSION};
pub use nocs_layout::NocsLayout;
pub use reader::TriconsRecording;
pub use writer::{RecordingWriter, WriteMode, write_frame_files};

use crate::error::{Error, Result};
use crate::frame::{Intrinsics, RgbdFrame};
use std::path::Path;

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
}

/// Opens a recording directory in either layout: `manifest.json` means the
/// tricons format, `*_color.png` files mean the NOCS layout.
pub fn open_recording(path: &Path) -> Result<Box<dyn Recording>> {
    if !path.is_dir() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "recording directory not found"),
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
