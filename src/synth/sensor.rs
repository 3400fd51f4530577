//! RealSense-like sensor model: depth noise, quantisation, range limits and
//! dropouts, plus colour noise. See docs/synthnocs.md for the model.

use super::raster::GBuffer;
use crate::frame::{ColorImage, DepthImage};
use crate::rng::Rng;

/// Closest measurable depth, metres.
pub const MIN_DEPTH_M: f32 = 0.2;
/// Farthest measurable depth, metres.
pub const MAX_DEPTH_M: f32 = 3.0;
/// Depth PNG unit, metres (millimetres).
pub const DEPTH_UNIT_M: f32 = 0.001;
/// Axial noise: sigma(z) = `NOISE_SIGMA0_M` + `NOISE_SIGMA_Z2_PER_M` * z^2.
pub const NOISE_SIGMA0_M: f32 = 0.0004;
/// See [`NOISE_SIGMA0_M`] (metres of sigma per square metre of depth).
pub const NOISE_SIGMA_Z2_PER_M: f32 = 0.0012;
/// Depth assumed where nothing was hit (for edge detection), metres.
const FAR_M: f32 = 100.0;
/// A depth jump to a 4-neighbour larger than this fraction of the nearer depth marks an edge.
pub const EDGE_JUMP_REL: f32 = 0.03;
/// Dropout probability of pixels next to a depth edge.
pub const EDGE_DROPOUT_P: f64 = 0.55;
/// Dropout probability of pixels two pixels (horizontally) from an edge.
pub const EDGE_DROPOUT_P2: f64 = 0.2;
/// Most random blob dropouts per frame.
pub const MAX_BLOBS: usize = 6;
/// Blob radius range, pixels.
pub const BLOB_RADIUS_PX: (f64, f64) = (1.5, 5.0);
/// Surfaces with albedo luminance below this lose depth with [`DARK_DROPOUT_P`].
pub const DARK_LUMA: f32 = 0.06;
/// Dropout probability on dark surfaces.
pub const DARK_DROPOUT_P: f64 = 0.35;
/// Pixels whose specular term exceeds this lose depth with [`SPECULAR_DROPOUT_P`].
pub const SPECULAR_LIMIT: f32 = 0.45;
/// Dropout probability on specular highlights.
pub const SPECULAR_DROPOUT_P: f64 = 0.5;
/// Colour noise standard deviation, 8-bit levels.
pub const COLOR_NOISE_LEVELS: f32 = 1.5;

fn quantize(z: f32) -> u16 {
    if (MIN_DEPTH_M..=MAX_DEPTH_M).contains(&z) { (z / DEPTH_UNIT_M).round() as u16 } else { 0 }
}

/// The depth image: exact depth quantised to mm (no noise), or with the full
/// sensor model when `noise` is set.
pub fn depth_image(gb: &GBuffer, noise: bool, rng: &mut Rng) -> DepthImage {
    let (w, h) = (gb.width, gb.height);
    let mut img = DepthImage::new(w as u32, h as u32, f64::from(DEPTH_UNIT_M));
    if !noise {
        for (o, &z) in img.data.iter_mut().zip(&gb.depth_m) {
            *o = quantize(z);
        }
        return img;
    }
    // Edge flags: bit 0 = depth jump to a 4-neighbour, bit 1 = jump two pixels away horizontally.
    let z: Vec<f32> = gb.depth_m.iter().map(|&v| if v > 0.0 { v } else { FAR_M }).collect();
    let mut edge = vec![0u8; w * h];
    let jump = |a: f32, b: f32| (a - b).abs() > EDGE_JUMP_REL * a.min(b);
    for v in 0..h {
        let row = v * w;
        for u in 0..w {
            let i = row + u;
            if u + 1 < w && jump(z[i], z[i + 1]) {
                edge[i] |= 1;
                edge[i + 1] |= 1;
            }
            if u + 2 < w && jump(z[i], z[i + 2]) {
                edge[i] |= 2;
                edge[i + 2] |= 2;
            }
            if v + 1 < h && jump(z[i], z[i + w]) {
                edge[i] |= 1;
                edge[i + w] |= 1;
            }
        }
    }
    let p = |x: f64| (x * 4_294_967_296.0) as u64;
    let (p_edge, p_edge2, p_dark, p_spec) =
        (p(EDGE_DROPOUT_P), p(EDGE_DROPOUT_P2), p(DARK_DROPOUT_P), p(SPECULAR_DROPOUT_P));
    for (i, &zi) in gb.depth_m.iter().enumerate() {
        if zi <= 0.0 {
            continue;
        }
        let r = rng.next_u64() >> 32;
        let e = edge[i];
        if (e & 1 != 0 && r < p_edge)
            || (e & 2 != 0 && r < p_edge2)
            || (gb.albedo_luma[i] < DARK_LUMA && r < p_dark)
            || (gb.specular[i] > SPECULAR_LIMIT && r < p_spec)
        {
            continue;
        }
        let sigma = NOISE_SIGMA0_M + NOISE_SIGMA_Z2_PER_M * zi * zi;
        img.data[i] = quantize(zi + sigma * rng.approx_normal());
    }
    let blobs = rng.below(MAX_BLOBS + 1);
    for _ in 0..blobs {
        let (cu, cv) = (rng.range(0.0, w as f64), rng.range(0.0, h as f64));
        let r = rng.range(BLOB_RADIUS_PX.0, BLOB_RADIUS_PX.1);
        let (ax, ay) = (r * rng.range(0.6, 1.4), r * rng.range(0.6, 1.4));
        let (u0, u1) = ((cu - ax).floor().max(0.0) as usize, ((cu + ax).ceil() as usize).min(w - 1));
        let (v0, v1) = ((cv - ay).floor().max(0.0) as usize, ((cv + ay).ceil() as usize).min(h - 1));
        for v in v0..=v1 {
            for u in u0..=u1 {
                let (du, dv) = ((u as f64 - cu) / ax, (v as f64 - cv) / ay);
                if du * du + dv * dv <= 1.0 {
                    img.data[v * w + u] = 0;
                }
            }
        }
    }
    img
}

/// The 8-bit colour image, with mild noise (triangular, sigma [`COLOR_NOISE_LEVELS`]) when `rng` is given.
pub fn color_image(gb: &GBuffer, mut rng: Option<&mut Rng>) -> ColorImage {
    let mut img = ColorImage::new(gb.width as u32, gb.height as u32);
    for (o, c) in img.data.chunks_exact_mut(3).zip(&gb.color) {
        // One 64-bit draw per pixel: per channel the sum of two 10-bit uniforms
        // (triangular, mean 0, unit variance after scaling).
        let bits = rng.as_deref_mut().map_or(0, |r| r.next_u64());
        for k in 0..3 {
            let n = if rng.is_some() {
                let a = ((bits >> (20 * k)) & 0x3FF) as f32 + ((bits >> (20 * k + 10)) & 0x3FF) as f32;
                (a / 1023.0 - 1.0) * 2.449_489_7 * COLOR_NOISE_LEVELS
            } else {
                0.0
            };
            o[k] = (c[k] * 255.0 + n).round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}
