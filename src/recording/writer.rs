//! Writer of the tricons recording format.
//!
//! Every file is written to a temporary name and renamed, and the manifest
//! only lists frames whose files are complete, so a killed writer leaves a
//! readable recording of the frames it finished.

use super::annotations::{AnnotationsFile, FrameAnnotations};
use super::manifest::{FrameEntry, MANIFEST_FILE, Manifest};
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use crate::image_io::{write_color_png, write_depth_png, write_label_png, write_nocs_png};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How often the manifest is rewritten while frames are being added.
pub const MANIFEST_FLUSH_INTERVAL: Duration = Duration::from_millis(500);

/// Writes one frame's files (colour, depth, and ground truth when given) into
/// `root` and returns its manifest entry. Safe to call from several threads
/// for different ids; the manifest is the caller's (see [`RecordingWriter`]).
pub fn write_frame_files(
    root: &Path,
    id: &str,
    frame: &RgbdFrame,
    annotations: Option<&FrameAnnotations>,
) -> Result<FrameEntry> {
    if id.is_empty() || id.contains(['/', '\\']) || id.starts_with('.') {
        return Err(Error::InvalidArgument(format!("frame id {id:?} is not a plain file-name stem")));
    }
    let entry = FrameEntry {
        id: id.to_string(),
        timestamp_s: frame.timestamp_s,
        color: format!("{id}_color.png"),
        depth: format!("{id}_depth.png"),
        annotations: annotations.map(|_| format!("{id}_gt.json")),
    };
    write_color_png(&root.join(&entry.color), &frame.color)?;
    write_depth_png(&root.join(&entry.depth), &frame.depth)?;
    if let (Some(ann), Some(name)) = (annotations, &entry.annotations) {
        let mut file = AnnotationsFile { instances: ann.instances.clone(), mask: None, nocs: None };
        if let Some(mask) = &ann.mask {
            let name = format!("{id}_mask.png");
            write_label_png(&root.join(&name), mask)?;
            file.mask = Some(name);
        }
        if let Some(nocs) = &ann.nocs {
            let name = format!("{id}_coord.png");
            write_nocs_png(&root.join(&name), nocs)?;
            file.nocs = Some(name);
        }
        let json = serde_json::to_string_pretty(&file).unwrap_or_default();
        write_atomic(&root.join(name), json.as_bytes())?;
    }
    Ok(entry)
}

/// Creates a recording and appends frames to it.
pub struct RecordingWriter {
    root: PathBuf,
    manifest: Manifest,
    last_flush: Instant,
}

/// How [`RecordingWriter::create`] treats what is already in the directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteMode {
    /// A new recording: the directory is missing or empty (besides stale temporaries).
    New,
    /// Replace the recording already there (its manifest is rewritten; `synth --overwrite`).
    Overwrite,
    /// Add frames to the recording already there; its camera must be the same, and a
    /// frame id it has (or a file of one) is never written again.
    Append,
}

impl RecordingWriter {
    /// Creates directory `root` (if needed) for a recording described by `manifest` (its
    /// frame list is ignored; with [`WriteMode::Append`] the existing list is kept).
    /// Temporary files left by a killed writer are removed first.
    pub fn create(root: &Path, mut manifest: Manifest, mode: WriteMode) -> Result<RecordingWriter> {
        manifest.frames.clear();
        manifest.validate().map_err(Error::InvalidArgument)?;
        std::fs::create_dir_all(root).map_err(|e| Error::io(root, e))?;
        let stale = crate::atomic::remove_stale_temporaries(root)?;
        if stale > 0 {
            log::warn!("{}: removed {stale} temporary files of a writer that was killed", root.display());
        }
        let manifest_path = root.join(MANIFEST_FILE);
        let exists = |why: &str| {
            Error::io(&manifest_path, std::io::Error::new(std::io::ErrorKind::AlreadyExists, why.to_string()))
        };
        match mode {
            WriteMode::New => {
                let mut entries = std::fs::read_dir(root).map_err(|e| Error::io(root, e))?;
                if let Some(first) = entries.next() {
                    let first = first.map_err(|e| Error::io(root, e))?.file_name();
                    return Err(Error::InvalidArgument(format!(
                        "{}: the directory is not empty (it has {:?}): choose another one, or replace or append \
                         to the recording in it",
                        root.display(),
                        first
                    )));
                }
            }
            WriteMode::Overwrite => {}
            WriteMode::Append => {
                if !manifest_path.exists() {
                    return Err(Error::InvalidArgument(format!(
                        "{}: no recording to append to",
                        manifest_path.display()
                    )));
                }
                let old = super::reader::TriconsRecording::open(root)?.manifest().clone();
                if old.intrinsics != manifest.intrinsics
                    || old.depth_scale_m != manifest.depth_scale_m
                    || old.depth_intrinsics != manifest.depth_intrinsics
                    || old.color_from_depth != manifest.color_from_depth
                {
                    return Err(exists(
                        "the recording here was made with another camera (intrinsics, depth scale or registration differ)",
                    ));
                }
                manifest.frames = old.frames;
            }
        }
        let writer = RecordingWriter { root: root.to_path_buf(), manifest, last_flush: Instant::now() };
        writer.flush()?;
        Ok(writer)
    }

