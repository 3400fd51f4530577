//! Results as a ROS 2 bag (MCAP, profile `ros2`, zstd chunks): per frame a
//! `vision_msgs/Detection3DArray`, a `visualization_msgs/MarkerArray` of boxes and labels, and
//! the overlay image (`sensor_msgs/Image` rgb8), so Foxglove or `ros2 bag play` shows them.
//!
//! The file is written as `OUT.mcap.part` and renamed to `OUT.mcap` once its summary is
//! written ([`Sink::close`]): a complete `OUT.mcap` is never replaced by a half-written one.
//! After a crash the `.part` file holds every chunk written so far (`mcap recover` reads it).

use super::overlay::overlay_image;
use super::predictions::FramePredictions;
use super::sink::Sink;
use crate::error::{Error, Result};
use crate::frame::RgbdFrame;
use crate::ros2::{cdr, convert, schema};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Topic of the detections.
pub const DETECTIONS_TOPIC: &str = "/tricons/detections";
/// Topic of the RViz markers.
pub const MARKERS_TOPIC: &str = "/tricons/markers";
/// Topic of the overlay images.
pub const OVERLAY_TOPIC: &str = "/tricons/overlay";

/// Channel ids of the three topics.
struct Channels {
    detections: u16,
    markers: u16,
    overlay: u16,
}

/// Writes results to an MCAP file (see the module docs).
pub struct McapSink {
    path: PathBuf,
    part: PathBuf,
    frame_id: String,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    channels: Channels,
    sequence: u32,
}

fn write_error(path: &Path, e: mcap::McapError) -> Error {
    match e {
        mcap::McapError::Io(io) => Error::io(path, io),
        other => Error::parse(path, None, format!("writing MCAP: {other}")),
    }
}

impl McapSink {
    /// Starts `path` (its directory is created); poses are in `frame_id`.
    pub fn create(path: &Path, frame_id: &str) -> Result<McapSink> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        let mut part = path.as_os_str().to_owned();
        part.push(".part");
        let part = PathBuf::from(part);
        let file = File::create(&part).map_err(|e| Error::io(&part, e))?;
        let err = |e| write_error(&part, e);
        let mut writer = mcap::WriteOptions::new()
            .profile(schema::PROFILE)
            .compression(Some(mcap::Compression::Zstd))
            .library(concat!("tricons ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(err)?;
        let mut channel = |(name, text): (&str, &str), topic: &str| -> Result<u16> {
            let schema_id = writer.add_schema(name, schema::SCHEMA_ENCODING, text.as_bytes()).map_err(err)?;
            writer.add_channel(schema_id, topic, schema::MESSAGE_ENCODING, &BTreeMap::new()).map_err(err)
        };
        let channels = Channels {
            detections: channel(schema::DETECTION_3D_ARRAY, DETECTIONS_TOPIC)?,
            markers: channel(schema::MARKER_ARRAY, MARKERS_TOPIC)?,
            overlay: channel(schema::IMAGE, OVERLAY_TOPIC)?,
        };
        Ok(McapSink {
            path: path.to_path_buf(),
            part,
            frame_id: frame_id.to_string(),
            writer: Some(writer),
            channels,
            sequence: 0,
        })
    }

    fn write(&mut self, channel_id: u16, stamp_ns: u64, payload: &[u8]) -> Result<()> {
        let Some(writer) = self.writer.as_mut() else {
            return Err(Error::InvalidArgument(format!("{}: written after close", self.path.display())));
        };
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: stamp_ns,
            publish_time: stamp_ns,
        };
        writer.write_to_known_channel(&header, payload).map_err(|e| write_error(&self.part, e))
    }

    fn write_frame(&mut self, frame: &FramePredictions, image: Option<&RgbdFrame>) -> Result<()> {
        let header = convert::header(frame, &self.frame_id);
        let stamp_ns = u64::try_from(header.stamp.as_nanos()).unwrap_or(0);
        let detections = cdr::encode(&convert::detections(frame, &self.frame_id))?;
        self.write(self.channels.detections, stamp_ns, &detections)?;
        let markers = cdr::encode(&convert::markers(frame, &self.frame_id))?;
        self.write(self.channels.markers, stamp_ns, &markers)?;
        if let Some(image) = image {
            let overlay = overlay_image(image, &frame.instances);
            let payload = cdr::encode(&convert::image(&overlay, header))?;
            self.write(self.channels.overlay, stamp_ns, &payload)?;
        }
        self.sequence = self.sequence.wrapping_add(1);
        Ok(())
    }
}

impl Sink for McapSink {
    fn describe(&self) -> String {
        format!("{} (MCAP)", self.path.display())
    }

    /// Without the image, only the detections and markers are written.
    fn publish(&mut self, frame: &FramePredictions, _line: &str) -> Result<()> {
        self.write_frame(frame, None)
    }

    fn publish_with_image(&mut self, frame: &FramePredictions, _line: &str, image: &RgbdFrame) -> Result<()> {
        self.write_frame(frame, Some(image))
    }

    fn flush(&mut self) -> Result<()> {
        match self.writer.as_mut() {
            Some(w) => w.flush().map_err(|e| write_error(&self.part, e)),
            None => Ok(()),
        }
    }

    /// Writes the summary and renames `OUT.mcap.part` to `OUT.mcap`.
    fn close(&mut self) -> Result<()> {
        let Some(mut writer) = self.writer.take() else {
            return Ok(());
        };
        writer.finish().map_err(|e| write_error(&self.part, e))?;
        let file = writer.into_inner().into_inner().map_err(|e| Error::io(&self.part, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&self.part, e))?;
        std::fs::rename(&self.part, &self.path).map_err(|e| Error::io(&self.path, e))?;
        log::info!("{}: {} frames written", self.path.display(), self.sequence);
        Ok(())
    }
}
