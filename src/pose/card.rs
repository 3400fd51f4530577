//! The model card beside an exported pose graph (docs/formats.md, "Pose model").

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::pose::preprocess::PreprocessConfig;

/// `format` field of a model card.
pub const CARD_FORMAT: &str = "tricons-model-card";
/// Card version this build reads.
pub const CARD_VERSION: u32 = 1;

/// What the runtime reads from a model card.
#[derive(Clone, Debug, Deserialize)]
pub struct ModelCard {
    /// Always [`CARD_FORMAT`].
    pub format: String,
    /// Card version.
    pub version: u32,
    /// Model family, e.g. "TriCons-Pose".
    pub model: String,
    /// Configuration name (shipped, paper, ablations).
    pub config_name: String,
    /// The graph file.
    pub onnx: OnnxInfo,
    /// Graph inputs in order.
    pub inputs: Vec<TensorInfo>,
    /// Graph outputs in order.
    pub outputs: Vec<TensorInfo>,
    /// Preprocessing constants.
    pub preprocessing: CardPreprocessing,
    /// Categories the model was trained on.
    pub categories: Vec<String>,
    /// Keypoints per instance (M).
    pub n_keypoints: usize,
    /// Trained or random weights, with provenance.
    pub weights: serde_json::Value,
    /// SynthNOCS-test metrics by IoU mode, when measured.
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// Classes whose rotation is solved from the keypoints instead of taken from the pose
    /// head: the least-squares similarity (Umeyama) between the keypoints' predicted NOCS
    /// coordinates (`kpt_nocs`) and their camera-frame positions (`kpt_3d`). Chosen per
    /// class with ground-truth and with segmenter masks (tools/MODEL.md, E1); empty (the
    /// default) keeps the head's.
    #[serde(default)]
    pub rotation_from_keypoints: Vec<crate::category::Category>,
    /// Classes whose rotation is a blend of the two: the weighted chordal mean (the rotation
    /// nearest to `(1 - w) R_head + w R_keypoints`) with the weight `w` in (0, 1) given here
    /// per class. The head's and the keypoints' errors are partly independent; chosen on
    /// SynthNOCS-val (tools/MODEL.md, E15). A class may not be in both fields. Empty (the
    /// default): no blend.
    #[serde(default)]
    pub rotation_keypoint_blend: std::collections::BTreeMap<crate::category::Category, f64>,
    /// How the keypoint rotation is fitted (default: least squares over every keypoint).
    #[serde(default)]
    pub keypoint_fit: KeypointFit,
    /// When set, the reported score is the detection's times `exp(-r / scale)`, `r` the
    /// disagreement between the pose head and the keypoints in box diagonals
    /// ([`crate::pose::consistency`]); absent (the default) reports the detection's score.
    /// Needs the keypoint outputs. Chosen on SynthNOCS-val (tools/MODEL.md, E11).
    #[serde(default)]
    pub consistency_score_scale: Option<f64>,
    /// When set, poses whose reported score (after the consistency factor) lies below it
    /// are not reported, only counted: most of them sit on distractors or on parts of an
    /// object (chosen on SynthNOCS-val, docs/results.md, "Score floor"). Absent (the
    /// default): every pose is reported.
    #[serde(default)]
    pub min_score: Option<f64>,
}

/// The fit of [`ModelCard::rotation_from_keypoints`] and [`ModelCard::rotation_keypoint_blend`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeypointFit {
    /// Umeyama over every keypoint ([`crate::geometry::fit_similarity`]).
    #[default]
    LeastSquares,
    /// The same, refitted once without the keypoints whose residual exceeds
    /// [`crate::geometry::OUTLIER_MEDIAN_FACTOR`] times the median (a keypoint that landed
    /// on background or a neighbour inside an imperfect mask;
    /// [`crate::geometry::fit_similarity_robust`]).
    Robust,
}

/// The graph file of a card.
#[derive(Clone, Debug, Deserialize)]
pub struct OnnxInfo {
    /// File name, relative to the card's directory.
    pub file: String,
    /// SHA-256 of the file, hex.
    pub sha256: String,
    /// Custom node counts by type.
    #[serde(default)]
    pub custom_nodes: std::collections::BTreeMap<String, usize>,
}

/// One graph input or output.
#[derive(Clone, Debug, Deserialize)]
pub struct TensorInfo {
    /// Tensor name.
    pub name: String,
    /// "float32" or "int64".
    pub dtype: String,
    /// Dims: numbers, or a name for the symbolic batch.
    pub shape: Vec<serde_json::Value>,
}

/// The card's `preprocessing` block: the preprocessing configuration plus the colour
/// scale, which must be 1/255 (the runtime divides by 255 exactly as training did).
#[derive(Clone, Debug, Deserialize)]
pub struct CardPreprocessing {
    /// N, S, pixel thresholds, crop sizes, normalisation.
    #[serde(flatten)]
    pub config: PreprocessConfig,
    /// Colour scale (1/255).
    pub rgb_scale: f64,
}

