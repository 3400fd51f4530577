//! tricons: category-level 6D object pose estimation on edge boards.
//!
//! The modules follow the data: [`frame`] (RGB-D frames and intrinsics) and
//! [`recording`] (on-disk recordings, NOCS dataset layout) feed the pose
//! pipeline; [`output`] holds the predictions format every producer emits;
//! [`metrics`] scores predictions with the NOCS protocol; [`synth`] renders the
//! SynthNOCS benchmark. [`geometry`] and [`category`] are shared vocabulary.

pub mod atomic;
pub mod category;
pub mod error;
pub mod frame;
pub mod geometry;
pub mod image_io;
pub mod metrics;
pub mod output;
pub mod recording;
pub mod synth;

pub use category::Category;
pub use error::{Error, Result};
pub use frame::{ColorImage, DepthImage, Intrinsics, LabelImage, NocsMap, RgbdFrame};
pub use geometry::Pose;
