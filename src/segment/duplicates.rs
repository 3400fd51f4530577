//! Class-agnostic duplicate suppression on instance masks.
//!
//! torchvision's Mask R-CNN runs NMS per class, so one object can come out twice
//! under two labels (a bowl that is also a mug). With the card's
//! `duplicate_mask_iou` set, [`suppress_duplicates`] keeps detections in descending
//! score order and drops every one whose mask overlaps an already kept one by more
//! than that IoU, whatever the two classes: greedy NMS on mask IoU.

/// The tight rectangle `[x0, y0, x1, y1)` of a mask's set pixels; `None` when empty.
fn mask_rect(mask: &[bool], width: usize) -> Option<[usize; 4]> {
    let mut rect: Option<[usize; 4]> = None;
    for (y, row) in mask.chunks_exact(width).enumerate() {
        let Some(first) = row.iter().position(|&m| m) else { continue };
        let last = row.iter().rposition(|&m| m).unwrap_or(first);
        rect = Some(match rect {
            None => [first, y, last + 1, y + 1],
            Some([x0, y0, x1, _]) => [x0.min(first), y0, x1.max(last + 1), y + 1],
        });
    }
    rect
}

/// A mask with its pixel count and tight rectangle, for repeated IoUs.
struct Summary {
    pixels: usize,
    rect: Option<[usize; 4]>,
}

impl Summary {
    fn of(mask: &[bool], width: usize) -> Summary {
        Summary { pixels: mask.iter().filter(|&&m| m).count(), rect: mask_rect(mask, width) }
    }
}

/// Mask IoU of `a` and `b` (row-major, `width` wide), scanning only where both
/// rectangles meet. Two empty masks have IoU 0.
fn iou(a: &[bool], sa: &Summary, b: &[bool], sb: &Summary, width: usize) -> f64 {
    let (Some(ra), Some(rb)) = (sa.rect, sb.rect) else { return 0.0 };
    let (x0, y0, x1, y1) = (ra[0].max(rb[0]), ra[1].max(rb[1]), ra[2].min(rb[2]), ra[3].min(rb[3]));
    let mut inter = 0usize;
    if x0 < x1 && y0 < y1 {
        for y in y0..y1 {
            let (ra, rb) = (&a[y * width + x0..y * width + x1], &b[y * width + x0..y * width + x1]);
            inter += ra.iter().zip(rb).filter(|(p, q)| **p && **q).count();
        }
    }
    let union = sa.pixels + sb.pixels - inter;
    if union == 0 { 0.0 } else { inter as f64 / union as f64 }
}

/// Which of `masks` (each `width * height`, scores in `scores`) survive greedy mask NMS
/// at `max_iou`: indices in descending score order (ties: the earlier index first). A
/// detection is dropped when its mask IoU with a kept, higher-ranked one exceeds
/// `max_iou`.
pub fn keep_after_mask_nms(masks: &[&[bool]], scores: &[f32], width: usize, max_iou: f64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..masks.len().min(scores.len())).collect();
    order.sort_by(|&i, &j| scores[j].total_cmp(&scores[i]).then(i.cmp(&j)));
    if width == 0 {
        return order;
    }
    let summaries: Vec<Summary> = masks.iter().map(|m| Summary::of(m, width)).collect();
    let mut kept: Vec<usize> = Vec::with_capacity(order.len());
    for i in order {
        let duplicate = kept.iter().any(|&k| iou(masks[i], &summaries[i], masks[k], &summaries[k], width) > max_iou);
        if !duplicate {
            kept.push(i);
        }
    }
    kept
}

