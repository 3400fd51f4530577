//! Property tests (proptest): invariants that must hold for every input, not only the
//! cases the other suites spell out. Issue 17: atomic writes, queue accounting,
//! decoders' sizes, torn-line recovery, frame pairing, the predictions line format.
//!
//! Each property runs proptest's default 256 cases (`PROPTEST_CASES` changes it);
//! a failure prints the minimal input proptest shrank it to.

use proptest::prelude::*;
use std::collections::VecDeque;
use tricons::atomic::write_atomic;
use tricons::capture::decode::{PixelFormat, decode_color, decode_depth_z16};
use tricons::capture::pairing::{FramePairer, Timed};
use tricons::output::predictions::to_json_line;
use tricons::output::sink::{JsonLinesSink, Sink};
use tricons::output::{FramePredictions, PredInstance};
use tricons::pipeline::{BoundedQueue, WhenFull};
use tricons::{Category, Pose};

#[derive(Clone, Debug)]
enum QueueOp {
    Push,
    Pop,
}

fn queue_ops() -> impl Strategy<Value = Vec<QueueOp>> {
    prop::collection::vec(prop_oneof![3 => Just(QueueOp::Push), 2 => Just(QueueOp::Pop)], 0..200)
}

proptest! {
    /// A newest-wins queue against a reference model: FIFO order, the capacity never
    /// exceeded, and every item pushed is either popped, still queued or counted as dropped
    /// (and the dropped ones are exactly the oldest at the time).
    #[test]
    fn drop_oldest_queue_accounts_for_every_item(capacity in 1usize..8, ops in queue_ops()) {
        let q = BoundedQueue::new(capacity, WhenFull::DropOldest);
        let mut model: VecDeque<u32> = VecDeque::new();
        let (mut pushed, mut popped, mut evicted) = (0u64, 0u64, 0u64);
        for (i, op) in ops.iter().enumerate() {
            match op {
                QueueOp::Push => {
                    let out = q.push(i as u32).expect("an open queue accepts items");
                    pushed += 1;
                    let want = if model.len() == capacity { model.pop_front() } else { None };
                    model.push_back(i as u32);
                    prop_assert_eq!(out, want);
                    evicted += u64::from(out.is_some());
                }
                QueueOp::Pop => {
                    if model.is_empty() {
                        continue; // pop would wait on an open, empty queue
                    }
                    prop_assert_eq!(q.pop(), model.pop_front());
                    popped += 1;
                }
            }
            prop_assert!(q.len() <= capacity);
            prop_assert_eq!(q.len(), model.len());
        }
        prop_assert_eq!(q.dropped(), evicted);
        prop_assert_eq!(pushed, popped + q.dropped() + q.len() as u64);
        prop_assert!(q.max_depth() <= capacity);
        q.close();
        prop_assert!(q.push(0).is_err(), "a closed queue refuses items");
        let rest: Vec<u32> = std::iter::from_fn(|| q.pop()).collect();
        prop_assert_eq!(rest, Vec::from(model));
    }

    /// A blocking queue used without waiting (push only when there is room) loses nothing.
    #[test]
    fn blocking_queue_never_drops(capacity in 1usize..8, ops in queue_ops()) {
        let q = BoundedQueue::new(capacity, WhenFull::Block);
        let mut model: VecDeque<u32> = VecDeque::new();
        for (i, op) in ops.iter().enumerate() {
            match op {
                QueueOp::Push if model.len() < capacity => {
                    prop_assert_eq!(q.push(i as u32).expect("open"), None);
                    model.push_back(i as u32);
                }
                QueueOp::Pop if !model.is_empty() => prop_assert_eq!(q.pop(), model.pop_front()),
                _ => {}
            }
        }
        prop_assert_eq!(q.dropped(), 0);
        prop_assert_eq!(q.len(), model.len());
    }
}

/// Strictly increasing timestamps from positive gaps.
fn stamps(max_len: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(0.001f64..0.08, 0..max_len).prop_map(|gaps| {
        let mut t = 0.0;
        gaps.iter()
            .map(|g| {
                t += g;
                t
            })
            .collect()
    })
}

proptest! {
    /// Pairing by stamp: every pair is within the tolerance, both streams come out in
    /// time order, no frame is used twice, and pushed = paired + dropped + still queued
    /// (checked by clearing at the end) for each stream.
    #[test]
    fn pairing_is_within_tolerance_ordered_and_accounted(
        color in stamps(40), depth in stamps(40), tolerance_s in 0.0f64..0.03,
        capacity in 1usize..6, order in prop::collection::vec(any::<bool>(), 80),
    ) {
        let mut pairer: FramePairer<usize, usize> = FramePairer::new(tolerance_s, capacity);
        let (mut ci, mut di) = (0, 0);
        let mut pairs = Vec::new();
        let mut k = 0;
        while ci < color.len() || di < depth.len() {
            let take_color = di >= depth.len() || (ci < color.len() && order[k % order.len()]);
            k += 1;
            if take_color {
                pairer.push_color(Timed { timestamp_s: color[ci], value: ci });
                ci += 1;
            } else {
                pairer.push_depth(Timed { timestamp_s: depth[di], value: di });
                di += 1;
            }
            while let Some(p) = pairer.pop_pair() {
                pairs.push(p);
            }
        }
        for p in &pairs {
            prop_assert!(p.skew_s().abs() <= tolerance_s + 1e-12, "skew {} > {}", p.skew_s(), tolerance_s);
            prop_assert_eq!(p.color.timestamp_s, color[p.color.value]);
            prop_assert_eq!(p.depth.timestamp_s, depth[p.depth.value]);
        }
        for w in pairs.windows(2) {
            prop_assert!(w[0].color.value < w[1].color.value);
            prop_assert!(w[0].depth.value < w[1].depth.value);
        }
        pairer.clear();
        let s = pairer.stats();
        prop_assert_eq!(s.paired as usize, pairs.len());
        prop_assert_eq!(s.paired + s.dropped_color, color.len() as u64);
        prop_assert_eq!(s.paired + s.dropped_depth, depth.len() as u64);
    }
}

