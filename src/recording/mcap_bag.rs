//! ROS 2 bags stored as MCAP (rosbag2's default storage) as a [`Recording`].
//!
//! A bag holds a colour topic (`sensor_msgs/Image` rgb8/bgr8/rgba8/bgra8/mono8, or
//! `sensor_msgs/CompressedImage` jpeg; the colour topic's `/compressed` sibling is read when
//! the colour topic itself has no messages), a depth topic aligned to colour (`sensor_msgs/Image`
//! `16UC1`/`mono16` millimetres or `32FC1` metres) and the colour `sensor_msgs/CameraInfo`.
//! Opening reads the file once, streaming (memory bounded by the largest chunk, not the
//! file): it notes where each colour and depth message is and its header stamp, keeps the
//! first camera info, and pairs colour with depth by stamp with the capture code's
//! [`FramePairer`]. Frames are then read by streaming forward again (reading in order, as
//! `replay` and `serve` do, passes over the file once more).
//!
//! Frame ids are the pair's index, zero-padded (`000000`, ...); timestamps are the colour
//! header stamps in seconds; the camera frame is the colour header's `frame_id`. Bags carry no
//! ground truth: `tricons eval --match timestamp` scores predictions against a recording that has it.

use super::{BagTopics, FrameAnnotations, GtInstance, Recording};
use crate::capture::decode::{PixelFormat, decode_color, decode_depth_z16};
use crate::capture::pairing::{DEFAULT_PAIR_QUEUE, FramePairer, Timed};
use crate::error::{Error, Result};
use crate::frame::{ColorImage, DEPTH_SCALE_MM, DepthImage, Intrinsics, RgbdFrame};
use crate::image_io::MAX_PIXELS;
use crate::ros2::cdr;
use crate::ros2::msg::{CameraInfo, CompressedImage, Header, Image};
use crate::ros2::schema;
use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Largest MCAP record or decompressed chunk read (a 4K 16UC1 frame is 16 MiB).
const RECORD_LIMIT_BYTES: usize = 512 << 20;
/// Messages read ahead of the frame asked for and kept (colour and depth out of order).
const STASH_LIMIT: usize = 16;

/// How the colour topic's messages are encoded.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ColorKind {
    Raw,
    Compressed,
}

/// What the first pass over a bag found on a colour topic.
#[derive(Default)]
struct ColorStream {
    times: Vec<Timed<usize>>,
    kind: Option<ColorKind>,
    frame_id: Option<String>,
}

/// A colour/depth pair: the messages' positions in file order and the colour stamp.
#[derive(Clone, Debug)]
struct BagFrame {
    id: String,
    color: usize,
    depth: usize,
    timestamp_s: f64,
}

/// Streams messages forward; frames ask for message positions.
struct Cursor {
    reader: mcap::io::MessageReader<BufReader<File>>,
    /// Position of the next message the reader yields.
    next: usize,
    /// Wanted messages read ahead of their frame, by position.
    stash: BTreeMap<usize, Vec<u8>>,
}

/// A ROS 2 bag (MCAP) opened as a recording (see the module docs).
pub struct McapBag {
    path: PathBuf,
    topics: BagTopics,
    color_kind: ColorKind,
    intrinsics: Intrinsics,
    frame_id: String,
    frames: Vec<BagFrame>,
    /// Positions of every paired message (to know what to stash when reading ahead).
    wanted: HashSet<usize>,
    cursor: Mutex<Option<Cursor>>,
    /// Colour and depth messages left unpaired at open.
    unpaired: (u64, u64),
}

fn open_reader(path: &Path) -> Result<mcap::io::MessageReader<BufReader<File>>> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let options = mcap::sans_io::LinearReaderOptions::default()
        .with_record_length_limit(RECORD_LIMIT_BYTES)
        .with_prevalidate_chunk_crcs(true);
    Ok(mcap::io::MessageReader::new_with_options(BufReader::new(file), options))
}

/// The reader's next message, its error naming the bag. mcap 0.26's reader subtracts
/// unchecked when a record inside an uncompressed chunk claims more bytes than the chunk
/// has left (found by the `ros2_bag` fuzz target; a panic where overflow checks are on,
/// a wrapped count and then an error elsewhere): a panic inside the reader becomes this
/// bag's error, and the reader is not used again.
fn next_message(
    reader: &mut mcap::io::MessageReader<BufReader<File>>,
    path: &Path,
    read: usize,
) -> Option<Result<mcap::Message<'static>>> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.next())) {
        Ok(item) => item.map(|m| m.map_err(|e| mcap_error(path, read, e))),
        Err(_) => Some(Err(Error::parse(
            path,
            None,
            format!("unreadable MCAP after {read} messages: a record overruns its chunk"),
        ))),
    }
}

