//! The segmenter card beside a Mask R-CNN graph (docs/formats.md, "Segmenter card").
//!
//! Optional: a bare torchvision export runs with [`SegmenterCard::bare`] (RGB in
//! [0, 1], outputs named boxes / labels / scores / masks, no class mapping).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::category::Category;
use crate::error::{Error, Result};

/// `format` field of a segmenter card.
pub const SEGMENTER_CARD_FORMAT: &str = "tricons-segmenter-card";
/// Card version this build reads.
pub const SEGMENTER_CARD_VERSION: u32 = 1;
/// Score threshold of a bare export (torchvision's demos use 0.5).
pub const DEFAULT_SCORE_THRESHOLD: f32 = 0.5;
/// Mask probability threshold (torchvision's convention).
pub const DEFAULT_MASK_THRESHOLD: f32 = 0.5;
/// Largest `pose_mask_erode_px` a card may ask for (a larger one is a typo: it would erase
/// most objects of a 640 x 480 image).
pub const MAX_POSE_MASK_ERODE_PX: usize = 16;

/// How the image tensor is built from 8-bit RGB: `((pixel * scale) - mean) / std` per
/// channel, `(3, H, W)`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// Graph input name (default: the graph's first input).
    #[serde(default)]
    pub name: Option<String>,
    /// Only "CHW" (torchvision takes a list of `(3, H, W)` images).
    #[serde(default = "chw")]
    pub layout: String,
    /// "rgb" or "bgr".
    #[serde(default = "rgb")]
    pub color: String,
    /// Multiplies 8-bit values (torchvision: 1/255; its graph normalises inside).
    #[serde(default = "unit_scale")]
    pub scale: f32,
    /// Subtracted after scaling.
    #[serde(default)]
    pub mean: [f32; 3],
    /// Divides after the mean.
    #[serde(default = "ones")]
    pub std: [f32; 3],
}

fn chw() -> String {
    "CHW".into()
}
fn rgb() -> String {
    "rgb".into()
}
fn unit_scale() -> f32 {
    1.0 / 255.0
}
fn ones() -> [f32; 3] {
    [1.0; 3]
}

impl Default for InputSpec {
    fn default() -> Self {
        InputSpec { name: None, layout: chw(), color: rgb(), scale: unit_scale(), mean: [0.0; 3], std: ones() }
    }
}

/// Graph output names of the four Mask R-CNN results.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputNames {
    /// `(N, 4)` boxes, x0 y0 x1 y1 in input pixels.
    pub boxes: String,
    /// `(N,)` int64 labels.
    pub labels: String,
    /// `(N,)` scores.
    pub scores: String,
    /// `(N, 1, H, W)` mask probabilities (pasted in Rust when the graph pastes with a Loop).
    pub masks: String,
}

impl Default for OutputNames {
    fn default() -> Self {
        OutputNames { boxes: "boxes".into(), labels: "labels".into(), scores: "scores".into(), masks: "masks".into() }
    }
}

/// What the runtime reads from a segmenter card.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct SegmenterCard {
    /// Always [`SEGMENTER_CARD_FORMAT`].
    pub format: String,
    /// Card version.
    pub version: u32,
    /// The ONNX file, relative to the card's directory.
    pub model: String,
    /// SHA-256 of the ONNX file (hex); checked at load when present.
    #[serde(default)]
    pub sha256: Option<String>,
    /// Free text: backbone, input size.
    #[serde(default)]
    pub architecture: String,
    /// Input construction.
    #[serde(default)]
    pub input: InputSpec,
    /// Output names.
    #[serde(default)]
    pub outputs: OutputNames,
    /// Model label id (as a string key) -> class name; NOCS names map to categories.
    #[serde(default)]
    pub labels: BTreeMap<String, String>,
    /// Instances scoring below are dropped.
    #[serde(default = "default_score")]
    pub score_threshold: f32,
    /// Mask probability at or above which a pixel belongs to the instance.
    #[serde(default = "default_mask")]
    pub mask_threshold: f32,
    /// Class-agnostic duplicate suppression: a detection whose mask overlaps a
    /// higher-scored one by more than this IoU is dropped, whatever the two labels
    /// ([`super::duplicates`]). Absent (a bare torchvision export): off.
    #[serde(default)]
    pub duplicate_mask_iou: Option<f32>,
    /// Duplicate suppression by containment: a detection with more than this fraction of
    /// its mask inside a higher-scored, kept one is dropped too (a part detected beside
    /// its whole). Absent: off.
    #[serde(default)]
    pub duplicate_mask_inside: Option<f32>,
    /// Pixels by which each detection's mask is eroded before the pose stage samples its
    /// points ([`super::erode`]; segmentation outputs and AP keep the masks as predicted).
    /// Absent (a bare torchvision export): 0, off.
    #[serde(default)]
    pub pose_mask_erode_px: usize,
    /// NOCS category name -> metres: after the erosion, a detection of that category loses
    /// the mask pixels whose point lies farther than this from the median point of its
    /// pixels with depth ([`super::depth_outliers`]). Categories absent: no such step.
    #[serde(default)]
    pub pose_mask_max_radius_m: BTreeMap<String, f64>,
    /// Training provenance and measured accuracy (not read by the runtime).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Measured accuracy (not read by the runtime).
    #[serde(default)]
    pub metrics: serde_json::Value,
}

