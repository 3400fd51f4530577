//! What the runtime emits: the predictions format (JSON Lines), shared by
//! replay, the pose service, `tricons inspect --predictions` and `tricons eval`;
//! and overlay images of estimated poses.

pub mod overlay;
pub mod predictions;

pub use predictions::{FramePredictions, PredInstance, read_predictions, write_predictions};
