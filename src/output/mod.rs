//! What the runtime emits: the predictions format (JSON Lines), shared by
//! replay, the pose service, `tricons inspect --predictions` and `tricons eval`.

pub mod predictions;

pub use predictions::{FramePredictions, PredInstance, read_predictions, write_predictions};
