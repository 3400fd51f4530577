//! Exact k-nearest-neighbour search for the `ThreeNN` and `TriangleDescriptor` kernels.
//!
//! [`knn_brute_force`] is the scalar reference: squared distances `(dx*dx + dy*dy) + dz*dz`
//! in `f32`, ascending, ties to the lower index, NaN last. [`PointsSoa`] computes the same
//! in a vectorisable layout; [`KnnIndex`] adds a KD-tree (kiddo) for large point sets,
//! where benches/knn.rs measured it faster, and keeps the reference's exact answer (ties
//! included) by checking every tree result and falling back to the scan when a tie or
//! near-tie crosses the k-th place.

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::squared_distance;

/// Indices of the `k` points of `points` (`(n, 3)`) nearest to `query`, ascending by squared
/// distance, ties to the lower index; also returns their squared distances.
///
/// Brute force with a bounded insertion buffer: `O(n k)`, the scalar reference for the kNN
/// of [`three_nn`](super::three_nn) and [`triangle`](super::triangle) (which use
/// [`KnnIndex`], checked against it).
/// `k` must be at most `n`.
pub fn knn_brute_force(query: &[f32], points: &[f32], k: usize, idx: &mut [usize], d2: &mut [f32]) {
    let distances = points.chunks_exact(3).map(|p| squared_distance(query, p));
    select_k_nearest(distances, k, idx, d2);
}

/// Points in structure-of-arrays layout, for the vectorised brute-force kNN.
#[derive(Clone, Debug, Default)]
pub struct PointsSoa {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    scratch: Vec<f32>,
}

impl PointsSoa {
    /// From `(n, 3)` row-major points.
    pub fn new(points: &[f32]) -> PointsSoa {
        let n = points.len() / 3;
        let mut soa = PointsSoa {
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            z: Vec::with_capacity(n),
            scratch: vec![0.0; n],
        };
        for p in points.chunks_exact(3) {
            soa.x.push(p[0]);
            soa.y.push(p[1]);
            soa.z.push(p[2]);
        }
        soa
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Exactly [`knn_brute_force`] (same arithmetic, same ties): the distances in one
    /// vectorisable pass, then blocks of [`Self::BLOCK`] whose minimum cannot enter the k
    /// best are skipped whole (their elements would all be rejected one by one).
    pub fn knn(&mut self, query: &[f32], k: usize, idx: &mut [usize], d2: &mut [f32]) {
        let (qx, qy, qz) = (query[0], query[1], query[2]);
        for (((d, &x), &y), &z) in self.scratch.iter_mut().zip(&self.x).zip(&self.y).zip(&self.z) {
            let (dx, dy, dz) = (qx - x, qy - y, qz - z);
            *d = (dx * dx + dy * dy) + dz * dz;
        }
        let mut best = KBest::new(k, idx, d2);
        for (b, block) in self.scratch.chunks(Self::BLOCK).enumerate() {
            if block_min(block) >= best.bound() {
                continue;
            }
            for (o, &d) in block.iter().enumerate() {
                best.offer(b * Self::BLOCK + o, d);
            }
        }
        best.finish(self.scratch.iter().copied());
    }

    /// Distances per skip test in [`Self::knn`].
    pub const BLOCK: usize = 16;
}

/// Minimum of the non-NaN values of `block` (+inf if none), in 8 lanes so that it vectorises.
#[inline]
fn block_min(block: &[f32]) -> f32 {
    let mut lanes = [f32::INFINITY; 8];
    let mut chunks = block.chunks_exact(8);
    for c in &mut chunks {
        for (l, &v) in lanes.iter_mut().zip(c) {
            *l = if v < *l { v } else { *l };
        }
    }
    for &v in chunks.remainder() {
        lanes[0] = if v < lanes[0] { v } else { lanes[0] };
    }
    lanes.iter().fold(f32::INFINITY, |a, &b| if b < a { b } else { a })
}

/// The `k` smallest of `distances` (in index order), ascending, ties to the lower index; NaN
/// distances sort last, in index order.
fn select_k_nearest(distances: impl Iterator<Item = f32> + Clone, k: usize, idx: &mut [usize], d2: &mut [f32]) {
    let mut best = KBest::new(k, idx, d2);
    for (j, d) in distances.clone().enumerate() {
        best.offer(j, d);
    }
    best.finish(distances);
}

/// The bounded insertion buffer of the kNN kernels.
struct KBest<'a> {
    k: usize,
    len: usize,
    idx: &'a mut [usize],
    d2: &'a mut [f32],
}

