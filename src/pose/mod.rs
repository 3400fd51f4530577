//! TriCons-Pose inference: inputs from frames and masks, the exported graph in tract.

pub mod preprocess;