fn mcap_error(path: &Path, read: usize, e: mcap::McapError) -> Error {
    let message = match e {
        mcap::McapError::UnexpectedEof => format!(
            "the MCAP bag is truncated: it ends inside a record after {read} whole messages \
             (an interrupted recording; `mcap recover` rewrites what is readable)"
        ),
        mcap::McapError::BadMagic => "not an MCAP file (bad magic; a rosbag2 .db3 bag is SQLite, \
                                       `ros2 bag convert` turns it into MCAP)"
            .to_string(),
        other => format!("unreadable MCAP after {read} messages: {other}"),
    };
    Error::parse(path, None, message)
}

/// The header at the start of an Image / CompressedImage / CameraInfo payload.
fn stamp_of(payload: &[u8], what: &str) -> Result<Header> {
    cdr::decode_prefix::<Header>(payload, what)
}

impl McapBag {
    /// Opens the bag at `path`, reading `topics` (see the module docs for what it does).
    pub fn open(path: &Path, topics: &BagTopics) -> Result<McapBag> {
        let err = |m: String| Error::parse(path, None, m);
        // topic -> (schema name, message count), for errors
        let mut seen: BTreeMap<String, (String, u64)> = BTreeMap::new();
        // the colour topic, and its image_transport `/compressed` sibling (used when the
        // colour topic itself has no messages, as in bags recorded with compressed colour)
        let compressed_topic = format!("{}/compressed", topics.color);
        let mut streams: [ColorStream; 2] = Default::default();
        let mut depth: Vec<Timed<usize>> = Vec::new();
        let mut info: Option<CameraInfo> = None;
        let mut reader = open_reader(path)?;
        let mut read = 0;
        while let Some(message) = next_message(&mut reader, path, read) {
            let message = message?;
            let pos = read; // this message's index in the file
            read += 1;
            let channel = &message.channel;
            let schema_name = channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default();
            let entry = seen.entry(channel.topic.clone()).or_insert_with(|| (schema_name.clone(), 0));
            entry.1 += 1;
            let topic = channel.topic.as_str();
            let color_slot = [&topics.color, &compressed_topic].iter().position(|t| t.as_str() == topic);
            if color_slot.is_none() && topic != topics.depth && topic != topics.camera_info {
                continue;
            }
            if channel.message_encoding != schema::MESSAGE_ENCODING {
                return Err(err(format!(
                    "topic {topic}: message encoding {:?}, expected {:?} (ROS 2 CDR)",
                    channel.message_encoding,
                    schema::MESSAGE_ENCODING
                )));
            }
            let what = format!("{} topic {topic} message {}", path.display(), entry.1);
            if topic == topics.camera_info {
                expect_schema(path, topic, &schema_name, &[schema::CAMERA_INFO.0])?;
                if info.is_none() {
                    info = Some(cdr::decode::<CameraInfo>(&message.data, &what)?);
                }
                continue;
            }
            let header = stamp_of(&message.data, &what)?;
            let timed = Timed { timestamp_s: header.stamp.as_seconds(), value: pos };
            if let Some(slot) = color_slot {
                let kind =
                    match expect_schema(path, topic, &schema_name, &[schema::IMAGE.0, schema::COMPRESSED_IMAGE.0])? {
                        0 => ColorKind::Raw,
                        _ => ColorKind::Compressed,
                    };
                let stream = &mut streams[slot];
                stream.kind.get_or_insert(kind);
                stream.frame_id.get_or_insert(header.frame_id);
                stream.times.push(timed);
            } else {
                expect_schema(path, topic, &schema_name, &[schema::IMAGE.0])?;
                depth.push(timed);
            }
        }
        let mut topics = topics.clone();
        let [raw, compressed] = streams;
        let ColorStream { times: mut color, kind: color_kind, frame_id } =
            if raw.times.is_empty() && !compressed.times.is_empty() {
                log::info!("{}: no messages on {}, reading {compressed_topic}", path.display(), topics.color);
                topics.color = compressed_topic;
                compressed
            } else {
                raw
            };
        let listing = || {
            if seen.is_empty() {
                "it has no messages".to_string()
            } else {
                let list: Vec<String> = seen.iter().map(|(t, (s, n))| format!("{t} ({s}, {n} messages)")).collect();
                format!("it has: {}", list.join(", "))
            }
        };
        for (topic, flag, n) in [
            (&topics.color, "--color-topic", color.len()),
            (&topics.depth, "--depth-topic", depth.len()),
            (&topics.camera_info, "--camera-info-topic", usize::from(info.is_some())),
        ] {
            if n == 0 {
                return Err(err(format!("no messages on {topic} (choose another with {flag}); {}", listing())));
            }
        }
        let (Some(info), Some(color_kind)) = (info, color_kind) else {
            return Err(err(format!("no colour or camera info messages; {}", listing())));
        };
        let intrinsics = intrinsics_of(&info).map_err(|m| err(format!("topic {}: {m}", topics.camera_info)))?;
        // pair in time order (bags are in receive order, which need not be stamp order)
        color.sort_by(|a, b| a.timestamp_s.total_cmp(&b.timestamp_s));
        depth.sort_by(|a, b| a.timestamp_s.total_cmp(&b.timestamp_s));
        let mut pairer: FramePairer<usize, usize> = FramePairer::new(topics.pair_tolerance_s, DEFAULT_PAIR_QUEUE);
        let mut frames = Vec::new();
        let (mut ci, mut di) = (0, 0);
        while ci < color.len() || di < depth.len() {
            let take_color = di >= depth.len() || (ci < color.len() && color[ci].timestamp_s <= depth[di].timestamp_s);
            if take_color {
                pairer.push_color(color[ci].clone());
                ci += 1;
            } else {
                pairer.push_depth(depth[di].clone());
                di += 1;
            }
            while let Some(pair) = pairer.pop_pair() {
                frames.push(BagFrame {
                    id: String::new(), // numbered below, in file order
                    color: pair.color.value,
                    depth: pair.depth.value,
                    timestamp_s: pair.color.timestamp_s,
                });
            }
        }
        let stats = pairer.stats();
        let unpaired = (color.len() as u64 - stats.paired, depth.len() as u64 - stats.paired);
        if frames.is_empty() {
            return Err(err(format!(
                "no colour message on {} has a depth message on {} within {:.1} ms of its stamp",
                topics.color,
                topics.depth,
                topics.pair_tolerance_s * 1e3
            )));
        }
        // file order, so that reading frames in order streams forward
        frames.sort_by_key(|f| f.color.min(f.depth));
        for (i, f) in frames.iter_mut().enumerate() {
            f.id = format!("{i:06}");
        }
        if unpaired.0 + unpaired.1 > 0 {
            log::warn!(
                "{}: {} colour and {} depth messages have no partner within {:.1} ms (left out)",
                path.display(),
                unpaired.0,
                unpaired.1,
                topics.pair_tolerance_s * 1e3
            );
        }
        let wanted = frames.iter().flat_map(|f| [f.color, f.depth]).collect();
        Ok(McapBag {
            path: path.to_path_buf(),
            topics,
            color_kind,
            intrinsics,
            frame_id: frame_id.unwrap_or_default(),
            frames,
            wanted,
            cursor: Mutex::new(None),
            unpaired,
        })
    }