impl<'a> KBest<'a> {
    fn new(k: usize, idx: &'a mut [usize], d2: &'a mut [f32]) -> KBest<'a> {
        debug_assert!(idx.len() >= k && d2.len() >= k);
        KBest { k, len: 0, idx, d2 }
    }

    /// Distances at or above this are rejected (once full); NaN is always rejected.
    #[inline]
    fn bound(&self) -> f32 {
        if self.len == self.k { self.d2[self.k - 1] } else { f32::INFINITY }
    }

    /// Offer point `j` at squared distance `d`; call in increasing `j`.
    #[inline]
    fn offer(&mut self, j: usize, d: f32) {
        // strictly smaller than the current k-th keeps the lower index on ties
        if self.k == 0 || d.is_nan() || (self.len == self.k && d >= self.d2[self.k - 1]) {
            return;
        }
        let mut pos = if self.len < self.k { self.len } else { self.k - 1 };
        while pos > 0 && d < self.d2[pos - 1] {
            self.d2[pos] = self.d2[pos - 1];
            self.idx[pos] = self.idx[pos - 1];
            pos -= 1;
        }
        self.d2[pos] = d;
        self.idx[pos] = j;
        if self.len < self.k {
            self.len += 1;
        }
    }

    /// Fewer than k comparable points (NaN coordinates): the NaN ones follow in index order.
    fn finish(mut self, distances: impl Iterator<Item = f32>) {
        for (j, d) in distances.enumerate() {
            if self.len == self.k {
                break;
            }
            if d.is_nan() {
                self.idx[self.len] = j;
                self.d2[self.len] = f32::NAN;
                self.len += 1;
            }
        }
        debug_assert_eq!(self.len, self.k, "k must be at most the number of points");
    }
}

/// Point sets at least this large get a KD-tree when there are at least
/// [`KD_TREE_MIN_QUERIES`] queries (benches/knn.rs, building and the exactness check
/// included: 1.5-2.7x faster than the scan at 512-1024 points; at 256 points the two are
/// within run-to-run noise of each other, at 64 points the scan wins, and for 32 queries
/// the build is not paid back).
pub const KD_TREE_MIN_POINTS: usize = 512;

/// See [`KD_TREE_MIN_POINTS`].
pub const KD_TREE_MIN_QUERIES: usize = 64;

/// Relative margin between the k-th and (k+1)-th tree distances under which the tree's
/// answer is not trusted (the tree's float rounding may differ from the reference's).
const TIE_MARGIN: f32 = 1e-5;

/// A point set indexed for repeated exact k-nearest queries: a KD-tree from
/// [`KD_TREE_MIN_POINTS`] points and [`KD_TREE_MIN_QUERIES`] queries on (finite coordinates
/// only), the vectorised scan otherwise. Answers equal [`knn_brute_force`]'s exactly.
pub struct KnnIndex<'a> {
    points: &'a [f32],
    soa: PointsSoa,
    tree: Option<ImmutableKdTree<f32, 3>>,
    candidates: Vec<(f32, usize)>,
}

impl<'a> KnnIndex<'a> {
    /// Index `(n, 3)` row-major `points` for about `queries` queries.
    pub fn new(points: &'a [f32], queries: usize) -> KnnIndex<'a> {
        let n = points.len() / 3;
        let big = n >= KD_TREE_MIN_POINTS && queries >= KD_TREE_MIN_QUERIES;
        let tree = (big && points.iter().all(|v| v.is_finite()))
            .then(|| {
                let rows: Vec<[f32; 3]> = points.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
                ImmutableKdTree::new_from_slice(&rows).ok()
            })
            .flatten();
        KnnIndex { points, soa: PointsSoa::new(points), tree, candidates: Vec::new() }
    }

    /// Whether queries go through the KD-tree.
    pub fn uses_tree(&self) -> bool {
        self.tree.is_some()
    }

    /// The `k` nearest points to `query` (as [`knn_brute_force`]).
    pub fn knn(&mut self, query: &[f32], k: usize, idx: &mut [usize], d2: &mut [f32]) {
        if !self.tree_knn(query, k, idx, d2) {
            self.soa.knn(query, k, idx, d2);
        }
    }

    /// The tree's k+1 nearest, re-measured with the reference arithmetic; `false` when the
    /// k-th and (k+1)-th are too close to be sure no other point ties with the k-th.
    fn tree_knn(&mut self, query: &[f32], k: usize, idx: &mut [usize], d2: &mut [f32]) -> bool {
        let Some(tree) = &self.tree else { return false };
        let n = self.points.len() / 3;
        let Some(k1) = std::num::NonZero::new(k + 1).filter(|k1| k1.get() <= n) else { return false };
        if k == 0 || !query.iter().all(|v| v.is_finite()) {
            return false;
        }
        let q = [query[0], query[1], query[2]];
        self.candidates.clear();
        for r in tree.query(&q).nearest_n::<SquaredEuclidean<f32>>(k1).execute() {
            let j = r.item as usize;
            self.candidates.push((squared_distance(query, &self.points[3 * j..3 * j + 3]), j));
        }
        self.candidates.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let (dk, dk1) = (self.candidates[k - 1].0, self.candidates[k].0);
        if dk1 <= dk * (1.0 + TIE_MARGIN) {
            return false;
        }
        for (t, &(d, j)) in self.candidates[..k].iter().enumerate() {
            d2[t] = d;
            idx[t] = j;
        }
        true
    }
}
