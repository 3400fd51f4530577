//! Mask erosion for the pose stage: a segmenter's masks are right inside and wrong at their
//! rim (a pixel or two of background or of a neighbour; tools/MODEL.md, E9), and the pose
//! network, trained on exact masks, moves its translation and size with every background
//! point. Eroding a detection's mask before the pose stage samples its points keeps the
//! interior, where the mask is right.
//!
//! The structuring element is the `(2r + 1) x (2r + 1)` square; pixels outside the image
//! count as mask, so an object cut by the image border is not eroded from the cut (as
//! `perturb_mask` in tools/tricons_pose/data.py treats its window).

/// `mask` (row-major, `width` columns) eroded by the `(2 radius + 1)`-square: a pixel stays
/// set when every pixel of the square around it that lies inside the image is set.
/// Separable (a horizontal then a vertical pass, each linear in its pixel count) and done
/// only over the mask's bounding box grown by `radius`: nothing outside it can stay set,
/// and nothing inside it sees farther.
///
/// A `width` of 0 or one that does not divide `mask.len()` leaves the mask as it is (there
/// is no image to erode).
pub fn erode_mask(mask: &[bool], width: usize, radius: usize) -> Vec<bool> {
    if radius == 0 || width == 0 || !mask.len().is_multiple_of(width) {
        return mask.to_vec();
    }
    let height = mask.len() / width;
    let mut out = vec![false; mask.len()];
    let Some((y0, y1, x0, x1)) = crate::pose::preprocess::mask_bbox(mask, width) else {
        return out;
    };
    let (y0, y1) = (y0.saturating_sub(radius), (y1 + radius).min(height));
    let (x0, x1) = (x0.saturating_sub(radius), (x1 + radius).min(width));
    let (w, h) = (x1 - x0, y1 - y0);
    // the window's edges inside the image are `radius` away from any set pixel, so treating
    // them as the image's edge changes only pixels that are unset anyway
    let mut rows = vec![false; w * h];
    let (mut line, mut prefix) = (Vec::with_capacity(w.max(h)), Vec::with_capacity(w.max(h) + 1));
    for (r, dst) in rows.chunks_exact_mut(w).enumerate() {
        line.clear();
        line.extend_from_slice(&mask[(y0 + r) * width + x0..(y0 + r) * width + x1]);
        erode_line(&line, radius, &mut prefix, |i, v| dst[i] = v);
    }
    for c in 0..w {
        line.clear();
        line.extend((0..h).map(|r| rows[r * w + c]));
        erode_line(&line, radius, &mut prefix, |r, v| out[(y0 + r) * width + x0 + c] = v);
    }
    out
}

/// One line: position `i` becomes set when no unset value lies in `i - radius ..= i +
/// radius` (clipped to the line), from a prefix count of the unset values (`prefix` is
/// scratch space).
fn erode_line(line: &[bool], radius: usize, prefix: &mut Vec<usize>, mut set: impl FnMut(usize, bool)) {
    prefix.clear();
    prefix.push(0);
    let mut holes = 0;
    for &v in line {
        holes += usize::from(!v);
        prefix.push(holes);
    }
    let len = line.len();
    for i in 0..len {
        let (lo, hi) = (i.saturating_sub(radius), (i + radius + 1).min(len));
        set(i, prefix[hi] == prefix[lo]);
    }
}