fn default_score() -> f32 {
    DEFAULT_SCORE_THRESHOLD
}
fn default_mask() -> f32 {
    DEFAULT_MASK_THRESHOLD
}

impl SegmenterCard {
    /// The card of a bare torchvision export `model` (no class mapping).
    pub fn bare(model: &Path) -> SegmenterCard {
        SegmenterCard {
            format: SEGMENTER_CARD_FORMAT.into(),
            version: SEGMENTER_CARD_VERSION,
            model: model.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            sha256: None,
            architecture: String::new(),
            input: InputSpec::default(),
            outputs: OutputNames::default(),
            labels: BTreeMap::new(),
            score_threshold: DEFAULT_SCORE_THRESHOLD,
            mask_threshold: DEFAULT_MASK_THRESHOLD,
            duplicate_mask_iou: None,
            duplicate_mask_inside: None,
            pose_mask_erode_px: 0,
            pose_mask_max_radius_m: BTreeMap::new(),
            training: serde_json::Value::Null,
            metrics: serde_json::Value::Null,
        }
    }

    /// Read and check a card file.
    pub fn read(path: &Path) -> Result<SegmenterCard> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let bad = |m: String| Err(Error::parse(path, None, m));
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| Error::parse(path, Some(e.line()), e.to_string()))?;
        let format = value.get("format").and_then(|f| f.as_str()).unwrap_or("");
        if format != SEGMENTER_CARD_FORMAT {
            return bad(format!("field `format`: expected {SEGMENTER_CARD_FORMAT:?}, found {format:?}"));
        }
        let card: SegmenterCard = crate::error::from_json_value(path, value)?;
        if card.version != SEGMENTER_CARD_VERSION {
            return bad(format!(
                "field `version`: this build reads version {SEGMENTER_CARD_VERSION}, found {}",
                card.version
            ));
        }
        if card.input.layout != "CHW" {
            return bad(format!("field `input.layout`: only \"CHW\" is supported, found {:?}", card.input.layout));
        }
        if card.input.color != "rgb" && card.input.color != "bgr" {
            return bad(format!("field `input.color`: expected \"rgb\" or \"bgr\", found {:?}", card.input.color));
        }
        if !card.input.scale.is_finite() || card.input.std.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return bad("field `input`: scale must be finite and std positive".into());
        }
        for (k, v) in &card.labels {
            if k.parse::<i64>().is_err() {
                return bad(format!("field `labels`: key {k:?} (for {v:?}) is not an integer label id"));
            }
        }
        if !(0.0..=1.0).contains(&card.score_threshold) || !(0.0..=1.0).contains(&card.mask_threshold) {
            return bad("fields `score_threshold` and `mask_threshold` must lie in [0, 1]".into());
        }
        if let Some(iou) = card.duplicate_mask_iou
            && !(iou > 0.0 && iou < 1.0)
        {
            return bad(format!("field `duplicate_mask_iou`: must lie in (0, 1), found {iou}"));
        }
        if let Some(inside) = card.duplicate_mask_inside
            && !(inside > 0.0 && inside < 1.0)
        {
            return bad(format!("field `duplicate_mask_inside`: must lie in (0, 1), found {inside}"));
        }
        if card.pose_mask_erode_px > MAX_POSE_MASK_ERODE_PX {
            return bad(format!(
                "field `pose_mask_erode_px`: at most {MAX_POSE_MASK_ERODE_PX} pixels, found {}",
                card.pose_mask_erode_px
            ));
        }
        for (class, radius_m) in &card.pose_mask_max_radius_m {
            if class.parse::<Category>().is_err() {
                return bad(format!("field `pose_mask_max_radius_m`: {class:?} is not a NOCS category"));
            }
            if !(radius_m.is_finite() && *radius_m > 0.0) {
                return bad(format!(
                    "field `pose_mask_max_radius_m`: the radius of {class:?} must be positive metres, found {radius_m}"
                ));
            }
        }
        Ok(card)
    }

    /// The depth-outlier radius of `category`'s detections, when the card sets one.
    pub fn pose_mask_max_radius_m(&self, category: Category) -> Option<f64> {
        self.pose_mask_max_radius_m.get(category.name()).copied()
    }

    /// The class name of model label `label`, when the card maps it.
    pub fn class_name(&self, label: i64) -> Option<&str> {
        self.labels.get(&label.to_string()).map(String::as_str)
    }

    /// The class names the card maps that are no NOCS category (such as "other"), in label order.
    pub fn non_nocs_classes(&self) -> Vec<&str> {
        let mut labels: Vec<(i64, &str)> = self
            .labels
            .iter()
            .filter(|(_, name)| name.parse::<Category>().is_err())
            .filter_map(|(k, name)| Some((k.parse().ok()?, name.as_str())))
            .collect();
        labels.sort_unstable();
        labels.into_iter().map(|(_, name)| name).collect()
    }

    /// The NOCS category of model label `label`, when the card maps it to one.
    pub fn category(&self, label: i64) -> Option<Category> {
        self.class_name(label).and_then(|n| n.parse().ok())
    }
}

