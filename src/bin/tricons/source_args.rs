//! Frame-source flags shared by `tricons serve` and `tricons record`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use tricons::capture::{FrameSource, Pace, RecordingSource};
use tricons::recording::BagTopics;

/// Topics of a ROS 2 bag given as the recording (`--recording BAG.mcap`). Flattened beside
/// [`SourceArgs`], not inside it: serde checks unknown config keys only across one level of
/// flattened structs.
#[derive(clap::Args, Clone, Debug, Default, Deserialize)]
pub struct BagTopicArgs {
    /// Colour topic of a bag: sensor_msgs/Image or CompressedImage (jpeg)
    /// [default: /camera/camera/color/image_raw].
    #[arg(long, value_name = "TOPIC")]
    pub color_topic: Option<String>,
    /// Depth topic of a bag, aligned to colour: 16UC1 mm or 32FC1 m
    /// [default: /camera/camera/aligned_depth_to_color/image_raw].
    #[arg(long, value_name = "TOPIC")]
    pub depth_topic: Option<String>,
    /// Colour CameraInfo topic of a bag [default: /camera/camera/color/camera_info].
    #[arg(long, value_name = "TOPIC")]
    pub camera_info_topic: Option<String>,
}

impl BagTopicArgs {
    /// Fills every unset field from `other` (the config file).
    pub fn or(self, other: BagTopicArgs) -> BagTopicArgs {
        BagTopicArgs {
            color_topic: self.color_topic.or(other.color_topic),
            depth_topic: self.depth_topic.or(other.depth_topic),
            camera_info_topic: self.camera_info_topic.or(other.camera_info_topic),
        }
    }

    /// The topics, with `pair_tolerance_ms` (None: the default) for pairing colour and depth.
    pub fn topics(&self, pair_tolerance_ms: Option<f64>) -> BagTopics {
        let d = BagTopics::default();
        BagTopics {
            color: self.color_topic.clone().unwrap_or(d.color),
            depth: self.depth_topic.clone().unwrap_or(d.depth),
            camera_info: self.camera_info_topic.clone().unwrap_or(d.camera_info),
            pair_tolerance_s: pair_tolerance_ms.map_or(d.pair_tolerance_s, |ms| ms / 1e3),
        }
    }
}

/// How a recording is replayed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rate {
    /// At its recorded timestamps (times --speed): a live source, frames drop when inference is behind.
    Recorded,
    /// As fast as inference goes: nothing is dropped.
    Max,
}

/// Where frames come from: two V4L2 nodes with a camera config, or a recording.
#[derive(clap::Args, Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceArgs {
    /// Colour V4L2 node, e.g. /dev/video4 (with --depth and --camera).
    #[arg(long, value_name = "DEV")]
    pub color: Option<PathBuf>,
    /// Depth V4L2 node delivering Z16, e.g. /dev/video0.
    #[arg(long, value_name = "DEV")]
    pub depth: Option<PathBuf>,
    /// Camera config (intrinsics of both sensors, extrinsics, depth unit; docs/formats.md).
    #[arg(long, value_name = "FILE")]
    pub camera: Option<PathBuf>,
    /// Colour pixel format: yuyv, mjpg or rgb3 [default: yuyv].
    #[arg(long, value_name = "FORMAT")]
    pub color_format: Option<String>,
    /// Frame rate asked of both nodes [default: 30].
    #[arg(long)]
    pub fps: Option<u32>,
    /// Largest colour/depth timestamp difference paired (cameras, bags), milliseconds [default: 15].
    #[arg(long, value_name = "MS")]
    pub pair_tolerance_ms: Option<f64>,
    /// Replay this recording instead of a camera (tricons format, NOCS layout, or a ROS 2
    /// bag `.mcap` with the --color-topic, --depth-topic, --camera-info-topic).
    #[arg(long, value_name = "DIR|BAG.mcap", conflicts_with_all = ["color", "depth", "camera"])]
    pub recording: Option<PathBuf>,
    /// Recording pace [default: recorded].
    #[arg(long, value_enum)]
    pub rate: Option<Rate>,
    /// Speed factor of --rate recorded [default: 1].
    #[arg(long)]
    pub speed: Option<f64>,
    /// Play the recording this many times (0 = forever) [default: 1].
    #[arg(long = "loop", value_name = "N")]
    #[serde(rename = "loop")]
    pub loops: Option<u64>,
}

