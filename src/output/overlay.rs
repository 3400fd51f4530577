//! Overlay images: each estimated instance's 3D box and axes projected on the colour
//! frame, with a class and score label.

use crate::category::Category;
use crate::error::Result;
use crate::frame::{ColorImage, Intrinsics, RgbdFrame};
use crate::geometry::Vec3;
use crate::image_io::encode_png;
use crate::output::predictions::PredInstance;

/// Points closer to the camera than this are not drawn (metres).
const MIN_DEPTH_M: f64 = 1e-3;
/// Axis length as a share of the largest box side.
const AXIS_SHARE: f64 = 0.6;
/// Label glyphs are drawn this many pixels per font pixel.
const TEXT_SCALE: usize = 2;

/// Box colour of each category.
pub fn class_color(c: Category) -> [u8; 3] {
    match c {
        Category::Bottle => [255, 140, 0],
        Category::Bowl => [0, 200, 255],
        Category::Camera => [255, 0, 255],
        Category::Can => [0, 230, 0],
        Category::Laptop => [255, 255, 0],
        Category::Mug => [255, 70, 70],
    }
}

/// Draw `instances` over a copy of the frame's colour image; returns PNG bytes.
pub fn draw_overlay(frame: &RgbdFrame, instances: &[PredInstance]) -> Result<Vec<u8>> {
    let img = overlay_image(frame, instances);
    encode_png(img.width, img.height, png::ColorType::Rgb, png::BitDepth::Eight, &img.data)
}

/// `instances` drawn over a copy of the frame's colour image.
pub fn overlay_image(frame: &RgbdFrame, instances: &[PredInstance]) -> ColorImage {
    let mut img = frame.color.clone();
    for inst in instances {
        draw_instance(&mut img, &frame.intrinsics, inst);
    }
    img
}

/// The 8 corners of an instance's box in the camera frame; corner `i` has the sign of
/// half-size axis `a` given by bit `a` of `i` (set: +), so corners `i` and `i | 1 << a` share an edge.
pub fn box_corners(inst: &PredInstance) -> [Vec3; 8] {
    let half = Vec3::new(inst.size_m[0], inst.size_m[1], inst.size_m[2]) / 2.0;
    std::array::from_fn(|i| {
        let sign = |bit: usize| if i >> bit & 1 == 1 { 1.0 } else { -1.0 };
        inst.camera_from_object.transform_point(&Vec3::new(sign(0) * half.x, sign(1) * half.y, sign(2) * half.z))
    })
}

/// The 12 edges of a box as pairs of corner indices of [`box_corners`].
pub fn box_edges() -> impl Iterator<Item = (usize, usize)> {
    (0..8usize).flat_map(|a| (0..3).map(move |bit| (a, a | (1 << bit)))).filter(|(a, b)| a != b)
}

/// Box edges (12) and axes (x red, y green, z blue) of one instance, and its label.
pub fn draw_instance(img: &mut ColorImage, k: &Intrinsics, inst: &PredInstance) {
    let pose = &inst.camera_from_object;
    let corners = box_corners(inst);
    let color = class_color(inst.class);
    for (a, b) in box_edges() {
        draw_segment(img, k, &corners[a], &corners[b], color);
    }
    let len = AXIS_SHARE * inst.size_m.iter().copied().fold(0.0, f64::max);
    let origin = pose.translation_m;
    for (axis, rgb) in [[255, 0, 0], [0, 255, 0], [0, 0, 255]].into_iter().enumerate() {
        let end = origin + pose.rotation.column(axis) * len;
        draw_segment(img, k, &origin, &end, rgb);
    }
    // label above the highest projected corner
    let projected: Vec<(f64, f64)> = corners.iter().filter(|p| p.z > MIN_DEPTH_M).map(|p| k.project(p)).collect();
    if let Some(&(u, v)) = projected.iter().min_by(|a, b| a.1.total_cmp(&b.1)) {
        let text = format!("{} {:.2}", inst.class.name(), inst.score);
        let y = (v - (GLYPH_H * TEXT_SCALE + 4) as f64).max(0.0);
        draw_text(img, u.max(0.0) as usize, y as usize, &text, color);
    }
}

