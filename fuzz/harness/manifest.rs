//! A recording's manifest.json: parsing, validation, then every frame it lists read
//! (the files are missing or garbage: errors, never a panic).

use tricons::recording::open_recording;

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let dir = crate::scratch::dir().join("manifest");
    std::fs::create_dir_all(&dir).expect("scratch recording");
    std::fs::write(dir.join("manifest.json"), data).expect("writing the manifest");
    if let Ok(rec) = open_recording(&dir) {
        for i in 0..rec.len().min(4) {
            let _ = rec.frame_id(i);
            let _ = rec.read_frame(i);
            let _ = rec.read_annotations(i);
        }
        let _ = rec.describe();
    }
}
