//! KD-tree (kiddo) against the brute-force kernels, at the sizes the pose network uses.
//!
//! `cargo bench --bench knn`. For every neighbour search of the
//! shipped (N 512) and paper (N 1024) graphs: ThreeNN (k = 3 of the coarser level), the
//! triangle descriptor's local kNN (keypoints among the points, k = 8 / 16) and BallQuery
//! (first `nsample` in index order within a radius). The kiddo side includes building the
//! tree, as the op must per call: each call gets a new cloud. `brute` is the scalar
//! reference, `brute-soa` the vectorised scan, `kiddo` the bare tree (no tie handling) and
//! `ops` what the kernels run ([`KnnIndex`]: tree from 256 points with an exactness check,
//! else the scan). Results: docs/results.md.

use std::hint::black_box;
use std::num::NonZero;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use tricons::ops::ball_query::kernel::ball_query;
use tricons::ops::{KnnIndex, PointsSoa, knn_brute_force};
use tricons::rng::Rng;

/// `n` points on an object-sized ellipsoid surface (semi-axes 5, 8, 4 cm) 0.7 m away, 1 mm noise.
fn object_cloud(n: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let (z, phi) = (rng.range(-1.0, 1.0), rng.range(0.0, std::f64::consts::TAU));
            let r = (1.0 - z * z).sqrt();
            let noise = |rng: &mut Rng| rng.range(-0.001, 0.001);
            [
                (0.05 * r * phi.cos() + noise(&mut rng)) as f32,
                (0.08 * r * phi.sin() + noise(&mut rng)) as f32,
                (0.7 + 0.04 * z + noise(&mut rng)) as f32,
            ]
        })
        .collect()
}

fn flat(points: &[[f32; 3]]) -> Vec<f32> {
    points.iter().flatten().copied().collect()
}

/// The k nearest of every query, concatenated, from `search(query, idx, d2)`.
fn each_query(queries: &[[f32; 3]], k: usize, mut search: impl FnMut(&[f32], &mut [usize], &mut [f32])) -> Vec<usize> {
    let (mut idx, mut d2) = (vec![0usize; k], vec![0f32; k]);
    let mut out = Vec::with_capacity(queries.len() * k);
    for q in queries {
        search(q, &mut idx, &mut d2);
        out.extend_from_slice(&idx);
    }
    out
}

fn brute_knn(queries: &[[f32; 3]], points: &[f32], k: usize) -> Vec<usize> {
    each_query(queries, k, |q, idx, d2| knn_brute_force(q, points, k, idx, d2))
}

/// Structure-of-arrays distances (vectorised), then the same selection.
fn soa_knn(queries: &[[f32; 3]], points: &[f32], k: usize) -> Vec<usize> {
    let mut soa = PointsSoa::new(points);
    each_query(queries, k, |q, idx, d2| soa.knn(q, k, idx, d2))
}

/// What the ops run.
fn index_knn(queries: &[[f32; 3]], points: &[f32], k: usize) -> Vec<usize> {
    let mut index = KnnIndex::new(points, queries.len());
    each_query(queries, k, |q, idx, d2| index.knn(q, k, idx, d2))
}

fn kiddo_knn(queries: &[[f32; 3]], points: &[[f32; 3]], k: usize) -> Vec<usize> {
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(points).expect("tree");
    let k = NonZero::new(k).expect("k > 0");
    let mut out = Vec::with_capacity(queries.len() * k.get());
    for q in queries {
        out.extend(tree.query(q).nearest_n::<SquaredEuclidean<f32>>(k).execute().iter().map(|r| r.item as usize));
    }
    out
}

fn kiddo_ball(points: &[[f32; 3]], centres: &[[f32; 3]], radius: f32, nsample: usize) -> Vec<i64> {
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(points).expect("tree");
    let mut out = Vec::with_capacity(centres.len() * nsample);
    for c in centres {
        let mut hits: Vec<i64> = tree
            .query(c)
            .within::<SquaredEuclidean<f32>>(radius * radius)
            .exclusive_boundaries()
            .unsorted()
            .execute()
            .iter()
            .map(|r| r.item as i64)
            .collect();
        hits.sort_unstable();
        hits.truncate(nsample);
        let pad = hits.first().copied().unwrap_or(0);
        hits.resize(nsample, pad);
        out.extend_from_slice(&hits);
    }
    out
}

