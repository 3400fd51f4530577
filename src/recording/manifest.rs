//! `manifest.json` of the tricons recording format.

use crate::error::{Error, Result};
use crate::frame::Intrinsics;
use crate::geometry::Pose;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The manifest's file name inside a recording directory.
pub const MANIFEST_FILE: &str = "manifest.json";
/// Value of the manifest's `format` field.
pub const RECORDING_FORMAT: &str = "tricons-recording";
/// The recording format version this build reads and writes.
pub const RECORDING_FORMAT_VERSION: u32 = 1;

/// A recording's manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always [`RECORDING_FORMAT`].
    pub format: String,
    /// Format version, [`RECORDING_FORMAT_VERSION`].
    pub version: u32,
    /// Intrinsics of the colour camera; depth images are registered to it.
    pub intrinsics: Intrinsics,
    /// Metres per depth unit in the depth PNGs.
    pub depth_scale_m: f64,
    /// Intrinsics of the depth sensor as calibrated (informative).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_intrinsics: Option<Intrinsics>,
    /// Colour-from-depth extrinsics as calibrated (informative).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color_from_depth: Option<Pose>,
    /// Free text saying where the frames came from (a command, a device).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// The frames, in time order.
    pub frames: Vec<FrameEntry>,
}

/// One frame's entry in the manifest; file names are relative to the directory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameEntry {
    /// Frame id, unique in the recording.
    pub id: String,
    /// Capture time in seconds.
    pub timestamp_s: f64,
    /// 8-bit RGB PNG.
    pub color: String,
    /// 16-bit grayscale PNG in units of `depth_scale_m`.
    pub depth: String,
    /// Ground-truth JSON, when the frame is annotated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub annotations: Option<String>,
}

impl Manifest {
    /// A manifest with no frames.
    pub fn new(intrinsics: Intrinsics, depth_scale_m: f64) -> Manifest {
        Manifest {
            format: RECORDING_FORMAT.into(),
            version: RECORDING_FORMAT_VERSION,
            intrinsics,
            depth_scale_m,
            depth_intrinsics: None,
            color_from_depth: None,
            source: None,
            frames: Vec::new(),
        }
    }

    /// Reads and validates `path` (a manifest.json).
    pub fn read(path: &Path) -> Result<Manifest> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| Error::parse(path, None, e.to_string()))?;
        // Check the version before the schema, so a future manifest gets a
        // version error rather than a confusing field error.
        if let Some(found) = value.get("version").and_then(|v| v.as_u64())
            && found != u64::from(RECORDING_FORMAT_VERSION)
        {
            return Err(Error::UnsupportedVersion {
                path: path.to_path_buf(),
                found: u32::try_from(found).unwrap_or(u32::MAX),
                supported: RECORDING_FORMAT_VERSION,
            });
        }
        let manifest: Manifest = crate::error::from_json_value(path, value)?;
        manifest.validate().map_err(|m| Error::parse(path, None, m))?;
        Ok(manifest)
    }

    /// Checks the fields that serde cannot.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.format != RECORDING_FORMAT {
            return Err(format!("field format: {:?}, expected {RECORDING_FORMAT:?}", self.format));
        }
        self.intrinsics.validate().map_err(|m| format!("field intrinsics: {m}"))?;
        if !(self.depth_scale_m.is_finite() && self.depth_scale_m > 0.0) {
            return Err(format!("field depth_scale_m: {} must be positive", self.depth_scale_m));
        }
        let mut seen = std::collections::HashSet::new();
        for (i, f) in self.frames.iter().enumerate() {
            if !seen.insert(f.id.as_str()) {
                return Err(format!("frames[{i}].id: duplicate id {:?}", f.id));
            }
            for name in [Some(&f.color), Some(&f.depth), f.annotations.as_ref()].into_iter().flatten() {
                if !inside_recording(name) {
                    return Err(format!("frames[{i}]: file {name:?} must be relative to the recording"));
                }
            }
        }
        Ok(())
    }

    /// Serialises the manifest (pretty JSON, trailing newline).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).unwrap_or_default();
        s.push('\n');
        s
    }
}

/// Whether `name` is a path inside the recording: relative, with no `..` (nor a root or
/// drive prefix) among its components.
pub fn inside_recording(name: &str) -> bool {
    use std::path::Component;
    !name.is_empty() && Path::new(name).components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
}
