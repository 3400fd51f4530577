//! RealSense-like sensor model: depth noise, quantisation, range limits and
//! dropouts, plus colour noise. See docs/synthnocs.md for the model.

use super::raster::GBuffer;
use super::rng::Rng;
use crate::frame::{ColorImage, DepthImage};

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
/// A depth jump to a 4-neighbour larger than this fraction of z marks an edge.
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
    let z = &gb.depth_m;
    let far = |v: f32| if v > 0.0 { v } else { 100.0 };
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            let zi = z[i];
            if zi <= 0.0 {
                continue;
            }
            let zc = far(zi);
            let thr = EDGE_JUMP_REL * zc;
            let jump = |j: usize| (far(z[j]) - zc).abs() > thr;
            let near_edge = (u > 0 && jump(i - 1))
                || (u + 1 < w && jump(i + 1))
                || (v > 0 && jump(i - w))
                || (v + 1 < h && jump(i + w));
            let near_edge2 = (u > 1 && jump(i - 2)) || (u + 2 < w && jump(i + 2));
            let r = rng.uniform();
            if (near_edge && r < EDGE_DROPOUT_P)
                || (near_edge2 && r < EDGE_DROPOUT_P2)
                || (gb.albedo_luma[i] < DARK_LUMA && r < DARK_DROPOUT_P)
                || (gb.specular[i] > SPECULAR_LIMIT && r < SPECULAR_DROPOUT_P)
            {
                continue;
            }
            let sigma = NOISE_SIGMA0_M + NOISE_SIGMA_Z2_PER_M * zi * zi;
            img.data[i] = quantize(zi + sigma * rng.approx_normal());
        }
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

/// The 8-bit colour image, with mild Gaussian-like noise when `rng` is given.
pub fn color_image(gb: &GBuffer, mut rng: Option<&mut Rng>) -> ColorImage {
    let mut img = ColorImage::new(gb.width as u32, gb.height as u32);
    for (o, c) in img.data.chunks_exact_mut(3).zip(&gb.color) {
        for k in 0..3 {
            let n = rng.as_deref_mut().map_or(0.0, |r| COLOR_NOISE_LEVELS * r.approx_normal());
            o[k] = (c[k] * 255.0 + n).round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}
