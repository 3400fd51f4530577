//! Live counters of the pipeline: the health/metrics view.

use super::queue::BoundedQueue;
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Latency samples kept per stage for the percentiles.
pub const LATENCY_WINDOW: usize = 4096;
/// The window of the recent frame rate.
pub const RECENT_FPS_WINDOW: Duration = Duration::from_secs(5);

/// Frames published before the warm memory baseline is taken.
pub const WARMUP_FRAMES: u64 = 100;

/// (resident, peak resident) memory of this process in KiB, from
/// `/proc/self/status`; zeros where that file does not exist.
pub fn memory_kib() -> (u64, u64) {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else {
        return (0, 0);
    };
    let field = |name: &str| -> u64 {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// The stages whose latency is measured, in pipeline order.
pub const STAGES: [&str; 5] = ["capture", "segment", "pose", "publish", "end_to_end"];

/// Index of a stage in [`STAGES`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Reading (and for cameras pairing, decoding, registering) a frame.
    Capture = 0,
    /// Instance masks.
    Segment = 1,
    /// The pose network over the frame's instances.
    Pose = 2,
    /// Writing the result to every output.
    Publish = 3,
    /// From the source handing the frame over to its result being published.
    EndToEnd = 4,
}

/// The state of the source as the health view reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceState {
    /// Frames are coming.
    Running,
    /// The source failed and is being reopened.
    Reconnecting,
    /// The source ended (end of a recording) or the service is stopping.
    Ended,
}

#[derive(Default)]
struct Window {
    samples: VecDeque<f64>,
    count: u64,
    sum_ms: f64,
    max_ms: f64,
}

/// Latency percentiles of one stage, milliseconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct LatencySummary {
    /// Frames measured since the start.
    pub count: u64,
    /// Mean since the start.
    pub mean_ms: f64,
    /// Median of the last [`LATENCY_WINDOW`] frames.
    pub p50_ms: f64,
    /// 90th percentile of the last frames.
    pub p90_ms: f64,
    /// 99th percentile of the last frames.
    pub p99_ms: f64,
    /// Maximum since the start.
    pub max_ms: f64,
}

/// One queue's state.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct QueueSnapshot {
    /// Which queue ("capture->segment", ...).
    pub name: String,
    /// Items queued now.
    pub depth: usize,
    /// Capacity.
    pub capacity: usize,
    /// Most items ever queued at once.
    pub max_depth: usize,
    /// Frames dropped here because inference fell behind.
    pub dropped: u64,
}

/// Everything the health endpoint reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StatsSnapshot {
    /// Seconds since the pipeline started.
    pub uptime_s: f64,
    /// The source's state.
    pub source: SourceState,
    /// Frames the source delivered.
    pub frames_captured: u64,
    /// Frames whose result was published.
    pub frames_published: u64,
    /// Frames dropped in all queues.
    pub frames_dropped: u64,
    /// Frames that failed in a stage (logged, not published).
    pub frames_failed: u64,
    /// Detections the segmenter dropped as duplicates of another (card's `duplicate_mask_iou`).
    pub duplicate_detections_dropped: u64,
    /// Detections of no NOCS category (a segmenter's "other") left out after the duplicate
    /// suppression.
    pub not_nocs_detections_dropped: u64,
    /// Poses not reported because their score lay below the pose card's `min_score`.
    pub low_score_poses_dropped: u64,
    /// Published frames per second since the start.
    pub fps: f64,
    /// Published frames per second over the last five seconds.
    pub fps_recent: f64,
    /// Source read errors.
    pub source_errors: u64,
    /// Successful source reopens.
    pub source_reopens: u64,
    /// Result lines not delivered to slow stream clients.
    pub stream_lines_dropped: u64,
    /// `/stream` clients disconnected because a write to them timed out.
    pub http_slow_clients_dropped: u64,
    /// HTTP connections refused because every slot (or every `/stream` slot) was taken.
    pub http_rejected: u64,
    /// HTTP clients that did not send a request head in time.
    pub http_request_timeouts: u64,
    /// HTTP connections closed unanswered because newer ones needed their place while
    /// they had not sent a request (idle clients cannot take every slot).
    pub http_idle_evicted: u64,
    /// Resident memory now, KiB (Linux; 0 elsewhere).
    pub rss_kib: u64,
    /// Peak resident memory of the process, KiB (Linux; 0 elsewhere).
    pub peak_rss_kib: u64,
    /// Resident memory after the first [`WARMUP_FRAMES`] frames were published, KiB
    /// (the baseline of the soak benchmark's growth figure; 0 before).
    pub warm_rss_kib: u64,
    /// Per-stage latency, in [`STAGES`] order.
    pub latency: Vec<(String, LatencySummary)>,
    /// The queues between stages.
    pub queues: Vec<QueueSnapshot>,
}

