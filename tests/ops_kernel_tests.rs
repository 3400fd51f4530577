//! Scalar kernels of the `ai.tricons` custom operators: golden fixtures from the PyTorch
//! reference (tests/fixtures/pose_ops) and properties.

mod common;

use common::npy::{Case, cases};
use tricons::ops::{
    KnnIndex, OpError, PointsSoa, ball_query::kernel::ball_query, fps::kernel::furthest_point_sample,
    gather::kernel as gather, knn_brute_force, squared_distance, three_nn::kernel as nn,
    triangle::kernel::triangle_descriptor,
};
use tricons::rng::Rng;

/// Split a row-major tensor of the given shape into batch items.
fn items<'a, T>(data: &'a [T], shape: &[usize]) -> Vec<&'a [T]> {
    let per: usize = shape[1..].iter().product();
    data.chunks(per.max(1)).take(shape[0]).collect()
}

fn assert_close(got: &[f32], want: &[f32], rel: f32, abs: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() <= abs + rel * w.abs(), "{what}[{i}]: got {g}, want {w}");
    }
}

/// Run the kernel of `case` on every batch item; returns outputs by name, flattened.
fn run(case: &Case) -> Vec<(String, Vec<f32>, Vec<i64>)> {
    let b = case.arrays.values().next().unwrap().shape()[0];
    let mut out: Vec<(String, Vec<f32>, Vec<i64>)> = Vec::new();
    let mut push = |name: &str, f: Vec<f32>, i: Vec<i64>| match out.iter_mut().find(|(n, ..)| n == name) {
        Some(e) => {
            e.1.extend(f);
            e.2.extend(i);
        }
        None => out.push((name.to_string(), f, i)),
    };
    for bi in 0..b {
        let f = |name: &str| items(case.get(name).f32(), case.get(name).shape())[bi];
        let ix = |name: &str| items(case.get(name).i64(), case.get(name).shape())[bi];
        let shape = |name: &str| case.get(name).shape().to_vec();
        match case.op() {
            "FurthestPointSample" => {
                let mut idx = vec![0i64; case.attr_u("npoint")];
                furthest_point_sample(f("xyz"), idx.len(), &mut idx).unwrap();
                push("idx", vec![], idx);
            }
            "GatherPoints" | "GroupPoints" => {
                let (fs, is) = (shape("features"), shape("idx"));
                let mut o = vec![0f32; fs[1] * is[1..].iter().product::<usize>()];
                if case.op() == "GatherPoints" {
                    gather::gather_points(f("features"), fs[2], ix("idx"), &mut o).unwrap();
                } else {
                    gather::group_points(f("features"), fs[2], ix("idx"), &mut o).unwrap();
                }
                push("out", o, vec![]);
            }
            "BallQuery" => {
                let ns = case.attr_u("nsample");
                let mut idx = vec![0i64; shape("new_xyz")[1] * ns];
                ball_query(f("xyz"), f("new_xyz"), case.attr_f("radius") as f32, ns, &mut idx).unwrap();
                push("idx", vec![], idx);
            }
            "ThreeNN" => {
                let n = shape("unknown")[1];
                let (mut d, mut i) = (vec![0f32; 3 * n], vec![0i64; 3 * n]);
                nn::three_nn(f("unknown"), f("known"), &mut d, &mut i).unwrap();
                push("dist", d, vec![]);
                push("idx", vec![], i);
            }
            "ThreeInterpolate" => {
                let fs = shape("features");
                let mut o = vec![0f32; fs[1] * shape("idx")[1]];
                nn::three_interpolate(f("features"), fs[2], ix("idx"), f("weight"), &mut o).unwrap();
                push("out", o, vec![]);
            }
            "TriangleDescriptor" => {
                let (k, m) = (case.attr_u("k"), shape("query")[1]);
                let (mut phi, mut idx) = (vec![0f32; m * k * (k - 1) / 2 * 3], vec![0i64; m * k]);
                triangle_descriptor(f("query"), f("points"), k, &mut phi, &mut idx).unwrap();
                push("phi", phi, vec![]);
                push("knn_idx", vec![], idx);
            }
            other => panic!("{}: unknown op {other}", case.dir.display()),
        }
    }
    out
}

#[test]
fn every_kernel_matches_its_pytorch_fixtures() {
    let all = cases("pose_ops");
    let mut ops: Vec<&str> = all.iter().map(|c| c.op()).collect();
    ops.sort();
    ops.dedup();
    assert_eq!(ops.len(), 7, "fixtures cover all seven ops: {ops:?}");
    for case in &all {
        for (name, f, i) in run(case) {
            let want = case.get(&name);
            let what = format!("{}.{name}", case.dir.file_name().unwrap().to_string_lossy());
            if i.is_empty() {
                assert_close(&f, want.f32(), 1e-5, 1e-6, &what);
            } else {
                assert_eq!(i, want.i64(), "{what}");
            }
        }
    }
}

fn cloud(rng: &mut Rng, n: usize, scale: f64) -> Vec<f32> {
    (0..3 * n).map(|_| (rng.range(-1.0, 1.0) * scale) as f32).collect()
}

fn random_rotation(rng: &mut Rng) -> [[f64; 3]; 3] {
    // unit quaternion from four uniform draws, normalised
    let q: Vec<f64> = (0..4).map(|_| rng.range(-1.0, 1.0)).collect();
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
        [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
        [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn transform(pts: &[f32], r: &[[f64; 3]; 3], t: [f64; 3]) -> Vec<f32> {
    pts.chunks_exact(3)
        .flat_map(|p| {
            let p = [p[0] as f64, p[1] as f64, p[2] as f64];
            (0..3).map(move |i| (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + t[i]) as f32)
        })
        .collect()
}

#[test]
fn triangle_descriptor_is_invariant_to_rigid_transforms() {
    let mut rng = Rng::new(11);
    let (n, m, k) = (256, 24, 16);
    let t_count = k * (k - 1) / 2;
    for _ in 0..5 {
        let pts = cloud(&mut rng, n, 0.1);
        let query = cloud(&mut rng, m, 0.08);
        let (mut phi, mut idx) = (vec![0f32; m * t_count * 3], vec![0i64; m * k]);
        triangle_descriptor(&query, &pts, k, &mut phi, &mut idx).unwrap();
        let r = random_rotation(&mut rng);
        let t = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(0.5, 2.0)];
        let (pts2, query2) = (transform(&pts, &r, t), transform(&query, &r, t));
        let (mut phi2, mut idx2) = (vec![0f32; phi.len()], vec![0i64; idx.len()]);
        triangle_descriptor(&query2, &pts2, k, &mut phi2, &mut idx2).unwrap();
        assert_eq!(idx, idx2, "same neighbours after a rigid transform");
        assert_close(&phi2, &phi, 0.0, 1e-5, "phi");
        // each triangle's weighted angles sum to weight * pi, the weights to 1
        for row in phi.chunks_exact(3 * t_count) {
            let total: f64 = row.iter().map(|&v| v as f64).sum();
            assert!((total - std::f64::consts::PI).abs() < 1e-4, "angles sum {total}");
        }
    }
}

#[test]
fn fps_picks_distinct_farthest_points_deterministically() {
    let mut rng = Rng::new(5);
    let pts = cloud(&mut rng, 300, 0.2);
    let mut a = vec![0i64; 64];
    furthest_point_sample(&pts, 64, &mut a).unwrap();
    let mut b = vec![0i64; 64];
    furthest_point_sample(&pts, 64, &mut b).unwrap();
    assert_eq!(a, b);
    assert_eq!(a[0], 0);
    let mut sorted = a.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), 64, "distinct indices");
    // greedy definition: each pick maximises the distance to the points picked before it
    let p = |i: i64| &pts[3 * i as usize..3 * i as usize + 3];
    for s in 1..a.len() {
        let min_to_chosen = |j: usize| {
            a[..s].iter().map(|&c| squared_distance(&pts[3 * j..3 * j + 3], p(c))).fold(f32::INFINITY, f32::min)
        };
        let best = (0..300).map(min_to_chosen).fold(f32::NEG_INFINITY, f32::max);
        assert_eq!(min_to_chosen(a[s] as usize), best, "pick {s}");
    }
}

