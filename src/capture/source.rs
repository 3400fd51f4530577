//! Frame sources: what the pipeline ([`crate::pipeline`]) and `tricons record` read.
//!
//! A [`FrameSource`] yields registered RGB-D frames one at a time. Two are
//! built in: [`RecordingSource`] replays a recording (at its recorded rate or
//! as fast as the reader goes, optionally in a loop); `capture::camera`'s
//! `CameraSource` (feature `v4l`) reads a colour and a depth V4L2 node.

use super::registration::CameraConfig;
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use crate::recording::{BagTopics, FrameAnnotations, Recording, TriconsRecording, open_recording_with};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// One frame from a source.
#[derive(Clone, Debug)]
pub struct SourceFrame {
    /// Position in the stream: 0, 1, 2, ... (continues across reopens and loops).
    pub seq: u64,
    /// The frame's id: the recording's frame id, or the zero-padded `seq` for cameras.
    pub id: String,
    /// Colour and registered depth with the colour camera's intrinsics.
    pub frame: RgbdFrame,
    /// Ground truth, when the source has it and was asked for it.
    pub annotations: Option<FrameAnnotations>,
    /// When the source handed the frame over (for end-to-end latency).
    pub captured_at: Instant,
}

/// A stream of registered RGB-D frames.
pub trait FrameSource: Send {
    /// One line saying what this is (devices or recording, formats, rate).
    fn describe(&self) -> String;
    /// The camera calibration frames are registered with.
    fn camera(&self) -> CameraConfig;
    /// Blocks until the next frame; `Ok(None)` at the end of the stream. After
    /// an error the source must be [`reopen`](Self::reopen)ed before it is read again.
    fn next_frame(&mut self) -> Result<Option<SourceFrame>>;
    /// Reopens the source after an error (a device that vanished, an
    /// unreadable file); reading goes on after the frame that failed.
    fn reopen(&mut self) -> Result<()>;
    /// Whether frames come in real time whether or not they are consumed (a
    /// camera, a paced replay). The pipeline drops the oldest unprocessed frame
    /// of a live source when inference falls behind; a source that is not live
    /// is read only as fast as inference goes, and nothing is dropped.
    fn is_live(&self) -> bool;
}

/// How a recording is replayed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pace {
    /// At the recorded timestamps, times a speed factor (1 = real time).
    Recorded {
        /// Playback speed (2 = twice as fast).
        speed: f64,
    },
    /// As fast as the consumer reads (not live: nothing is dropped).
    Max,
}

/// Replays a recording as a [`FrameSource`].
pub struct RecordingSource {
    path: PathBuf,
    topics: BagTopics,
    recording: Box<dyn Recording>,
    camera: CameraConfig,
    pace: Pace,
    loops: Option<u64>,
    with_annotations: bool,
    /// Index of the next frame in the recording, and how many full passes are done.
    next_index: usize,
    pass: u64,
    seq: u64,
    /// Wall-clock start and recorded time of the first frame of the current pass.
    clock: Option<(Instant, f64)>,
    /// Recorded time offset of the current pass (so timestamps keep increasing in loops).
    pass_offset_s: f64,
    /// Recorded times of the first and the latest frame read (without the offset).
    pass_span_s: Option<(f64, f64)>,
    failed: bool,
}

impl RecordingSource {
    /// Opens the recording at `path` (tricons format, NOCS layout, or a ROS 2 bag read
    /// from the default topics), played once at `pace`.
    pub fn open(path: &Path, pace: Pace) -> Result<RecordingSource> {
        RecordingSource::open_with(path, pace, &BagTopics::default())
    }

    /// [`open`](Self::open), reading a ROS 2 bag from `topics`.
    pub fn open_with(path: &Path, pace: Pace, topics: &BagTopics) -> Result<RecordingSource> {
        if let Pace::Recorded { speed } = pace
            && !(speed.is_finite() && speed > 0.0)
        {
            return Err(Error::InvalidArgument(format!("replay speed {speed} must be positive")));
        }
        let recording = open_recording_with(path, topics)?;
        if recording.is_empty() {
            return Err(Error::parse(path, None, "the recording has no frames"));
        }
        let camera = recording_camera(path, recording.as_ref());
        Ok(RecordingSource {
            path: path.to_path_buf(),
            topics: topics.clone(),
            recording,
            camera,
            pace,
            loops: Some(1),
            with_annotations: false,
            next_index: 0,
            pass: 0,
            seq: 0,
            clock: None,
            pass_offset_s: 0.0,
            pass_span_s: None,
            failed: false,
        })
    }

