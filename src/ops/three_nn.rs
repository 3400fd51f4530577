//! `ThreeNN` and `ThreeInterpolate`: inverse-distance feature propagation.

pub mod kernel;
