//! The service pipeline: order, drops under a slow stage, draining on stop,
//! a source failing mid-stream, the HTTP view.

use std::io::{Read, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tricons::capture::{CameraConfig, FrameSource, Pace, RecordingSource, SourceFrame};
use tricons::output::http::{HttpServer, HubSink, StreamHub};
use tricons::output::sink::Sink;
use tricons::output::{FramePredictions, PredInstance};
use tricons::pipeline::{Detection, Estimate, GroundTruthMasks, PipelineBuilder, PipelineStats, PoseStage, Segment};
use tricons::pose::PoseEstimator;

const DEMO: &str = "tests/data/synthnocs-demo";

/// Collects what the pipeline publishes.
#[derive(Clone, Default)]
struct Collect(Arc<Mutex<Vec<FramePredictions>>>);

impl Sink for Collect {
    fn describe(&self) -> String {
        "collect".into()
    }
    fn publish(&mut self, frame: &FramePredictions, line: &str) -> tricons::Result<()> {
        let parsed: FramePredictions = serde_json::from_str(line).unwrap();
        assert_eq!(&parsed, frame);
        self.0.lock().unwrap().push(frame.clone());
        Ok(())
    }
    fn flush(&mut self) -> tricons::Result<()> {
        Ok(())
    }
}

impl Collect {
    fn frames(&self) -> Vec<FramePredictions> {
        self.0.lock().unwrap().clone()
    }
}

/// A live camera stand-in: `frames` tiny frames, one every `period`, whether or not they are consumed.
struct Ticker {
    frames: u64,
    period: Duration,
    seq: u64,
    next_at: Option<Instant>,
}

impl Ticker {
    fn new(frames: u64, period: Duration) -> Ticker {
        Ticker { frames, period, seq: 0, next_at: None }
    }
}

impl FrameSource for Ticker {
    fn describe(&self) -> String {
        "ticker".into()
    }
    fn camera(&self) -> CameraConfig {
        CameraConfig::registered(INTRINSICS_4X4, 0.001)
    }
    fn next_frame(&mut self) -> tricons::Result<Option<SourceFrame>> {
        if self.seq == self.frames {
            return Ok(None);
        }
        let due = *self.next_at.get_or_insert_with(Instant::now);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        self.next_at = Some(due + self.period);
        let frame = tricons::RgbdFrame {
            color: tricons::ColorImage::new(4, 4),
            depth: tricons::DepthImage::new(4, 4, 0.001),
            intrinsics: INTRINSICS_4X4,
            timestamp_s: self.seq as f64 * self.period.as_secs_f64(),
        };
        self.seq += 1;
        Ok(Some(SourceFrame {
            seq: self.seq - 1,
            id: format!("{:06}", self.seq - 1),
            frame,
            annotations: None,
            captured_at: Instant::now(),
        }))
    }
    fn reopen(&mut self) -> tricons::Result<()> {
        Ok(())
    }
    fn is_live(&self) -> bool {
        true
    }
}

const INTRINSICS_4X4: tricons::Intrinsics =
    tricons::Intrinsics { width: 4, height: 4, fx: 4.0, fy: 4.0, cx: 1.5, cy: 1.5 };

/// No instances (the stage costs nothing).
struct NoMasks;
impl Segment for NoMasks {
    fn segment(&mut self, _frame: &SourceFrame) -> tricons::Result<Vec<Detection>> {
        Ok(Vec::new())
    }
}

/// No instances, but every frame it "drops" one duplicate and two detections of no NOCS
/// class, as a segmenter with an "other" class counts them.
#[derive(Default)]
struct DropsOthers(u64);
impl Segment for DropsOthers {
    fn segment(&mut self, _frame: &SourceFrame) -> tricons::Result<Vec<Detection>> {
        self.0 += 1;
        Ok(Vec::new())
    }
    fn duplicates_dropped(&self) -> u64 {
        self.0
    }
    fn not_nocs_dropped(&self) -> u64 {
        2 * self.0
    }
}

/// A pose stage that takes `delay` per frame and reports the frame's sequence number as its score.
struct Slow(Duration);
impl Estimate for Slow {
    fn estimate(&mut self, frame: &SourceFrame, _d: &[Detection]) -> tricons::Result<Vec<PredInstance>> {
        std::thread::sleep(self.0);
        Ok(vec![PredInstance {
            class: tricons::Category::Mug,
            score: 1.0 / (1.0 + frame.seq as f64),
            camera_from_object: tricons::Pose::IDENTITY,
            size_m: [0.1; 3],
            box2d: None,
            mask: None,
        }])
    }
}

fn seq_of(f: &FramePredictions) -> u64 {
    (1.0 / f.instances[0].score - 1.0).round() as u64
}

fn demo(pace: Pace, loops: Option<u64>) -> RecordingSource {
    RecordingSource::open(Path::new(&crate::common::cli::repo(DEMO)), pace)
        .unwrap()
        .looped(loops)
        .with_annotations(true)
}

#[test]
fn the_pose_service_publishes_what_the_estimator_gives_in_order() {
    let model = crate::common::cli::repo("models/tricons-pose.card.json");
    let estimator = PoseEstimator::load(Path::new(&model)).unwrap();
    // One frame twice (the aarch64 suite runs this under qemu).
    let dir = tempfile::tempdir().unwrap();
    let rec = crate::common::cli::demo_subset(dir.path(), 1, true);
    let open = || RecordingSource::open(&rec, Pace::Max).unwrap().looped(Some(2)).with_annotations(true);
    let out = Collect::default();
    let summary =
        PipelineBuilder::new(Box::new(open()), Box::new(GroundTruthMasks), Box::new(PoseStage::new(estimator, 7)))
            .sink(Box::new(out.clone()))
            .build()
            .run()
            .unwrap();
    let frames = out.frames();
    let ids: Vec<&str> = frames.iter().map(|f| f.frame.as_str()).collect();
    assert_eq!(ids, ["000000", "000000"]);
    assert!(frames[0].timestamp_s < frames[1].timestamp_s, "timestamps must increase across loops");
    assert_eq!((summary.frames_captured, summary.frames_published, summary.frames_dropped), (2, 2, 0));
    // Each result is exactly the estimator's on that frame with the stream position's seed.
    let estimator = PoseEstimator::load(Path::new(&model)).unwrap();
    let mut source = open();
    for published in &frames {
        let f = source.next_frame().unwrap().unwrap();
        let detections =
            tricons::pipeline::stages::detections_from_annotations(f.annotations.as_ref().unwrap()).unwrap();
        let seed = tricons::rng::mix_seed(&[7, f.seq]);
        let (direct, _) =
            tricons::pipeline::stages::estimate_detections(&estimator, &f.frame, &detections, seed).unwrap();
        assert!(!direct.is_empty());
        assert_eq!(published.instances, direct, "frame {}", f.seq);
    }
}

#[test]
fn a_live_source_loses_nothing_when_inference_keeps_up() {
    let out = Collect::default();
    let summary = PipelineBuilder::new(
        Box::new(Ticker::new(8, Duration::from_millis(30))),
        Box::new(NoMasks),
        Box::new(Slow(Duration::from_millis(1))),
    )
    .sink(Box::new(out.clone()))
    .build()
    .run()
    .unwrap();
    assert_eq!((summary.frames_captured, summary.frames_published, summary.frames_dropped), (8, 8, 0));
    assert_eq!(out.frames().iter().map(seq_of).collect::<Vec<_>>(), (0..8).collect::<Vec<_>>());
}

#[test]
fn the_segment_stages_drop_counts_reach_health_and_metrics() {
    let summary = PipelineBuilder::new(
        Box::new(Ticker::new(6, Duration::from_millis(30))),
        Box::new(DropsOthers::default()),
        Box::new(Slow(Duration::from_millis(1))),
    )
    .build()
    .run()
    .unwrap();
    assert_eq!(summary.frames_published, 6);
    assert_eq!((summary.duplicate_detections_dropped, summary.not_nocs_detections_dropped), (6, 12));
    let text = summary.to_prometheus();
    assert!(text.contains("tricons_duplicate_detections_dropped_total 6\n"), "{text}");
    assert!(text.contains("tricons_not_nocs_detections_dropped_total 12\n"), "{text}");
    let health = serde_json::to_value(&summary).unwrap();
    assert_eq!(health["not_nocs_detections_dropped"], 12);
}

#[test]
fn a_slow_stage_drops_oldest_frames_counts_them_and_stays_bounded() {
    let out = Collect::default();
    // 60 frames at 200 fps into a 40 ms stage.
    let pipeline = PipelineBuilder::new(
        Box::new(Ticker::new(60, Duration::from_millis(5))),
        Box::new(NoMasks),
        Box::new(Slow(Duration::from_millis(40))),
    )
    .capture_queue(2)
    .sink(Box::new(out.clone()))
    .build();
    let summary = pipeline.run().unwrap();
    let frames = out.frames();
    let seqs: Vec<u64> = frames.iter().map(seq_of).collect();
    assert_eq!(summary.frames_captured, 60);
    assert!(summary.frames_dropped >= 30, "{summary:?}");
    assert_eq!(summary.frames_published + summary.frames_dropped, 60, "every frame is published or counted as dropped");
    assert_eq!(seqs.len() as u64, summary.frames_published);
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "published out of order: {seqs:?}");
    assert_eq!(*seqs.last().unwrap(), 59, "the newest frame wins");
    for q in &summary.queues {
        assert!(q.max_depth <= q.capacity, "{q:?}");
    }
    let capture_q = summary.queues.iter().find(|q| q.name == "capture->segment").unwrap();
    assert_eq!(capture_q.dropped, summary.frames_dropped);
}

