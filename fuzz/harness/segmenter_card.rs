//! The segmenter card (`*.card.json` beside a Mask R-CNN graph).

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("seg.card.json", data);
    if let Ok(card) = tricons::segment::SegmenterCard::read(&path) {
        for label in [-1, 0, 1, 6, i64::MAX] {
            let _ = card.category(label);
        }
    }
}
