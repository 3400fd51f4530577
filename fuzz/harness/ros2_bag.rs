//! ROS 2 bags (`--recording BAG.mcap`): the MCAP container (records, chunks in any
//! compression) and the CDR messages in it (images, camera info).

use tricons::recording::{BagTopics, McapBag, Recording};

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("fuzz.mcap", data);
    let topics = BagTopics { color: "/c".into(), depth: "/d".into(), camera_info: "/i".into(), ..BagTopics::default() };
    if let Ok(bag) = McapBag::open(&path, &topics) {
        // the last frame first (a restart of the stream), then in order; a few at most
        let n = bag.len().min(4);
        for i in std::iter::once(n.saturating_sub(1)).chain(0..n) {
            let _ = bag.read_frame(i);
        }
    }
}
