//! Live RGB-D frames from two V4L2 nodes (feature `v4l`, Linux): colour and
//! depth buffers are paired by timestamp, decoded, and depth is registered to
//! colour ([`CameraSource`]).

use super::source::{FrameSource, SourceFrame};
use crate::capture::decode::{PixelFormat, decode_color, decode_depth_z16};
use crate::capture::pairing::{FramePairer, PairingStats, Timed};
use crate::capture::registration::{CameraConfig, register_depth};
use crate::capture::v4l2::{RawBuffer, V4l2Stream};
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Buffers requested from each V4L2 node.
pub const CAPTURE_BUFFERS: u32 = 4;
/// How long one node is polled before the other gets its turn.
const POLL_SLICE: Duration = Duration::from_millis(2);

/// Which nodes to open and how.
#[derive(Clone, Debug)]
pub struct CameraSettings {
    /// Colour node, e.g. `/dev/video4`.
    pub color_device: PathBuf,
    /// Colour pixel format (YUYV, MJPG or RGB3).
    pub color_format: PixelFormat,
    /// Depth node (Z16), e.g. `/dev/video0`.
    pub depth_device: PathBuf,
    /// Frame rate asked of both nodes.
    pub fps: Option<u32>,
    /// Calibration: image sizes, intrinsics, extrinsics, depth unit.
    pub camera: CameraConfig,
    /// Pairing tolerance, seconds.
    pub pair_tolerance_s: f64,
    /// No frame pair for this long counts as a lost device.
    pub stall_timeout: Duration,
}

/// Live RGB-D frames from two V4L2 nodes: paired by timestamp, decoded,
/// depth registered to colour.
pub struct CameraSource {
    settings: CameraSettings,
    streams: Option<(V4l2Stream, V4l2Stream)>,
    pairer: FramePairer<RawBuffer, RawBuffer>,
    seq: u64,
}

impl CameraSource {
    /// Opens both nodes and starts streaming.
    pub fn open(settings: CameraSettings) -> Result<CameraSource> {
        if settings.color_format.is_depth() {
            return Err(Error::InvalidArgument(format!("colour format {} is a depth format", settings.color_format)));
        }
        settings.camera.validate().map_err(Error::InvalidArgument)?;
        let mut source = CameraSource {
            pairer: FramePairer::new(settings.pair_tolerance_s, crate::capture::pairing::DEFAULT_PAIR_QUEUE),
            settings,
            streams: None,
            seq: 0,
        };
        source.reopen()?;
        Ok(source)
    }

    /// Pairing counts so far (frames each node delivered without a partner).
    pub fn pairing_stats(&self) -> PairingStats {
        self.pairer.stats()
    }

    fn decode(&self, color: &RawBuffer, depth: &RawBuffer, streams: &(V4l2Stream, V4l2Stream)) -> Result<RgbdFrame> {
        let (cf, cw, ch, cbpl) = streams.0.format();
        let (_, dw, dh, dbpl) = streams.1.format();
        let image = decode_color(cf, &color.data, cw, ch, cbpl)?;
        let raw = decode_depth_z16(&depth.data, dw, dh, dbpl)?;
        let depth = register_depth(&raw, &self.settings.camera)?;
        Ok(RgbdFrame { color: image, depth, intrinsics: self.settings.camera.color, timestamp_s: color.timestamp_s })
    }
}

impl FrameSource for CameraSource {
    fn describe(&self) -> String {
        let s = &self.settings;
        format!(
            "camera: colour {} ({} {}x{}), depth {} (Z16 {}x{})",
            s.color_device.display(),
            s.color_format,
            s.camera.color.width,
            s.camera.color.height,
            s.depth_device.display(),
            s.camera.depth.width,
            s.camera.depth.height
        )
    }

    fn camera(&self) -> CameraConfig {
        self.settings.camera.clone()
    }

    fn next_frame(&mut self) -> Result<Option<SourceFrame>> {
        if self.streams.is_none() {
            return Err(Error::device(&self.settings.color_device, "not open (reopen after an error)"));
        }
        let started = Instant::now();
        loop {
            if let Some(pair) = self.pairer.pop_pair() {
                let streams = self
                    .streams
                    .as_ref()
                    .ok_or_else(|| Error::device(&self.settings.color_device, "not open (reopen after an error)"))?;
                let frame = self.decode(&pair.color.value, &pair.depth.value, streams)?;
                let seq = self.seq;
                self.seq += 1;
                return Ok(Some(SourceFrame {
                    seq,
                    id: format!("{seq:06}"),
                    frame,
                    annotations: None,
                    captured_at: Instant::now(),
                }));
            }
            if started.elapsed() > self.settings.stall_timeout {
                self.streams = None;
                return Err(Error::device(
                    &self.settings.color_device,
                    format!("no colour/depth pair for {:.1} s", self.settings.stall_timeout.as_secs_f64()),
                ));
            }
            let Some(streams) = self.streams.as_mut() else {
                return Err(Error::device(&self.settings.color_device, "not open (reopen after an error)"));
            };
            let pairer = &mut self.pairer;
            let result = (|| -> Result<()> {
                if let Some(b) = streams.0.next_buffer(POLL_SLICE)? {
                    pairer.push_color(Timed { timestamp_s: b.timestamp_s, value: b });
                }
                if let Some(b) = streams.1.next_buffer(POLL_SLICE)? {
                    pairer.push_depth(Timed { timestamp_s: b.timestamp_s, value: b });
                }
                Ok(())
            })();
            if let Err(e) = result {
                self.streams = None;
                return Err(e);
            }
        }
    }

    fn reopen(&mut self) -> Result<()> {
        self.streams = None;
        self.pairer.clear();
        let s = &self.settings;
        let color = V4l2Stream::open(
            &s.color_device,
            s.color_format,
            s.camera.color.width,
            s.camera.color.height,
            s.fps,
            CAPTURE_BUFFERS,
        )?;
        let depth = V4l2Stream::open(
            &s.depth_device,
            PixelFormat::Z16,
            s.camera.depth.width,
            s.camera.depth.height,
            s.fps,
            CAPTURE_BUFFERS,
        )?;
        self.streams = Some((color, depth));
        Ok(())
    }

    fn is_live(&self) -> bool {
        true
    }
}
