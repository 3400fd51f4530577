//! The on-device pose service's pipeline: capture -> segment -> pose -> publish.
//!
//! Each stage runs in its own thread (the segment stage in
//! [`PipelineBuilder::segment_workers`] threads, each on a different frame, their
//! results put back in frame order); bounded queues join them. A live source
//! (a camera, a paced replay) feeds the first queue newest-frame-wins: when
//! inference falls behind, the oldest waiting frame is dropped and counted. A
//! source that is not live is read only as fast as inference goes (nothing is
//! dropped). Later queues block (backpressure), so every frame that entered
//! inference is published. Source errors are logged, the source is reopened
//! with exponential backoff, and reading goes on. [`StopHandle::stop`] (a
//! signal, in `tricons serve`) drains the pipeline: frames already read are
//! finished and published, outputs flushed.
//!
//! ```no_run
//! use tricons::capture::{Pace, RecordingSource};
//! use tricons::pipeline::{GroundTruthMasks, PipelineBuilder, PoseStage};
//! use tricons::output::sink::JsonLinesSink;
//! use tricons::pose::PoseEstimator;
//! use std::path::Path;
//!
//! # fn main() -> tricons::Result<()> {
//! let source = RecordingSource::open(Path::new("tests/data/synthnocs-demo"), Pace::Max)?.with_annotations(true);
//! let estimator = PoseEstimator::load(Path::new("models/tricons-pose.card.json"))?;
//! let summary = PipelineBuilder::new(Box::new(source), Box::new(GroundTruthMasks), Box::new(PoseStage::new(estimator, 0)))
//!     .sink(Box::new(JsonLinesSink::stdout()))
//!     .build()
//!     .run()?;
//! assert_eq!(summary.frames_published, 4);
//! # Ok(())
//! # }
//! ```

pub mod queue;
pub mod stages;
pub mod stats;

pub use queue::{BoundedQueue, WhenFull};
pub use stages::{Detection, Estimate, GroundTruthMasks, PoseStage, PublishedMasks, Segment};
pub use stats::{PipelineStats, SourceState, Stage, StatsSnapshot};

use crate::capture::{FrameSource, SourceFrame};
use crate::error::{Error, Result};
use crate::output::sink::Sink;
use crate::output::{FramePredictions, PredInstance};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Default capacity of the capture -> segment queue (live sources).
pub const DEFAULT_CAPTURE_QUEUE: usize = 2;
/// Default capacity of the later queues.
pub const DEFAULT_STAGE_QUEUE: usize = 2;
/// First wait before reopening a failed source.
pub const DEFAULT_BACKOFF_INITIAL: Duration = Duration::from_millis(100);
/// Longest wait between reopen attempts.
pub const DEFAULT_BACKOFF_MAX: Duration = Duration::from_secs(5);
/// Granularity of waits that must notice a stop request.
const STOP_POLL: Duration = Duration::from_millis(20);

/// Stops a running pipeline (cloneable, usable from a signal handler thread).
#[derive(Clone, Debug, Default)]
pub struct StopHandle(Arc<AtomicBool>);