#[test]
fn a_source_not_live_is_paced_by_inference_and_nothing_drops() {
    let out = Collect::default();
    let summary = PipelineBuilder::new(
        Box::new(demo(Pace::Max, Some(3))),
        Box::new(NoMasks),
        Box::new(Slow(Duration::from_millis(10))),
    )
    .sink(Box::new(out.clone()))
    .build()
    .run()
    .unwrap();
    assert_eq!((summary.frames_published, summary.frames_dropped), (12, 0));
    assert_eq!(out.frames().iter().map(seq_of).collect::<Vec<_>>(), (0..12).collect::<Vec<_>>());
}

#[test]
fn stop_drains_the_frames_in_flight() {
    let out = Collect::default();
    let pipeline = PipelineBuilder::new(
        Box::new(demo(Pace::Max, None)),
        Box::new(NoMasks),
        Box::new(Slow(Duration::from_millis(30))),
    )
    .sink(Box::new(out.clone()))
    .build();
    let stop = pipeline.stop_handle();
    let stopper = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        stop.stop();
    });
    let t = Instant::now();
    let summary = pipeline.run().unwrap();
    stopper.join().unwrap();
    assert!(t.elapsed() < Duration::from_secs(5));
    assert!(summary.frames_published >= 3, "{summary:?}");
    assert_eq!(summary.frames_published, summary.frames_captured, "a frame read before the stop was lost");
    assert_eq!(out.frames().len() as u64, summary.frames_published);
}

