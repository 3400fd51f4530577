//! NMS kernels on one (batch, class) slice: the pairwise reference and the grid.

use std::collections::HashMap;

/// How the four numbers of a box are laid out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BoxFormat {
    /// `center_point_box = 0`: two opposite corners, `(y1, x1, y2, x2)` in any order.
    Corners,
    /// `center_point_box = 1`: `(x_center, y_center, width, height)`.
    Center,
}

/// Parameters of one NMS call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NmsParams {
    /// Box layout.
    pub format: BoxFormat,
    /// Keep at most this many boxes.
    pub max_output: usize,
    /// Suppress when IoU is strictly greater than this.
    pub iou_threshold: f32,
    /// Drop candidates whose score is not strictly greater than this.
    pub score_threshold: Option<f32>,
}

/// A box as `(min_a, min_b, max_a, max_b)`; axis `a` is the first coordinate of the
/// input pair (y for corner boxes), which does not matter for IoU.
#[derive(Clone, Copy, Debug)]
struct Rect {
    lo: [f32; 2],
    hi: [f32; 2],
}

impl Rect {
    fn new(b: &[f32], format: BoxFormat) -> Rect {
        match format {
            BoxFormat::Corners => Rect { lo: [b[0].min(b[2]), b[1].min(b[3])], hi: [b[0].max(b[2]), b[1].max(b[3])] },
            BoxFormat::Center => {
                let (hw, hh) = (b[2] / 2.0, b[3] / 2.0);
                Rect { lo: [b[1] - hh, b[0] - hw], hi: [b[1] + hh, b[0] + hw] }
            }
        }
    }

    fn area(&self) -> f32 {
        (self.hi[0] - self.lo[0]) * (self.hi[1] - self.lo[1])
    }

    /// onnxruntime's `SuppressByIOU`.
    fn suppresses(&self, other: &Rect, iou_threshold: f32) -> bool {
        let x_min = self.lo[1].max(other.lo[1]);
        let x_max = self.hi[1].min(other.hi[1]);
        if x_max <= x_min {
            return false;
        }
        let y_min = self.lo[0].max(other.lo[0]);
        let y_max = self.hi[0].min(other.hi[0]);
        if y_max <= y_min {
            return false;
        }
        let inter = (y_max - y_min) * (x_max - x_min);
        if inter <= 0.0 {
            return false;
        }
        let (a1, a2) = (self.area(), other.area());
        let union = a1 + a2 - inter;
        if a1 <= 0.0 || a2 <= 0.0 || union <= 0.0 {
            return false;
        }
        inter / union > iou_threshold
    }
}

/// Candidate indices above the score threshold, by decreasing score, ties to the lower index.
fn candidates(scores: &[f32], p: &NmsParams) -> Vec<usize> {
    let mut c: Vec<usize> = (0..scores.len()).filter(|&i| p.score_threshold.is_none_or(|t| scores[i] > t)).collect();
    c.sort_by(|&a, &b| scores[b].partial_cmp(&scores[a]).unwrap_or(std::cmp::Ordering::Equal).then(a.cmp(&b)));
    c
}

/// Pairwise greedy NMS: the scalar reference. `boxes` is `(n, 4)`, `scores` `(n,)`;
/// returns the kept indices in selection order.
pub fn nms_reference(boxes: &[f32], scores: &[f32], p: &NmsParams) -> Vec<usize> {
    let rects: Vec<Rect> = boxes.chunks_exact(4).map(|b| Rect::new(b, p.format)).collect();
    let mut kept: Vec<usize> = Vec::new();
    for i in candidates(scores, p) {
        if kept.len() >= p.max_output {
            break;
        }
        if !kept.iter().any(|&k| rects[k].suppresses(&rects[i], p.iou_threshold)) {
            kept.push(i);
        }
    }
    kept
}

/// A box spanning more cells than this is checked against every candidate instead.
const MAX_CELLS_PER_BOX: i64 = 64;

/// Grid NMS: same selection as [`nms_reference`]. A kept box is registered in every
/// grid cell it overlaps; boxes with positive intersection share a cell, so only those
/// are compared. The cell size is the median box extent.
pub fn nms(boxes: &[f32], scores: &[f32], p: &NmsParams) -> Vec<usize> {
    let rects: Vec<Rect> = boxes.chunks_exact(4).map(|b| Rect::new(b, p.format)).collect();
    let order = candidates(scores, p);
    let cell = cell_size(&rects, &order);
    let cell_range = |r: &Rect| -> Option<[i64; 4]> {
        let v = [r.lo[0] / cell, r.lo[1] / cell, r.hi[0] / cell, r.hi[1] / cell];
        if v.iter().any(|x| !x.is_finite() || x.abs() > 1e15) {
            return None;
        }
        let v = v.map(|x| x.floor() as i64);
        if (v[2] - v[0] + 1) * (v[3] - v[1] + 1) > MAX_CELLS_PER_BOX { None } else { Some(v) }
    };
    let mut grid: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
    // Kept boxes not in the grid (huge or non-finite extent): compared with everyone.
    let mut unbinned: Vec<u32> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    // Per kept box, the last candidate it was compared with (a box sits in several cells).
    let mut seen: Vec<usize> = Vec::new();
    for (ci, &i) in order.iter().enumerate() {
        if kept.len() >= p.max_output {
            break;
        }
        let r = &rects[i];
        let range = cell_range(r);
        let mut suppressed = match range {
            // A huge or non-finite candidate is compared with every kept box.
            None => kept.iter().any(|&k| rects[k].suppresses(r, p.iou_threshold)),
            Some(_) => unbinned.iter().any(|&k| rects[kept[k as usize]].suppresses(r, p.iou_threshold)),
        };
        if !suppressed && let Some([a0, b0, a1, b1]) = range {
            'cells: for a in a0..=a1 {
                for b in b0..=b1 {
                    for &k in grid.get(&(a, b)).map(Vec::as_slice).unwrap_or(&[]) {
                        if seen[k as usize] == ci + 1 {
                            continue;
                        }
                        seen[k as usize] = ci + 1;
                        if rects[kept[k as usize]].suppresses(r, p.iou_threshold) {
                            suppressed = true;
                            break 'cells;
                        }
                    }
                }
            }
        }
        if suppressed {
            continue;
        }
        let slot = kept.len() as u32;
        kept.push(i);
        seen.push(0);
        match range {
            Some([a0, b0, a1, b1]) => {
                for a in a0..=a1 {
                    for b in b0..=b1 {
                        grid.entry((a, b)).or_default().push(slot);
                    }
                }
            }
            None => unbinned.push(slot),
        }
    }
    kept
}

/// Median of the candidates' larger side (finite, positive), or 1.
fn cell_size(rects: &[Rect], order: &[usize]) -> f32 {
    let mut sides: Vec<f32> = order
        .iter()
        .map(|&i| (rects[i].hi[0] - rects[i].lo[0]).max(rects[i].hi[1] - rects[i].lo[1]))
        .filter(|s| s.is_finite() && *s > 0.0)
        .collect();
    if sides.is_empty() {
        return 1.0;
    }
    let mid = sides.len() / 2;
    let (_, m, _) = sides.select_nth_unstable_by(mid, f32::total_cmp);
    *m
}
