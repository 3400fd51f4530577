//! PNG decoding through image_io: the size check before allocation, every reader.

use tricons::image_io::{self, SizeLimit};

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("input.png", data);
    let _ = image_io::read_png(&path, SizeLimit::Capped);
    let _ = image_io::read_color_png(&path, SizeLimit::Exactly { width: 64, height: 48, source: "fuzz" });
    let _ = image_io::read_depth_png(&path, 0.001, SizeLimit::Capped);
    let _ = image_io::read_label_png(&path, SizeLimit::Capped);
    let _ = image_io::read_nocs_png(&path, SizeLimit::Capped);
}
