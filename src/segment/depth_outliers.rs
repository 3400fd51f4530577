//! Depth outliers of a predicted mask: where a segmenter's mask spills over an object's
//! silhouette, its pixels see the table or the wall behind, often tens of centimetres away.
//! No point of an object lies farther from the median of its visible points than the
//! object's diagonal, so a per-category radius of the largest objects' size separates them
//! (tools/MODEL.md, E9).

use crate::frame::{DepthImage, Intrinsics};

/// `mask` without the pixels whose back-projected point lies farther than `radius_m` from
/// the median point of the mask's pixels with depth (the per-axis median, in f64). Pixels
/// without depth stay as they are (the pose stage never samples them). The mask is
/// returned unchanged when fewer than a quarter of its pixels with depth would remain (the
/// median then sits on the background, not on the object), when it has no pixel with depth,
/// or when its size is not the depth image's.
pub fn drop_far_pixels(mask: Vec<bool>, depth: &DepthImage, intrinsics: &Intrinsics, radius_m: f64) -> Vec<bool> {
    let width = depth.width as usize;
    if mask.len() != depth.data.len() || width == 0 {
        return mask;
    }
    let point = |i: usize| -> [f64; 3] {
        let (v, u) = ((i / width) as f64, (i % width) as f64);
        let z = depth.data[i] as f64 * depth.depth_scale_m;
        [(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z]
    };
    let valid: Vec<usize> = (0..mask.len()).filter(|&i| mask[i] && depth.data[i] > 0).collect();
    if valid.is_empty() {
        return mask;
    }
    let points: Vec<[f64; 3]> = valid.iter().map(|&i| point(i)).collect();
    let centre = median_point(&points);
    let far: Vec<usize> = valid
        .iter()
        .zip(&points)
        .filter(|(_, p)| distance_sq(p, &centre) > radius_m * radius_m)
        .map(|(&i, _)| i)
        .collect();
    if 4 * (valid.len() - far.len()) < valid.len() {
        return mask;
    }
    let mut out = mask;
    for i in far {
        out[i] = false;
    }
    out
}

/// Per-axis median of `points` (non-empty): the upper middle value of each axis, sorted.
fn median_point(points: &[[f64; 3]]) -> [f64; 3] {
    let mut axis = Vec::with_capacity(points.len());
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        axis.clear();
        axis.extend(points.iter().map(|p| p[k]));
        let mid = axis.len() / 2;
        let (_, m, _) = axis.select_nth_unstable_by(mid, f64::total_cmp);
        *o = *m;
    }
    out
}

fn distance_sq(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intrinsics(w: u32, h: u32) -> Intrinsics {
        Intrinsics { width: w, height: h, fx: 500.0, fy: 500.0, cx: w as f64 / 2.0, cy: h as f64 / 2.0 }
    }

    /// A 40x30 frame: an object at 1.00 m (columns 10..26), a wall behind it at 1.60 m, a
    /// mask over the object plus a 2-pixel rim on the wall and a hole without depth.
    fn scene() -> (DepthImage, Vec<bool>, Vec<bool>) {
        let (w, h) = (40usize, 30usize);
        let mut depth = DepthImage::new(w as u32, h as u32, 0.001);
        let (mut mask, mut object) = (vec![false; w * h], vec![false; w * h]);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let on = (10..26).contains(&x) && (8..22).contains(&y);
                depth.data[i] = if on { 1000 + (x as u16 % 3) } else { 1600 };
                object[i] = on;
                mask[i] = (8..26).contains(&x) && (6..24).contains(&y);
            }
        }
        depth.data[15 * w + 15] = 0;
        (depth, mask, object)
    }

    #[test]
    fn background_rim_goes_and_the_object_stays() {
        let (depth, mask, object) = scene();
        let out = drop_far_pixels(mask.clone(), &depth, &intrinsics(40, 30), 0.2);
        for i in 0..mask.len() {
            let want = object[i] || (mask[i] && depth.data[i] == 0);
            assert_eq!(out[i], want, "pixel {i}");
        }
    }

    #[test]
    fn a_radius_larger_than_the_gap_or_a_mask_mostly_on_background_keeps_the_mask() {
        let (depth, mask, _) = scene();
        assert_eq!(drop_far_pixels(mask.clone(), &depth, &intrinsics(40, 30), 1.0), mask);
        // a mask of one object pixel and many wall pixels: the median is on the wall, and
        // dropping what is far from it would keep less than a quarter
        let w = 40;
        let mut wall = vec![false; mask.len()];
        wall[..w * 5].iter_mut().for_each(|m| *m = true);
        wall[15 * w + 12] = true;
        let out = drop_far_pixels(wall.clone(), &depth, &intrinsics(40, 30), 0.2);
        assert!(!out[15 * w + 12], "the lone object pixel is the outlier here");
        let mut mostly_far = vec![false; mask.len()];
        for (i, m) in mostly_far.iter_mut().enumerate() {
            let (y, x) = (i / w, i % w);
            // 16x14 object pixels (224) against 3 wall columns x 30 rows (90): the median is on
            // the object; a tiny radius leaves less than a quarter of the pixels
            *m = ((10..26).contains(&x) && (8..22).contains(&y)) || x < 3;
        }
        assert_eq!(drop_far_pixels(mostly_far.clone(), &depth, &intrinsics(40, 30), 1e-4), mostly_far);
    }

    #[test]
    fn masks_without_depth_or_of_another_size_are_left_alone() {
        let (depth, mask, _) = scene();
        let none = vec![false; mask.len()];
        assert_eq!(drop_far_pixels(none.clone(), &depth, &intrinsics(40, 30), 0.2), none);
        let short = vec![true; 7];
        assert_eq!(drop_far_pixels(short.clone(), &depth, &intrinsics(40, 30), 0.2), short);
    }

    #[test]
    fn median_point_is_the_upper_middle_per_axis() {
        let p = [[3.0, 0.0, 1.0], [1.0, 5.0, 2.0], [2.0, 1.0, 9.0], [4.0, 2.0, 0.5]];
        assert_eq!(median_point(&p), [3.0, 2.0, 2.0]);
    }
}
