//! Capture: raw V4L2 buffers decoded against fixtures, the hand-written V4L2
//! ABI against the kernel headers, and depth-to-colour registration and
//! colour/depth pairing against SynthNOCS ground truth. One test binary (each
//! binary links the whole runtime; CI builds them twice).

mod common;

#[path = "capture/decode.rs"]
mod decode;
#[path = "capture/registration.rs"]
mod registration;
#[path = "capture/v4l2_abi.rs"]
mod v4l2_abi;
