//! Class-agnostic duplicate suppression on instance masks.
//!
//! torchvision's Mask R-CNN runs NMS per class, so one object can come out twice
//! under two labels (a bowl that is also a mug). With the card's
//! `duplicate_mask_iou` set, [`suppress_duplicates`] keeps detections in descending
//! score order and drops every one whose mask overlaps an already kept one by more
//! than that IoU, whatever the two classes: greedy NMS on mask IoU. With the card's
//! `duplicate_mask_inside` set as well, a detection is also dropped when more than that
//! fraction of its own mask lies inside a kept one: a part of an object (a camera's lens)
//! detected beside the whole, whose IoU with the whole is small.

/// When a detection is a duplicate of a kept, higher-ranked one.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DuplicateRule {
    /// Their mask IoU exceeds this (`None`: never by IoU).
    pub max_iou: Option<f64>,
    /// The fraction of its mask's pixels inside the kept one exceeds this (`None`: never
    /// by containment).
    pub max_inside: Option<f64>,
}

impl DuplicateRule {
    /// Whether the rule drops anything.
    pub fn is_on(&self) -> bool {
        self.max_iou.is_some() || self.max_inside.is_some()
    }

    /// Whether a mask of `pixels` pixels meeting a kept one of `kept_pixels` in `inter`
    /// pixels is a duplicate of it.
    fn is_duplicate(&self, pixels: usize, kept_pixels: usize, inter: usize) -> bool {
        let union = pixels + kept_pixels - inter;
        let over = |max: Option<f64>, den: usize| max.is_some_and(|m| den > 0 && inter as f64 / den as f64 > m);
        over(self.max_iou, union) || over(self.max_inside, pixels)
    }
}

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

/// Pixels set in both `a` and `b` (row-major, `width` wide), scanning only where both
/// rectangles meet.
fn intersection(a: &[bool], sa: &Summary, b: &[bool], sb: &Summary, width: usize) -> usize {
    let (Some(ra), Some(rb)) = (sa.rect, sb.rect) else { return 0 };
    let (x0, y0, x1, y1) = (ra[0].max(rb[0]), ra[1].max(rb[1]), ra[2].min(rb[2]), ra[3].min(rb[3]));
    let mut inter = 0usize;
    if x0 < x1 && y0 < y1 {
        for y in y0..y1 {
            let (ra, rb) = (&a[y * width + x0..y * width + x1], &b[y * width + x0..y * width + x1]);
            inter += ra.iter().zip(rb).filter(|(p, q)| **p && **q).count();
        }
    }
    inter
}

/// Which of `masks` (each `width * height`, scores in `scores`) survive greedy mask NMS
/// under `rule`: indices in descending score order (ties: the earlier index first). A
/// detection is dropped when the rule finds it a duplicate of a kept, higher-ranked one.
pub fn keep_after_mask_nms(masks: &[&[bool]], scores: &[f32], width: usize, rule: DuplicateRule) -> Vec<usize> {
    let mut order: Vec<usize> = (0..masks.len().min(scores.len())).collect();
    order.sort_by(|&i, &j| scores[j].total_cmp(&scores[i]).then(i.cmp(&j)));
    if width == 0 {
        return order;
    }
    let summaries: Vec<Summary> = masks.iter().map(|m| Summary::of(m, width)).collect();
    let mut kept: Vec<usize> = Vec::with_capacity(order.len());
    for i in order {
        let (si, pixels) = (&summaries[i], summaries[i].pixels);
        let duplicate = kept.iter().any(|&k| {
            let inter = intersection(masks[i], si, masks[k], &summaries[k], width);
            rule.is_duplicate(pixels, summaries[k].pixels, inter)
        });
        if !duplicate {
            kept.push(i);
        }
    }
    kept
}

