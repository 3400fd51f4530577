//! Shared helpers of the integration tests.
#![allow(dead_code)] // each test crate uses part of the helpers
pub mod cli;
pub mod npy;
