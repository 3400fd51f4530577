//! Average precision with VOC all-point interpolation.

/// Average precision (a fraction in [0, 1]) of scored detections, each flagged
/// true positive or not, against `num_gt` ground-truth objects; `None` when
/// `num_gt == 0` (the reference divides by zero there).
///
/// As the reference's `compute_ap_from_matches_scores`: detections sorted by
/// score, descending (a stable sort: equal scores keep their input order);
/// precision = cumulative TP / rank, recall = cumulative TP / `num_gt`; the
/// curves are padded with precision 0 at both ends and recall 0 and 1; the
/// precision is made non-increasing from the right; AP = sum over the points
/// where recall changes of (recall step) * precision. No detections gives 0.
/// The true positives must not outnumber `num_gt` (matching guarantees it).
pub fn voc_ap(scores_and_tp: &[(f64, bool)], num_gt: usize) -> Option<f64> {
    if num_gt == 0 {
        return None;
    }
    let mut sorted: Vec<(f64, bool)> = scores_and_tp.to_vec();
    sorted.sort_by(|a, b| b.0.total_cmp(&a.0));

    let n = sorted.len();
    let mut precision = Vec::with_capacity(n + 2);
    let mut recall = Vec::with_capacity(n + 2);
    precision.push(0.0);
    recall.push(0.0);
    let mut tp = 0usize;
    for (rank, &(_, is_tp)) in sorted.iter().enumerate() {
        if is_tp {
            tp += 1;
        }
        precision.push(tp as f64 / (rank + 1) as f64);
        recall.push(tp as f64 / num_gt as f64);
    }
    precision.push(0.0);
    recall.push(1.0);

    for i in (0..precision.len() - 1).rev() {
        precision[i] = precision[i].max(precision[i + 1]);
    }
    let ap = (1..recall.len())
        .filter(|&i| recall[i] != recall[i - 1])
        .map(|i| (recall[i] - recall[i - 1]) * precision[i])
        .sum();
    Some(ap)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_values() {
        // 2 GT; TP, FP, TP: 0.5 * 1 + 0.5 * 2/3.
        let ap = voc_ap(&[(0.9, true), (0.8, false), (0.7, true)], 2).unwrap_or(f64::NAN);
        assert!((ap - (0.5 + 0.5 * 2.0 / 3.0)).abs() < 1e-12, "{ap}");
        // Same detections in another input order: the score order is what counts.
        let ap2 = voc_ap(&[(0.7, true), (0.9, true), (0.8, false)], 2).unwrap_or(f64::NAN);
        assert_eq!(ap, ap2);
        // The FP last leaves AP at 1.
        assert_eq!(voc_ap(&[(0.9, true), (0.8, true), (0.1, false)], 2), Some(1.0));
        // Half the GT found, perfectly ranked.
        assert_eq!(voc_ap(&[(0.9, true)], 2), Some(0.5));
        // FP first, then the only TP: precision 1/2 over the whole recall range.
        assert_eq!(voc_ap(&[(0.9, false), (0.5, true)], 1), Some(0.5));
    }

    #[test]
    fn empty_cases() {
        assert_eq!(voc_ap(&[], 3), Some(0.0));
        assert_eq!(voc_ap(&[(0.5, false)], 1), Some(0.0));
        assert_eq!(voc_ap(&[(0.5, false)], 0), None);
        assert_eq!(voc_ap(&[], 0), None);
    }

    #[test]
    fn ties_keep_input_order() {
        // Equal scores: the stable sort keeps FP before TP here ...
        assert_eq!(voc_ap(&[(0.5, false), (0.5, true)], 1), Some(0.5));
        // ... and TP before FP here.
        assert_eq!(voc_ap(&[(0.5, true), (0.5, false)], 1), Some(1.0));
    }
}
