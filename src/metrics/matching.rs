//! Greedy matching of one class's predictions to its ground truth in one
//! image, by 3D IoU and by pose error, as the reference does it.
//!
//! Predictions are always given in score order (highest first); the caller
//! sorts them.

use super::config::PoseThreshold;

/// Result of matching predictions (rows) to ground-truth objects (columns).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Matches {
    /// For each prediction, the ground-truth index it matched.
    pub pred_to_gt: Vec<Option<usize>>,
    /// For each ground-truth object, the prediction index that matched it.
    pub gt_to_pred: Vec<Option<usize>>,
}

impl Matches {
    fn unmatched(num_pred: usize, num_gt: usize) -> Matches {
        Matches { pred_to_gt: vec![None; num_pred], gt_to_pred: vec![None; num_gt] }
    }

    fn link(&mut self, pred: usize, gt: usize) {
        self.pred_to_gt[pred] = Some(gt);
        self.gt_to_pred[gt] = Some(pred);
    }
}

/// Matches by IoU at `threshold`. `ious[i][j]` is the IoU of prediction `i`
/// (score order) with ground truth `j`; all rows have `num_gt` entries.
///
/// For each prediction in turn, the ground truth is visited by IoU, highest
/// first (stable: equal IoUs in index order; NaN, which can only come from a
/// degenerate published IoU, sorts first and is skipped as in the reference);
/// already matched ground truth is skipped; an IoU below the threshold ends the
/// search; an IoU strictly above it is a match. An IoU equal to the threshold
/// neither matches nor ends the search.
pub(crate) fn match_by_iou(ious: &[Vec<f64>], num_gt: usize, threshold: f64) -> Matches {
    let mut m = Matches::unmatched(ious.len(), num_gt);
    for (i, row) in ious.iter().enumerate() {
        let mut order: Vec<usize> = (0..num_gt).collect();
        order.sort_by(|&a, &b| row[b].total_cmp(&row[a]));
        for j in order {
            if m.gt_to_pred[j].is_some() {
                continue;
            }
            let iou = row[j];
            if iou < threshold {
                break;
            }
            if iou > threshold {
                m.link(i, j);
                break;
            }
        }
    }
    m
}

/// Matches by pose error at `threshold`. `errors[i][j]` is (degrees, cm) of
/// prediction `i` (score order) against ground truth `j`.
///
/// For each prediction in turn, the ground truth is visited by degrees + cm,
/// lowest first (stable); already matched ground truth is skipped; the first
/// one with degrees <= threshold AND cm <= threshold is the match (both
/// inclusive, as the reference tests `>` and goes on).
pub(crate) fn match_by_pose(errors: &[Vec<(f64, f64)>], num_gt: usize, threshold: &PoseThreshold) -> Matches {
    let mut m = Matches::unmatched(errors.len(), num_gt);
    for (i, row) in errors.iter().enumerate() {
        let mut order: Vec<usize> = (0..num_gt).collect();
        order.sort_by(|&a, &b| (row[a].0 + row[a].1).total_cmp(&(row[b].0 + row[b].1)));
        for j in order {
            if m.gt_to_pred[j].is_some() {
                continue;
            }
            let (deg, cm) = row[j];
            if deg > threshold.degrees || cm > threshold.cm {
                continue;
            }
            m.link(i, j);
            break;
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_match_is_strict_and_greedy_in_score_order() {
        // Prediction 0 takes GT 1 (its best), prediction 1 then takes GT 0.
        let ious = vec![vec![0.6, 0.9], vec![0.7, 0.8]];
        let m = match_by_iou(&ious, 2, 0.5);
        assert_eq!(m.pred_to_gt, vec![Some(1), Some(0)]);
        assert_eq!(m.gt_to_pred, vec![Some(1), Some(0)]);
        // IoU exactly at the threshold is not a match.
        let m = match_by_iou(&[vec![0.5]], 1, 0.5);
        assert_eq!(m.pred_to_gt, vec![None]);
        // Below the threshold stops the search.
        let m = match_by_iou(&[vec![0.4, 0.3]], 2, 0.5);
        assert_eq!(m.pred_to_gt, vec![None]);
        // The second prediction finds its best GT taken and the next one too low.
        let m = match_by_iou(&[vec![0.9, 0.2], vec![0.95, 0.2]], 2, 0.5);
        assert_eq!(m.pred_to_gt, vec![Some(0), None]);
    }

    #[test]
    fn iou_nan_is_skipped_not_matched() {
        let m = match_by_iou(&[vec![f64::NAN, 0.7]], 2, 0.5);
        assert_eq!(m.pred_to_gt, vec![Some(1)]);
        let m = match_by_iou(&[vec![f64::NAN]], 1, 0.0);
        assert_eq!(m.pred_to_gt, vec![None]);
    }

    #[test]
    fn pose_match_is_inclusive_and_ordered_by_sum() {
        let t = PoseThreshold { degrees: 5.0, cm: 2.0 };
        // Exactly on both thresholds matches.
        assert_eq!(match_by_pose(&[vec![(5.0, 2.0)]], 1, &t).pred_to_gt, vec![Some(0)]);
        assert_eq!(match_by_pose(&[vec![(5.1, 0.0)]], 1, &t).pred_to_gt, vec![None]);
        // GT 0 has the lower sum but fails cm; GT 1 passes: the search goes on.
        assert_eq!(match_by_pose(&[vec![(0.0, 2.5), (4.0, 1.0)]], 2, &t).pred_to_gt, vec![Some(1)]);
        // Both pass: lowest sum wins, the second prediction gets the other one.
        let m = match_by_pose(&[vec![(4.0, 1.0), (1.0, 1.0)], vec![(1.0, 0.5), (0.1, 0.1)]], 2, &t);
        assert_eq!(m.pred_to_gt, vec![Some(1), Some(0)]);
    }
}