proptest! {
    /// Decoders check sizes before they touch the buffer: for any geometry and any buffer
    /// length they return an error or an image of exactly width x height pixels, and they
    /// succeed whenever the buffer holds the rows the stride promises.
    #[test]
    fn packed_decoders_return_exact_sizes_or_errors(
        format in prop_oneof![Just(PixelFormat::Yuyv), Just(PixelFormat::Rgb3), Just(PixelFormat::Z16)],
        width in 0u32..24, height in 0u32..12, pad in 0u32..9, len_delta in -40i64..40,
    ) {
        let bpp = match format { PixelFormat::Rgb3 => 3, _ => 2 };
        let stride = width * bpp + pad;
        let full = i64::from(stride) * i64::from(height);
        let len = (full + len_delta).max(0) as usize;
        let data: Vec<u8> = (0..len).map(|i| (i * 37 % 251) as u8).collect();
        let result = match format {
            PixelFormat::Z16 => decode_depth_z16(&data, width, height, stride).map(|d| d.len()),
            f => decode_color(f, &data, width, height, stride).map(|img| {
                assert_eq!((img.width, img.height), (width, height));
                img.data.len() / 3
            }),
        };
        if let Ok(pixels) = result {
            prop_assert_eq!(pixels, (width * height) as usize);
            prop_assert!(width > 0 && height > 0, "an empty frame is not a frame");
        }
        // YUYV needs an even width; otherwise a buffer with every row present decodes
        let valid_geometry = width > 0 && height > 0 && !(format == PixelFormat::Yuyv && width % 2 == 1);
        if (len as i64) < full {
            prop_assert!(result.is_err(), "a buffer short of the {full} bytes the stride promises was accepted");
        }
        if valid_geometry && len_delta >= 0 {
            prop_assert!(result.is_ok(), "a complete {width}x{height} buffer was refused: {:?}", result.err());
        }
    }
}

proptest! {
    /// Whatever an earlier run left (any bytes, torn or not), opening a JSON Lines sink
    /// keeps exactly the complete lines and the next line starts on a line of its own.
    #[test]
    fn a_sink_keeps_the_whole_lines_of_any_previous_file(
        previous in prop::collection::vec(prop_oneof![4 => any::<u8>(), 1 => Just(b'\n')], 0..300),
        line in "[a-z{}:,\"0-9]{0,40}",
    ) {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("out.jsonl");
        std::fs::write(&path, &previous).expect("seed file");
        let whole = previous.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let mut sink = JsonLinesSink::append(&path).expect("open");
        prop_assert_eq!(std::fs::read(&path).expect("read"), previous[..whole].to_vec());
        sink.publish(&FramePredictions::default(), &line).expect("publish");
        sink.flush().expect("flush");
        let mut want = previous[..whole].to_vec();
        want.extend_from_slice(line.as_bytes());
        want.push(b'\n');
        prop_assert_eq!(std::fs::read(&path).expect("read"), want);
    }

    /// Atomic writes: after any sequence of writes the file holds the last content in
    /// full and no temporary file is left beside it.
    #[test]
    fn atomic_writes_leave_the_last_content_and_no_temporaries(
        contents in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..2000), 1..6),
    ) {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("frame.bin");
        for c in &contents {
            write_atomic(&path, c).expect("write");
            prop_assert_eq!(&std::fs::read(&path).expect("read"), c);
        }
        let names: Vec<_> = std::fs::read_dir(dir.path()).expect("list").map(|e| e.expect("entry").file_name()).collect();
        prop_assert_eq!(names, vec![std::ffi::OsString::from("frame.bin")]);
    }
}

fn instance() -> impl Strategy<Value = PredInstance> {
    (
        0usize..6,
        0.0f64..=1.0,
        (-3.2f64..3.2, -1.5f64..1.5, -3.2f64..3.2),
        prop::array::uniform3(-5.0f64..5.0),
        prop::array::uniform3(0.001f64..2.0),
        prop::option::of(prop::array::uniform4(0.0f64..640.0)),
    )
        .prop_map(|(c, score, (roll, pitch, yaw), t, size_m, box2d)| PredInstance {
            class: Category::ALL[c],
            score,
            camera_from_object: Pose::new(
                *nalgebra::Rotation3::from_euler_angles(roll, pitch, yaw).matrix(),
                nalgebra::Vector3::from(t),
            ),
            size_m,
            box2d,
            mask: None,
        })
}

proptest! {
    /// The predictions format round-trips: a line written by the runtime reads back equal
    /// (every float exactly, the rotation still accepted as a rotation) and is one line.
    #[test]
    fn prediction_lines_read_back_equal(
        frame in "[0-9]{6}", timestamp_s in prop::option::of(0.0f64..1e6),
        instances in prop::collection::vec(instance(), 0..6),
    ) {
        let original = FramePredictions { frame, timestamp_s, instances };
        let line = to_json_line(&original);
        prop_assert!(!line.contains('\n'));
        let back: FramePredictions = serde_json::from_str(&line).expect("the runtime's own line parses");
        prop_assert_eq!(back, original);
    }
}