    /// Colour and depth messages that found no partner.
    pub fn unpaired(&self) -> (u64, u64) {
        self.unpaired
    }

    /// The payloads of the messages at positions `a` and `b`, streaming forward (from the
    /// start again if either is behind the reader and not stashed).
    fn payloads(&self, a: usize, b: usize) -> Result<(Vec<u8>, Vec<u8>)> {
        let mut guard = self.cursor.lock().map_err(|_| Error::Inference("bag reader poisoned".into()))?;
        let behind = |c: &Cursor, p: usize| p < c.next && !c.stash.contains_key(&p);
        if guard.as_ref().is_none_or(|c| behind(c, a) || behind(c, b)) {
            *guard = Some(Cursor { reader: open_reader(&self.path)?, next: 0, stash: BTreeMap::new() });
        }
        let Some(cursor) = guard.as_mut() else {
            return Err(Error::Inference("bag reader missing".into()));
        };
        let last = a.max(b);
        while cursor.next <= last {
            let message = match next_message(&mut cursor.reader, &self.path, cursor.next) {
                Some(Ok(m)) => m,
                Some(Err(e)) => {
                    *guard = None; // reopened on the next read
                    return Err(e);
                }
                None => {
                    return Err(Error::parse(&self.path, None, "the bag changed since it was opened (fewer messages)"));
                }
            };
            let pos = cursor.next;
            cursor.next += 1;
            if self.wanted.contains(&pos) {
                cursor.stash.insert(pos, message.data.into_owned());
                // bounded: the oldest read-ahead goes first (never the two asked for)
                while cursor.stash.len() > STASH_LIMIT {
                    let Some(&old) = cursor.stash.keys().find(|&&p| p != a && p != b) else { break };
                    cursor.stash.remove(&old);
                }
            }
        }
        let take = |c: &mut Cursor, p: usize| {
            c.stash.remove(&p).ok_or_else(|| Error::Inference(format!("bag message {p} was not kept")))
        };
        Ok((take(cursor, a)?, take(cursor, b)?))
    }