/// Read access to a queue's counters, whatever it carries.
pub trait QueueProbe: Send + Sync {
    /// Items queued now.
    fn depth(&self) -> usize;
    /// Capacity.
    fn capacity(&self) -> usize;
    /// Most items ever queued at once.
    fn max_depth(&self) -> usize;
    /// Items dropped.
    fn dropped(&self) -> u64;
}

impl<T: Send> QueueProbe for BoundedQueue<T> {
    fn depth(&self) -> usize {
        self.len()
    }
    fn capacity(&self) -> usize {
        BoundedQueue::capacity(self)
    }
    fn max_depth(&self) -> usize {
        BoundedQueue::max_depth(self)
    }
    fn dropped(&self) -> u64 {
        BoundedQueue::dropped(self)
    }
}

/// The pipeline's shared counters (one per pipeline, behind an `Arc`).
pub struct PipelineStats {
    started: Instant,
    windows: [Mutex<Window>; 5],
    published_at: Mutex<VecDeque<Instant>>,
    source_state: AtomicU8,
    /// Frames the source delivered.
    pub frames_captured: AtomicU64,
    /// Frames published.
    pub frames_published: AtomicU64,
    /// Frames that failed in a stage.
    pub frames_failed: AtomicU64,
    /// Detections the segmenter dropped as duplicates.
    pub duplicate_detections_dropped: AtomicU64,
    /// Detections of no NOCS category left out.
    pub not_nocs_detections_dropped: AtomicU64,
    /// Poses below the pose card's `min_score`.
    pub low_score_poses_dropped: AtomicU64,
    /// Source read errors.
    pub source_errors: AtomicU64,
    /// Successful reopens.
    pub source_reopens: AtomicU64,
    /// Lines not delivered to slow stream clients.
    pub stream_lines_dropped: AtomicU64,
    /// `/stream` clients dropped for a timed-out write.
    pub http_slow_clients_dropped: AtomicU64,
    /// HTTP connections refused for lack of a slot.
    pub http_rejected: AtomicU64,
    /// HTTP request heads not received in time.
    pub http_request_timeouts: AtomicU64,
    /// See [`StatsSnapshot::http_idle_evicted`].
    pub http_idle_evicted: AtomicU64,
    warm_rss_kib: AtomicU64,
    queues: Mutex<Vec<(String, std::sync::Arc<dyn QueueProbe>)>>,
}

impl Default for PipelineStats {
    fn default() -> Self {
        PipelineStats::new()
    }
}

impl PipelineStats {
    /// Counters starting now.
    pub fn new() -> PipelineStats {
        PipelineStats {
            started: Instant::now(),
            windows: Default::default(),
            published_at: Mutex::new(VecDeque::new()),
            source_state: AtomicU8::new(0),
            frames_captured: AtomicU64::new(0),
            frames_published: AtomicU64::new(0),
            frames_failed: AtomicU64::new(0),
            duplicate_detections_dropped: AtomicU64::new(0),
            not_nocs_detections_dropped: AtomicU64::new(0),
            low_score_poses_dropped: AtomicU64::new(0),
            source_errors: AtomicU64::new(0),
            source_reopens: AtomicU64::new(0),
            stream_lines_dropped: AtomicU64::new(0),
            http_slow_clients_dropped: AtomicU64::new(0),
            http_rejected: AtomicU64::new(0),
            http_request_timeouts: AtomicU64::new(0),
            http_idle_evicted: AtomicU64::new(0),
            warm_rss_kib: AtomicU64::new(0),
            queues: Mutex::new(Vec::new()),
        }
    }

