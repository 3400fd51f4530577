//! Reader of the tricons recording format.

use super::Recording;
use super::annotations::{AnnotationsFile, FrameAnnotations, GtInstance};
use super::manifest::{MANIFEST_FILE, Manifest};
use crate::error::{Error, Result};
use crate::frame::{Intrinsics, RgbdFrame};
use crate::image_io::{SizeLimit, read_color_png, read_depth_png, read_label_png, read_nocs_png};
use std::path::{Path, PathBuf};

/// A recording in the tricons format, opened for reading.
#[derive(Clone, Debug)]
pub struct TriconsRecording {
    root: PathBuf,
    manifest: Manifest,
}

impl TriconsRecording {
    /// Opens the recording in directory `root` (reads and checks its manifest).
    pub fn open(root: &Path) -> Result<TriconsRecording> {
        let manifest = Manifest::read(&root.join(MANIFEST_FILE))?;
        Ok(TriconsRecording { root: root.to_path_buf(), manifest })
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The recording directory.
    pub fn root(&self) -> &Path {
        &self.root
    }

    fn entry(&self, index: usize) -> Result<&super::FrameEntry> {
        self.manifest.frames.get(index).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "frame index {index} out of range ({} frames in {})",
                self.manifest.frames.len(),
                self.root.display()
            ))
        })
    }

    fn read_annotations_file(&self, index: usize) -> Result<Option<AnnotationsFile>> {
        let Some(name) = &self.entry(index)?.annotations else {
            return Ok(None);
        };
        let path = self.root.join(name);
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let file: AnnotationsFile = crate::error::from_json_str(&path, &text)?;
        for (k, inst) in file.instances.iter().enumerate() {
            inst.validate().map_err(|m| Error::parse(&path, None, format!("instances[{k}]: {m}")))?;
        }
        for (field, name) in [("mask", &file.mask), ("nocs", &file.nocs)] {
            if let Some(name) = name.as_deref().filter(|n| !super::manifest::inside_recording(n)) {
                return Err(Error::parse(
                    &path,
                    None,
                    format!("field {field}: {name:?} must be a file inside the recording"),
                ));
            }
        }
        Ok(Some(file))
    }

    /// Every image of a frame has the manifest's size (checked before decoding).
    fn frame_size(&self) -> SizeLimit {
        let k = &self.manifest.intrinsics;
        SizeLimit::Exactly { width: k.width, height: k.height, source: "as in the manifest" }
    }
}

impl Recording for TriconsRecording {
    fn describe(&self) -> String {
        format!(
            "tricons recording {} (format v{}, {} frames)",
            self.root.display(),
            self.manifest.version,
            self.manifest.frames.len()
        )
    }

    fn len(&self) -> usize {
        self.manifest.frames.len()
    }

    fn frame_id(&self, index: usize) -> &str {
        &self.manifest.frames[index].id
    }

    fn intrinsics(&self) -> Intrinsics {
        self.manifest.intrinsics
    }

    fn timestamp_s(&self, index: usize) -> Option<f64> {
        self.manifest.frames.get(index).map(|f| f.timestamp_s)
    }

    fn read_frame(&self, index: usize) -> Result<RgbdFrame> {
        let entry = self.entry(index)?;
        let color_path = self.root.join(&entry.color);
        let depth_path = self.root.join(&entry.depth);
        let color = read_color_png(&color_path, self.frame_size())?;
        let depth = read_depth_png(&depth_path, self.manifest.depth_scale_m, self.frame_size())?;
        Ok(RgbdFrame { color, depth, intrinsics: self.manifest.intrinsics, timestamp_s: entry.timestamp_s })
    }

    fn read_instances(&self, index: usize) -> Result<Option<Vec<GtInstance>>> {
        Ok(self.read_annotations_file(index)?.map(|f| f.instances))
    }

    fn read_annotations(&self, index: usize) -> Result<Option<FrameAnnotations>> {
        let Some(file) = self.read_annotations_file(index)? else {
            return Ok(None);
        };
        let mask = match &file.mask {
            Some(name) => {
                let path = self.root.join(name);
                Some(read_label_png(&path, self.frame_size())?)
            }
            None => None,
        };
        let nocs = match &file.nocs {
            Some(name) => {
                let path = self.root.join(name);
                Some(read_nocs_png(&path, self.frame_size())?)
            }
            None => None,
        };
        Ok(Some(FrameAnnotations { instances: file.instances, mask, nocs }))
    }
}
