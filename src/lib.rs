//! tricons: category-level 6D object pose estimation on edge boards.
//!
//! The modules follow the data: [`capture`] (V4L2 cameras, decoding, pairing,
//! registration, recording replay), [`frame`] (RGB-D frames and intrinsics) and
//! [`recording`] (on-disk recordings, NOCS dataset layout) feed [`segment`]
//! (Mask R-CNN) and [`pose`] (TriCons-Pose), which [`pipeline`] runs as a
//! threaded service; [`output`] holds the predictions format every producer emits;
//! [`metrics`] scores predictions with the NOCS protocol; [`synth`] renders the
//! SynthNOCS benchmark. [`geometry`] and [`category`] are shared vocabulary; `ros2`
//! (feature `ros2`) holds the ROS 2 messages that bags, MCAP outputs and DDS topics carry.
//!
//! # Example
//!
//! Render a small SynthNOCS recording, read it back, and score its ground
//! truth as if it were a perfect estimator's output:
//!
//! ```
//! use tricons::metrics::{EvalConfig, IouMode, evaluate};
//! use tricons::output::PredInstance;
//! use tricons::recording::open_recording;
//! use tricons::synth::{SynthConfig, generate};
//!
//! # fn main() -> tricons::Result<()> {
//! let dir = tempfile::tempdir().map_err(|e| tricons::Error::io("tempdir", e))?;
//! generate(dir.path(), &SynthConfig::default(), 7, 2, false, &|_| {})?;
//!
//! let rec = open_recording(dir.path())?;
//! let frame = rec.read_frame(0)?; // colour, depth (metres via depth_scale_m), intrinsics
//! assert_eq!((frame.color.width, frame.color.height), (640, 480));
//!
//! let mut gts = Vec::new();
//! for i in 0..rec.len() {
//!     gts.push(rec.read_instances(i)?.unwrap_or_default());
//! }
//! let preds: Vec<Vec<PredInstance>> =
//!     gts.iter().map(|g| g.iter().map(PredInstance::from_ground_truth).collect()).collect();
//! let report = evaluate(
//!     gts.iter().zip(&preds).map(|(g, p)| (g.as_slice(), p.as_slice())),
//!     &EvalConfig::standard(IouMode::Corrected),
//! );
//! assert_eq!(report.mean("5deg2cm"), Some(100.0));
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod atomic;
pub mod capture;
pub mod category;
pub mod error;
pub mod frame;
pub mod geometry;
pub mod image_io;
pub mod metrics;
pub mod ops;
pub mod output;
pub mod pipeline;
pub mod pose;
pub mod quant;
pub mod recording;
pub mod rng;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod segment;
pub mod synth;
pub mod workers;

pub use category::Category;
pub use error::{Error, Result};
pub use frame::{ColorImage, DepthImage, Intrinsics, LabelImage, NocsMap, RgbdFrame};
pub use geometry::Pose;
