//! The V4L2 buffer decoders (YUYV, MJPG, RGB3, Z16). The first bytes pick the format and
//! a small frame size (a driver negotiates the size; the buffer is the untrusted part).

use tricons::capture::decode::{PixelFormat, decode_color, decode_depth_z16};

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let [f, w, h, pad, rest @ ..] = data else { return };
    let (width, height) = (u32::from(*w % 64) + 1, u32::from(*h % 48) + 1);
    let format = [PixelFormat::Yuyv, PixelFormat::Mjpg, PixelFormat::Rgb3, PixelFormat::Z16][usize::from(*f % 4)];
    let bytes_per_pixel = match format {
        PixelFormat::Rgb3 => 3,
        PixelFormat::Mjpg => 0,
        _ => 2,
    };
    let bytes_per_line = width * bytes_per_pixel + u32::from(*pad % 8);
    match format {
        PixelFormat::Z16 => {
            if let Ok(depth) = decode_depth_z16(rest, width, height, bytes_per_line) {
                assert_eq!(depth.len(), (width * height) as usize);
            }
        }
        _ => {
            if let Ok(img) = decode_color(format, rest, width, height, bytes_per_line) {
                assert_eq!(img.data.len(), (img.width * img.height * 3) as usize);
            }
        }
    }
}
