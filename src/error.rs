//! The library's error type. Every variant that comes from a file names it.

use std::path::PathBuf;

/// Errors returned by the tricons library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A PNG file could not be decoded or encoded.
    #[error("{}: not a readable PNG: {message}", path.display())]
    Png {
        /// The PNG file.
        path: PathBuf,
        /// What the decoder reported.
        message: String,
    },
    /// An image has the wrong colour type, bit depth or size.
    #[error("{}: expected {expected}, found {found}", path.display())]
    ImageFormat {
        /// The image file.
        path: PathBuf,
        /// What the format requires, e.g. "16-bit grayscale depth".
        expected: String,
        /// What the file holds.
        found: String,
    },
    /// A JSON, JSON Lines or text file is malformed or has an invalid field.
    #[error("{}{}: {message}", path.display(), line.map(|l| format!(" line {l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number, for line-oriented formats.
        line: Option<usize>,
        /// What is wrong, naming the field where there is one.
        message: String,
    },
    /// A recording's manifest has a format version this build cannot read.
    #[error("{}: recording format version {found} is not supported (this build reads version {supported})", path.display())]
    UnsupportedVersion {
        /// The manifest file.
        path: PathBuf,
        /// The version found in the file.
        found: u32,
        /// The version this build reads.
        supported: u32,
    },
    /// A model (graph or card) cannot be used: unreadable, inconsistent with its card,
    /// or using an operator this build lacks.
    #[error("{}: {message}", path.display())]
    Model {
        /// The graph or card file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Running a model failed.
    #[error("inference failed: {0}")]
    Inference(String),
    /// A capture device could not be opened, configured or read, or it vanished.
    #[error("{}: {message}", path.display())]
    Device {
        /// The device node, e.g. `/dev/video0`.
        path: PathBuf,
        /// What failed (the ioctl or step, and the OS error).
        message: String,
    },
    /// A raw camera buffer could not be decoded.
    #[error("{format} buffer: {message}")]
    Decode {
        /// The pixel format, e.g. "MJPG".
        format: String,
        /// What is wrong with the buffer.
        message: String,
    },
    /// A caller passed an argument outside its valid range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }

    /// A model error on `path`.
    pub fn model(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Model { path: path.into(), message: message.into() }
    }

    /// A device error on `path`.
    pub fn device(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Device { path: path.into(), message: message.into() }
    }

    /// A decode error for a buffer of pixel format `format`.
    pub fn decode(format: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Decode { format: format.into(), message: message.into() }
    }

    /// A parse error in `path` (optionally at a 1-based `line`).
    pub fn parse(path: impl Into<PathBuf>, line: Option<usize>, message: impl Into<String>) -> Self {
        Error::Parse { path: path.into(), line, message: message.into() }
    }
}

/// A JSON file's error message naming the field it is in (`field frames[2].height:
/// invalid value ...`; the whole document: no prefix).
fn field_message<E: std::fmt::Display>(e: &serde_path_to_error::Error<E>) -> String {
    let field = e.path().to_string();
    if field == "." { e.inner().to_string() } else { format!("field {field}: {}", e.inner()) }
}

/// Parses JSON `text` of `path` into `T`; a type error names its field and line.
pub fn from_json_str<T: serde::de::DeserializeOwned>(path: &std::path::Path, text: &str) -> Result<T> {
    let mut de = serde_json::Deserializer::from_str(text);
    let value = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| Error::parse(path, Some(e.inner().line()).filter(|&l| l > 0), field_message(&e)))?;
    de.end().map_err(|e| Error::parse(path, Some(e.line()), e.to_string()))?;
    Ok(value)
}

/// Converts a parsed JSON document of `path` into `T`; a type error names its field.
pub fn from_json_value<T: serde::de::DeserializeOwned>(path: &std::path::Path, value: serde_json::Value) -> Result<T> {
    serde_path_to_error::deserialize(value).map_err(|e| Error::parse(path, None, field_message(&e)))
}

/// Result with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