impl SourceArgs {
    /// Fills every unset field from `other` (the config file).
    pub fn or(self, other: SourceArgs) -> SourceArgs {
        SourceArgs {
            color: self.color.or(other.color),
            depth: self.depth.or(other.depth),
            camera: self.camera.or(other.camera),
            color_format: self.color_format.or(other.color_format),
            fps: self.fps.or(other.fps),
            pair_tolerance_ms: self.pair_tolerance_ms.or(other.pair_tolerance_ms),
            recording: self.recording.or(other.recording),
            rate: self.rate.or(other.rate),
            speed: self.speed.or(other.speed),
            loops: self.loops.or(other.loops),
        }
    }

    /// Opens the source; `annotations`: also read ground truth (recordings only); `bag`: the
    /// topics of a ROS 2 bag given as the recording.
    pub fn open(&self, annotations: bool, bag: &BagTopicArgs) -> Result<Box<dyn FrameSource>> {
        if let Some(dir) = &self.recording {
            let pace = match self.rate.unwrap_or(Rate::Recorded) {
                Rate::Recorded => Pace::Recorded { speed: self.speed.unwrap_or(1.0) },
                Rate::Max => Pace::Max,
            };
            let loops = match self.loops.unwrap_or(1) {
                0 => None,
                n => Some(n),
            };
            let topics = bag.topics(self.pair_tolerance_ms);
            let source = RecordingSource::open_with(dir, pace, &topics)
                .with_context(|| "opening the recording (--recording)")?
                .looped(loops)
                .with_annotations(annotations);
            return Ok(Box::new(source));
        }
        if self.color.is_none() && self.depth.is_none() {
            bail!(
                "no source: give --color DEV --depth DEV --camera FILE (a V4L2 camera; `tricons devices` lists them) \
                 or --recording DIR"
            );
        }
        if annotations {
            bail!("ground-truth masks (--masks gt) need a recording with annotations, not a camera");
        }
        self.open_camera()
    }

    #[cfg(all(feature = "v4l", target_os = "linux"))]
    fn open_camera(&self) -> Result<Box<dyn FrameSource>> {
        use tricons::capture::decode::PixelFormat;
        use tricons::capture::{CameraConfig, CameraSettings, CameraSource};
        let (Some(color), Some(depth), Some(camera)) = (&self.color, &self.depth, &self.camera) else {
            bail!("a camera needs all of --color DEV, --depth DEV and --camera FILE");
        };
        let camera = CameraConfig::read(camera).with_context(|| "reading the camera config (--camera)")?;
        let color_format: PixelFormat = match &self.color_format {
            Some(f) => f.parse().map_err(|e| anyhow::anyhow!("--color-format {f}: {e}"))?,
            None => PixelFormat::Yuyv,
        };
        let settings = CameraSettings {
            color_device: color.clone(),
            color_format,
            depth_device: depth.clone(),
            fps: Some(self.fps.unwrap_or(30)),
            camera,
            pair_tolerance_s: self
                .pair_tolerance_ms
                .unwrap_or(tricons::capture::pairing::DEFAULT_PAIR_TOLERANCE_S * 1e3)
                / 1e3,
            stall_timeout: std::time::Duration::from_secs(2),
        };
        Ok(Box::new(CameraSource::open(settings)?))
    }

    #[cfg(not(all(feature = "v4l", target_os = "linux")))]
    fn open_camera(&self) -> Result<Box<dyn FrameSource>> {
        bail!("this build has no V4L2 capture (feature `v4l`, Linux only): use --recording DIR")
    }
}

/// Installs SIGINT/SIGTERM/SIGHUP handling: the first signal asks `stop` to
/// drain and finish; a second one exits at once (status 130).
pub fn stop_on_signals(stop: tricons::pipeline::StopHandle) -> Result<()> {
    let signals = std::sync::atomic::AtomicU32::new(0);
    ctrlc::set_handler(move || {
        if signals.fetch_add(1, std::sync::atomic::Ordering::SeqCst) == 0 {
            log::info!("stopping: finishing the frames in flight (signal again to exit at once)");
            stop.stop();
        } else {
            std::process::exit(130);
        }
    })
    .context("installing the signal handler")
}