/// Fails once at the given stream position, and fails its first reopen too.
struct Flaky {
    inner: RecordingSource,
    fail_at: u64,
    served: u64,
    failed: bool,
    reopen_failures_left: u32,
    reopens: Arc<Mutex<u32>>,
}

impl FrameSource for Flaky {
    fn describe(&self) -> String {
        "flaky".into()
    }
    fn camera(&self) -> CameraConfig {
        self.inner.camera()
    }
    fn next_frame(&mut self) -> tricons::Result<Option<SourceFrame>> {
        if self.served == self.fail_at && !self.failed {
            self.failed = true;
            return Err(tricons::Error::device("/dev/video9", "VIDIOC_DQBUF: No such device"));
        }
        self.served += 1;
        self.inner.next_frame()
    }
    fn reopen(&mut self) -> tricons::Result<()> {
        *self.reopens.lock().unwrap() += 1;
        if self.reopen_failures_left > 0 {
            self.reopen_failures_left -= 1;
            return Err(tricons::Error::device("/dev/video9", "open: No such file or directory"));
        }
        self.inner.reopen()
    }
    fn is_live(&self) -> bool {
        false
    }
}

#[test]
fn a_source_that_fails_mid_stream_is_reopened_and_the_service_goes_on() {
    let out = Collect::default();
    let attempts = Arc::new(Mutex::new(0));
    let source = Flaky {
        inner: demo(Pace::Max, Some(3)),
        fail_at: 5,
        served: 0,
        failed: false,
        reopen_failures_left: 1,
        reopens: Arc::clone(&attempts),
    };
    let summary = PipelineBuilder::new(Box::new(source), Box::new(NoMasks), Box::new(Slow(Duration::ZERO)))
        .backoff(Duration::from_millis(10), Duration::from_millis(40))
        .sink(Box::new(out.clone()))
        .build()
        .run()
        .unwrap();
    assert_eq!((summary.source_errors, summary.source_reopens), (1, 1));
    assert_eq!(*attempts.lock().unwrap(), 2, "one failed reopen, then one that worked");
    assert_eq!(out.frames().iter().map(seq_of).collect::<Vec<_>>(), (0..12).collect::<Vec<_>>());
}

