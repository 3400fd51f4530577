//! What the runtime emits: the predictions format (JSON Lines), shared by
//! replay, the pose service, `tricons inspect --predictions` and `tricons eval`;
//! overlay images of estimated poses; the service's outputs (JSON Lines sinks, the HTTP endpoint); segmentation records, label images and mask overlays.

pub mod http;
pub mod overlay;
pub mod predictions;
pub mod segments;
pub mod sink;

pub use predictions::{FramePredictions, PredInstance, read_predictions, write_predictions};
