//! The predictions format: JSON Lines, one line per frame.
//!
//! ```json
//! {"frame":"000012","timestamp_s":0.4,"instances":[{"class":"mug","score":0.93,
//!   "R":[[1,0,0],[0,1,0],[0,0,1]],"t":[0.02,-0.05,0.61],"s":[0.12,0.09,0.09],
//!   "box2d":[210,140,305,230]}]}
//! ```
//! See docs/formats.md for every field.

use crate::atomic::write_atomic_with;
use crate::category::Category;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::recording::annotations::GtInstance;
use serde::{Deserialize, Serialize};
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// One predicted object instance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PredInstance {
    /// Predicted category.
    pub class: Category,
    /// Detection confidence in [0, 1]; matching is done in score order.
    pub score: f64,
    /// Predicted pose (`R`, `t` in JSON).
    #[serde(flatten)]
    pub camera_from_object: Pose,
    /// Predicted box size along the object axes, metres (`s` in JSON).
    #[serde(rename = "s")]
    pub size_m: [f64; 3],
    /// Optional 2D box `[x0, y0, x1, y1]` in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub box2d: Option<[f64; 4]>,
    /// Optional reference to a mask file, relative to the predictions file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
}

/// All predictions for one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FramePredictions {
    /// The frame id (as in the recording's manifest).
    pub frame: String,
    /// Frame timestamp in seconds, when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp_s: Option<f64>,
    /// Predicted instances.
    pub instances: Vec<PredInstance>,
}

impl PredInstance {
    /// The prediction a perfect estimator would make for `gt` (score 1): the
    /// oracle that `tricons inspect --predictions` prints.
    pub fn from_ground_truth(gt: &GtInstance) -> PredInstance {
        PredInstance {
            class: gt.class,
            score: 1.0,
            camera_from_object: gt.camera_from_object,
            size_m: gt.size_m,
            box2d: None,
            mask: None,
        }
    }

    fn validate(&self) -> std::result::Result<(), String> {
        if !(self.score.is_finite() && (0.0..=1.0).contains(&self.score)) {
            return Err(format!("field score: {} is not in [0, 1]", self.score));
        }
        if self.size_m.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(format!("field s: sizes must be positive, got {:?}", self.size_m));
        }
        Ok(())
    }
}

/// Serialises one frame as a single JSON line (no trailing newline).
pub fn to_json_line(frame: &FramePredictions) -> String {
    // Serialising plain data with finite floats cannot fail.
    serde_json::to_string(frame).unwrap_or_default()
}

/// Reads a predictions file; errors name the file, the line and the field.
/// Entry `k` of the result is line `k + 1` of the file (blank lines may only
/// trail).
pub fn read_predictions(path: &Path) -> Result<Vec<FramePredictions>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut frames = Vec::new();
    let mut blank_line = None;
    for (i, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| Error::io(path, e))?;
        if line.trim().is_empty() {
            blank_line.get_or_insert(i + 1);
            continue;
        }
        // Blank lines may only trail, so that entry k is always on line k + 1.
        if let Some(blank) = blank_line {
            return Err(Error::parse(path, Some(blank), "blank line between frames (one JSON object per line)"));
        }
        let frame: FramePredictions = crate::error::from_json_str(path, &line).map_err(|e| match e {
            Error::Parse { message, .. } => Error::parse(path, Some(i + 1), message),
            other => other,
        })?;
        for (k, inst) in frame.instances.iter().enumerate() {
            inst.validate().map_err(|m| Error::parse(path, Some(i + 1), format!("instances[{k}]: {m}")))?;
        }
        frames.push(frame);
    }
    Ok(frames)
}

/// Writes a predictions file atomically.
pub fn write_predictions(path: &Path, frames: &[FramePredictions]) -> Result<()> {
    write_atomic_with(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        for frame in frames {
            writeln!(w, "{}", to_json_line(frame))?;
        }
        w.flush()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Vec3, rotation_y};

    #[test]
    fn round_trip_and_line_numbered_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pred.jsonl");
        let frames = vec![FramePredictions {
            frame: "000001".into(),
            timestamp_s: Some(0.5),
            instances: vec![PredInstance {
                class: Category::Mug,
                score: 0.8,
                camera_from_object: Pose::new(rotation_y(0.2), Vec3::new(0.0, 0.1, 0.7)),
                size_m: [0.1, 0.09, 0.08],
                box2d: Some([1.0, 2.0, 30.0, 40.0]),
                mask: None,
            }],
        }];
        write_predictions(&path, &frames).unwrap();
        assert_eq!(read_predictions(&path).unwrap(), frames);

        std::fs::write(
            &path,
            "{\"frame\":\"a\",\"instances\":[]}\n{\"frame\":\"b\",\"instances\":[{\"class\":\"mug\"}]}\n",
        )
        .unwrap();
        let err = read_predictions(&path).unwrap_err().to_string();
        assert!(err.contains("pred.jsonl line 2"), "{err}");
        std::fs::write(&path, "{\"frame\":\"b\",\"instances\":[{\"class\":\"mug\",\"score\":2,\"R\":[[1,0,0],[0,1,0],[0,0,1]],\"t\":[0,0,1],\"s\":[1,1,1]}]}\n").unwrap();
        let err = read_predictions(&path).unwrap_err().to_string();
        assert!(err.contains("line 1") && err.contains("score"), "{err}");
        std::fs::write(&path, "{\"frame\":\"a\",\"instances\":[]}\n\n{\"frame\":\"b\",\"instances\":[]}\n").unwrap();
        let err = read_predictions(&path).unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("blank"), "{err}");
        std::fs::write(&path, "{\"frame\":\"a\",\"instances\":[]}\n\n\n").unwrap();
        assert_eq!(read_predictions(&path).unwrap().len(), 1);
    }
}