#[test]
fn ball_query_equals_the_brute_force_definition() {
    let mut rng = Rng::new(9);
    let (n, s, ns, radius) = (400, 50, 12, 0.05f32);
    let xyz = cloud(&mut rng, n, 0.1);
    let centres = cloud(&mut rng, s, 0.12);
    let mut idx = vec![0i64; s * ns];
    ball_query(&xyz, &centres, radius, ns, &mut idx).unwrap();
    for (c, row) in centres.chunks_exact(3).zip(idx.chunks_exact(ns)) {
        let inside: Vec<i64> = (0..n)
            .filter(|&j| squared_distance(c, &xyz[3 * j..3 * j + 3]) < radius * radius)
            .map(|j| j as i64)
            .collect();
        let mut want: Vec<i64> = inside.iter().copied().take(ns).collect();
        let pad = want.first().copied().unwrap_or(0);
        want.resize(ns, pad);
        assert_eq!(row, want.as_slice());
    }
}

#[test]
fn knn_matches_a_stable_sort_including_ties_and_nan() {
    let mut rng = Rng::new(3);
    let mut pts = cloud(&mut rng, 60, 1.0);
    for j in 10..20 {
        // duplicates of point 3: ties must go to the lower index
        let (a, b) = pts.split_at_mut(3 * j);
        b[..3].copy_from_slice(&a[9..12]);
    }
    pts[3 * 40] = f32::NAN;
    let q = [pts[9], pts[10], pts[11]];
    for k in [1, 5, 16, 60] {
        let (mut idx, mut d2) = (vec![0usize; k], vec![0f32; k]);
        knn_brute_force(&q, &pts, k, &mut idx, &mut d2);
        let mut order: Vec<usize> = (0..60).collect();
        order.sort_by(|&a, &b| {
            let (da, db) = (squared_distance(&q, &pts[3 * a..3 * a + 3]), squared_distance(&q, &pts[3 * b..3 * b + 3]));
            da.total_cmp(&db).then(a.cmp(&b))
        });
        assert_eq!(idx, order[..k], "k = {k}");
        // the vectorised kernel the ops use is the scalar reference, bit for bit
        let (mut idx_soa, mut d2_soa) = (vec![0usize; k], vec![0f32; k]);
        PointsSoa::new(&pts).knn(&q, k, &mut idx_soa, &mut d2_soa);
        assert_eq!(idx_soa, idx, "k = {k}");
        assert_eq!(
            d2_soa.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            d2.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
    }
}

#[test]
fn kd_tree_knn_equals_the_scalar_reference_with_duplicates_and_lattice_ties() {
    let mut rng = Rng::new(5);
    for (n, k) in [(512usize, 3usize), (600, 8), (1024, 16)] {
        // depth-like lattice (exact ties between different points) plus duplicated samples
        // (sampling with replacement) plus a smooth random part
        let mut pts: Vec<f32> = (0..n)
            .flat_map(|i| [(i % 23) as f32 * 0.002, (i / 23) as f32 * 0.002, 0.7 + (rng.below(4) as f32) * 0.001])
            .collect();
        for j in (0..n).step_by(5) {
            let src = rng.below(n);
            let p = [pts[3 * src], pts[3 * src + 1], pts[3 * src + 2]];
            pts[3 * j..3 * j + 3].copy_from_slice(&p);
        }
        let mut index = KnnIndex::new(&pts, n);
        assert!(index.uses_tree(), "{n} points get a tree");
        for qi in 0..n {
            // the points themselves (distance 0, duplicates), lattice midpoints (ties), random
            let q = match qi % 3 {
                0 => [pts[3 * qi], pts[3 * qi + 1], pts[3 * qi + 2]],
                1 => [pts[3 * qi] + 0.001, pts[3 * qi + 1], pts[3 * qi + 2]],
                _ => [rng.range(0.0, 0.05) as f32, rng.range(0.0, 0.09) as f32, 0.7],
            };
            let (mut a, mut da, mut b, mut db) = (vec![0; k], vec![0f32; k], vec![0; k], vec![0f32; k]);
            knn_brute_force(&q, &pts, k, &mut a, &mut da);
            index.knn(&q, k, &mut b, &mut db);
            assert_eq!((a, da), (b, db), "n {n}, query {qi}");
        }
    }
    // NaN coordinates: no tree, the scan's NaN rule
    let mut pts: Vec<f32> = (0..600).flat_map(|i| [i as f32, 0.0, 0.0]).collect();
    pts[30] = f32::NAN;
    assert!(!KnnIndex::new(&pts, 600).uses_tree());
    assert!(!KnnIndex::new(&pts[..3 * 100], 300).uses_tree(), "small sets are scanned");
    let finite: Vec<f32> = (0..600).flat_map(|i| [i as f32, 0.0, 0.0]).collect();
    assert!(KnnIndex::new(&finite, 600).uses_tree() && !KnnIndex::new(&finite, 8).uses_tree(), "few queries: no tree");
}

#[test]
fn vectorised_knn_equals_the_scalar_reference_on_grid_clouds() {
    // depth-image-like clouds: points on a pixel lattice, where exact distance ties happen
    let mut rng = Rng::new(11);
    for (n, k) in [(3usize, 3usize), (64, 3), (300, 8), (1024, 16)] {
        let pts: Vec<f32> = (0..n)
            .flat_map(|i| [(i % 17) as f32 * 0.002, (i / 17) as f32 * 0.002, 0.7 + (rng.below(3) as f32) * 0.001])
            .collect();
        let mut soa = PointsSoa::new(&pts);
        assert_eq!(soa.len(), n);
        for qi in (0..n).step_by(7) {
            let q = [pts[3 * qi] + 0.001, pts[3 * qi + 1], pts[3 * qi + 2]];
            let (mut a, mut da, mut b, mut db) = (vec![0; k], vec![0f32; k], vec![0; k], vec![0f32; k]);
            knn_brute_force(&q, &pts, k, &mut a, &mut da);
            soa.knn(&q, k, &mut b, &mut db);
            assert_eq!((a, da), (b, db), "n {n}, query {qi}");
        }
    }
}

#[test]
fn kernels_refuse_bad_indices_and_too_few_points() {
    let feats = vec![1f32; 2 * 5];
    let mut out = vec![0f32; 2 * 2];
    let err = gather::gather_points(&feats, 5, &[0, 5], &mut out).unwrap_err();
    assert_eq!(err, OpError::IndexOutOfRange { op: "GatherPoints", index: 5, len: 5 });
    assert!(gather::group_points(&feats, 5, &[-1, 0], &mut out).is_err());
    let (mut d, mut i) = (vec![0f32; 3], vec![0i64; 3]);
    let err = nn::three_nn(&[0.0; 3], &[0.0; 6], &mut d, &mut i).unwrap_err();
    assert_eq!(err, OpError::TooFewPoints { op: "ThreeNN", need: 3, got: 2 });
    let (mut phi, mut knn) = (vec![0f32; 3 * 3], vec![0i64; 3]);
    assert!(triangle_descriptor(&[0.0; 3], &[0.0; 6], 3, &mut phi, &mut knn).is_err());
    let mut idx = vec![0i64; 4];
    assert!(matches!(furthest_point_sample(&[0.0; 9], 5, &mut idx), Err(OpError::BadLength { what: "out", .. })));
    assert!(err.to_string().contains("ThreeNN"));
}

/// Values with the cases a max fold must get right: NaN, both infinities, f32::MIN, -0.0.
fn awkward(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n)
        .map(|_| match rng.next_u64() % 16 {
            0 => f32::NAN,
            1 => f32::NEG_INFINITY,
            2 => f32::INFINITY,
            3 => f32::MIN,
            4 => -0.0,
            _ => (rng.next_u64() >> 40) as f32 / (1u64 << 23) as f32 * 4.0 - 2.0,
        })
        .collect()
}