    /// Registers a queue for the snapshot.
    pub fn add_queue(&self, name: &str, queue: std::sync::Arc<dyn QueueProbe>) {
        self.queues.lock().unwrap_or_else(|p| p.into_inner()).push((name.to_string(), queue));
    }

    /// Records one frame's time in `stage`.
    pub fn record(&self, stage: Stage, elapsed: Duration) {
        let ms = elapsed.as_secs_f64() * 1e3;
        let mut w = self.windows[stage as usize].lock().unwrap_or_else(|p| p.into_inner());
        if w.samples.len() == LATENCY_WINDOW {
            w.samples.pop_front();
        }
        w.samples.push_back(ms);
        w.count += 1;
        w.sum_ms += ms;
        w.max_ms = w.max_ms.max(ms);
    }

    /// Counts a published frame (for the frame rates).
    pub fn published(&self) {
        if self.frames_published.fetch_add(1, Ordering::Relaxed) + 1 == WARMUP_FRAMES {
            self.warm_rss_kib.store(memory_kib().0, Ordering::Relaxed);
        }
        let now = Instant::now();
        let mut at = self.published_at.lock().unwrap_or_else(|p| p.into_inner());
        at.push_back(now);
        while at.front().is_some_and(|t| now.duration_since(*t) > RECENT_FPS_WINDOW) {
            at.pop_front();
        }
    }

    /// Sets the source's state.
    pub fn set_source_state(&self, state: SourceState) {
        self.source_state.store(state as u8, Ordering::Relaxed);
    }

    /// A consistent-enough copy of every counter.
    pub fn snapshot(&self) -> StatsSnapshot {
        let uptime_s = self.started.elapsed().as_secs_f64();
        let latency = STAGES
            .iter()
            .zip(&self.windows)
            .map(|(name, w)| {
                let w = w.lock().unwrap_or_else(|p| p.into_inner());
                let mut sorted: Vec<f64> = w.samples.iter().copied().collect();
                sorted.sort_by(f64::total_cmp);
                let summary = LatencySummary {
                    count: w.count,
                    mean_ms: if w.count > 0 { w.sum_ms / w.count as f64 } else { 0.0 },
                    p50_ms: percentile(&sorted, 50.0),
                    p90_ms: percentile(&sorted, 90.0),
                    p99_ms: percentile(&sorted, 99.0),
                    max_ms: w.max_ms,
                };
                (name.to_string(), summary)
            })
            .collect();
        let queues: Vec<QueueSnapshot> = self
            .queues
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .map(|(name, q)| QueueSnapshot {
                name: name.clone(),
                depth: q.depth(),
                capacity: q.capacity(),
                max_depth: q.max_depth(),
                dropped: q.dropped(),
            })
            .collect();
        let published = self.frames_published.load(Ordering::Relaxed);
        let (rss_kib, peak_rss_kib) = memory_kib();
        let recent = {
            let at = self.published_at.lock().unwrap_or_else(|p| p.into_inner());
            let window = uptime_s.min(RECENT_FPS_WINDOW.as_secs_f64());
            if window > 0.0 { at.len() as f64 / window } else { 0.0 }
        };
        StatsSnapshot {
            uptime_s,
            source: match self.source_state.load(Ordering::Relaxed) {
                0 => SourceState::Running,
                1 => SourceState::Reconnecting,
                _ => SourceState::Ended,
            },
            frames_captured: self.frames_captured.load(Ordering::Relaxed),
            frames_published: published,
            frames_dropped: queues.iter().map(|q| q.dropped).sum(),
            frames_failed: self.frames_failed.load(Ordering::Relaxed),
            duplicate_detections_dropped: self.duplicate_detections_dropped.load(Ordering::Relaxed),
            not_nocs_detections_dropped: self.not_nocs_detections_dropped.load(Ordering::Relaxed),
            low_score_poses_dropped: self.low_score_poses_dropped.load(Ordering::Relaxed),
            fps: if uptime_s > 0.0 { published as f64 / uptime_s } else { 0.0 },
            fps_recent: recent,
            source_errors: self.source_errors.load(Ordering::Relaxed),
            source_reopens: self.source_reopens.load(Ordering::Relaxed),
            stream_lines_dropped: self.stream_lines_dropped.load(Ordering::Relaxed),
            http_slow_clients_dropped: self.http_slow_clients_dropped.load(Ordering::Relaxed),
            http_rejected: self.http_rejected.load(Ordering::Relaxed),
            http_request_timeouts: self.http_request_timeouts.load(Ordering::Relaxed),
            http_idle_evicted: self.http_idle_evicted.load(Ordering::Relaxed),
            rss_kib,
            peak_rss_kib,
            warm_rss_kib: self.warm_rss_kib.load(Ordering::Relaxed),
            latency,
            queues,
        }
    }
}