    /// Plays the recording `loops` times (`None`: forever).
    pub fn looped(mut self, loops: Option<u64>) -> RecordingSource {
        self.loops = loops;
        self
    }

    /// Also reads each frame's ground truth (for ground-truth masks).
    pub fn with_annotations(mut self, yes: bool) -> RecordingSource {
        self.with_annotations = yes;
        self
    }

    /// Number of frames in one pass.
    pub fn len(&self) -> usize {
        self.recording.len()
    }

    /// Whether the recording is empty (never: [`open`](Self::open) refuses that).
    pub fn is_empty(&self) -> bool {
        self.recording.is_empty()
    }
}

/// The camera config of a recording: from its manifest where it has one.
fn recording_camera(path: &Path, recording: &dyn Recording) -> CameraConfig {
    match TriconsRecording::open(path) {
        Ok(rec) => {
            let m = rec.manifest();
            let mut config = CameraConfig::registered(m.intrinsics, m.depth_scale_m);
            if let (Some(depth), Some(color_from_depth)) = (m.depth_intrinsics, m.color_from_depth) {
                config.depth = depth;
                config.color_from_depth = color_from_depth;
            }
            config
        }
        Err(_) => {
            let mut config = CameraConfig::registered(recording.intrinsics(), crate::frame::DEPTH_SCALE_MM);
            if let Some(frame_id) = recording.camera_frame_id() {
                config.frame_id = frame_id.to_string();
            }
            config
        }
    }
}

impl FrameSource for RecordingSource {
    fn describe(&self) -> String {
        let pace = match self.pace {
            Pace::Recorded { speed: 1.0 } => "at the recorded rate".to_string(),
            Pace::Recorded { speed } => format!("at {speed}x the recorded rate"),
            Pace::Max => "as fast as inference goes".to_string(),
        };
        let loops = match self.loops {
            Some(1) => String::new(),
            Some(n) => format!(", {n} passes"),
            None => ", looping".to_string(),
        };
        format!("{} {pace}{loops}", self.recording.describe())
    }

    fn camera(&self) -> CameraConfig {
        self.camera.clone()
    }

    fn next_frame(&mut self) -> Result<Option<SourceFrame>> {
        if self.failed {
            return Err(Error::InvalidArgument(format!("{}: read after an error without reopen", self.path.display())));
        }
        if self.next_index >= self.recording.len() {
            self.pass += 1;
            if self.loops.is_some_and(|n| self.pass >= n) {
                return Ok(None);
            }
            // The next pass continues one frame period after the last frame.
            let n = self.recording.len();
            let (first, last) = self.pass_span_s.unwrap_or((0.0, 0.0));
            let period = if n > 1 { (last - first) / (n - 1) as f64 } else { 1.0 / 30.0 };
            self.pass_offset_s += last - first + period;
            self.next_index = 0;
        }
        let index = self.next_index;
        self.next_index += 1;
        let read = self.recording.read_frame(index).and_then(|f| {
            let ann = if self.with_annotations { self.recording.read_annotations(index)? } else { None };
            Ok((f, ann))
        });
        let (mut frame, annotations) = match read {
            Ok(x) => x,
            Err(e) => {
                self.failed = true;
                return Err(e);
            }
        };
        let (first, _) = *self.pass_span_s.get_or_insert((frame.timestamp_s, frame.timestamp_s));
        self.pass_span_s = Some((first, frame.timestamp_s));
        let t_s = self.pass_offset_s + frame.timestamp_s;
        if let Pace::Recorded { speed } = self.pace {
            let (start, t0) = *self.clock.get_or_insert((Instant::now(), t_s));
            let due = start + Duration::from_secs_f64(((t_s - t0) / speed).max(0.0));
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        frame.timestamp_s = t_s;
        let seq = self.seq;
        self.seq += 1;
        Ok(Some(SourceFrame {
            seq,
            id: self.recording.frame_id(index).to_string(),
            frame,
            annotations,
            captured_at: Instant::now(),
        }))
    }

    fn reopen(&mut self) -> Result<()> {
        self.recording = open_recording_with(&self.path, &self.topics)?;
        if self.next_index > self.recording.len() {
            self.next_index = self.recording.len();
        }
        self.failed = false;
        Ok(())
    }

    fn is_live(&self) -> bool {
        matches!(self.pace, Pace::Recorded { .. })
    }
}