fn bench_knn(c: &mut Criterion) {
    // (label, queries, points, k): ThreeNN of each FP level, then the PIGA local kNN
    let cases: &[(&str, usize, usize, usize)] = &[
        ("shipped ThreeNN 512<-256", 512, 256, 3),
        ("shipped ThreeNN 256<-64", 256, 64, 3),
        ("shipped local kNN 32 in 512, k8", 32, 512, 8),
        ("paper ThreeNN 1024<-512", 1024, 512, 3),
        ("paper ThreeNN 512<-256", 512, 256, 3),
        ("paper local kNN 96 in 1024, k16", 96, 1024, 16),
    ];
    let mut group = c.benchmark_group("knn");
    for &(label, nq, np, k) in cases {
        let points = object_cloud(np, 1);
        let queries = object_cloud(nq, 2);
        let pf = flat(&points);
        // same neighbours (the random cloud has no exact distance ties)
        assert_eq!(brute_knn(&queries, &pf, k), kiddo_knn(&queries, &points, k), "{label}");
        assert_eq!(brute_knn(&queries, &pf, k), soa_knn(&queries, &pf, k), "{label}");
        assert_eq!(brute_knn(&queries, &pf, k), index_knn(&queries, &pf, k), "{label}");
        group.bench_with_input(BenchmarkId::new("brute", label), &k, |b, &k| {
            b.iter(|| black_box(brute_knn(&queries, &pf, k)))
        });
        group.bench_with_input(BenchmarkId::new("brute-soa", label), &k, |b, &k| {
            b.iter(|| black_box(soa_knn(&queries, &pf, k)))
        });
        group.bench_with_input(BenchmarkId::new("kiddo", label), &k, |b, &k| {
            b.iter(|| black_box(kiddo_knn(&queries, &points, k)))
        });
        group.bench_with_input(BenchmarkId::new("ops", label), &k, |b, &k| {
            b.iter(|| black_box(index_knn(&queries, &pf, k)))
        });
    }
    group.finish();
}

fn bench_ball_query(c: &mut Criterion) {
    // (label, points, centres, radius m, nsample): the first SA level of each config
    let cases: &[(&str, usize, usize, f32, usize)] = &[
        ("shipped 256 in 512, r 4 cm, 16", 512, 256, 0.04, 16),
        ("shipped 64 in 256, r 8 cm, 16", 256, 64, 0.08, 16),
        ("paper 512 in 1024, r 2 cm, 32", 1024, 512, 0.02, 32),
        ("paper 256 in 512, r 4 cm, 32", 512, 256, 0.04, 32),
    ];
    let mut group = c.benchmark_group("ball_query");
    for &(label, np, ns, radius, nsample) in cases {
        let points = object_cloud(np, 3);
        let centres: Vec<[f32; 3]> = points.iter().step_by(np / ns).copied().take(ns).collect();
        let (pf, cf) = (flat(&points), flat(&centres));
        let mut out = vec![0i64; ns * nsample];
        ball_query(&pf, &cf, radius, nsample, &mut out).expect("ball query");
        assert_eq!(out, kiddo_ball(&points, &centres, radius, nsample), "{label}");
        group.bench_function(BenchmarkId::new("brute", label), |b| {
            b.iter(|| {
                ball_query(&pf, &cf, radius, nsample, &mut out).expect("ball query");
                black_box(&out);
            })
        });
        group.bench_function(BenchmarkId::new("kiddo", label), |b| {
            b.iter(|| black_box(kiddo_ball(&points, &centres, radius, nsample)))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(std::time::Duration::from_secs(2));
    targets = bench_knn, bench_ball_query
}
criterion_main!(benches);
