#![no_main]
//! Fuzz target: see fuzz/harness/ros2_bag.rs.
#[path = "../harness/ros2_bag.rs"]
mod harness;
#[path = "../harness/scratch.rs"]
mod scratch;
#[path = "../harness/tiny_frame.rs"]
mod tiny_frame;

libfuzzer_sys::fuzz_target!(|data: &[u8]| harness::run(data));