#[test]
fn reduce_max_axis_equals_the_fold_reference_bit_for_bit() {
    use tricons::ops::reduce_max::kernel::{reduce_max_axis, reduce_max_axis_reference};
    let mut rng = Rng::new(11);
    for (outer, k, inner) in [(1, 1, 1), (3, 8, 64), (256, 16, 32), (2, 1, 5), (4, 7, 1), (5, 0, 3), (0, 4, 4)] {
        let x = awkward(&mut rng, outer * k * inner);
        let mut out = vec![0f32; outer * inner];
        reduce_max_axis(&x, outer, k, inner, &mut out).unwrap();
        let want = reduce_max_axis_reference(&x, outer, k, inner);
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&out), bits(&want), "({outer}, {k}, {inner})");
    }
    // exact cases: the maximum, and the fold's start value for an all -inf column
    let mut out = [0f32; 2];
    reduce_max_axis(&[1.0, f32::NEG_INFINITY, 3.0, f32::NEG_INFINITY, 2.0, f32::NEG_INFINITY], 1, 3, 2, &mut out)
        .unwrap();
    assert_eq!(out, [3.0, f32::MIN]);
    assert!(reduce_max_axis(&[0.0; 5], 1, 2, 2, &mut out).is_err(), "wrong input length");
}

#[test]
fn bilinear_upsample_equals_its_reference_and_the_exact_taps() {
    use tricons::ops::upsample::kernel::{upsample2x_plane, upsample2x_reference};
    let mut rng = Rng::new(12);
    let mut scratch = Vec::new();
    for (h, w) in [(1, 1), (1, 5), (6, 1), (3, 4), (24, 24), (7, 13)] {
        let x = awkward(&mut rng, h * w);
        let mut out = vec![0f32; 4 * h * w];
        upsample2x_plane(&x, h, w, &mut scratch, &mut out).unwrap();
        let want = upsample2x_reference(&x, h, w);
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&out), bits(&want), "{h}x{w}");
    }
    // a 2x2 ramp by hand: rows (0, 4) -> (0, 1, 3, 4); columns likewise
    let mut out = [0f32; 16];
    upsample2x_plane(&[0.0, 4.0, 8.0, 12.0], 2, 2, &mut scratch, &mut out).unwrap();
    assert_eq!(&out[..4], &[0.0, 1.0, 3.0, 4.0]);
    assert_eq!(&out[4..8], &[2.0, 3.0, 5.0, 6.0]);
    assert_eq!(&out[12..], &[8.0, 9.0, 11.0, 12.0]);
}

#[test]
fn scatter_elements_equals_its_reference_and_the_onnx_examples() {
    use tricons::ops::scatter_elements::{scatter_elements, scatter_elements_reference};
    let mut rng = Rng::new(13);
    let mut below = |n: usize| (rng.next_u64() % n.max(1) as u64) as usize;
    // ranks 1-4, every axis, updates smaller than the data off the axis, negative and
    // repeated indices (the last update in row-major order wins)
    for case in 0..200 {
        let rank = 1 + case % 4;
        let data_shape: Vec<usize> = (0..rank).map(|_| 1 + below(5)).collect();
        let axis = below(rank);
        let updates_shape: Vec<usize> =
            (0..rank).map(|d| if d == axis { 1 + below(6) } else { 1 + below(data_shape[d]) }).collect();
        let n: usize = updates_shape.iter().product();
        let len = data_shape[axis] as i64;
        let indices: Vec<i64> = (0..n).map(|_| below(2 * len as usize) as i64 - len).collect();
        let updates: Vec<f32> = (0..n).map(|i| i as f32 + 0.5).collect();
        let data: Vec<f32> = (0..data_shape.iter().product::<usize>()).map(|i| -(i as f32)).collect();
        let want = scatter_elements_reference(&data, &data_shape, &indices, &updates, &updates_shape, axis).unwrap();
        let mut got = data.clone();
        scatter_elements(&mut got, &data_shape, &indices, &updates, &updates_shape, axis).unwrap();
        assert_eq!(got, want, "data {data_shape:?} updates {updates_shape:?} axis {axis}");
    }
    // the ONNX operator documentation's two examples
    let mut data = vec![0f32; 9];
    scatter_elements(&mut data, &[3, 3], &[1, 0, 2, 0, 2, 1], &[1.0, 1.1, 1.2, 2.0, 2.1, 2.2], &[2, 3], 0).unwrap();
    assert_eq!(data, [2.0, 1.1, 0.0, 1.0, 0.0, 2.2, 0.0, 2.1, 1.2]);
    let mut data = vec![1.0f32, 2.0, 3.0, 4.0, 5.0];
    scatter_elements(&mut data, &[1, 5], &[1, 3], &[1.1, 2.1], &[1, 2], 1).unwrap();
    assert_eq!(data, [1.0, 1.1, 3.0, 2.1, 5.0]);
    // negative index counts from the end
    let mut data = vec![0i64; 4];
    scatter_elements(&mut data, &[4], &[-1, -4], &[7, 9], &[2], 0).unwrap();
    assert_eq!(data, [9, 0, 0, 7]);
    // bad input: an error, and nothing written
    let mut data = vec![0f32; 4];
    let err = scatter_elements(&mut data, &[4], &[1, 4], &[1.0, 2.0], &[2], 0).unwrap_err();
    assert_eq!(err, OpError::IndexOutOfRange { op: "ScatterElements", index: 4, len: 4 });
    assert_eq!(data, [0.0; 4], "an out-of-range index writes nothing");
    assert!(scatter_elements(&mut data, &[2, 2], &[0; 3], &[0.0; 3], &[1, 3], 0).is_err(), "updates wider than data");
    assert!(scatter_elements(&mut data, &[2, 2], &[0; 2], &[0.0; 2], &[2, 1], 2).is_err(), "axis out of range");
    assert!(scatter_elements(&mut data, &[4], &[0; 2], &[0.0; 3], &[2], 0).is_err(), "updates length");
}