fn put(img: &mut ColorImage, x: i64, y: i64, rgb: [u8; 3]) {
    if x >= 0 && y >= 0 && (x as u32) < img.width && (y as u32) < img.height {
        let i = (y as usize * img.width as usize + x as usize) * 3;
        img.data[i..i + 3].copy_from_slice(&rgb);
    }
}

/// A 2-pixel-wide projected segment; skipped if an end is behind the camera.
fn draw_segment(img: &mut ColorImage, k: &Intrinsics, a: &Vec3, b: &Vec3, rgb: [u8; 3]) {
    if a.z <= MIN_DEPTH_M || b.z <= MIN_DEPTH_M {
        return;
    }
    let (pa, pb) = (k.project(a), k.project(b));
    let steps = ((pb.0 - pa.0).abs().max((pb.1 - pa.1).abs()).ceil() as usize).clamp(1, 4 * 4096);
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        let (x, y) = (pa.0 + t * (pb.0 - pa.0), pa.1 + t * (pb.1 - pa.1));
        let (x, y) = (x.round() as i64, y.round() as i64);
        put(img, x, y, rgb);
        put(img, x + 1, y, rgb);
    }
}

const GLYPH_W: usize = 5;
const GLYPH_H: usize = 7;

/// 5x7 glyphs (rows top to bottom, bit 4 = left column) for a-z, 0-9, '.' and space.
fn glyph(c: char) -> [u8; GLYPH_H] {
    match c.to_ascii_lowercase() {
        'a' => [0, 0, 14, 1, 15, 17, 15],
        'b' => [16, 16, 30, 17, 17, 17, 30],
        'c' => [0, 0, 14, 16, 16, 17, 14],
        'd' => [1, 1, 15, 17, 17, 17, 15],
        'e' => [0, 0, 14, 17, 31, 16, 14],
        'f' => [6, 9, 8, 28, 8, 8, 8],
        'g' => [0, 15, 17, 17, 15, 1, 14],
        'h' => [16, 16, 22, 25, 17, 17, 17],
        'i' => [4, 0, 12, 4, 4, 4, 14],
        'j' => [2, 0, 6, 2, 2, 18, 12],
        'k' => [16, 16, 18, 20, 24, 20, 18],
        'l' => [12, 4, 4, 4, 4, 4, 14],
        'm' => [0, 0, 26, 21, 21, 17, 17],
        'n' => [0, 0, 22, 25, 17, 17, 17],
        'o' => [0, 0, 14, 17, 17, 17, 14],
        'p' => [0, 0, 30, 17, 30, 16, 16],
        'q' => [0, 0, 13, 19, 15, 1, 1],
        'r' => [0, 0, 22, 25, 16, 16, 16],
        's' => [0, 0, 14, 16, 14, 1, 30],
        't' => [8, 8, 28, 8, 8, 9, 6],
        'u' => [0, 0, 17, 17, 17, 19, 13],
        'v' => [0, 0, 17, 17, 17, 10, 4],
        'w' => [0, 0, 17, 17, 21, 21, 10],
        'x' => [0, 0, 17, 10, 4, 10, 17],
        'y' => [0, 0, 17, 17, 15, 1, 14],
        'z' => [0, 0, 31, 2, 4, 8, 31],
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        _ => [0; GLYPH_H],
    }
}

/// Text on a black box at `(x, y)` (top-left), clipped to the image.
pub fn draw_text(img: &mut ColorImage, x: usize, y: usize, text: &str, rgb: [u8; 3]) {
    let (cw, ch) = ((GLYPH_W + 1) * TEXT_SCALE, (GLYPH_H + 2) * TEXT_SCALE);
    let width = cw * text.chars().count() + TEXT_SCALE;
    for dy in 0..ch {
        for dx in 0..width {
            put(img, (x + dx) as i64, (y + dy) as i64, [0, 0, 0]);
        }
    }
    for (n, c) in text.chars().enumerate() {
        let g = glyph(c);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..GLYPH_W {
                if bits >> (GLYPH_W - 1 - col) & 1 == 1 {
                    for sy in 0..TEXT_SCALE {
                        for sx in 0..TEXT_SCALE {
                            let px = x + TEXT_SCALE + n * cw + col * TEXT_SCALE + sx;
                            let py = y + TEXT_SCALE + row * TEXT_SCALE + sy;
                            put(img, px as i64, py as i64, rgb);
                        }
                    }
                }
            }
        }
    }
}
