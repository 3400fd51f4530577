//! Where the pose service's results go: JSON Lines writers (stdout, a file)
//! and the HTTP stream hub ([`super::http`]).

use super::predictions::FramePredictions;
use crate::error::{Error, Result};
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An output of the pipeline. `publish` is called once per frame, in frame order.
pub trait Sink: Send {
    /// What this output is (for logs).
    fn describe(&self) -> String;
    /// Emits one frame's result; `line` is its JSON Lines form (no newline).
    fn publish(&mut self, frame: &FramePredictions, line: &str) -> Result<()>;
    /// Makes everything published so far durable/visible.
    fn flush(&mut self) -> Result<()>;
}

/// JSON Lines to stdout or a file. Each line is written whole and flushed, so
/// a reader (or a crash) never sees half a line; a file is opened for
/// appending, so a restarted service never loses what an earlier run wrote.
pub struct JsonLinesSink {
    target: Target,
    out: Box<dyn Write + Send>,
}

enum Target {
    Stdout,
    File(PathBuf),
}

impl JsonLinesSink {
    /// Writes to standard output.
    pub fn stdout() -> JsonLinesSink {
        JsonLinesSink { target: Target::Stdout, out: Box::new(std::io::stdout()) }
    }

    /// Appends to `path` (created if missing, its directory too).
    pub fn append(path: &Path) -> Result<JsonLinesSink> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        let file: File = OpenOptions::new().create(true).append(true).open(path).map_err(|e| Error::io(path, e))?;
        Ok(JsonLinesSink { target: Target::File(path.to_path_buf()), out: Box::new(BufWriter::new(file)) })
    }

    fn path(&self) -> PathBuf {
        match &self.target {
            Target::Stdout => PathBuf::from("<stdout>"),
            Target::File(p) => p.clone(),
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
        self.out.write_all(&bytes).and_then(|()| self.out.flush()).map_err(|e| Error::io(self.path(), e))
    }

    fn flush(&mut self) -> Result<()> {
        self.out.flush().map_err(|e| Error::io(self.path(), e))?;
        Ok(())
    }
}