#[test]
fn scatter_rows_equals_scatter_elements_with_broadcast_indices() {
    use tricons::ops::scatter_elements::{scatter_elements_reference, scatter_rows};
    let mut rng = Rng::new(15);
    let mut below = |n: usize| (rng.next_u64() % n.max(1) as u64) as usize;
    for case in 0..200 {
        let rank = 2 + case % 3;
        let data_shape: Vec<usize> = (0..rank).map(|_| 1 + below(5)).collect();
        let rows = data_shape[0];
        let n = 1 + below(7);
        let mut updates_shape = data_shape.clone();
        updates_shape[0] = n;
        let row_len: usize = data_shape[1..].iter().product();
        // negative and repeated indices; every fifth case one index broadcast to all rows
        let k = if case % 5 == 0 { 1 } else { n };
        let indices: Vec<i64> = (0..k).map(|_| below(2 * rows) as i64 - rows as i64).collect();
        let updates: Vec<f32> = (0..n * row_len).map(|i| i as f32 + 0.25).collect();
        let data: Vec<f32> = (0..rows * row_len).map(|i| -(i as f32)).collect();
        // what Expand(Reshape(indices, [-1, 1, ..]), shape(updates)) gives ScatterElements
        let expanded: Vec<i64> = (0..n * row_len).map(|j| indices[if k == 1 { 0 } else { j / row_len }]).collect();
        let want = scatter_elements_reference(&data, &data_shape, &expanded, &updates, &updates_shape, 0).unwrap();
        let mut got = data.clone();
        scatter_rows(&mut got, &data_shape, &indices, &updates, &updates_shape).unwrap();
        assert_eq!(got, want, "data {data_shape:?} updates {updates_shape:?} indices {indices:?}");
    }
    let mut data = vec![0f32; 6];
    let err = scatter_rows(&mut data, &[3, 2], &[1, 3], &[1.0; 4], &[2, 2]).unwrap_err();
    assert_eq!(err, OpError::IndexOutOfRange { op: "ScatterRows", index: 3, len: 3 });
    assert_eq!(data, [0.0; 6], "an out-of-range index writes nothing");
    assert!(scatter_rows(&mut data, &[3, 2], &[0, 1], &[1.0; 3], &[1, 3]).is_err(), "rows of another length");
    assert!(scatter_rows(&mut data, &[3, 2], &[0, 1, 2], &[1.0; 4], &[2, 2]).is_err(), "more indices than rows");
    assert!(scatter_rows(&mut data, &[4, 2], &[0], &[1.0; 2], &[1, 2]).is_err(), "data length");
    // no rows at all (a frame without detections): nothing to do, whatever the index
    scatter_rows::<f32>(&mut [], &[0, 4, 7, 7], &[], &[], &[0, 4, 7, 7]).unwrap();
    scatter_rows::<f32>(&mut [], &[0, 4, 7, 7], &[5], &[], &[0, 4, 7, 7]).unwrap();
}

/// torchvision's level merge, `ScatterElements(data, Expand(Reshape(i, [-1, 1, 1, 1]),
/// Shape(updates)), updates)` along axis 0: rewritten to `ScatterRows` by the Mask R-CNN
/// loader, the same bits as tract's own `ScatterElements`; other shapes are left alone.
#[test]
fn scatter_by_rows_is_rewritten_and_agrees_with_tracts_own() {
    use tract_onnx::pb::tensor_proto::DataType;
    use tract_onnx::pb::{GraphProto, ModelProto, NodeProto, OperatorSetIdProto, TensorProto, ValueInfoProto};
    use tract_onnx::prelude::*;
    let io = |name: &str| ValueInfoProto { name: name.into(), ..Default::default() };
    let node = |op: &str, inputs: &[&str], output: &str| NodeProto {
        name: output.into(),
        op_type: op.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        ..Default::default()
    };
    let model = |shape: Vec<i64>| {
        let mut idx_info = f32_value_info("idx", &[3]);
        if let Some(tract_onnx::pb::type_proto::Value::TensorType(t)) =
            idx_info.r#type.as_mut().and_then(|t| t.value.as_mut())
        {
            t.elem_type = DataType::Int64 as i32;
        }
        let rows_shape = TensorProto {
            name: "rows_shape".into(),
            dims: vec![shape.len() as i64],
            data_type: DataType::Int64 as i32,
            int64_data: shape,
            ..Default::default()
        };
        ModelProto {
            ir_version: 8,
            opset_import: vec![OperatorSetIdProto { domain: String::new(), version: 17 }],
            graph: Some(GraphProto {
                node: vec![
                    node("Reshape", &["idx", "rows_shape"], "idx4"),
                    node("Shape", &["updates"], "updates_shape"),
                    node("Expand", &["idx4", "updates_shape"], "idx_full"),
                    node("ScatterElements", &["data", "idx_full", "updates"], "y"),
                ],
                initializer: vec![rows_shape],
                input: vec![f32_value_info("data", &[5, 4, 2, 3]), idx_info, f32_value_info("updates", &[3, 4, 2, 3])],
                output: vec![io("y")],
                ..Default::default()
            }),
            ..Default::default()
        }
    };
    let data: Vec<f32> = (0..5 * 24).map(|i| i as f32 * 0.5).collect();
    let updates: Vec<f32> = (0..3 * 24).map(|i| -(i as f32) - 1.0).collect();
    let inputs = || {
        tvec![
            Tensor::from_shape(&[5, 4, 2, 3], &data).unwrap().into_tvalue(),
            Tensor::from_shape(&[3], &[4i64, -5, 1]).unwrap().into_tvalue(),
            Tensor::from_shape(&[3, 4, 2, 3], &updates).unwrap().into_tvalue(),
        ]
    };
    let run = |onnx: &tract_onnx::Onnx, m: &ModelProto| -> Vec<f32> {
        let plan = onnx.model_for_proto_model(m).unwrap().into_optimized().unwrap().into_runnable().unwrap();
        let out = plan.run(inputs()).unwrap();
        assert_eq!(out[0].shape(), [5, 4, 2, 3]);
        out[0].try_as_plain_ram().unwrap().as_slice::<f32>().unwrap().to_vec()
    };
    let original = model(vec![-1, 1, 1, 1]);
    let tract_own = run(&tract_onnx::onnx(), &original);
    let mut rewritten = original.clone();
    let report = tricons::segment::rewrite(&mut rewritten).unwrap();
    assert_eq!(report.scatter_rows, 1);
    assert_eq!(rewritten.graph.as_ref().unwrap().node[3].op_type, "ScatterRows");
    let ours = run(&tricons::ops::onnx_with_custom_ops(), &rewritten);
    assert!(ours.iter().zip(&tract_own).all(|(a, b)| a.to_bits() == b.to_bits()));
    // indices 4, -5 (row 0 from the end), 1
    assert_eq!((&ours[96..120], &ours[..24], &ours[24..48]), (&updates[..24], &updates[24..48], &updates[48..]));
    assert_eq!(&ours[48..96], &data[48..96], "rows 2 and 3 untouched");
    // indices that vary inside a row are not a row scatter
    for shape in [vec![-1, 4, 1, 1], vec![-1]] {
        let mut m = model(shape.clone());
        assert_eq!(tricons::segment::rewrite(&mut m).unwrap().scatter_rows, 0, "reshape to {shape:?}");
    }
}

