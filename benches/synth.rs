//! SynthNOCS benchmarks: `render_frame` at 640x480 (rendering only), and the
//! PNG encoding + writing of one frame's files, measured separately.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use tricons::recording::write_frame_files;
use tricons::synth::{SynthConfig, render_frame};

fn bench_render(c: &mut Criterion) {
    let cfg = SynthConfig::default();
    let mut index = 0u64;
    c.bench_function("synth render_frame 640x480", |b| {
        b.iter(|| {
            index = (index + 1) % 64;
            black_box(render_frame(&cfg, 1, index))
        })
    });
}

fn bench_write(c: &mut Criterion) {
    let cfg = SynthConfig::default();
    let frame = render_frame(&cfg, 1, 0);
    let dir = std::env::temp_dir().join(format!("synth-bench-{}", std::process::id()));
    if std::fs::create_dir_all(&dir).is_err() {
        return;
    }
    c.bench_function("synth write_frame_files (PNG encode + write)", |b| {
        b.iter(|| black_box(write_frame_files(&dir, "000000", &frame.frame, Some(&frame.annotations)).is_ok()))
    });
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench_render, bench_write
}
criterion_main!(benches);
