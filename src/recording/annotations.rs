//! Ground truth attached to a recorded frame.

use crate::category::Category;
use crate::frame::{LabelImage, NocsMap};
use crate::geometry::Pose;
use serde::{Deserialize, Serialize};

/// One annotated object instance.
///
/// The object frame is the NOCS canonical frame scaled to metres: y up, centred
/// on the tight box, so the object's box spans `[-size_m/2, size_m/2]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GtInstance {
    /// The instance's value in the frame's instance mask (1..=255).
    pub id: u8,
    /// Object category.
    pub class: Category,
    /// Pose of the object in the colour camera frame (`R`, `t` in JSON; a
    /// 4x4 `RT` is also accepted).
    #[serde(flatten)]
    pub camera_from_object: Pose,
    /// Tight box size along the object's x, y, z axes in metres (`s` in JSON).
    #[serde(rename = "s")]
    pub size_m: [f64; 3],
    /// Whether a mug's handle is visible (matters for mugs only).
    #[serde(default = "default_true")]
    pub handle_visible: bool,
}

fn default_true() -> bool {
    true
}

impl GtInstance {
    /// Box diagonal in metres (the NOCS "scale").
    pub fn diagonal_m(&self) -> f64 {
        self.size_m.iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    /// Checks sizes and id; returns a message naming the bad field.
    pub fn validate(&self) -> Result<(), String> {
        if self.id == 0 {
            return Err("field id: 0 is the background label".into());
        }
        if self.size_m.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(format!("field s: sizes must be positive, got {:?}", self.size_m));
        }
        Ok(())
    }
}

/// A frame's ground truth: instances, and optionally the instance mask and
/// NOCS map images.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameAnnotations {
    /// Annotated instances.
    pub instances: Vec<GtInstance>,
    /// Instance mask (pixel value = [`GtInstance::id`], 0 background).
    pub mask: Option<LabelImage>,
    /// NOCS map, meaningful where `mask` is non-zero.
    pub nocs: Option<NocsMap>,
}

impl FrameAnnotations {
    /// One row-major boolean mask per instance, in [`Self::instances`] order; `None`
    /// without a mask image.
    pub fn instance_masks(&self) -> Option<Vec<Vec<bool>>> {
        let label = self.mask.as_ref()?;
        Some(self.instances.iter().map(|g| label.data.iter().map(|&v| v == g.id).collect()).collect())
    }
}

/// The per-frame ground-truth JSON file of the tricons recording format.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AnnotationsFile {
    /// Annotated instances.
    pub instances: Vec<GtInstance>,
    /// Instance mask PNG (8-bit, value = instance id), relative file name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    /// NOCS map PNG (16-bit RGB), relative file name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nocs: Option<String>,
}