/// One-node ONNX graph `ScatterElements(data, indices, updates)` run by tract's own op and
/// by this crate's (`ops::onnx_with_custom_ops`): the same bits.
#[test]
fn scatter_elements_node_equals_tracts_own() {
    use tract_onnx::pb::{AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, ValueInfoProto};
    use tract_onnx::prelude::*;
    fn model(axis: i64, reduction: &str, inputs: &[Tensor]) -> ModelProto {
        use tract_onnx::pb::tensor_shape_proto::{Dimension, dimension};
        use tract_onnx::pb::{TensorShapeProto, TypeProto, tensor_proto::DataType, type_proto};
        let io = |name: &str| ValueInfoProto { name: name.into(), ..Default::default() };
        let typed = |name: &str, t: &Tensor| {
            let elem_type = match t.datum_type() {
                DatumType::F32 => DataType::Float,
                _ => DataType::Int64,
            } as i32;
            let dim = t
                .shape()
                .iter()
                .map(|&d| Dimension { value: Some(dimension::Value::DimValue(d as i64)), ..Default::default() })
                .collect();
            let tensor = type_proto::Tensor { elem_type, shape: Some(TensorShapeProto { dim }) };
            ValueInfoProto {
                name: name.into(),
                r#type: Some(TypeProto { value: Some(type_proto::Value::TensorType(tensor)), ..Default::default() }),
                ..Default::default()
            }
        };
        let attr = |name: &str| AttributeProto { name: name.into(), ..Default::default() };
        let mut a = attr("axis");
        a.r#type = tract_onnx::pb::attribute_proto::AttributeType::Int as i32;
        a.i = axis;
        let mut r = attr("reduction");
        r.r#type = tract_onnx::pb::attribute_proto::AttributeType::String as i32;
        r.s = reduction.as_bytes().to_vec();
        let node = NodeProto {
            name: "scatter".into(),
            op_type: "ScatterElements".into(),
            input: vec!["data".into(), "indices".into(), "updates".into()],
            output: vec!["y".into()],
            attribute: vec![a, r],
            ..Default::default()
        };
        ModelProto {
            ir_version: 8,
            opset_import: vec![OperatorSetIdProto { domain: String::new(), version: 18 }],
            graph: Some(GraphProto {
                node: vec![node],
                input: vec![typed("data", &inputs[0]), typed("indices", &inputs[1]), typed("updates", &inputs[2])],
                output: vec![io("y")],
                ..Default::default()
            }),
            ..Default::default()
        }
    }
    fn run(onnx: &tract_onnx::Onnx, m: &ModelProto, inputs: &[Tensor]) -> Tensor {
        let model = onnx.model_for_proto_model(m).unwrap();
        let plan = model.into_optimized().unwrap().into_runnable().unwrap();
        let out = plan.run(inputs.iter().cloned().map(|t| t.into_tvalue()).collect()).unwrap();
        out[0].clone().into_tensor()
    }
    let mut rng = Rng::new(14);
    // the Mask R-CNN pattern: (R, C, 7, 7) pooled features of one FPN level scattered
    // into the (N, C, 7, 7) result along axis 0 (indices broadcast over C, 7, 7)
    let (n, r, c) = (12usize, 5usize, 8usize);
    let rows: Vec<i64> = vec![3, 0, 11, 7, 5];
    let idx: Vec<i64> = rows.iter().flat_map(|&i| std::iter::repeat_n(i, c * 49)).collect();
    let upd: Vec<f32> = (0..r * c * 49).map(|_| (rng.next_u64() >> 40) as f32 / 1e5 - 80.0).collect();
    let data = Tensor::zero::<f32>(&[n, c, 7, 7]).unwrap();
    let cases: Vec<(i64, &str, Vec<Tensor>)> = vec![
        (
            0,
            "none",
            vec![
                data.clone(),
                Tensor::from_shape(&[r, c, 7, 7], &idx).unwrap(),
                Tensor::from_shape(&[r, c, 7, 7], &upd).unwrap(),
            ],
        ),
        (
            -1,
            "none",
            vec![
                Tensor::from_shape(&[2, 5], &[0i64, 1, 2, 3, 4, 5, 6, 7, 8, 9]).unwrap(),
                Tensor::from_shape(&[2, 2], &[4i64, -5, 0, 0]).unwrap(),
                Tensor::from_shape(&[2, 2], &[40i64, 50, 60, 70]).unwrap(),
            ],
        ),
        (
            1,
            "add",
            vec![
                Tensor::from_shape(&[2, 3], &[1f32, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap(),
                Tensor::from_shape(&[2, 2], &[0i64, 0, 2, 1]).unwrap(),
                Tensor::from_shape(&[2, 2], &[0.5f32, 0.25, 8.0, 16.0]).unwrap(),
            ],
        ),
    ];
    for (axis, reduction, inputs) in cases {
        let m = model(axis, reduction, &inputs);
        let tract_own = run(&tract_onnx::onnx(), &m, &inputs);
        let ours = run(&tricons::ops::onnx_with_custom_ops(), &m, &inputs);
        assert_eq!(ours, tract_own, "axis {axis}, reduction {reduction}");
        assert_ne!(ours, inputs[0], "the scatter changed the data (axis {axis})");
    }
}

/// Random depthwise geometries (kernels 1x1 to 5x5, strides 1 to 3, dilations, asymmetric
/// padding, planes narrower than the kernel span): the row kernel gives the reference's bits.
#[test]
fn depthwise_equals_its_reference_bit_for_bit() {
    use tricons::ops::conv_geometry::ConvGeometry;
    use tricons::ops::depthwise::{depthwise, depthwise_reference, depthwise_rows};
    let mut rng = Rng::new(18);
    let mut below = |n: u64| (rng.next_u64() % n) as usize;
    let mut checked = 0;
    for _ in 0..300 {
        let g = ConvGeometry {
            c_in: 1 + below(5),
            h: 1 + below(12),
            w: 1 + below(12),
            kernel: [1 + below(5), 1 + below(5)],
            strides: [1 + below(3), 1 + below(3)],
            pads: [below(3), below(3), below(3), below(3)],
            dilations: [1 + below(2), 1 + below(2)],
        };
        let Ok((ho, wo)) = g.output_hw() else { continue };
        let value = |below: &mut dyn FnMut(u64) -> usize| below(2001) as f32 / 100.0 - 10.0;
        let x: Vec<f32> = (0..g.c_in * g.h * g.w).map(|_| value(&mut below)).collect();
        let w: Vec<f32> = (0..g.patch_len()).map(|_| value(&mut below)).collect();
        let b: Vec<f32> = (0..g.c_in).map(|_| value(&mut below)).collect();
        let mut want = vec![0f32; g.c_in * ho * wo];
        depthwise_reference(&x, &w, &b, &g, &mut want).unwrap();
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        // the best build of the CPU, and the baseline one
        for kernel in [depthwise, depthwise_rows] {
            let mut got = vec![f32::NAN; want.len()];
            kernel(&x, &w, &b, &g, &mut got).unwrap();
            assert_eq!(bits(&got), bits(&want), "{g:?}");
        }
        checked += 1;
    }
    assert!(checked > 150, "{checked} geometries fit");
    // wrong lengths are errors, not panics
    let g = ConvGeometry { c_in: 2, h: 3, w: 3, kernel: [3, 3], strides: [1, 1], pads: [1; 4], dilations: [1, 1] };
    assert!(depthwise(&[0.0; 18], &[0.0; 17], &[0.0; 2], &g, &mut [0.0; 18]).is_err());
    assert!(depthwise(&[0.0; 18], &[0.0; 18], &[0.0; 2], &g, &mut [0.0; 17]).is_err());
}

/// A depthwise `Conv` node (MobileNetV3's 5x5 stride-2 and 3x3 stride-1 forms, with and
/// without bias) through the Mask R-CNN loader's rewrite: replaced by `DepthwiseConv2d`,
/// which gives the reference kernel's bits and agrees with tract's own `Conv` on the
/// unrewritten graph within the rounding of a differently ordered sum of the same
/// products (`(taps + 1) * eps * (sum |w x| + |b|)`, twice for both sides); a grouped
/// `Conv` that is not depthwise is left alone.
#[test]
fn depthwise_conv_node_is_rewritten_and_agrees_with_tracts_own() {
    use tract_onnx::pb::{ModelProto, NodeProto, TensorProto, tensor_proto::DataType};
    use tricons::ops::conv_geometry::ConvGeometry;
    use tricons::ops::proto::{a_int, a_ints};
    let tensor = |name: &str, dims: &[usize], v: &[f32]| TensorProto {
        name: name.into(),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: DataType::Float as i32,
        float_data: v.to_vec(),
        ..Default::default()
    };
    let mut rng = Rng::new(19);
    let mut value = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 4.0 - 2.0;
    for (c, k, s, bias, group_in) in [(6, 5, 2, true, 1), (4, 3, 1, false, 1), (4, 3, 1, true, 2)] {
        let (h, w, p) = (11, 9, k / 2);
        let x: Vec<f32> = (0..2 * c * h * w).map(|_| value()).collect();
        let wt: Vec<f32> = (0..c * group_in * k * k).map(|_| value()).collect();
        let b: Vec<f32> = (0..c).map(|_| value()).collect();
        let mut inputs = vec!["x".to_string(), "w".into()];
        let mut initializer = vec![tensor("w", &[c, group_in, k, k], &wt)];
        if bias {
            inputs.push("b".into());
            initializer.push(tensor("b", &[c], &b));
        }
        let node = NodeProto {
            name: "dw".into(),
            op_type: "Conv".into(),
            input: inputs,
            output: vec!["y".into()],
            attribute: vec![
                a_int("group", (c / group_in) as i64),
                a_ints("kernel_shape", vec![k as i64; 2]),
                a_ints("strides", vec![s as i64; 2]),
                a_ints("pads", vec![p as i64; 4]),
            ],
            ..Default::default()
        };
        let g = ConvGeometry { c_in: c, h, w, kernel: [k, k], strides: [s, s], pads: [p; 4], dilations: [1, 1] };
        let (ho, wo) = g.output_hw().unwrap();
        let model = one_node_model(node, initializer, &[2, c, h, w], f32_value_info("y", &[2, c, ho, wo]));
        let run = |m: &ModelProto| run_one_node_graph(m, &x, &[2, c, h, w], &[2, c, ho, wo]);
        let tract_own = run(&model);
        let mut rewritten = model.clone();
        let report = tricons::segment::rewrite(&mut rewritten).unwrap();
        if group_in != 1 {
            assert_eq!(report.depthwise, 0, "a grouped Conv with 2 channels per group is not depthwise");
            continue;
        }
        assert_eq!(report.depthwise, 1);
        assert_eq!(rewritten.graph.as_ref().unwrap().node[0].op_type, "DepthwiseConv2d");
        let ours = run(&rewritten);
        let b = if bias { b.clone() } else { vec![0.0; c] };
        let per = c * ho * wo;
        let mut want = vec![0f32; 2 * per];
        for i in 0..2 {
            let xi = &x[i * c * h * w..(i + 1) * c * h * w];
            tricons::ops::depthwise::depthwise_reference(xi, &wt, &b, &g, &mut want[i * per..(i + 1) * per]).unwrap();
        }
        assert!(ours.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "the rewritten node's bits");
        // |sum| of the products per output, for the bound
        let mut mag = vec![0f32; 2 * per];
        let abs_x: Vec<f32> = x.iter().map(|v| v.abs()).collect();
        let abs_w: Vec<f32> = wt.iter().map(|v| v.abs()).collect();
        let abs_b: Vec<f32> = b.iter().map(|v| v.abs()).collect();
        for i in 0..2 {
            let xi = &abs_x[i * c * h * w..(i + 1) * c * h * w];
            tricons::ops::depthwise::depthwise_reference(xi, &abs_w, &abs_b, &g, &mut mag[i * per..(i + 1) * per])
                .unwrap();
        }
        let taps = (k * k + 1) as f32;
        for (j, ((a, t), m)) in ours.iter().zip(&tract_own).zip(&mag).enumerate() {
            assert!((a - t).abs() <= 2.0 * taps * f32::EPSILON * m, "output {j}: ours {a}, tract {t} (|sum| {m})");
        }
    }
}

/// `Resize2d`'s row kernel against its per-element reference, both modes, on random sizes
/// (up and down, 1-pixel planes): the same bits.
#[test]
fn resize_equals_its_reference_bit_for_bit() {
    use tricons::ops::resize::{ResizeMode, resize_columns, resize_plane, resize_plane_reference};
    let mut rng = Rng::new(20);
    let mut below = |n: u64| (rng.next_u64() % n) as usize;
    for _ in 0..200 {
        let (h, w, ho, wo) = (1 + below(9), 1 + below(9), 1 + below(20), 1 + below(20));
        let x: Vec<f32> = (0..h * w).map(|_| below(2001) as f32 / 100.0 - 10.0).collect();
        for mode in [ResizeMode::LinearHalfPixel, ResizeMode::NearestAsymmetricFloor] {
            let mut want = vec![0f32; ho * wo];
            resize_plane_reference(mode, &x, [h, w], &mut want, [ho, wo]).unwrap();
            let mut got = vec![f32::NAN; ho * wo];
            resize_plane(mode, &x, [h, w], &mut got, [ho, wo], &resize_columns(mode, w, wo)).unwrap();
            assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "{mode:?} {h}x{w} -> {ho}x{wo}");
        }
    }
    let columns = resize_columns(ResizeMode::LinearHalfPixel, 3, 2);
    assert!(resize_plane(ResizeMode::LinearHalfPixel, &[0.0; 5], [2, 3], &mut [0.0; 4], [2, 2], &columns).is_err());
    assert!(
        resize_plane(ResizeMode::LinearHalfPixel, &[0.0; 6], [2, 3], &mut [0.0; 4], [2, 2], &columns[..1]).is_err()
    );
}

/// The Mask R-CNN's two `Resize` forms as one-node graphs (sizes as a constant), through
/// the loader's rewrite: `Resize2d`; nearest gives tract's own bits, linear agrees with
/// tract's own `Resize` within the rounding of the blend (a convex combination of four
/// inputs: `8 * eps * max |x|`); a `Resize` by `scales` is left alone.
#[test]
fn resize_nodes_are_rewritten_and_agree_with_tracts_own() {
    use tract_onnx::pb::{ModelProto, NodeProto, TensorProto, ValueInfoProto, tensor_proto::DataType};
    use tricons::ops::proto::a_string;
    let mut rng = Rng::new(21);
    let (n, c, h, w) = (1, 3, 12, 17);
    let x: Vec<f32> =
        (0..n * c * h * w).map(|_| (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 4.0 - 2.0).collect();
    let cases = [
        ("linear", "half_pixel", None, [8, 11], true),
        ("linear", "half_pixel", None, [29, 40], true),
        ("nearest", "asymmetric", Some("floor"), [24, 34], true),
        ("nearest", "asymmetric", Some("floor"), [24, 34], false),
    ];
    for (mode, coords, nearest, [ho, wo], by_sizes) in cases {
        let mut attribute = vec![a_string("mode", mode), a_string("coordinate_transformation_mode", coords)];
        if let Some(nm) = nearest {
            attribute.push(a_string("nearest_mode", nm));
        }
        let (input, initializer) = if by_sizes {
            let sizes = TensorProto {
                name: "sizes".into(),
                dims: vec![4],
                data_type: DataType::Int64 as i32,
                int64_data: vec![n as i64, c as i64, ho as i64, wo as i64],
                ..Default::default()
            };
            (vec!["x".into(), String::new(), String::new(), "sizes".into()], vec![sizes])
        } else {
            let scales = TensorProto {
                name: "scales".into(),
                dims: vec![4],
                data_type: DataType::Float as i32,
                float_data: vec![1.0, 1.0, 2.0, 2.0],
                ..Default::default()
            };
            (vec!["x".into(), String::new(), "scales".into()], vec![scales])
        };
        let node = NodeProto {
            name: "resize".into(),
            op_type: "Resize".into(),
            input,
            output: vec!["y".into()],
            attribute,
            ..Default::default()
        };
        let model =
            one_node_model(node, initializer, &[n, c, h, w], ValueInfoProto { name: "y".into(), ..Default::default() });
        let run = |m: &ModelProto| run_one_node_graph(m, &x, &[n, c, h, w], &[n, c, ho, wo]);
        let tract_own = run(&model);
        let mut rewritten = model.clone();
        let report = tricons::segment::rewrite(&mut rewritten).unwrap();
        assert_eq!(report.resize, by_sizes as usize, "{mode}, by sizes: {by_sizes}");
        if !by_sizes {
            continue;
        }
        let ours = run(&rewritten);
        let max = x.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (j, (a, t)) in ours.iter().zip(&tract_own).enumerate() {
            if mode == "nearest" {
                assert_eq!(a.to_bits(), t.to_bits(), "{mode} output {j}");
            } else {
                assert!((a - t).abs() <= 8.0 * f32::EPSILON * max, "{mode} output {j}: ours {a}, tract {t}");
            }
        }
    }
}

/// A graph input or output of f32 elements and the given concrete shape.
fn f32_value_info(name: &str, dims: &[usize]) -> tract_onnx::pb::ValueInfoProto {
    use tract_onnx::pb::tensor_shape_proto::{Dimension, dimension};
    use tract_onnx::pb::{TensorShapeProto, TypeProto, ValueInfoProto, tensor_proto::DataType, type_proto};
    let dim = dims
        .iter()
        .map(|&d| Dimension { value: Some(dimension::Value::DimValue(d as i64)), ..Default::default() })
        .collect();
    let t = type_proto::Tensor { elem_type: DataType::Float as i32, shape: Some(TensorShapeProto { dim }) };
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto { value: Some(type_proto::Value::TensorType(t)), ..Default::default() }),
        ..Default::default()
    }
}