/// Drop the duplicates among `instances` (see the module doc); the survivors stay in
/// their original order. Returns how many were dropped.
pub fn suppress_duplicates(instances: &mut Vec<super::SegInstance>, width: usize, max_iou: f64) -> usize {
    let masks: Vec<&[bool]> = instances.iter().map(|d| d.mask.as_slice()).collect();
    let scores: Vec<f32> = instances.iter().map(|d| d.score).collect();
    let mut keep = vec![false; instances.len()];
    for i in keep_after_mask_nms(&masks, &scores, width, max_iou) {
        keep[i] = true;
    }
    let before = instances.len();
    let mut flags = keep.into_iter();
    instances.retain(|_| flags.next().unwrap_or(false));
    before - instances.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::mask_ap::mask_iou;

    /// A `w x h` mask with the rectangle `[x0, x1) x [y0, y1)` set.
    fn rect(w: usize, h: usize, x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<bool> {
        (0..w * h).map(|i| (x0..x1).contains(&(i % w)) && (y0..y1).contains(&(i / w))).collect()
    }

    #[test]
    fn rectangle_scan_equals_the_whole_image_iou() {
        let (w, h) = (23, 17);
        let mut rng = crate::rng::Rng::new(7);
        for _ in 0..200 {
            let mut pick = |n: usize| rng.below(n);
            let (a0, a1, b0, b1) = (pick(w), pick(h), pick(w), pick(h));
            let a = rect(w, h, a0, a1, a0 + pick(w - a0) + 1, a1 + pick(h - a1) + 1);
            let mut b = rect(w, h, b0, b1, b0 + pick(w - b0) + 1, b1 + pick(h - b1) + 1);
            // Holes, so the masks are not their rectangles.
            for i in (pick(5)..w * h).step_by(7) {
                b[i] = false;
            }
            let got = iou(&a, &Summary::of(&a, w), &b, &Summary::of(&b, w), w);
            assert_eq!(got, mask_iou(&a, &b));
        }
        let empty = vec![false; w * h];
        let s = Summary::of(&empty, w);
        assert_eq!((s.pixels, s.rect), (0, None));
        assert_eq!(iou(&empty, &s, &empty, &s, w), 0.0);
    }

    #[test]
    fn greedy_keeps_the_best_of_each_overlapping_group() {
        let (w, h) = (10, 10);
        let a = rect(w, h, 0, 0, 5, 5); // 25 px
        let a_dup = rect(w, h, 0, 0, 5, 4); // IoU 20/25 = 0.8 with a
        let b = rect(w, h, 5, 5, 10, 10); // disjoint from a
        let touching = rect(w, h, 3, 0, 8, 5); // IoU 10/40 = 0.25 with a
        let masks: Vec<&[bool]> = vec![&a_dup, &a, &b, &touching];
        // a outranks its duplicate; b and `touching` overlap nothing above 0.5.
        assert_eq!(keep_after_mask_nms(&masks, &[0.7, 0.9, 0.6, 0.8], w, 0.5), vec![1, 3, 2]);
        // The threshold is strict: at exactly the IoU both stay.
        assert_eq!(keep_after_mask_nms(&masks, &[0.7, 0.9, 0.6, 0.8], w, 0.8), vec![1, 3, 0, 2]);
        // Ties rank the earlier index first.
        assert_eq!(keep_after_mask_nms(&[&a, &a], &[0.5, 0.5], w, 0.5), vec![0]);
        // A dropped detection suppresses nothing: c overlaps only the dropped a_dup2.
        let big = rect(w, h, 0, 0, 6, 10); // 60 px
        let mid = rect(w, h, 0, 2, 6, 10); // IoU 48/60 with big
        let low = rect(w, h, 0, 4, 6, 10); // IoU 36/60 with big, 36/48 with mid
        let masks: Vec<&[bool]> = vec![&big, &mid, &low];
        assert_eq!(keep_after_mask_nms(&masks, &[0.9, 0.8, 0.7], w, 0.7), vec![0, 2]);
    }

    #[test]
    fn suppression_is_order_independent_and_leaves_no_overlap_above_the_threshold() {
        let (w, h) = (16, 12);
        let mut rng = crate::rng::Rng::new(11);
        for _ in 0..100 {
            let n = 1 + rng.below(8);
            let mut masks = Vec::new();
            let mut scores = Vec::new();
            for k in 0..n {
                let mut pick = |n: usize| rng.below(n);
                let (x0, y0) = (pick(w / 2), pick(h / 2));
                masks.push(rect(w, h, x0, y0, x0 + 2 + pick(w / 2), y0 + 2 + pick(h / 2)));
                scores.push(1.0 - k as f32 / 16.0); // distinct
            }
            let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
            let kept = keep_after_mask_nms(&refs, &scores, w, 0.5);
            for (x, &i) in kept.iter().enumerate() {
                for &j in &kept[x + 1..] {
                    assert!(mask_iou(&masks[i], &masks[j]) <= 0.5);
                }
            }
            // Every dropped one overlaps a kept, higher-scored one.
            for i in (0..n).filter(|i| !kept.contains(i)) {
                assert!(kept.iter().any(|&k| scores[k] > scores[i] && mask_iou(&masks[k], &masks[i]) > 0.5));
            }
            // Reversed input order: the same masks survive.
            let rev_refs: Vec<&[bool]> = refs.iter().rev().copied().collect();
            let rev_scores: Vec<f32> = scores.iter().rev().copied().collect();
            let mut back: Vec<usize> =
                keep_after_mask_nms(&rev_refs, &rev_scores, w, 0.5).into_iter().map(|i| n - 1 - i).collect();
            back.sort_unstable();
            let mut sorted = kept.clone();
            sorted.sort_unstable();
            assert_eq!(back, sorted);
        }
    }
}
