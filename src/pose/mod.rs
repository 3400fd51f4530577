//! TriCons-Pose inference: inputs from frames and masks, the exported graph in tract.
//!
//! [`card`] reads the model card that drives every size and constant, [`preprocess`]
//! builds the network inputs exactly as training did, [`estimator`] runs the graph
//! ([`PoseEstimator`]).

pub mod card;
pub mod estimator;
pub mod preprocess;

pub use card::ModelCard;
pub use estimator::{InstanceOutcome, PoseEstimate, PoseEstimator, PreparedFrame, Skipped};
