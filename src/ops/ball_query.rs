//! `BallQuery`: the first neighbours within a radius.

pub mod kernel;