    fn decode_color(&self, payload: &[u8], what: &str) -> Result<ColorImage> {
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        let img = match self.color_kind {
            ColorKind::Compressed => {
                let msg: CompressedImage = cdr::decode(payload, what)?;
                let format = msg.format.to_ascii_lowercase();
                if !(format.contains("jpeg") || format.contains("jpg")) {
                    return Err(Error::decode(
                        format!("{what}: CompressedImage format {:?}", msg.format),
                        "only jpeg is read (republish as raw or jpeg)",
                    ));
                }
                decode_color(PixelFormat::Mjpg, &msg.data, w, h, 0)
                    .map_err(|e| Error::decode(what.to_string(), e.to_string()))?
            }
            ColorKind::Raw => {
                let msg: Image = cdr::decode(payload, what)?;
                check_size(&msg, w, h)
                    .and_then(|()| color_from_image(&msg))
                    .map_err(|m| Error::decode(what.to_string(), m))?
            }
        };
        Ok(img)
    }

    fn decode_depth(&self, payload: &[u8], what: &str) -> Result<DepthImage> {
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        let msg: Image = cdr::decode(payload, what)?;
        check_size(&msg, w, h)
            .map_err(|m| format!("{m}; is {} the depth aligned to colour?", self.topics.depth))
            .and_then(|()| depth_from_image(&msg))
            .map_err(|m| Error::decode(what.to_string(), m))
    }
}

/// Which of `allowed` the channel's schema is (its index), or an error naming the topic.
fn expect_schema(path: &Path, topic: &str, found: &str, allowed: &[&str]) -> Result<usize> {
    allowed.iter().position(|a| *a == found).ok_or_else(|| {
        Error::parse(path, None, format!("topic {topic} carries {found:?}, expected {}", allowed.join(" or ")))
    })
}

fn intrinsics_of(info: &CameraInfo) -> std::result::Result<Intrinsics, String> {
    let k = &info.k;
    let intrinsics = Intrinsics { width: info.width, height: info.height, fx: k[0], fy: k[4], cx: k[2], cy: k[5] };
    intrinsics.validate()?;
    if u64::from(info.width) * u64::from(info.height) > MAX_PIXELS {
        return Err(format!("{}x{} images are larger than {MAX_PIXELS} pixels", info.width, info.height));
    }
    if info.d.iter().any(|d| *d != 0.0) {
        log::warn!("camera info has lens distortion {:?}: tricons treats the images as undistorted", info.d);
    }
    Ok(intrinsics)
}

/// The image has the camera info's size (the message for an error otherwise).
fn check_size(msg: &Image, width: u32, height: u32) -> std::result::Result<(), String> {
    if (msg.width, msg.height) != (width, height) {
        return Err(format!("image is {}x{}, the camera info says {width}x{height}", msg.width, msg.height));
    }
    Ok(())
}