/// Nearest-rank percentile of sorted samples (0 when empty).
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

impl StatsSnapshot {
    /// The snapshot in the Prometheus text exposition format.
    pub fn to_prometheus(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let mut metric = |name: &str, help: &str, kind: &str, lines: Vec<(String, f64)>| {
            let _ = writeln!(s, "# HELP tricons_{name} {help}\n# TYPE tricons_{name} {kind}");
            for (labels, v) in lines {
                let _ = writeln!(s, "tricons_{name}{labels} {v}");
            }
        };
        metric("uptime_seconds", "Seconds since the pipeline started.", "gauge", vec![(String::new(), self.uptime_s)]);
        for (name, v, help) in [
            ("frames_captured_total", self.frames_captured, "Frames the source delivered."),
            ("frames_published_total", self.frames_published, "Frames whose result was published."),
            ("frames_dropped_total", self.frames_dropped, "Frames dropped because inference fell behind."),
            ("frames_failed_total", self.frames_failed, "Frames that failed in a stage."),
            (
                "duplicate_detections_dropped_total",
                self.duplicate_detections_dropped,
                "Detections dropped as duplicates of a higher-scored one (mask IoU).",
            ),
            (
                "not_nocs_detections_dropped_total",
                self.not_nocs_detections_dropped,
                "Detections of no NOCS category (a segmenter's other class) left out after duplicate suppression.",
            ),
            (
                "low_score_poses_dropped_total",
                self.low_score_poses_dropped,
                "Poses not reported because their score lay below the pose card's min_score.",
            ),
            ("source_errors_total", self.source_errors, "Source read errors."),
            ("source_reopens_total", self.source_reopens, "Successful source reopens."),
            ("stream_lines_dropped_total", self.stream_lines_dropped, "Lines not delivered to slow stream clients."),
            (
                "http_slow_clients_dropped_total",
                self.http_slow_clients_dropped,
                "Stream clients disconnected because a write to them timed out.",
            ),
            ("http_rejected_total", self.http_rejected, "HTTP connections refused because the slots were taken."),
            ("http_request_timeouts_total", self.http_request_timeouts, "HTTP clients that sent no request in time."),
            (
                "http_idle_evicted_total",
                self.http_idle_evicted,
                "Idle HTTP connections closed to make room for newer ones.",
            ),
        ] {
            metric(name, help, "counter", vec![(String::new(), v as f64)]);
        }
        metric(
            "resident_memory_bytes",
            "Resident memory.",
            "gauge",
            vec![(String::new(), self.rss_kib as f64 * 1024.0)],
        );
        metric(
            "fps",
            "Published frames per second over the last five seconds.",
            "gauge",
            vec![(String::new(), self.fps_recent)],
        );
        let lat = |q: &str, f: fn(&LatencySummary) -> f64| -> Vec<(String, f64)> {
            self.latency.iter().map(|(st, l)| (format!("{{stage=\"{st}\",quantile=\"{q}\"}}"), f(l))).collect()
        };
        let mut lines = lat("0.5", |l| l.p50_ms / 1e3);
        lines.extend(lat("0.9", |l| l.p90_ms / 1e3));
        lines.extend(lat("0.99", |l| l.p99_ms / 1e3));
        metric("stage_latency_seconds", "Per-stage latency over the last frames.", "summary", lines);
        metric(
            "queue_depth",
            "Items queued between stages.",
            "gauge",
            self.queues.iter().map(|q| (format!("{{queue=\"{}\"}}", q.name), q.depth as f64)).collect(),
        );
        metric(
            "queue_dropped_total",
            "Frames dropped per queue.",
            "counter",
            self.queues.iter().map(|q| (format!("{{queue=\"{}\"}}", q.name), q.dropped as f64)).collect(),
        );
        s
    }
}