/// Plan `model` with this crate's loader, run it on the f32 input `x` of `shape`, check the
/// output's shape and return its values.
/// An opset-17 model of one node reading `x` (f32, `shape`) and writing `y` (`output`).
fn one_node_model(
    node: tract_onnx::pb::NodeProto,
    initializer: Vec<tract_onnx::pb::TensorProto>,
    shape: &[usize],
    output: tract_onnx::pb::ValueInfoProto,
) -> tract_onnx::pb::ModelProto {
    use tract_onnx::pb::{GraphProto, ModelProto, OperatorSetIdProto};
    ModelProto {
        ir_version: 8,
        opset_import: vec![OperatorSetIdProto { domain: String::new(), version: 17 }],
        graph: Some(GraphProto {
            node: vec![node],
            initializer,
            input: vec![f32_value_info("x", shape)],
            output: vec![output],
            ..Default::default()
        }),
        ..Default::default()
    }
}

fn run_one_node_graph(model: &tract_onnx::pb::ModelProto, x: &[f32], shape: &[usize], out_shape: &[usize]) -> Vec<f32> {
    use tract_onnx::prelude::*;
    let onnx = tricons::ops::onnx_with_custom_ops();
    let plan = onnx.model_for_proto_model(model).unwrap().into_optimized().unwrap().into_runnable().unwrap();
    let out = plan.run(tvec![Tensor::from_shape(shape, x).unwrap().into_tvalue()]).unwrap();
    assert_eq!(out[0].shape(), out_shape);
    out[0].try_as_plain_ram().unwrap().as_slice::<f32>().unwrap().to_vec()
}

