//! A valid 4x3 frame on disk (colour, depth, a label image with instances 1 and 2, a
//! NOCS map) for the targets that fuzz one file beside it.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::OnceLock;
use tricons::frame::{ColorImage, DepthImage, Intrinsics, LabelImage, NocsMap};
use tricons::image_io;

/// The frame size.
pub const INTRINSICS: Intrinsics = Intrinsics { width: 4, height: 3, fx: 4.0, fy: 4.0, cx: 2.0, cy: 1.5 };

fn write_images(dir: &std::path::Path, prefix: &str) {
    let (w, h) = (INTRINSICS.width, INTRINSICS.height);
    let n = (w * h) as usize;
    let color = ColorImage { width: w, height: h, data: (0..3 * n).map(|i| (i * 17) as u8).collect() };
    let depth =
        DepthImage { width: w, height: h, data: (0..n).map(|i| 500 + i as u16).collect(), depth_scale_m: 0.001 };
    let label = LabelImage { width: w, height: h, data: (0..n).map(|i| (i % 3) as u8).collect() };
    let nocs = NocsMap { width: w, height: h, data: (0..3 * n).map(|i| (i * 4099) as u16).collect() };
    image_io::write_color_png(&dir.join(format!("{prefix}_color.png")), &color).expect("colour");
    image_io::write_depth_png(&dir.join(format!("{prefix}_depth.png")), &depth).expect("depth");
    image_io::write_label_png(&dir.join(format!("{prefix}_mask.png")), &label).expect("mask");
    image_io::write_nocs_png(&dir.join(format!("{prefix}_coord.png")), &nocs).expect("nocs");
}

/// A tricons recording of that one frame (`000000`, annotations `000000_gt.json`).
pub fn recording() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = crate::scratch::dir().join("tiny-recording");
        std::fs::create_dir_all(&dir).expect("scratch recording");
        write_images(&dir, "000000");
        let mut manifest = tricons::recording::Manifest::new(INTRINSICS, 0.001);
        manifest.frames.push(tricons::recording::manifest::FrameEntry {
            id: "000000".into(),
            timestamp_s: 0.0,
            color: "000000_color.png".into(),
            depth: "000000_depth.png".into(),
            annotations: Some("000000_gt.json".into()),
        });
        std::fs::write(dir.join("manifest.json"), manifest.to_json()).expect("manifest");
        dir
    })
    .clone()
}

/// A NOCS-layout scene of that one frame (`0000_*`; the meta file is the caller's).
pub fn nocs_scene() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = crate::scratch::dir().join("tiny-nocs");
        std::fs::create_dir_all(&dir).expect("scratch scene");
        write_images(&dir, "0000");
        dir
    })
    .clone()
}