impl ModelCard {
    /// Read and check a card file (format, version, I/O names, constants).
    pub fn read(path: &Path) -> Result<ModelCard> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let card: ModelCard = crate::error::from_json_str(path, &text)?;
        let bad = |m: String| Err(Error::parse(path, None, m));
        if card.format != CARD_FORMAT {
            return bad(format!("field `format`: expected {CARD_FORMAT:?}, found {:?}", card.format));
        }
        if card.version != CARD_VERSION {
            return bad(format!("field `version`: this build reads version {CARD_VERSION}, found {}", card.version));
        }
        let names = |v: &[TensorInfo]| v.iter().map(|t| t.name.clone()).collect::<Vec<_>>();
        if names(&card.inputs) != ["rgb", "pts", "choose"] {
            return bad(format!("field `inputs`: expected rgb, pts, choose, found {:?}", names(&card.inputs)));
        }
        let outputs = names(&card.outputs);
        if outputs.get(..3) != Some(&["R", "t", "s"].map(String::from)[..]) {
            return bad(format!("field `outputs`: expected R, t, s first, found {outputs:?}"));
        }
        if let Some(scale) = card.consistency_score_scale
            && !(scale > 0.0 && scale.is_finite())
        {
            return bad(format!("field `consistency_score_scale`: must be a positive number, found {scale}"));
        }
        if let Some(min) = card.min_score
            && !(0.0..1.0).contains(&min)
        {
            return bad(format!("field `min_score`: must lie in [0, 1), found {min}"));
        }
        for (class, &w) in &card.rotation_keypoint_blend {
            if !(w > 0.0 && w < 1.0) {
                return bad(format!(
                    "field `rotation_keypoint_blend`: the weight of {} must lie strictly between 0 and 1, found {w} \
                     (1: list the class in rotation_from_keypoints; 0: leave it out)",
                    class.name()
                ));
            }
            if card.rotation_from_keypoints.contains(class) {
                return bad(format!(
                    "field `rotation_keypoint_blend`: {} is also in rotation_from_keypoints; name it in one",
                    class.name()
                ));
            }
        }
        let has_keypoint_outputs = outputs.get(3..5) == Some(&["kpt_3d", "kpt_nocs"].map(String::from)[..]);
        for (used, field) in [
            (!card.rotation_from_keypoints.is_empty(), "rotation_from_keypoints"),
            (!card.rotation_keypoint_blend.is_empty(), "rotation_keypoint_blend"),
            (card.consistency_score_scale.is_some(), "consistency_score_scale"),
        ] {
            if used && !has_keypoint_outputs {
                return bad(format!(
                    "field `{field}`: needs the outputs kpt_3d, kpt_nocs after R, t, s, found {outputs:?}"
                ));
            }
        }
        let (p, rgb_scale) = (&card.preprocessing.config, card.preprocessing.rgb_scale);
        if p.n_points == 0 || p.crop_size == 0 || p.crop_step_px == 0 || p.max_crop_px < p.crop_step_px {
            return bad("field `preprocessing`: sizes must be positive".into());
        }
        if (rgb_scale - 1.0 / 255.0).abs() > 1e-12 || p.rgb_std.iter().any(|&s| s <= 0.0) {
            return bad("field `preprocessing`: rgb_scale must be 1/255 and rgb_std positive".into());
        }
        Ok(card)
    }

    /// The weight of the keypoint rotation for `class`: 1 for the classes of
    /// [`Self::rotation_from_keypoints`], the [`Self::rotation_keypoint_blend`] weight, else 0.
    pub fn keypoint_rotation_weight(&self, class: crate::category::Category) -> f64 {
        if self.rotation_from_keypoints.contains(&class) {
            1.0
        } else {
            self.rotation_keypoint_blend.get(&class).copied().unwrap_or(0.0)
        }
    }

    /// The graph file, resolved against the card's directory.
    pub fn onnx_path(&self, card_path: &Path) -> PathBuf {
        card_path.parent().unwrap_or(Path::new(".")).join(&self.onnx.file)
    }

    /// Preprocessing configuration for this model.
    pub fn preprocess_config(&self) -> PreprocessConfig {
        self.preprocessing.config.clone()
    }

    /// Read the graph file and check its hash against the card; returns its bytes.
    pub fn read_verified_graph(&self, card_path: &Path) -> Result<Vec<u8>> {
        let path = self.onnx_path(card_path);
        let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
        let hex = crate::atomic::sha256_hex(&bytes);
        if !hex.eq_ignore_ascii_case(&self.onnx.sha256) {
            return Err(Error::model(
                &path,
                format!(
                    "sha256 {hex} does not match its card {} ({}): the graph and card belong to different exports",
                    self.onnx.sha256,
                    card_path.display()
                ),
            ));
        }
        Ok(bytes)
    }
}

/// The card path for a model argument: a `.card.json` as is, a `.onnx` with its card beside it.
pub fn card_path_for(model: &Path) -> PathBuf {
    let name = model.file_name().and_then(|n| n.to_str()).unwrap_or("");
    match name.strip_suffix(".onnx") {
        Some(stem) => model.with_file_name(format!("{stem}.card.json")),
        None => model.to_path_buf(),
    }
}