/// `LayerNormLastAxis` against the f64 reference within the kernel's derived bound, on
/// rows of the widths the pose graphs use (and a remainder width), centred and far from
/// zero (a mean 40x the spread stresses the centring); then a one-node `LayerNormalization`
/// graph through the pose rewrite against tract's own expansion of it, within the two
/// kernels' bounds added.
#[test]
fn layer_norm_is_within_its_bound_of_the_reference_and_of_tracts_own() {
    use tract_onnx::pb::{ModelProto, NodeProto, TensorProto, tensor_proto::DataType};
    use tricons::ops::layer_norm::kernel::{error_bound, layer_norm_reference, layer_norm_rows};
    use tricons::ops::proto::a_float;
    let mut rng = Rng::new(23);
    let mut value = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
    // the bound of every element of (rows, cols) from the exact statistics
    let bounds = |x: &[f32], cols: usize, scale: &[f32], bias: &[f32], eps: f32| -> Vec<f64> {
        let mut out = Vec::new();
        for row in x.chunks_exact(cols) {
            let mean = row.iter().map(|&v| f64::from(v)).sum::<f64>() / cols as f64;
            let var = row.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / cols as f64;
            let sigma = (var + f64::from(eps)).sqrt();
            let mean_abs = row.iter().map(|&v| f64::from(v).abs()).sum::<f64>() / cols as f64;
            for c in 0..cols {
                out.push(error_bound(cols, f64::from(row[c]) - mean, sigma, mean_abs, scale[c], bias[c]));
            }
        }
        out
    };
    for (rows, cols, offset, eps) in [(5, 384, 0.0, 1e-6), (7, 128, 3.0, 1e-5), (3, 35, -40.0, 1e-5), (2, 1, 0.5, 1e-5)]
    {
        let x: Vec<f32> = (0..rows * cols).map(|_| offset + value()).collect();
        let scale: Vec<f32> = (0..cols).map(|_| 1.0 + value()).collect();
        let bias: Vec<f32> = (0..cols).map(|_| value()).collect();
        let mut got = vec![0f32; rows * cols];
        layer_norm_rows(&x, rows, cols, &scale, &bias, eps, &mut got).unwrap();
        let want = layer_norm_reference(&x, cols, &scale, &bias, eps);
        let bound = bounds(&x, cols, &scale, &bias, eps);
        for (i, ((g, w), b)) in got.iter().zip(&want).zip(&bound).enumerate() {
            // the reference is rounded to f32 once: half an ulp of it on top
            let slack = b + f64::from(w.abs()) * f64::from(f32::EPSILON) / 2.0;
            assert!(f64::from((g - w).abs()) <= slack, "cols {cols} offset {offset} [{i}]: {g} vs {w}, bound {slack}");
        }
    }

    // one node: (2, 6, 128) with scale and bias, tract's expansion against the rewrite
    let (b, n, c) = (2usize, 6usize, 128usize);
    let x: Vec<f32> = (0..b * n * c).map(|_| 0.5 + value()).collect();
    let scale: Vec<f32> = (0..c).map(|_| 1.0 + value()).collect();
    let bias: Vec<f32> = (0..c).map(|_| value()).collect();
    let tensor = |name: &str, v: &[f32]| TensorProto {
        name: name.into(),
        dims: vec![v.len() as i64],
        data_type: DataType::Float as i32,
        float_data: v.to_vec(),
        ..Default::default()
    };
    let node = NodeProto {
        name: "ln".into(),
        op_type: "LayerNormalization".into(),
        input: vec!["x".into(), "scale".into(), "bias".into()],
        output: vec!["y".into()],
        attribute: vec![a_float("epsilon", 1e-5)],
        ..Default::default()
    };
    let model = one_node_model(
        node,
        vec![tensor("scale", &scale), tensor("bias", &bias)],
        &[b, n, c],
        f32_value_info("y", &[b, n, c]),
    );
    let run = |m: &ModelProto| run_one_node_graph(m, &x, &[b, n, c], &[b, n, c]);
    let tract_own = run(&model);
    let mut rewritten = model.clone();
    assert_eq!(tricons::pose::rewrite::replace_layer_norms(&mut rewritten), 1);
    assert_eq!(rewritten.graph.as_ref().unwrap().node[0].op_type, "LayerNormLastAxis");
    let ours = run(&rewritten);
    let want = layer_norm_reference(&x, c, &scale, &bias, 1e-5);
    let bound = bounds(&x, c, &scale, &bias, 1e-5);
    for (i, (((o, t), w), bd)) in ours.iter().zip(&tract_own).zip(&want).zip(&bound).enumerate() {
        let slack = 2.0 * bd + f64::from(w.abs()) * f64::from(f32::EPSILON);
        assert!(f64::from((o - t).abs()) <= slack, "[{i}]: ours {o}, tract {t}, bound {slack}");
    }
    // a node the rewrite does not cover (a second output) is left alone
    let mut two = model.clone();
    two.graph.as_mut().unwrap().node[0].output.push("mean".into());
    assert_eq!(tricons::pose::rewrite::replace_layer_norms(&mut two), 0);
}

