//! What the segmenter card's pose-stage mask handling costs per frame (issue 16): the rim
//! erosion (`pose_mask_erode_px`) and the depth-outlier step (`pose_mask_max_radius_m`) on
//! every object mask of the first demo frame (640 x 480), as `Segmenter::pose_mask` runs
//! them for each detection.
//!
//! `cargo bench --bench pose_mask`. Results: docs/results.md, "Predicted masks for the pose
//! stage".

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use tricons::recording::open_recording;
use tricons::segment::depth_outliers::drop_far_pixels;
use tricons::segment::erode::erode_for_pose;

fn bench(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let rec = open_recording(&root.join("tests/data/synthnocs-demo")).expect("the demo recording");
    let frame = rec.read_frame(0).expect("frame 0");
    let masks = rec.read_annotations(0).expect("annotations").and_then(|a| a.instance_masks()).expect("instance masks");
    let width = frame.color.width as usize;
    let mut g = c.benchmark_group(format!("pose_mask/{}_masks_640x480", masks.len()));
    g.bench_function("erode_1px", |b| {
        b.iter(|| {
            for m in &masks {
                black_box(erode_for_pose(black_box(m.clone()), width, 1));
            }
        })
    });
    g.bench_function("depth_outliers", |b| {
        b.iter(|| {
            for m in &masks {
                black_box(drop_far_pixels(black_box(m.clone()), &frame.depth, &frame.intrinsics, 0.18));
            }
        })
    });
    g.bench_function("clone_only", |b| {
        b.iter(|| {
            for m in &masks {
                black_box(black_box(m.clone()));
            }
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
