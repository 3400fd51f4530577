//! What the runtime emits: the predictions format (JSON Lines), shared by
//! replay, the pose service, `tricons inspect --predictions` and `tricons eval`;
//! overlay images of estimated poses; segmentation records, label images and mask overlays.

pub mod overlay;
pub mod predictions;
pub mod segments;

pub use predictions::{FramePredictions, PredInstance, read_predictions, write_predictions};