    /// The first numeric frame id free in this recording: after every numeric id of the
    /// manifest and of the colour files in the directory (a killed writer may have left
    /// a frame's files without listing it).
    pub fn next_numeric_id(&self) -> Result<u64> {
        let stem = |name: &str| name.split('_').next().and_then(|n| n.parse::<u64>().ok());
        let mut next = self.manifest.frames.iter().filter_map(|f| stem(&f.id)).map(|n| n + 1).max().unwrap_or(0);
        for entry in std::fs::read_dir(&self.root).map_err(|e| Error::io(&self.root, e))? {
            let name = entry.map_err(|e| Error::io(&self.root, e))?.file_name();
            if let Some(n) = name.to_str().filter(|n| n.ends_with("_color.png")).and_then(stem) {
                next = next.max(n + 1);
            }
        }
        Ok(next)
    }

    /// The recording directory.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Number of frames added so far.
    pub fn len(&self) -> usize {
        self.manifest.frames.len()
    }

    /// Whether no frame has been added.
    pub fn is_empty(&self) -> bool {
        self.manifest.frames.is_empty()
    }

    /// Writes a frame's files and adds it to the manifest.
    pub fn write_frame(&mut self, id: &str, frame: &RgbdFrame, annotations: Option<&FrameAnnotations>) -> Result<()> {
        let k = &self.manifest.intrinsics;
        if (frame.color.width, frame.color.height) != (k.width, k.height)
            || (frame.depth.width, frame.depth.height) != (k.width, k.height)
        {
            return Err(Error::InvalidArgument(format!(
                "frame {id}: images are {}x{} / {}x{}, the recording is {}x{}",
                frame.color.width, frame.color.height, frame.depth.width, frame.depth.height, k.width, k.height
            )));
        }
        if self.manifest.frames.iter().any(|f| f.id == id) {
            return Err(Error::InvalidArgument(format!("frame id {id:?} is already in the recording")));
        }
        let entry = write_frame_files(&self.root, id, frame, annotations)?;
        self.push_entry(entry)
    }

    /// Adds an entry whose files are already written (see [`write_frame_files`]).
    pub fn push_entry(&mut self, entry: FrameEntry) -> Result<()> {
        if self.manifest.frames.iter().any(|f| f.id == entry.id) {
            return Err(Error::InvalidArgument(format!("frame id {:?} written twice", entry.id)));
        }
        self.manifest.frames.push(entry);
        if self.last_flush.elapsed() >= MANIFEST_FLUSH_INTERVAL {
            self.flush()?;
            self.last_flush = Instant::now();
        }
        Ok(())
    }

    /// Rewrites the manifest (atomically) with the frames added so far.
    pub fn flush(&self) -> Result<()> {
        write_atomic(&self.root.join(MANIFEST_FILE), self.manifest.to_json().as_bytes())
    }

    /// Writes the final manifest and returns it.
    pub fn finish(self) -> Result<Manifest> {
        self.flush()?;
        Ok(self.manifest)
    }
}
