//! The quantization profile: what `tricons quantize` writes and the runtime applies at
//! load. The float ONNX stays as it is; the profile names it (path and sha256) and
//! lists, per quantized node, the input's activation parameters, the followers fused
//! into it and whether its output stays int8 for the next int8 op. Weights are
//! quantized at load (per output channel, deterministic), so the profile is small.
//! Format: docs/formats.md, "Quantization profile".

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::params::{QParams, RangeMethod};
use crate::error::{Error, Result};

/// `format` field of a profile.
pub const PROFILE_FORMAT: &str = "tricons-quant-profile";
/// Profile version this build reads and writes.
pub const PROFILE_VERSION: u32 = 1;

/// Which runtime model a profile quantizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// A TriCons-Pose graph (loaded through its model card).
    Pose,
    /// A Mask R-CNN segmenter.
    Segmenter,
}

/// One node executed in int8.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QuantNode {
    /// ONNX node name (a `MatMul`, `Gemm` or `Conv`).
    pub node: String,
    /// Its ONNX op type.
    pub op: String,
    /// The activation input tensor.
    pub input: String,
    /// Quantization of that input.
    pub input_q: QParams,
    /// The input already arrives as u7 from the int8 node before it.
    #[serde(default)]
    pub input_u7: bool,
    /// Op types of the single-consumer followers folded into the output stage, in
    /// order (`Add` bias, `BatchNormalization`, `Relu`).
    #[serde(default)]
    pub fuse: Vec<String>,
    /// When set, the output is requantised to u7 with these parameters for the int8
    /// nodes that consume it (no float round trip).
    #[serde(default)]
    pub output_u7: Option<QParams>,
    /// Calibration SQNR of the input quantization, dB.
    pub input_sqnr_db: f64,
    /// SQNR of the per-channel weight quantization, dB.
    pub weight_sqnr_db: f64,
}

/// A node left in float, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FloatNode {
    /// ONNX node name.
    pub node: String,
    /// Its ONNX op type.
    pub op: String,
    /// Why it stays float.
    pub reason: String,
}

/// A quantization profile (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QuantProfile {
    /// Always [`PROFILE_FORMAT`].
    pub format: String,
    /// Always [`PROFILE_VERSION`].
    pub version: u32,
    /// Pose or segmenter.
    pub kind: ModelKind,
    /// The float model this profile applies to (card or ONNX), relative to the profile.
    pub model: PathBuf,
    /// sha256 of the float ONNX graph.
    pub onnx_sha256: String,
    /// How activation ranges were chosen.
    pub range: RangeMethod,
    /// Nodes with an input SQNR below this stayed float.
    pub min_sqnr_db: f64,
    /// Calibration data: directory, frames used, runs (instances or images).
    pub calibration: CalibrationInfo,
    /// Nodes run in int8.
    pub nodes: Vec<QuantNode>,
    /// Candidate nodes left in float.
    pub float: Vec<FloatNode>,
}

/// Where the statistics came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationInfo {
    /// The calibration recording, as given.
    pub data: String,
    /// Frames read.
    pub frames: usize,
    /// Graph runs observed (pose: instances; segmenter: images).
    pub runs: usize,
}

impl QuantProfile {
    /// Read and check a profile.
    pub fn read(path: &Path) -> Result<QuantProfile> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let parse = |message: String| Error::Parse { path: path.to_path_buf(), line: None, message };
        let p: QuantProfile = crate::error::from_json_str(path, &text)?;
        if p.format != PROFILE_FORMAT {
            return Err(parse(format!("field format is {:?}, expected {PROFILE_FORMAT:?}", p.format)));
        }
        if p.version != PROFILE_VERSION {
            return Err(parse(format!("field version is {}, this build reads {PROFILE_VERSION}", p.version)));
        }
        for n in &p.nodes {
            let q = n.input_q;
            if !(q.scale.is_finite() && q.scale > 0.0 && (0..=127).contains(&q.zero_point)) {
                return Err(parse(format!("node {:?}: invalid input_q {q:?}", n.node)));
            }
        }
        Ok(p)
    }

    /// Write atomically (temporary file, then rename).
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|e| Error::InvalidArgument(format!("profile does not serialise: {e}")))?;
        crate::atomic::write_atomic(path, format!("{text}\n").as_bytes())
    }

    /// The float model's path, resolved against the profile's directory.
    pub fn model_path(&self, profile_path: &Path) -> PathBuf {
        profile_path.parent().unwrap_or(Path::new(".")).join(&self.model)
    }
}

/// Whether `path` is a quantization profile (a JSON file whose `format` says so).
pub fn is_profile(path: &Path) -> bool {
    if path.extension().and_then(|e| e.to_str()) != Some("json") {
        return false;
    }
    #[derive(Deserialize)]
    struct Head {
        format: Option<String>,
    }
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<Head>(&t).ok())
        .and_then(|h| h.format)
        .is_some_and(|f| f == PROFILE_FORMAT)
}
