//! The camera configuration JSON (`--camera-config`): devices, formats, intrinsics,
//! depth-to-colour registration.

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("camera.json", data);
    let _ = tricons::capture::registration::CameraConfig::read(&path);
}