/// Drop the duplicates among `instances` (see the module doc); the survivors stay in
/// their original order. Returns how many were dropped.
pub fn suppress_duplicates(instances: &mut Vec<super::SegInstance>, width: usize, rule: DuplicateRule) -> usize {
    let masks: Vec<&[bool]> = instances.iter().map(|d| d.mask.as_slice()).collect();
    let scores: Vec<f32> = instances.iter().map(|d| d.score).collect();
    let mut keep = vec![false; instances.len()];
    for i in keep_after_mask_nms(&masks, &scores, width, rule) {
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

    fn by_iou(max_iou: f64) -> DuplicateRule {
        DuplicateRule { max_iou: Some(max_iou), max_inside: None }
    }

    /// Mask IoU through [`intersection`].
    fn iou(a: &[bool], sa: &Summary, b: &[bool], sb: &Summary, w: usize) -> f64 {
        let inter = intersection(a, sa, b, sb, w);
        let union = sa.pixels + sb.pixels - inter;
        if union == 0 { 0.0 } else { inter as f64 / union as f64 }
    }

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
        assert_eq!(keep_after_mask_nms(&masks, &[0.7, 0.9, 0.6, 0.8], w, by_iou(0.5)), vec![1, 3, 2]);
        // The threshold is strict: at exactly the IoU both stay.
        assert_eq!(keep_after_mask_nms(&masks, &[0.7, 0.9, 0.6, 0.8], w, by_iou(0.8)), vec![1, 3, 0, 2]);
        // Ties rank the earlier index first.
        assert_eq!(keep_after_mask_nms(&[&a, &a], &[0.5, 0.5], w, by_iou(0.5)), vec![0]);
        // A dropped detection suppresses nothing: c overlaps only the dropped a_dup2.
        let big = rect(w, h, 0, 0, 6, 10); // 60 px
        let mid = rect(w, h, 0, 2, 6, 10); // IoU 48/60 with big
        let low = rect(w, h, 0, 4, 6, 10); // IoU 36/60 with big, 36/48 with mid
        let masks: Vec<&[bool]> = vec![&big, &mid, &low];
        assert_eq!(keep_after_mask_nms(&masks, &[0.9, 0.8, 0.7], w, by_iou(0.7)), vec![0, 2]);
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
            let kept = keep_after_mask_nms(&refs, &scores, w, by_iou(0.5));
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
                keep_after_mask_nms(&rev_refs, &rev_scores, w, by_iou(0.5)).into_iter().map(|i| n - 1 - i).collect();
            back.sort_unstable();
            let mut sorted = kept.clone();
            sorted.sort_unstable();
            assert_eq!(back, sorted);
        }
    }

    #[test]
    fn containment_drops_a_part_beside_its_whole() {
        let (w, h) = (12, 10);
        let whole = rect(w, h, 0, 0, 10, 10); // 100 px
        let part = rect(w, h, 2, 2, 6, 6); // 16 px, all inside: IoU 0.16
        let half_out = rect(w, h, 8, 0, 12, 4); // 16 px, 8 inside: IoU 8/108
        let masks: Vec<&[bool]> = vec![&whole, &part, &half_out];
        let scores = [0.9, 0.8, 0.7];
        // IoU alone keeps the part.
        assert_eq!(keep_after_mask_nms(&masks, &scores, w, by_iou(0.3)), vec![0, 1, 2]);
        let rule = DuplicateRule { max_iou: Some(0.3), max_inside: Some(0.5) };
        assert_eq!(keep_after_mask_nms(&masks, &scores, w, rule), vec![0, 2]);
        // Strict: exactly half inside stays; containment alone works without the IoU rule.
        let inside_only = DuplicateRule { max_iou: None, max_inside: Some(0.5) };
        assert_eq!(keep_after_mask_nms(&masks, &scores, w, inside_only), vec![0, 2]);
        let inside_049 = DuplicateRule { max_iou: None, max_inside: Some(0.49) };
        assert_eq!(keep_after_mask_nms(&masks, &scores, w, inside_049), vec![0]);
        // Containment looks one way: a whole scored above its part is not inside it.
        assert_eq!(keep_after_mask_nms(&masks, &[0.5, 0.9, 0.7], w, inside_only), vec![1, 2, 0]);
        // Off: nothing dropped; an empty mask is nobody's duplicate.
        assert!(!DuplicateRule::default().is_on());
        assert_eq!(keep_after_mask_nms(&masks, &scores, w, DuplicateRule::default()), vec![0, 1, 2]);
        let empty = vec![false; w * h];
        assert_eq!(keep_after_mask_nms(&[&whole, &empty], &[0.9, 0.8], w, inside_only), vec![0, 1]);
    }
}
