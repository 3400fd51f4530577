//! TriCons-Pose inference: inputs from frames and masks, the exported graph in tract.
//!
//! [`card`] reads the model card that drives every size and constant, [`preprocess`]
//! builds the network inputs exactly as training did, [`rewrite`] swaps the standard
//! nodes tract runs slowly for exact `ai.tricons` kernels at load (and, with
//! [`early_gather`], runs the image decoder's per-pixel layers on the sampled pixels
//! only), [`estimator`] runs
//! the graph ([`PoseEstimator`]) after [`fold`] has folded batch normalisation into
//! the weights before it. [`consistency`] scores a pose by how well the head agrees with
//! the network's keypoints.

pub mod card;
pub mod consistency;
pub mod early_gather;
pub mod estimator;
pub mod fold;
pub mod preprocess;
pub mod rewrite;

pub use card::ModelCard;
pub use estimator::{InstanceOutcome, PoseEstimate, PoseEstimator, PreparedFrame, Skipped};
