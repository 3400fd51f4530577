//! 2-D detection and mask average precision (COCO style), for the segmenter.
//!
//! Per class, detections of all frames in descending score order are matched
//! greedily to the unmatched ground truth of their frame with the highest IoU (a
//! hit when it reaches the threshold); AP is the precision envelope sampled at 101
//! recall points; the result is the mean over the classes with ground truth. The
//! same as `average_precision` in tools/tricons_pose/maskrcnn.py, which produced the
//! numbers in docs/results.md.

use crate::category::Category;

/// One detection or ground-truth object in a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Object2d {
    /// Category.
    pub class: Category,
    /// Score (ground truth: ignored).
    pub score: f64,
    /// Box `(x0, y0, x1, y1)`, pixels.
    pub box_xyxy: [f64; 4],
    /// Full-image mask, row-major.
    pub mask: Vec<bool>,
}

impl Object2d {
    /// The tight box of a mask of width `width` (`x1`, `y1` exclusive); zeros if empty.
    pub fn mask_box(mask: &[bool], width: usize) -> [f64; 4] {
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            let (x, y) = (i % width, i / width);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x + 1);
            y1 = y1.max(y + 1);
        }
        if x0 == usize::MAX { [0.0; 4] } else { [x0 as f64, y0 as f64, x1 as f64, y1 as f64] }
    }
}

/// What the IoU is computed on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Overlap {
    /// Boxes.
    Box,
    /// Masks.
    Mask,
}

/// IoU of two boxes.
pub fn box_iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// IoU of two masks of the same size.
pub fn mask_iou(a: &[bool], b: &[bool]) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += (x && y) as usize;
        union += (x || y) as usize;
    }
    if union > 0 { inter as f64 / union as f64 } else { 0.0 }
}

/// COCO AP of scored hits against `num_gt` objects: precision made non-increasing from
/// the right, sampled at recall 0, 0.01, ..., 1. `None` without ground truth; 0 without
/// detections.
pub fn coco_ap(scores_and_tp: &[(f64, bool)], num_gt: usize) -> Option<f64> {
    if num_gt == 0 {
        return None;
    }
    let mut sorted = scores_and_tp.to_vec();
    sorted.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (mut tp, mut fp) = (0usize, 0usize);
    let mut recall = Vec::with_capacity(sorted.len());
    let mut precision = Vec::with_capacity(sorted.len());
    for &(_, hit) in &sorted {
        if hit {
            tp += 1
        } else {
            fp += 1
        }
        recall.push(tp as f64 / num_gt as f64);
        precision.push(tp as f64 / (tp + fp) as f64);
    }
    for i in (0..precision.len().saturating_sub(1)).rev() {
        precision[i] = precision[i].max(precision[i + 1]);
    }
    let sum: f64 = (0..=100)
        .map(|k| {
            let r = k as f64 / 100.0;
            let i = recall.partition_point(|&x| x < r);
            precision.get(i).copied().unwrap_or(0.0)
        })
        .sum();
    Some(sum / 101.0)
}

/// Mean AP over the classes with ground truth at one IoU threshold; `frames` holds
/// `(detections, ground truth)` per frame. `None` when there is no ground truth.
pub fn average_precision_2d(
    frames: &[(Vec<Object2d>, Vec<Object2d>)],
    overlap: Overlap,
    threshold: f64,
) -> Option<f64> {
    let mut aps = Vec::new();
    for class in Category::ALL {
        let mut hits: Vec<(f64, bool)> = Vec::new();
        let mut num_gt = 0;
        for (dets, gts) in frames {
            let gts: Vec<&Object2d> = gts.iter().filter(|g| g.class == class).collect();
            num_gt += gts.len();
            let mut dets: Vec<&Object2d> = dets.iter().filter(|d| d.class == class).collect();
            dets.sort_by(|a, b| b.score.total_cmp(&a.score));
            let mut matched = vec![false; gts.len()];
            for d in dets {
                let best = gts
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| !matched[*j])
                    .map(|(j, g)| {
                        let iou = match overlap {
                            Overlap::Box => box_iou(&d.box_xyxy, &g.box_xyxy),
                            Overlap::Mask => mask_iou(&d.mask, &g.mask),
                        };
                        (j, iou)
                    })
                    .fold(None::<(usize, f64)>, |acc, x| match acc {
                        Some(a) if a.1 >= x.1 => Some(a),
                        _ => Some(x),
                    });
                let hit = matches!(best, Some((_, iou)) if iou >= threshold);
                if let (true, Some((j, _))) = (hit, best) {
                    matched[j] = true;
                }
                hits.push((d.score, hit));
            }
        }
        if let Some(ap) = coco_ap(&hits, num_gt) {
            aps.push(ap);
        }
    }
    (!aps.is_empty()).then(|| aps.iter().sum::<f64>() / aps.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(class: Category, score: f64, x0: f64) -> Object2d {
        let mut mask = vec![false; 100];
        for x in x0 as usize..(x0 as usize + 2) {
            mask[x] = true;
            mask[10 + x] = true;
        }
        Object2d { class, score, box_xyxy: [x0, 0.0, x0 + 2.0, 2.0], mask }
    }

    #[test]
    fn perfect_detections_score_one_and_a_miss_halves_recall() {
        let gt = vec![obj(Category::Mug, 1.0, 0.0), obj(Category::Mug, 1.0, 5.0)];
        let frames = vec![(gt.clone(), gt.clone())];
        assert_eq!(average_precision_2d(&frames, Overlap::Mask, 0.5), Some(1.0));
        assert_eq!(average_precision_2d(&frames, Overlap::Box, 0.75), Some(1.0));
        // Only one of two found: precision 1 up to recall 0.5 -> 51 of 101 samples.
        let frames = vec![(vec![obj(Category::Mug, 0.9, 0.0)], gt)];
        assert_eq!(average_precision_2d(&frames, Overlap::Mask, 0.5), Some(51.0 / 101.0));
    }

    #[test]
    fn a_higher_scored_false_positive_lowers_precision() {
        let gt = vec![obj(Category::Can, 1.0, 0.0)];
        // The false positive (shifted by one pixel: IoU 1/3) ranks first.
        let dets = vec![obj(Category::Can, 0.9, 1.0), obj(Category::Can, 0.8, 0.0)];
        assert!((mask_iou(&dets[0].mask, &gt[0].mask) - 1.0 / 3.0).abs() < 1e-12);
        let ap = average_precision_2d(&[(dets, gt)], Overlap::Mask, 0.5).unwrap();
        assert!((ap - 0.5).abs() < 1e-12, "{ap}");
        assert_eq!(coco_ap(&[], 3), Some(0.0));
        assert_eq!(coco_ap(&[(1.0, true)], 0), None);
    }
}