impl StopHandle {
    /// Asks the pipeline to stop reading and drain.
    pub fn stop(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    /// Whether a stop was requested.
    pub fn is_stopped(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// Builds a [`Pipeline`].
pub struct PipelineBuilder {
    source: Box<dyn FrameSource>,
    segment: Box<dyn Segment>,
    estimate: Box<dyn Estimate>,
    sinks: Vec<Box<dyn Sink>>,
    capture_queue: usize,
    stage_queue: usize,
    backoff: (Duration, Duration),
    max_frames: Option<u64>,
    segment_workers: usize,
    stats: Arc<PipelineStats>,
    stop: StopHandle,
}

impl PipelineBuilder {
    /// A pipeline reading `source`, masking with `segment`, estimating with `estimate`.
    pub fn new(
        source: Box<dyn FrameSource>,
        segment: Box<dyn Segment>,
        estimate: Box<dyn Estimate>,
    ) -> PipelineBuilder {
        PipelineBuilder {
            source,
            segment,
            estimate,
            sinks: Vec::new(),
            capture_queue: DEFAULT_CAPTURE_QUEUE,
            stage_queue: DEFAULT_STAGE_QUEUE,
            backoff: (DEFAULT_BACKOFF_INITIAL, DEFAULT_BACKOFF_MAX),
            max_frames: None,
            segment_workers: 1,
            stats: Arc::new(PipelineStats::new()),
            stop: StopHandle::default(),
        }
    }

    /// Adds an output; every result goes to every sink, in frame order.
    pub fn sink(mut self, sink: Box<dyn Sink>) -> PipelineBuilder {
        self.sinks.push(sink);
        self
    }

    /// Capacity of the capture -> segment queue (>= 1).
    pub fn capture_queue(mut self, capacity: usize) -> PipelineBuilder {
        self.capture_queue = capacity.max(1);
        self
    }

    /// Capacity of the segment -> pose and pose -> publish queues (>= 1).
    pub fn stage_queue(mut self, capacity: usize) -> PipelineBuilder {
        self.stage_queue = capacity.max(1);
        self
    }

    /// Waits between reopen attempts: `initial`, doubling up to `max`.
    pub fn backoff(mut self, initial: Duration, max: Duration) -> PipelineBuilder {
        self.backoff = (initial, max.max(initial));
        self
    }

    /// Stops after the source delivered `frames` frames.
    pub fn max_frames(mut self, frames: Option<u64>) -> PipelineBuilder {
        self.max_frames = frames;
        self
    }

    /// Frames segmented at once (>= 1; default 1), each by a worker from
    /// [`Segment::fork`]; results keep the source's order. A stage that cannot fork
    /// runs with one worker (logged). With a compute-bound segmenter on a multi-core
    /// machine this lets the segment stage use the cores the pose stage leaves idle.
    pub fn segment_workers(mut self, workers: usize) -> PipelineBuilder {
        self.segment_workers = workers.max(1);
        self
    }

    /// Uses these counters (e.g. shared with an HTTP health endpoint started first).
    pub fn stats(mut self, stats: Arc<PipelineStats>) -> PipelineBuilder {
        self.stats = stats;
        self
    }

    /// Uses this stop handle (e.g. one a signal handler already holds).
    pub fn stop_handle(mut self, stop: StopHandle) -> PipelineBuilder {
        self.stop = stop;
        self
    }

    /// The pipeline, ready to [`run`](Pipeline::run).
    pub fn build(self) -> Pipeline {
        Pipeline { b: self }
    }
}

/// A configured pipeline.
pub struct Pipeline {
    b: PipelineBuilder,
}

/// A frame between stages.
struct Work {
    frame: SourceFrame,
    detections: Vec<Detection>,
    instances: Vec<PredInstance>,
}

impl Pipeline {
    /// The counters (live while the pipeline runs).
    pub fn stats(&self) -> Arc<PipelineStats> {
        Arc::clone(&self.b.stats)
    }

    /// A handle that stops the pipeline.
    pub fn stop_handle(&self) -> StopHandle {
        self.b.stop.clone()
    }

    /// Runs until the source ends, `max_frames` is reached or a stop is
    /// requested; then drains every queue, flushes the sinks and returns the
    /// final counters. Fails only if a sink cannot be written or a stage thread panicked.
    pub fn run(self) -> Result<StatsSnapshot> {
        let PipelineBuilder {
            mut source,
            segment,
            mut estimate,
            mut sinks,
            capture_queue,
            stage_queue,
            backoff,
            max_frames,
            segment_workers,
            stats,
            stop,
        } = self.b;
        let first_policy = if source.is_live() { WhenFull::DropOldest } else { WhenFull::Block };
        let q_capture = Arc::new(BoundedQueue::<SourceFrame>::new(capture_queue, first_policy));
        let q_segment = Arc::new(BoundedQueue::<Work>::new(stage_queue, WhenFull::Block));
        let q_pose = Arc::new(BoundedQueue::<Work>::new(stage_queue, WhenFull::Block));
        stats.add_queue("capture->segment", q_capture.clone());
        stats.add_queue("segment->pose", q_segment.clone());
        stats.add_queue("pose->publish", q_pose.clone());
        stats.set_source_state(SourceState::Running);
        log::info!("source: {}", source.describe());

        let mut segmenters = vec![segment];
        while segmenters.len() < segment_workers {
            match segmenters[0].fork() {
                Some(s) => segmenters.push(s),
                None => {
                    log::warn!("the segment stage cannot run side by side with itself: 1 worker");
                    break;
                }
            }
        }
        let order = SegmentOrder::new(segmenters.len());
        std::thread::scope(|scope| -> Result<StatsSnapshot> {
            let capture = {
                let (q, stats, stop) = (&q_capture, &stats, &stop);
                scope.spawn(move || {
                    capture_loop(source.as_mut(), q, stats, stop, backoff, max_frames);
                    q.close();
                })
            };
            let segmenting: Vec<_> = segmenters
                .into_iter()
                .map(|mut segment| {
                    let (input, output, stats, order) = (&q_capture, &q_segment, &stats, &order);
                    scope.spawn(move || {
                        while let Some((seq, frame)) = order.take(input) {
                            let t = Instant::now();
                            let work = match segment.segment(&frame) {
                                Ok(detections) => {
                                    stats.record(Stage::Segment, t.elapsed());
                                    stats
                                        .duplicate_detections_dropped
                                        .fetch_max(segment.duplicates_dropped(), Ordering::Relaxed);
                                    stats
                                        .not_nocs_detections_dropped
                                        .fetch_max(segment.not_nocs_dropped(), Ordering::Relaxed);
                                    Some(Work { frame, detections, instances: Vec::new() })
                                }
                                Err(e) => {
                                    stats.frames_failed.fetch_add(1, Ordering::Relaxed);
                                    log::warn!("frame {}: segmentation failed: {e}", frame.id);
                                    None
                                }
                            };
                            if order.put(seq, work, output).is_err() {
                                break;
                            }
                        }
                        order.worker_done(output);
                    })
                })
                .collect();
            let posing = {
                let (input, output, stats) = (&q_segment, &q_pose, &stats);
                scope.spawn(move || {
                    while let Some(mut work) = input.pop() {
                        let t = Instant::now();
                        match estimate.estimate(&work.frame, &work.detections) {
                            Ok(instances) => {
                                stats.record(Stage::Pose, t.elapsed());
                                stats.low_score_poses_dropped.store(estimate.low_scores_dropped(), Ordering::Relaxed);
                                work.instances = instances;
                                work.detections = Vec::new();
                                if output.push(work).is_err() {
                                    break;
                                }
                            }
                            Err(e) => {
                                stats.frames_failed.fetch_add(1, Ordering::Relaxed);
                                log::warn!("frame {}: pose estimation failed: {e}", work.frame.id);
                            }
                        }
                    }
                    output.close();
                })
            };
            // Publishing runs here; a sink error stops the pipeline (after draining).
            let mut sink_error: Option<Error> = None;
            while let Some(work) = q_pose.pop() {
                let t = Instant::now();
                let predictions = FramePredictions {
                    frame: work.frame.id.clone(),
                    timestamp_s: Some(work.frame.frame.timestamp_s),
                    instances: work.instances,
                };
                let line = crate::output::predictions::to_json_line(&predictions);
                for sink in sinks.iter_mut() {
                    if let Err(e) = sink.publish_with_image(&predictions, &line, &work.frame.frame) {
                        log::error!("output {}: {e}; stopping", sink.describe());
                        sink_error.get_or_insert(e);
                        stop.stop();
                    }
                }
                stats.record(Stage::Publish, t.elapsed());
                stats.record(Stage::EndToEnd, work.frame.captured_at.elapsed());
                stats.published();
            }
            for sink in sinks.iter_mut() {
                if let Err(e) = sink.close() {
                    log::error!("output {}: {e}", sink.describe());
                    sink_error.get_or_insert(e);
                }
            }
            let joined: Vec<bool> = std::iter::once(capture)
                .chain(segmenting)
                .chain(std::iter::once(posing))
                .map(|h| h.join().is_err())
                .collect();
            let panicked = joined.contains(&true);
            stats.set_source_state(SourceState::Ended);
            if panicked {
                return Err(Error::Inference("a pipeline stage panicked".into()));
            }
            match sink_error {
                Some(e) => Err(e),
                None => Ok(stats.snapshot()),
            }
        })
    }
}

/// Puts the segment workers' results back in the order their frames were taken.
///
/// [`SegmentOrder::take`] numbers each frame as it leaves the capture queue;
/// [`SegmentOrder::put`] holds a result until every earlier frame's is in (a failed
/// frame's `None` counts), then pushes the run of consecutive results downstream.
/// The last worker to finish closes the output.
struct SegmentOrder {
    taken: std::sync::Mutex<u64>,
    done: std::sync::Mutex<(u64, std::collections::BTreeMap<u64, Option<Work>>)>,
    workers_left: std::sync::atomic::AtomicUsize,
}

impl SegmentOrder {
    fn new(workers: usize) -> SegmentOrder {
        SegmentOrder {
            taken: std::sync::Mutex::new(0),
            done: std::sync::Mutex::new((0, std::collections::BTreeMap::new())),
            workers_left: std::sync::atomic::AtomicUsize::new(workers),
        }
    }

    /// The next frame and its number; `None` once the input is closed and empty.
    fn take(&self, input: &BoundedQueue<SourceFrame>) -> Option<(u64, SourceFrame)> {
        // numbering under the lock keeps the numbers in the queue's order
        let mut taken = self.taken.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let frame = input.pop()?;
        let seq = *taken;
        *taken += 1;
        Some((seq, frame))
    }

    /// Hands in frame `seq`'s result; Err when the output was closed.
    fn put(&self, seq: u64, work: Option<Work>, output: &BoundedQueue<Work>) -> std::result::Result<(), ()> {
        let mut done = self.done.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let (next, waiting) = &mut *done;
        waiting.insert(seq, work);
        while let Some(work) = waiting.remove(next) {
            *next += 1;
            if let Some(work) = work {
                output.push(work).map_err(|_| ())?;
            }
        }
        Ok(())
    }

    fn worker_done(&self, output: &BoundedQueue<Work>) {
        if self.workers_left.fetch_sub(1, Ordering::SeqCst) == 1 {
            output.close();
        }
    }
}

/// Sleeps `duration` in slices, returning early (false) when a stop is requested.
fn sleep_unless_stopped(duration: Duration, stop: &StopHandle) -> bool {
    let until = Instant::now() + duration;
    while Instant::now() < until {
        if stop.is_stopped() {
            return false;
        }
        std::thread::sleep(STOP_POLL.min(until.saturating_duration_since(Instant::now())));
    }
    !stop.is_stopped()
}

fn capture_loop(
    source: &mut dyn FrameSource,
    queue: &BoundedQueue<SourceFrame>,
    stats: &PipelineStats,
    stop: &StopHandle,
    (backoff_initial, backoff_max): (Duration, Duration),
    max_frames: Option<u64>,
) {
    let mut delivered = 0u64;
    while !stop.is_stopped() && max_frames.is_none_or(|m| delivered < m) {
        let t = Instant::now();
        match source.next_frame() {
            Ok(Some(frame)) => {
                stats.record(Stage::Capture, t.elapsed());
                stats.frames_captured.fetch_add(1, Ordering::Relaxed);
                delivered += 1;
                match queue.push(frame) {
                    Ok(Some(old)) => log::debug!("frame {} dropped: inference is behind", old.id),
                    Ok(None) => {}
                    Err(_) => break,
                }
            }
            Ok(None) => {
                log::info!("source ended after {delivered} frames");
                break;
            }
            Err(e) => {
                stats.source_errors.fetch_add(1, Ordering::Relaxed);
                stats.set_source_state(SourceState::Reconnecting);
                log::warn!("source error: {e}; reopening");
                if !reopen_with_backoff(source, stop, backoff_initial, backoff_max) {
                    return;
                }
                stats.source_reopens.fetch_add(1, Ordering::Relaxed);
                stats.set_source_state(SourceState::Running);
            }
        }
    }
}

/// Reopens `source` after an error: waits `initial`, tries, doubles the wait
/// up to `max` after each failure, until it reopens (true) or a stop is
/// requested (false).
pub fn reopen_with_backoff(source: &mut dyn FrameSource, stop: &StopHandle, initial: Duration, max: Duration) -> bool {
    let mut wait = initial;
    loop {
        if !sleep_unless_stopped(wait, stop) {
            return false;
        }
        match source.reopen() {
            Ok(()) => {
                log::info!("source reopened: {}", source.describe());
                return true;
            }
            Err(e) => {
                wait = (wait * 2).min(max);
                log::warn!("reopening the source failed: {e}; next try in {:.1} s", wait.as_secs_f64());
            }
        }
    }
}