#[test]
fn an_unreadable_recorded_frame_is_skipped_after_reopening() {
    let dir = tempfile::tempdir().unwrap();
    let rec = crate::common::cli::demo_subset(dir.path(), 4, true);
    std::fs::write(rec.join("000002_color.png"), b"not a png").unwrap();
    let out = Collect::default();
    let source = RecordingSource::open(&rec, Pace::Max).unwrap().with_annotations(true);
    let summary = PipelineBuilder::new(Box::new(source), Box::new(NoMasks), Box::new(Slow(Duration::ZERO)))
        .backoff(Duration::from_millis(5), Duration::from_millis(5))
        .sink(Box::new(out.clone()))
        .build()
        .run()
        .unwrap();
    let ids: Vec<String> = out.frames().iter().map(|f| f.frame.clone()).collect();
    assert_eq!(ids, ["000000", "000003", "000005"]);
    assert_eq!((summary.source_errors, summary.source_reopens), (1, 1));
}

fn http_get(addr: std::net::SocketAddr, path: &str) -> (String, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap();
    (head.to_string(), body.to_string())
}

#[test]
fn http_health_metrics_latest_and_stream() {
    let stats = Arc::new(PipelineStats::new());
    let hub = Arc::new(StreamHub::new(Arc::clone(&stats)));
    let server = HttpServer::start("127.0.0.1:0", false, Arc::clone(&stats), Arc::clone(&hub)).unwrap();
    let addr = server.local_addr();
    assert!(addr.ip().is_loopback());
    assert!(http_get(addr, "/latest").0.starts_with("HTTP/1.1 204"));

    // A stream client connected before the run receives every line.
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    write!(stream, "GET /stream HTTP/1.1\r\n\r\n").unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let out = Collect::default();
    let summary = PipelineBuilder::new(
        Box::new(demo(Pace::Max, Some(2))),
        Box::new(NoMasks),
        Box::new(Slow(Duration::from_millis(5))),
    )
    .stats(Arc::clone(&stats))
    .sink(Box::new(out.clone()))
    .sink(Box::new(HubSink(Arc::clone(&hub))))
    .build()
    .run()
    .unwrap();
    assert_eq!(summary.frames_published, 8);

    let (head, body) = http_get(addr, "/health");
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    let health: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(health["status"], "ended");
    assert_eq!(health["frames_published"], 8);
    assert_eq!(health["frames_dropped"], 0);
    assert!(health["latency"].as_array().unwrap().iter().any(|l| l[0] == "end_to_end" && l[1]["count"] == 8));
    let (_, metrics) = http_get(addr, "/metrics");
    assert!(metrics.contains("tricons_frames_published_total 8"), "{metrics}");
    assert!(metrics.contains("tricons_queue_dropped_total{queue=\"capture->segment\"} 0"), "{metrics}");
    let (_, latest) = http_get(addr, "/latest");
    let last: FramePredictions = serde_json::from_str(latest.trim()).unwrap();
    assert_eq!(last, out.frames()[7]);
    assert!(http_get(addr, "/nope").0.starts_with("HTTP/1.1 404"));

    server.shutdown();
    let mut text = String::new();
    stream.read_to_string(&mut text).unwrap();
    let lines: Vec<FramePredictions> =
        text.split_once("\r\n\r\n").unwrap().1.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines, out.frames());
}