/// The mask the pose stage gets for a detection: `mask` eroded by `radius`, or `mask`
/// unchanged when the erosion would keep fewer than a quarter of its pixels (a thin or tiny
/// mask, whose rim is most of it: eroding it would lose the object rather than its rim).
pub fn erode_for_pose(mask: Vec<bool>, width: usize, radius: usize) -> Vec<bool> {
    if radius == 0 {
        return mask;
    }
    let eroded = erode_mask(&mask, width, radius);
    let count = |m: &[bool]| m.iter().filter(|&&v| v).count();
    if 4 * count(&eroded) < count(&mask) { mask } else { eroded }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// The definition, pixel by pixel: every in-image pixel of the square is set.
    fn erode_reference(mask: &[bool], width: usize, radius: usize) -> Vec<bool> {
        let height = mask.len() / width;
        let r = radius as i64;
        (0..mask.len())
            .map(|i| {
                let (y, x) = ((i / width) as i64, (i % width) as i64);
                (-r..=r).all(|dy| {
                    (-r..=r).all(|dx| {
                        let (yy, xx) = (y + dy, x + dx);
                        yy < 0
                            || xx < 0
                            || yy >= height as i64
                            || xx >= width as i64
                            || mask[(yy * width as i64 + xx) as usize]
                    })
                })
            })
            .collect()
    }

    fn random_mask(rng: &mut Rng, w: usize, h: usize) -> Vec<bool> {
        // blobs: a few filled rectangles plus salt noise, so that erosion has rims to eat
        let mut m = vec![false; w * h];
        for _ in 0..3 {
            let (y0, x0) = (rng.below(h), rng.below(w));
            let (y1, x1) = ((y0 + 1 + rng.below(h)).min(h), (x0 + 1 + rng.below(w)).min(w));
            for y in y0..y1 {
                m[y * w + x0..y * w + x1].iter_mut().for_each(|v| *v = true);
            }
        }
        for _ in 0..(w * h / 10) {
            let i = rng.below(w * h);
            m[i] = !m[i];
        }
        m
    }

    #[test]
    fn separable_erosion_equals_the_definition() {
        let mut rng = Rng::new(5);
        for case in 0..60 {
            let (w, h) = (1 + rng.below(23), 1 + rng.below(19));
            let m = random_mask(&mut rng, w, h);
            for radius in 0..4 {
                assert_eq!(erode_mask(&m, w, radius), erode_reference(&m, w, radius), "case {case} {w}x{h} r={radius}");
            }
        }
    }

    #[test]
    fn a_blob_far_from_the_border_erodes_as_the_definition_says() {
        // the work is done in the bounding box grown by the radius: its edges lie inside
        // the image here, and an empty mask stays empty
        let mut rng = Rng::new(9);
        let (w, h) = (31, 27);
        assert_eq!(erode_mask(&vec![false; w * h], w, 2), vec![false; w * h]);
        for case in 0..20 {
            let mut m = vec![false; w * h];
            let (y0, x0) = (8 + rng.below(4), 9 + rng.below(4));
            for y in y0..y0 + 7 {
                for x in x0..x0 + 8 {
                    m[y * w + x] = rng.below(5) > 0;
                }
            }
            for radius in 1..4 {
                assert_eq!(erode_mask(&m, w, radius), erode_reference(&m, w, radius), "case {case} r={radius}");
            }
        }
    }

    #[test]
    fn erosion_shrinks_a_square_by_its_radius_and_keeps_cut_edges() {
        // a 6x6 square at rows 2..8, columns 4..10 of a 10x12 image, and a 2-pixel strip
        // at columns 0..2 cut by the left border
        let (w, h) = (12, 10);
        let mut m = vec![false; w * h];
        for y in 2..8 {
            for x in 4..10 {
                m[y * w + x] = true;
            }
            m[y * w] = true;
            m[y * w + 1] = true;
        }
        let e = erode_mask(&m, w, 1);
        let set: Vec<(usize, usize)> = (0..w * h).filter(|&i| e[i]).map(|i| (i / w, i % w)).collect();
        let mut want: Vec<(usize, usize)> = (3..7).flat_map(|y| (5..9).map(move |x| (y, x))).collect();
        // the border-cut strip (columns 0..2, rows 2..8) erodes from above, below and its
        // right side only: column 0 of rows 3..7 stays
        want.extend((3..7).map(|y| (y, 0)));
        want.sort();
        assert_eq!(set, want);
        assert!(erode_mask(&m, w, 1).iter().zip(&m).all(|(e, o)| !e || *o), "erosion only removes");
    }

    #[test]
    fn radius_zero_and_degenerate_shapes_leave_the_mask() {
        let m = vec![true, false, true, true, false, true];
        assert_eq!(erode_mask(&m, 3, 0), m);
        assert_eq!(erode_mask(&m, 0, 2), m);
        assert_eq!(erode_mask(&m, 4, 2), m, "a width that does not divide the length");
        assert_eq!(erode_for_pose(m.clone(), 3, 0), m);
    }

    #[test]
    fn pose_erosion_falls_back_for_masks_it_would_mostly_remove() {
        let (w, h) = (20, 20);
        // a 2-pixel-wide bar: radius 1 leaves nothing
        let mut bar = vec![false; w * h];
        for y in 5..15 {
            bar[y * w + 9] = true;
            bar[y * w + 10] = true;
        }
        assert_eq!(erode_for_pose(bar.clone(), w, 1), bar);
        // a 10x10 block: radius 1 keeps 64 of 100 pixels
        let mut block = vec![false; w * h];
        for y in 5..15 {
            block[y * w + 5..y * w + 15].iter_mut().for_each(|v| *v = true);
        }
        let e = erode_for_pose(block.clone(), w, 1);
        assert_eq!(e.iter().filter(|&&v| v).count(), 64);
        assert_eq!(e, erode_mask(&block, w, 1));
    }
}
