//! A frame's ground-truth JSON (`<id>_gt.json`) in a valid one-frame recording, with
//! the mask and NOCS images it may name (path checks, sizes, instance validation).

use tricons::recording::open_recording;

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let dir = crate::tiny_frame::recording();
    std::fs::write(dir.join("000000_gt.json"), data).expect("writing the annotations");
    if let Ok(rec) = open_recording(&dir) {
        let _ = rec.read_instances(0);
        if let Ok(Some(ann)) = rec.read_annotations(0) {
            let _ = ann.instance_masks();
        }
    }
}