/// RGB from the raw colour encodings cameras publish.
fn color_from_image(msg: &Image) -> std::result::Result<ColorImage, String> {
    let channels = match msg.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" | "8UC1" => 1,
        other => return Err(format!("colour encoding {other:?} is not read (rgb8, bgr8, rgba8, bgra8, mono8)")),
    };
    let (w, h, step) = (msg.width as usize, msg.height as usize, msg.step as usize);
    if step < w * channels || msg.data.len() < step * h {
        return Err(format!("{} bytes with step {step} do not hold {w}x{h} {}", msg.data.len(), msg.encoding));
    }
    if msg.encoding == "rgb8" {
        return decode_color(PixelFormat::Rgb3, &msg.data, msg.width, msg.height, msg.step).map_err(|e| e.to_string());
    }
    let mut data = Vec::with_capacity(w * h * 3);
    for row in msg.data.chunks_exact(step).take(h) {
        for px in row[..w * channels].chunks_exact(channels) {
            match msg.encoding.as_str() {
                "bgr8" | "bgra8" => data.extend_from_slice(&[px[2], px[1], px[0]]),
                "rgba8" => data.extend_from_slice(&px[..3]),
                _ => data.extend_from_slice(&[px[0]; 3]),
            }
        }
    }
    Ok(ColorImage { width: msg.width, height: msg.height, data })
}

/// Depth in millimetres from `16UC1`/`mono16` (millimetres) or `32FC1` (metres; rounded to
/// the millimetre, non-finite, non-positive and beyond 65.535 m read as no measurement).
fn depth_from_image(msg: &Image) -> std::result::Result<DepthImage, String> {
    let (w, h, step) = (msg.width as usize, msg.height as usize, msg.step as usize);
    let bytes = match msg.encoding.as_str() {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => return Err(format!("depth encoding {other:?} is not read (16UC1 millimetres, 32FC1 metres)")),
    };
    if step < w * bytes || msg.data.len() < step * h {
        return Err(format!("{} bytes with step {step} do not hold {w}x{h} {}", msg.data.len(), msg.encoding));
    }
    let big = msg.is_bigendian != 0;
    let data: Vec<u16> = if bytes == 2 && !big {
        decode_depth_z16(&msg.data, msg.width, msg.height, msg.step).map_err(|e| e.to_string())?
    } else {
        let mut out = Vec::with_capacity(w * h);
        for row in msg.data.chunks_exact(step).take(h) {
            for px in row[..w * bytes].chunks_exact(bytes) {
                out.push(if bytes == 2 {
                    u16::from_be_bytes([px[0], px[1]])
                } else {
                    let v = if big {
                        f32::from_be_bytes([px[0], px[1], px[2], px[3]])
                    } else {
                        f32::from_le_bytes([px[0], px[1], px[2], px[3]])
                    };
                    let mm = f64::from(v) * 1e3;
                    if mm.is_finite() && mm > 0.0 && mm.round() <= f64::from(u16::MAX) { mm.round() as u16 } else { 0 }
                });
            }
        }
        out
    };
    Ok(DepthImage { width: msg.width, height: msg.height, data, depth_scale_m: DEPTH_SCALE_MM })
}

impl Recording for McapBag {
    fn describe(&self) -> String {
        format!(
            "ROS 2 bag {} ({} frames from {} + {})",
            self.path.display(),
            self.frames.len(),
            self.topics.color,
            self.topics.depth
        )
    }

    fn len(&self) -> usize {
        self.frames.len()
    }

    fn frame_id(&self, index: usize) -> &str {
        self.frames.get(index).map(|f| f.id.as_str()).unwrap_or("")
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn timestamp_s(&self, index: usize) -> Option<f64> {
        self.frames.get(index).map(|f| f.timestamp_s)
    }

    fn camera_frame_id(&self) -> Option<&str> {
        Some(self.frame_id.as_str()).filter(|f| !f.is_empty())
    }

    fn read_frame(&self, index: usize) -> Result<RgbdFrame> {
        let frame = self.frames.get(index).ok_or_else(|| {
            Error::InvalidArgument(format!("{}: frame {index} of {}", self.path.display(), self.frames.len()))
        })?;
        let (color, depth) = self.payloads(frame.color, frame.depth)?;
        let what = |topic: &str| format!("{} frame {} ({topic})", self.path.display(), frame.id);
        let color = self.decode_color(&color, &what(&self.topics.color))?;
        let depth = self.decode_depth(&depth, &what(&self.topics.depth))?;
        Ok(RgbdFrame { color, depth, intrinsics: self.intrinsics, timestamp_s: frame.timestamp_s })
    }

    fn read_instances(&self, _index: usize) -> Result<Option<Vec<GtInstance>>> {
        Ok(None)
    }

    fn read_annotations(&self, _index: usize) -> Result<Option<FrameAnnotations>> {
        Ok(None)
    }
}
