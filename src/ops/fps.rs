//! `FurthestPointSample`: greedy farthest point sampling.

pub mod kernel;