/// `SoftmaxLastAxis` against the f64 reference within the kernel's derived bound, on rows
/// of the lengths the pose graphs use (the ViT's 197 tokens, 32 keypoints, 1024 points), a
/// remainder length and a single value, with spreads from 0.1 to 200 (rows whose smallest
/// terms underflow); then a one-node `Softmax` graph through the pose rewrite against
/// tract's own `Softmax`, within our bound twice plus 8 ulps of the value for tract's.
#[test]
fn softmax_is_within_its_bound_of_the_reference_and_of_tracts_own() {
    use tract_onnx::pb::{ModelProto, NodeProto};
    use tricons::ops::proto::a_int;
    use tricons::ops::softmax::kernel::{error_bounds, softmax_reference, softmax_rows};
    let mut rng = Rng::new(29);
    let mut value = || (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
    let check = |x: &[f32], got: &[f32], cols: usize, extra_ulps: f64, what: &str| {
        let want = softmax_reference(x, cols);
        for (r, (row, (g, w))) in x.chunks(cols).zip(got.chunks(cols).zip(want.chunks(cols))).enumerate() {
            let bound = error_bounds(row);
            for i in 0..cols {
                let slack = bound[i] * if extra_ulps > 0.0 { 2.0 } else { 1.0 }
                    + extra_ulps * w[i] * f64::from(f32::EPSILON) / 2.0;
                let err = (f64::from(g[i]) - w[i]).abs();
                assert!(err <= slack, "{what}: cols {cols} row {r} [{i}]: {} vs {}, bound {slack:e}", g[i], w[i]);
            }
        }
    };
    for (rows, cols, spread) in [(6, 197, 8.0), (4, 32, 0.1), (2, 1024, 30.0), (5, 35, 200.0), (3, 1, 1.0)] {
        let x: Vec<f32> = (0..rows * cols).map(|_| spread * value()).collect();
        let mut got = x.clone();
        softmax_rows(&mut got, cols).unwrap();
        check(&x, &got, cols, 0.0, "kernel");
    }

    // one node over (2, 6, 197): tract's Softmax against the rewrite's
    let shape = [2usize, 6, 197];
    let x: Vec<f32> = (0..shape.iter().product()).map(|_| 6.0 * value()).collect();
    let node = NodeProto {
        name: "sm".into(),
        op_type: "Softmax".into(),
        input: vec!["x".into()],
        output: vec!["y".into()],
        attribute: vec![a_int("axis", -1)],
        ..Default::default()
    };
    let model = one_node_model(node, vec![], &shape, f32_value_info("y", &shape));
    let run = |m: &ModelProto| run_one_node_graph(m, &x, &shape, &shape);
    let tract_own = run(&model);
    check(&x, &tract_own, 197, 8.0, "tract's own Softmax");
    let mut rewritten = model.clone();
    assert_eq!(tricons::pose::rewrite::replace_softmaxes(&mut rewritten), 1);
    assert_eq!(rewritten.graph.as_ref().unwrap().node[0].op_type, "SoftmaxLastAxis");
    let ours = run(&rewritten);
    check(&x, &ours, 197, 0.0, "rewritten");
    // another axis, or no axis before opset 13 (where the default is 1), is left alone
    let mut other = model.clone();
    other.graph.as_mut().unwrap().node[0].attribute = vec![a_int("axis", 1)];
    assert_eq!(tricons::pose::rewrite::replace_softmaxes(&mut other), 0);
    let mut old = model.clone();
    old.graph.as_mut().unwrap().node[0].attribute.clear();
    old.opset_import[0].version = 12;
    assert_eq!(tricons::pose::rewrite::replace_softmaxes(&mut old), 0);
    old.opset_import[0].version = 13;
    assert_eq!(tricons::pose::rewrite::replace_softmaxes(&mut old), 1);
}
