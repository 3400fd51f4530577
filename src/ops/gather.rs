//! `GatherPoints` and `GroupPoints`: feature gathers by point index.

pub mod kernel;
