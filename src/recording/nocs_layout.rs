//! Reader for the NOCS dataset layout (REAL275 / CAMERA25 scene folders).
//! (Implementation in progress.)

use super::Recording;
use super::annotations::{FrameAnnotations, GtInstance};
use crate::error::Result;
use crate::frame::{Intrinsics, RgbdFrame};
use std::path::{Path, PathBuf};

/// A NOCS dataset scene directory opened for reading.
pub struct NocsLayout {
    root: PathBuf,
    ids: Vec<String>,
    intrinsics: Intrinsics,
}

impl NocsLayout {
    /// Whether `dir` holds `*_color.png` files.
    pub fn looks_like(dir: &Path) -> Result<bool> {
        let _ = dir;
        Ok(false)
    }

    /// Opens a scene directory.
    pub fn open(root: &Path, intrinsics: Option<Intrinsics>) -> Result<NocsLayout> {
        Ok(NocsLayout {
            root: root.to_path_buf(),
            ids: Vec::new(),
            intrinsics: intrinsics.unwrap_or(Intrinsics::REAL275),
        })
    }
}

impl Recording for NocsLayout {
    fn describe(&self) -> String {
        format!("NOCS layout {}", self.root.display())
    }
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        &self.ids[index]
    }
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }
    fn read_frame(&self, _index: usize) -> Result<RgbdFrame> {
        todo!()
    }
    fn read_instances(&self, _index: usize) -> Result<Option<Vec<GtInstance>>> {
        todo!()
    }
    fn read_annotations(&self, _index: usize) -> Result<Option<FrameAnnotations>> {
        todo!()
    }
}
