//! ROS 2 interoperability (feature `ros2`; pure Rust, no ROS installation).
//!
//! - [`msg`]: the messages, as serde structs in wire order;
//! - [`cdr`]: their CDR payloads (the 4-byte encapsulation header + classic CDR, little endian);
//! - [`schema`]: the `ros2msg` schema texts MCAP files carry;
//! - [`convert`]: tricons results as `vision_msgs/Detection3DArray`, RViz markers and images.
//!
//! The sources and sinks built on them sit with the others: ROS 2 bags are read by
//! [`crate::recording::McapBag`] (a [`crate::recording::Recording`], so `replay` and `serve`
//! read them like any recording), and results leave through [`crate::output::mcap_sink`] and
//! [`crate::output::ros2_sink`] ([`crate::output::sink::Sink`]s).

pub mod cdr;
pub mod convert;
pub mod msg;
pub mod schema;