/// A segment stage whose frames take uneven times (later frames often finish first on
/// another worker) and which fails every frame with `seq % 7 == 4`.
#[derive(Clone)]
struct Uneven {
    calls: Arc<Mutex<Vec<(u64, std::thread::ThreadId)>>>,
}
impl Segment for Uneven {
    fn segment(&mut self, frame: &SourceFrame) -> tricons::Result<Vec<Detection>> {
        self.calls.lock().unwrap().push((frame.seq, std::thread::current().id()));
        std::thread::sleep(Duration::from_millis([9, 1, 5, 0, 3][(frame.seq % 5) as usize]));
        if frame.seq % 7 == 4 {
            return Err(tricons::Error::Inference("uneven: this frame fails".into()));
        }
        Ok(Vec::new())
    }
    fn fork(&self) -> Option<Box<dyn Segment>> {
        Some(Box::new(self.clone()))
    }
}

#[test]
fn segment_workers_keep_frame_order_and_count_failed_frames() {
    for workers in [1, 3] {
        let out = Collect::default();
        let segment = Uneven { calls: Arc::default() };
        let calls = Arc::clone(&segment.calls);
        // 4 frames x 5 loops = 20 frames, not live: nothing may be dropped.
        let summary =
            PipelineBuilder::new(Box::new(demo(Pace::Max, Some(5))), Box::new(segment), Box::new(Slow(Duration::ZERO)))
                .segment_workers(workers)
                .sink(Box::new(out.clone()))
                .build()
                .run()
                .unwrap();
        let want: Vec<u64> = (0..20).filter(|s| s % 7 != 4).collect();
        assert_eq!(out.frames().iter().map(seq_of).collect::<Vec<_>>(), want, "{workers} worker(s)");
        assert_eq!((summary.frames_failed, summary.frames_dropped), (3, 0), "{workers} worker(s)");
        let calls = calls.lock().unwrap();
        let mut seqs: Vec<u64> = calls.iter().map(|c| c.0).collect();
        seqs.sort_unstable();
        assert_eq!(seqs, (0..20).collect::<Vec<_>>(), "each frame segmented once");
        let threads: std::collections::HashSet<_> = calls.iter().map(|c| c.1).collect();
        assert!(threads.len() <= workers, "{workers} worker(s) ran on {} threads", threads.len());
        if workers > 1 {
            assert!(threads.len() > 1, "the frames were all segmented by one worker");
        }
    }
}

#[test]
fn a_segment_stage_that_cannot_fork_runs_with_one_worker() {
    let out = Collect::default();
    let summary =
        PipelineBuilder::new(Box::new(demo(Pace::Max, Some(2))), Box::new(NoMasks), Box::new(Slow(Duration::ZERO)))
            .segment_workers(4)
            .sink(Box::new(out.clone()))
            .build()
            .run()
            .unwrap();
    assert_eq!(out.frames().iter().map(seq_of).collect::<Vec<_>>(), (0..8).collect::<Vec<_>>());
    assert_eq!(summary.frames_published, 8);
}
