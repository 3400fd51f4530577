//! A NOCS-layout frame's `<id>_meta.txt` (instance id, class id, model name per line)
//! against a valid 4x3 frame: instance recovery from mask, NOCS map and depth.

use tricons::recording::{NocsLayout, Recording};

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let dir = crate::tiny_frame::nocs_scene();
    std::fs::write(dir.join("0000_meta.txt"), data).expect("writing the meta file");
    if let Ok(scene) = NocsLayout::open(&dir, Some(crate::tiny_frame::INTRINSICS)) {
        let _ = scene.read_instances(0);
        let _ = scene.read_annotations(0);
    }
}