/// Where a segmenter argument's card and graph are: a `*.card.json` (graph named inside),
/// or a `*.onnx` with an optional `<stem>.card.json` beside it.
pub fn resolve(model: &Path) -> Result<(SegmenterCard, PathBuf)> {
    let name = model.file_name().and_then(|n| n.to_str()).unwrap_or("");
    if name.ends_with(".json") {
        let card = SegmenterCard::read(model)?;
        let onnx = model.parent().unwrap_or(Path::new(".")).join(&card.model);
        return Ok((card, onnx));
    }
    let card_path = crate::pose::card::card_path_for(model);
    if card_path != model && card_path.exists() {
        let card = SegmenterCard::read(&card_path)?;
        return Ok((card, model.to_path_buf()));
    }
    Ok((SegmenterCard::bare(model), model.to_path_buf()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn card_with(extra: &str) -> Result<SegmenterCard> {
        let dir = tempfile::tempdir().map_err(|e| Error::io(Path::new("tempdir"), e))?;
        let path = dir.path().join("m.card.json");
        let text = format!(r#"{{"format": "tricons-segmenter-card", "version": 1, "model": "m.onnx"{extra}}}"#);
        std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
        SegmenterCard::read(&path)
    }

    #[test]
    fn duplicate_suppression_is_off_unless_set_and_checked() {
        assert_eq!(card_with("").unwrap().duplicate_mask_iou, None);
        assert_eq!(card_with(r#", "duplicate_mask_iou": 0.5"#).unwrap().duplicate_mask_iou, Some(0.5));
        for bad in ["0", "1", "-0.2", "1.5"] {
            let e = card_with(&format!(r#", "duplicate_mask_iou": {bad}"#)).unwrap_err().to_string();
            assert!(e.contains("duplicate_mask_iou"), "{e}");
        }
        let e = card_with(r#", "duplicate_mask_iou": "high""#).unwrap_err().to_string();
        assert!(e.contains("duplicate_mask_iou"), "{e}");
        assert_eq!(card_with("").unwrap().duplicate_mask_inside, None);
        assert_eq!(card_with(r#", "duplicate_mask_inside": 0.5"#).unwrap().duplicate_mask_inside, Some(0.5));
        for bad in ["0", "1", "-0.2", "1.5"] {
            let e = card_with(&format!(r#", "duplicate_mask_inside": {bad}"#)).unwrap_err().to_string();
            assert!(e.contains("duplicate_mask_inside"), "{e}");
        }
    }

    #[test]
    fn pose_mask_erosion_is_off_unless_set_and_bounded() {
        assert_eq!(card_with("").unwrap().pose_mask_erode_px, 0);
        assert_eq!(card_with(r#", "pose_mask_erode_px": 2"#).unwrap().pose_mask_erode_px, 2);
        for bad in ["17", "-1", "1.5", "\"two\""] {
            let e = card_with(&format!(r#", "pose_mask_erode_px": {bad}"#)).unwrap_err().to_string();
            assert!(e.contains("pose_mask_erode_px"), "{bad}: {e}");
        }
    }

    #[test]
    fn depth_outlier_radii_are_per_category_and_checked() {
        let card = card_with(r#", "pose_mask_max_radius_m": {"mug": 0.14, "laptop": 0.38}"#).unwrap();
        assert_eq!(card.pose_mask_max_radius_m(Category::Mug), Some(0.14));
        assert_eq!(card.pose_mask_max_radius_m(Category::Bottle), None);
        assert_eq!(card_with("").unwrap().pose_mask_max_radius_m(Category::Mug), None);
        for bad in [r#"{"cup": 0.1}"#, r#"{"mug": 0}"#, r#"{"mug": -0.1}"#, r#"{"mug": "far"}"#, "[0.1]"] {
            let e = card_with(&format!(r#", "pose_mask_max_radius_m": {bad}"#)).unwrap_err().to_string();
            assert!(e.contains("pose_mask_max_radius_m"), "{bad}: {e}");
        }
    }
}
