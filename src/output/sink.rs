//! Where the pose service's results go: JSON Lines writers (stdout, a file), the HTTP
//! stream hub ([`super::http`]), MCAP files ([`super::mcap_sink`]) and ROS 2 topics
//! ([`super::ros2_sink`]).

use super::predictions::FramePredictions;
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// An output of the pipeline. `publish` is called once per frame, in frame order.
pub trait Sink: Send {
    /// What this output is (for logs).
    fn describe(&self) -> String;
    /// Emits one frame's result; `line` is its JSON Lines form (no newline).
    fn publish(&mut self, frame: &FramePredictions, line: &str) -> Result<()>;
    /// Emits one frame's result with the RGB-D frame it came from; sinks that show images
    /// (overlays in an MCAP file) use it, the others ignore the image. The pipeline calls this.
    fn publish_with_image(&mut self, frame: &FramePredictions, line: &str, _image: &RgbdFrame) -> Result<()> {
        self.publish(frame, line)
    }
    /// Makes everything published so far durable/visible.
    fn flush(&mut self) -> Result<()>;
    /// The end of the stream: completes the output (an MCAP file's summary) and flushes.
    fn close(&mut self) -> Result<()> {
        self.flush()
    }
}

/// JSON Lines to stdout or a file. Each line is written whole and flushed, so a reader
/// never sees half a line from a running service; a file is opened for appending, so a
/// restarted service never loses what an earlier run wrote.
///
/// A file never keeps a torn line: a write that fails part-way (a full disk) is cut back
/// to the last whole line before the error is returned, and a file whose last line was
/// torn by a crash is truncated back to its last complete line when it is opened (logged
/// at WARN with the byte count), so the next line starts on a line of its own.
pub struct JsonLinesSink {
    target: Target,
}

enum Target {
    Stdout(std::io::Stdout),
    File {
        path: PathBuf,
        file: File,
        /// Length of the file up to its last whole line.
        whole_len: u64,
    },
}

/// Truncates `file` after its last newline (to empty if it has none); the new length and
/// how many bytes were removed.
fn cut_torn_tail(file: &mut File, path: &Path) -> Result<(u64, u64)> {
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    // scan back from the end in blocks for the last newline (memory stays bounded)
    let mut end = len;
    let mut buf = vec![0u8; 64 * 1024];
    let keep = loop {
        if end == 0 {
            break 0;
        }
        let start = end.saturating_sub(buf.len() as u64);
        let chunk = &mut buf[..(end - start) as usize];
        file.seek(SeekFrom::Start(start)).and_then(|_| file.read_exact(chunk)).map_err(|e| Error::io(path, e))?;
        if let Some(i) = chunk.iter().rposition(|&b| b == b'\n') {
            break start + i as u64 + 1;
        }
        end = start;
    };
    if keep < len {
        file.set_len(keep).map_err(|e| Error::io(path, e))?;
    }
    file.seek(SeekFrom::End(0)).map_err(|e| Error::io(path, e))?;
    Ok((keep, len - keep))
}

impl JsonLinesSink {
    /// Writes to standard output.
    pub fn stdout() -> JsonLinesSink {
        JsonLinesSink { target: Target::Stdout(std::io::stdout()) }
    }

    /// Appends to `path` (created if missing, its directory too), after cutting a torn
    /// last line left by an earlier run.
    pub fn append(path: &Path) -> Result<JsonLinesSink> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        let mut file: File =
            OpenOptions::new().create(true).read(true).append(true).open(path).map_err(|e| Error::io(path, e))?;
        let (whole_len, cut) = cut_torn_tail(&mut file, path)?;
        if cut > 0 {
            log::warn!("{}: removed a torn last line ({cut} bytes) left by an earlier run", path.display());
        }
        Ok(JsonLinesSink { target: Target::File { path: path.to_path_buf(), file, whole_len } })
    }

    fn path(&self) -> PathBuf {
        match &self.target {
            Target::Stdout(_) => PathBuf::from("<stdout>"),
            Target::File { path, .. } => path.clone(),
        }
    }
}

impl Sink for JsonLinesSink {
    fn describe(&self) -> String {
        self.path().display().to_string()
    }

    fn publish(&mut self, _frame: &FramePredictions, line: &str) -> Result<()> {
        let mut bytes = Vec::with_capacity(line.len() + 1);
        bytes.extend_from_slice(line.as_bytes());
        bytes.push(b'\n');
        match &mut self.target {
            Target::Stdout(out) => {
                let mut out = out.lock();
                out.write_all(&bytes).and_then(|()| out.flush()).map_err(|e| Error::io("<stdout>", e))
            }
            Target::File { path, file, whole_len } => match file.write_all(&bytes) {
                Ok(()) => {
                    *whole_len += bytes.len() as u64;
                    Ok(())
                }
                Err(e) => {
                    // cut the part that was written: the file ends on a whole line again
                    if let Err(cut) = file.set_len(*whole_len) {
                        log::error!("{}: cannot cut a torn line back ({cut})", path.display());
                    }
                    Err(Error::io(&*path, e))
                }
            },
        }
    }

    fn flush(&mut self) -> Result<()> {
        match &mut self.target {
            Target::Stdout(out) => out.flush().map_err(|e| Error::io("<stdout>", e)),
            Target::File { path, file, .. } => file.flush().map_err(|e| Error::io(&*path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn publish(sink: &mut JsonLinesSink, line: &str) {
        sink.publish(&FramePredictions::default(), line).unwrap();
    }

    #[test]
    fn a_torn_last_line_is_cut_at_open_and_whole_lines_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.jsonl");
        std::fs::write(&path, "{\"a\":1}\n{\"b\":2}\n{\"c\":").unwrap();
        let mut sink = JsonLinesSink::append(&path).unwrap();
        publish(&mut sink, "{\"d\":4}");
        drop(sink);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{\"a\":1}\n{\"b\":2}\n{\"d\":4}\n");
        // a file of one torn line becomes empty; a whole file is left as it is
        std::fs::write(&path, "{\"torn").unwrap();
        drop(JsonLinesSink::append(&path).unwrap());
        assert_eq!(std::fs::read(&path).unwrap(), b"");
        std::fs::write(&path, "x\n").unwrap();
        drop(JsonLinesSink::append(&path).unwrap());
        assert_eq!(std::fs::read(&path).unwrap(), b"x\n");
    }

    #[test]
    fn a_torn_line_longer_than_the_scan_block_is_cut_too() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.jsonl");
        let mut text = "whole\n".to_string();
        text.push_str(&"t".repeat(200_000));
        std::fs::write(&path, &text).unwrap();
        drop(JsonLinesSink::append(&path).unwrap());
        assert_eq!(std::fs::read(&path).unwrap(), b"whole\n");
    }

    /// A full disk (Linux's /dev/full fails every write with ENOSPC): the error names the
    /// file and nothing torn is left behind for the next line to follow.
    #[test]
    fn a_failed_write_is_an_error_naming_the_file() {
        let full = Path::new("/dev/full");
        if !full.exists() {
            return;
        }
        let mut sink = JsonLinesSink::append(full).unwrap();
        let err = sink.publish(&FramePredictions::default(), "{}").unwrap_err().to_string();
        assert!(err.contains("/dev/full"), "{err}");
    }
}
