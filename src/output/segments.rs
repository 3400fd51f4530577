//! Segmentation results: JSON Lines records with run-length masks, label images and
//! mask overlays (what `tricons segment` writes).

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::frame::{ColorImage, LabelImage};
use crate::image_io::encode_png;
use crate::output::overlay::{class_color, draw_text};
use crate::segment::SegInstance;

/// Colour of instances whose label has no NOCS category.
const OTHER_COLOR: [u8; 3] = [200, 200, 200];
/// Weight of the instance colour when tinting mask pixels.
const MASK_TINT: f32 = 0.5;

/// One instance of a segmentation record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegRecordInstance {
    /// The model's label id.
    pub label: i64,
    /// The card's class name, when it maps the label.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub class: Option<String>,
    /// Detection score.
    pub score: f32,
    /// `[x0, y0, x1, y1]` in pixels.
    #[serde(rename = "box")]
    pub box_xyxy: [f32; 4],
    /// Mask pixel count.
    pub pixels: usize,
    /// Row-major run lengths of the mask, starting with a background run ([`mask_to_rle`]).
    pub mask_rle: Vec<u32>,
}

/// All instances of one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegRecord {
    /// Frame id.
    pub frame: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Instances in score order.
    pub instances: Vec<SegRecordInstance>,
}

impl SegRecord {
    /// The record of `instances` on a `width x height` frame.
    pub fn new(frame: &str, width: u32, height: u32, instances: &[SegInstance]) -> SegRecord {
        SegRecord {
            frame: frame.to_string(),
            width,
            height,
            instances: instances
                .iter()
                .map(|i| SegRecordInstance {
                    label: i.label,
                    class: i.class_name.clone(),
                    score: i.score,
                    box_xyxy: i.box_xyxy,
                    pixels: i.mask_pixels(),
                    mask_rle: mask_to_rle(&i.mask),
                })
                .collect(),
        }
    }
}

/// Run lengths of a row-major binary mask, alternating background / foreground and
/// starting with a (possibly empty) background run.
pub fn mask_to_rle(mask: &[bool]) -> Vec<u32> {
    let mut runs = Vec::new();
    let (mut current, mut len) = (false, 0u32);
    for &m in mask {
        if m != current {
            runs.push(len);
            current = m;
            len = 0;
        }
        len += 1;
    }
    runs.push(len);
    runs
}

/// Decode [`mask_to_rle`]; `None` if the runs do not add up to `pixels`.
pub fn rle_to_mask(runs: &[u32], pixels: usize) -> Option<Vec<bool>> {
    let mut mask = Vec::with_capacity(pixels);
    for (k, &r) in runs.iter().enumerate() {
        mask.extend(std::iter::repeat_n(k % 2 == 1, r as usize));
    }
    (mask.len() == pixels).then_some(mask)
}

/// A label image: pixel = 1 + index of the highest-scoring instance covering it (0 = none).
/// At most 255 instances are labelled.
pub fn label_image(width: u32, height: u32, instances: &[SegInstance]) -> LabelImage {
    let mut img = LabelImage::new(width, height);
    for (k, inst) in instances.iter().enumerate().take(255).rev() {
        for (px, &m) in img.data.iter_mut().zip(&inst.mask) {
            if m {
                *px = k as u8 + 1;
            }
        }
    }
    img
}

/// Masks tinted in their class colour, boxes and "class score" labels over `image`; PNG bytes.
pub fn draw_segments(image: &ColorImage, instances: &[SegInstance]) -> Result<Vec<u8>> {
    let mut img = image.clone();
    let w = img.width as usize;
    for inst in instances.iter().rev() {
        let color = inst.category.map(class_color).unwrap_or(OTHER_COLOR);
        for (k, _) in inst.mask.iter().enumerate().filter(|(_, m)| **m) {
            for (v, &c) in img.data[k * 3..k * 3 + 3].iter_mut().zip(&color) {
                *v = ((1.0 - MASK_TINT) * *v as f32 + MASK_TINT * c as f32).round() as u8;
            }
        }
        let [x0, y0, x1, y1] = inst.box_xyxy.map(|v| v.max(0.0) as usize);
        let (x1, y1) = (x1.min(w.saturating_sub(1)), y1.min(img.height as usize - 1));
        for x in x0.min(x1)..=x1 {
            for y in [y0.min(y1), y1] {
                img.data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&color);
            }
        }
        for y in y0.min(y1)..=y1 {
            for x in [x0.min(x1), x1] {
                img.data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&color);
            }
        }
        let name = inst.class_name.clone().unwrap_or_else(|| format!("label{}", inst.label));
        draw_text(&mut img, x0, y0.saturating_sub(20), &format!("{name} {:.2}", inst.score), color);
    }
    encode_png(img.width, img.height, png::ColorType::Rgb, png::BitDepth::Eight, &img.data)
}
