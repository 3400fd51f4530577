//! What the runtime emits: the predictions format (JSON Lines), shared by
//! replay, the pose service, `tricons inspect --predictions` and `tricons eval`;
//! overlay images of estimated poses; the service's outputs (JSON Lines sinks, the HTTP endpoint, MCAP
//! files and ROS 2 topics with feature `ros2`); segmentation records, label images and mask overlays.

pub mod http;
#[cfg(feature = "ros2")]
pub mod mcap_sink;
pub mod overlay;
pub mod predictions;
#[cfg(feature = "ros2")]
pub mod ros2_sink;
pub mod segments;
pub mod sink;

pub use predictions::{FramePredictions, PredInstance, read_predictions, write_predictions};
