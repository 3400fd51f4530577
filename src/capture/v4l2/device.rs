//! V4L2 device enumeration ([`list_devices`]) and memory-mapped streaming ([`V4l2Stream`]).
//!
//! Every failing ioctl becomes an [`Error::Device`] naming the node and the
//! request, e.g. `/dev/video0: VIDIOC_S_FMT: Device or resource busy (os error 16)`.
//! Interrupted calls (`EINTR`) are retried.

use super::sys::{self, Zeroed};
use crate::capture::decode::{PixelFormat, fourcc_to_string};
use crate::error::{Error, Result};
use serde::Serialize;
use std::fmt;
use std::fs::{File, OpenOptions};
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Enumeration stops here even if a driver keeps answering (a guard against broken drivers).
const MAX_ENUM_ENTRIES: u32 = 1024;
/// The kernel's limit on buffers per queue (`VIDEO_MAX_FRAME`).
const MAX_BUFFERS: u32 = 32;

/// A `/dev/video*` node as [`list_devices`] found it.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceInfo {
    /// The node, e.g. `/dev/video0`.
    pub path: PathBuf,
    /// Driver name, e.g. "uvcvideo" (empty if the node could not be queried).
    pub driver: String,
    /// Device name, e.g. "Intel(R) RealSense(TM) Depth Ca".
    pub card: String,
    /// Bus location, e.g. "usb-0000:00:14.0-2".
    pub bus: String,
    /// True for single-planar video capture nodes (false for uvcvideo's metadata nodes).
    pub capture: bool,
    /// Formats with their frame sizes (capture nodes only).
    pub formats: Vec<FormatInfo>,
    /// Why the node could not be opened or queried (busy, permission denied, not V4L2), if so.
    pub error: Option<String>,
}

/// One pixel format a capture node offers.
#[derive(Clone, Debug, Serialize)]
pub struct FormatInfo {
    /// The fourcc as four characters, e.g. "YUYV", "Z16 ".
    pub fourcc: String,
    /// The driver's description, e.g. "YUYV 4:2:2".
    pub description: String,
    /// The format if tricons can decode it.
    pub known: Option<PixelFormat>,
    /// Frame sizes offered in this format.
    pub sizes: Vec<FrameSize>,
}

/// A frame size from `VIDIOC_ENUM_FRAMESIZES`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum FrameSize {
    /// One size (what UVC cameras list).
    Discrete {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// A range of sizes (continuous ranges have steps of 1).
    Stepwise {
        /// Smallest width.
        min_width: u32,
        /// Largest width.
        max_width: u32,
        /// Width increment.
        step_width: u32,
        /// Smallest height.
        min_height: u32,
        /// Largest height.
        max_height: u32,
        /// Height increment.
        step_height: u32,
    },
}

impl fmt::Display for FrameSize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameSize::Discrete { width, height } => write!(f, "{width}x{height}"),
            FrameSize::Stepwise { min_width, max_width, step_width, min_height, max_height, step_height } => {
                write!(f, "{min_width}x{min_height} to {max_width}x{max_height} in steps of {step_width}x{step_height}")
            }
        }
    }
}

/// One captured frame's raw bytes, copied out of the driver's buffer.
#[derive(Clone, Debug)]
pub struct RawBuffer {
    /// The frame's bytes (`bytesused` of the buffer), in the stream's [`V4l2Stream::format`].
    pub data: Vec<u8>,
    /// The driver's timestamp in seconds. Its clock is the one the buffer flags
    /// name; uvcvideo uses `CLOCK_MONOTONIC`, taken when the frame's first
    /// packet arrived (start of exposure readout), so colour and depth nodes of
    /// one camera can be paired by it.
    pub timestamp_s: f64,
    /// The driver's frame counter (gaps mean dropped frames).
    pub sequence: u32,
}

/// `ioctl` on `fd`, retried on `EINTR`.
///
/// Each request passed here is one of the `VIDIOC_*` constants of [`sys`],
/// encoded with the size of the `T` its caller passes.
fn xioctl<T>(fd: RawFd, request: libc::Ioctl, arg: &mut T) -> io::Result<()> {
    loop {
        // SAFETY: `arg` is a valid, exclusively borrowed `T` for the whole call,
        // and the request's encoded argument size is `size_of::<T>()` (sys.rs),
        // so the kernel reads and writes only within it.
        let r = unsafe { libc::ioctl(fd, request, arg as *mut T) };
        if r != -1 {
            return Ok(());
        }
        let err = io::Error::last_os_error();
        if err.kind() != io::ErrorKind::Interrupted {
            return Err(err);
        }
    }
}

/// An ioctl failure as a device error, with a hint for the common cases.
fn ioctl_error(path: &Path, request: &str, err: &io::Error) -> Error {
    let hint = match err.raw_os_error() {
        Some(libc::ENOTTY) => ": not a V4L2 device",
        // What qemu-user answers for ioctls it does not translate.
        Some(libc::ENOSYS) => ": ioctl not implemented here (running under an emulator such as qemu-user?)",
        Some(libc::ENODEV) => ": device vanished (unplugged?)",
        Some(libc::EBUSY) => ": another program is using the device",
        _ => "",
    };
    Error::device(path, format!("{request}: {err}{hint}"))
}

/// Opens a node read-write and non-blocking (as V4L2 streaming expects; close-on-exec by std).
fn open_node(path: &Path) -> Result<File> {
    OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| Error::device(path, format!("cannot open: {e}")))
}

fn query_capabilities(fd: RawFd, path: &Path) -> Result<sys::v4l2_capability> {
    let mut cap = sys::v4l2_capability::zeroed();
    xioctl(fd, sys::VIDIOC_QUERYCAP, &mut cap).map_err(|e| ioctl_error(path, "VIDIOC_QUERYCAP", &e))?;
    Ok(cap)
}

/// The capabilities of this node (not of the whole device).
fn node_capabilities(cap: &sys::v4l2_capability) -> u32 {
    if cap.capabilities & sys::V4L2_CAP_DEVICE_CAPS != 0 { cap.device_caps } else { cap.capabilities }
}

/// True when an enumeration ioctl reports its end (`EINVAL` past the last index).
fn is_end_of_list(err: &io::Error) -> bool {
    err.raw_os_error() == Some(libc::EINVAL)
}

fn enumerate_formats(fd: RawFd, path: &Path) -> Result<Vec<FormatInfo>> {
    let mut formats = Vec::new();
    for index in 0..MAX_ENUM_ENTRIES {
        let mut desc = sys::v4l2_fmtdesc::zeroed();
        desc.index = index;
        desc.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        match xioctl(fd, sys::VIDIOC_ENUM_FMT, &mut desc) {
            Ok(()) => {}
            Err(e) if is_end_of_list(&e) => break,
            Err(e) => return Err(ioctl_error(path, "VIDIOC_ENUM_FMT", &e)),
        }
        formats.push(FormatInfo {
            fourcc: fourcc_to_string(desc.pixelformat),
            description: sys::c_chars(&desc.description),
            known: PixelFormat::from_fourcc(desc.pixelformat),
            sizes: enumerate_frame_sizes(fd, path, desc.pixelformat)?,
        });
    }
    Ok(formats)
}

fn enumerate_frame_sizes(fd: RawFd, path: &Path, fourcc: u32) -> Result<Vec<FrameSize>> {
    let mut sizes = Vec::new();
    for index in 0..MAX_ENUM_ENTRIES {
        let mut size = sys::v4l2_frmsizeenum::zeroed();
        size.index = index;
        size.pixel_format = fourcc;
        match xioctl(fd, sys::VIDIOC_ENUM_FRAMESIZES, &mut size) {
            Ok(()) => {}
            Err(e) if is_end_of_list(&e) => break,
            // Drivers without frame size enumeration: no list, not an error.
            Err(e) if e.raw_os_error() == Some(libc::ENOTTY) => break,
            Err(e) => return Err(ioctl_error(path, "VIDIOC_ENUM_FRAMESIZES", &e)),
        }
        match size.type_ {
            sys::V4L2_FRMSIZE_TYPE_DISCRETE => {
                // SAFETY: the driver filled the `discrete` member for this type.
                let d = unsafe { size.size.discrete };
                sizes.push(FrameSize::Discrete { width: d.width, height: d.height });
            }
            sys::V4L2_FRMSIZE_TYPE_STEPWISE | sys::V4L2_FRMSIZE_TYPE_CONTINUOUS => {
                // SAFETY: the driver filled the `stepwise` member for these types.
                let s = unsafe { size.size.stepwise };
                sizes.push(FrameSize::Stepwise {
                    min_width: s.min_width,
                    max_width: s.max_width,
                    step_width: s.step_width,
                    min_height: s.min_height,
                    max_height: s.max_height,
                    step_height: s.step_height,
                });
                break; // a range is the only entry (index 0)
            }
            other => {
                log::debug!("{}: unknown frame size type {other}", path.display());
                break;
            }
        }
    }
    Ok(sizes)
}

/// Queries one node: identity, and formats when it is a capture node.
fn probe(path: &Path) -> Result<DeviceInfo> {
    let file = open_node(path)?;
    let fd = file.as_raw_fd();
    let cap = query_capabilities(fd, path)?;
    let capture = node_capabilities(&cap) & sys::V4L2_CAP_VIDEO_CAPTURE != 0;
    let mut info = DeviceInfo {
        path: path.to_path_buf(),
        driver: sys::c_chars(&cap.driver),
        card: sys::c_chars(&cap.card),
        bus: sys::c_chars(&cap.bus_info),
        capture,
        formats: Vec::new(),
        error: None,
    };
    if capture {
        match enumerate_formats(fd, path) {
            Ok(formats) => info.formats = formats,
            Err(e) => info.error = Some(error_message(e)),
        }
    }
    Ok(info)
}

/// A device error's message without the path (the listing shows the path already).
fn error_message(err: Error) -> String {
    match err {
        Error::Device { message, .. } => message,
        other => other.to_string(),
    }
}

/// Every `/dev/video<N>` node, sorted by N. See [`list_devices_in`].
pub fn list_devices() -> Result<Vec<DeviceInfo>> {
    list_devices_in(Path::new("/dev"))
}

/// Every `video<N>` node in `dir`, sorted by N: identity and (for capture
/// nodes) formats and frame sizes. A node that cannot be opened or queried
/// (busy, no permission, not V4L2) is listed with [`DeviceInfo::error`] set,
/// it does not fail the listing; a directory without such nodes gives an
/// empty list. Only an unreadable `dir` is an error.
pub fn list_devices_in(dir: &Path) -> Result<Vec<DeviceInfo>> {
    let mut nodes: Vec<(u32, PathBuf)> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|entry| {
            let entry = entry.ok()?;
            let name = entry.file_name();
            let number = name.to_str()?.strip_prefix("video")?;
            if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            Some((number.parse().ok()?, entry.path()))
        })
        .collect();
    nodes.sort();
    Ok(nodes
        .into_iter()
        .map(|(_, path)| {
            probe(&path).unwrap_or_else(|e| DeviceInfo {
                path: path.clone(),
                driver: String::new(),
                card: String::new(),
                bus: String::new(),
                capture: false,
                formats: Vec::new(),
                error: Some(error_message(e)),
            })
        })
        .collect())
}

/// One driver buffer mapped into this process.
struct MappedBuffer {
    ptr: *mut libc::c_void,
    len: usize,
}

/// A capture node streaming one format through memory-mapped driver buffers.
///
/// Frames come out of [`V4l2Stream::next_buffer`] as copies, so the driver
/// buffer goes straight back to the queue. Dropping the stream stops it
/// (`VIDIOC_STREAMOFF`), unmaps the buffers and closes the node.
pub struct V4l2Stream {
    path: PathBuf,
    file: File,
    format: PixelFormat,
    width: u32,
    height: u32,
    bytes_per_line: u32,
    buffers: Vec<MappedBuffer>,
    streaming: bool,
    warned_clock: bool,
}

// SAFETY: the mappings are owned by the stream alone and only touched through
// `&mut self` (next_buffer) or in Drop; nothing ties them to a thread.
unsafe impl Send for V4l2Stream {}

impl V4l2Stream {
    /// Opens `path` and starts streaming `format` at exactly `width` x `height`.
    ///
    /// Steps: open (read-write, non-blocking), `VIDIOC_QUERYCAP` (must be a
    /// capture node with streaming I/O), `VIDIOC_S_FMT` (an error if the driver
    /// substitutes another format or size, naming both), optionally
    /// `VIDIOC_S_PARM` for `fps` (a refusal is only a warning: the driver's rate
    /// is kept), `VIDIOC_REQBUFS` for `buffer_count` mmap buffers (the driver
    /// may grant another count), `VIDIOC_QUERYBUF` + `mmap` of each,
    /// `VIDIOC_QBUF` of all, `VIDIOC_STREAMON`.
    pub fn open(
        path: &Path,
        format: PixelFormat,
        width: u32,
        height: u32,
        fps: Option<u32>,
        buffer_count: u32,
    ) -> Result<V4l2Stream> {
        if width == 0 || height == 0 {
            return Err(Error::InvalidArgument(format!("capture size {width}x{height} is empty")));
        }
        if !(1..=MAX_BUFFERS).contains(&buffer_count) {
            return Err(Error::InvalidArgument(format!("buffer count {buffer_count} outside 1..={MAX_BUFFERS}")));
        }
        if fps == Some(0) {
            return Err(Error::InvalidArgument("frame rate 0".into()));
        }
        let file = open_node(path)?;
        let fd = file.as_raw_fd();
        let cap = query_capabilities(fd, path)?;
        let caps = node_capabilities(&cap);
        if caps & sys::V4L2_CAP_VIDEO_CAPTURE == 0 {
            let what = if caps & sys::V4L2_CAP_META_CAPTURE != 0 {
                "a metadata node, not video: uvcvideo's video node is usually the one numbered just before it"
            } else if caps & sys::V4L2_CAP_VIDEO_CAPTURE_MPLANE != 0 {
                "a multi-planar capture node, which tricons does not support"
            } else {
                "not a video capture node"
            };
            return Err(Error::device(
                path,
                format!(
                    "{} ({}) is {what} (capabilities 0x{caps:08x})",
                    sys::c_chars(&cap.card),
                    sys::c_chars(&cap.driver)
                ),
            ));
        }
        if caps & sys::V4L2_CAP_STREAMING == 0 {
            return Err(Error::device(path, "the driver does not support streaming I/O (V4L2_CAP_STREAMING)"));
        }

        let pix = set_format(fd, path, format, width, height)?;
        let bytes_per_line = match (format, pix.bytesperline) {
            (PixelFormat::Mjpg, b) => b,
            (PixelFormat::Yuyv | PixelFormat::Z16, 0) => width * 2,
            (PixelFormat::Rgb3, 0) => width * 3,
            (_, b) => b,
        };
        if let Some(fps) = fps {
            set_frame_rate(fd, path, fps);
        }

        let mut stream = V4l2Stream {
            path: path.to_path_buf(),
            file,
            format,
            width,
            height,
            bytes_per_line,
            buffers: Vec::new(),
            streaming: false,
            warned_clock: false,
        };
        // On error from here on, Drop releases what was set up.
        stream.map_buffers(buffer_count)?;
        stream.start()?;
        log::debug!(
            "{}: streaming {format} {width}x{height}, {bytes_per_line} bytes per line, {} buffers",
            path.display(),
            stream.buffers.len()
        );
        Ok(stream)
    }

    /// The node this stream reads.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The negotiated format: pixel format, width, height and bytes per line
    /// (the driver's row stride; 0 or unused for MJPG), as [`crate::capture::decode`] takes them.
    pub fn format(&self) -> (PixelFormat, u32, u32, u32) {
        (self.format, self.width, self.height, self.bytes_per_line)
    }

    /// Waits up to `timeout` for the next frame and returns a copy of it;
    /// `Ok(None)` when none came in time. Frames the driver flags as corrupt
    /// are requeued and skipped. A device that vanished (unplugged: `POLLERR`,
    /// `POLLHUP`, `ENODEV`) is an [`Error::Device`] saying so.
    pub fn next_buffer(&mut self, timeout: Duration) -> Result<Option<RawBuffer>> {
        // A timeout too large to represent means "wait indefinitely".
        let deadline = Instant::now().checked_add(timeout);
        loop {
            if !self.wait_readable(deadline)? {
                return Ok(None);
            }
            let mut buf = sys::v4l2_buffer::zeroed();
            buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
            buf.memory = sys::V4L2_MEMORY_MMAP;
            match xioctl(self.file.as_raw_fd(), sys::VIDIOC_DQBUF, &mut buf) {
                Ok(()) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(None),
                Err(e) if e.raw_os_error() == Some(libc::ENODEV) => return Err(self.vanished("VIDIOC_DQBUF: ENODEV")),
                Err(e) => return Err(ioctl_error(&self.path, "VIDIOC_DQBUF", &e)),
            }
            let Some(mapped) = self.buffers.get(buf.index as usize) else {
                return Err(Error::device(
                    &self.path,
                    format!("VIDIOC_DQBUF: the driver returned buffer {} of {}", buf.index, self.buffers.len()),
                ));
            };
            if buf.flags & sys::V4L2_BUF_FLAG_ERROR != 0 {
                log::debug!("{}: frame {} flagged corrupt by the driver, skipped", self.path.display(), buf.sequence);
                self.queue(buf.index)?;
                continue;
            }
            let used = (buf.bytesused as usize).min(mapped.len);
            // SAFETY: the buffer is dequeued, so the driver does not write it
            // until it is queued again below; `ptr` is a live mapping of `len`
            // bytes owned by this stream and `used <= len`.
            let data = unsafe { std::slice::from_raw_parts(mapped.ptr.cast::<u8>(), used) }.to_vec();
            self.queue(buf.index)?;
            if !self.warned_clock
                && buf.flags & sys::V4L2_BUF_FLAG_TIMESTAMP_MASK != sys::V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
            {
                self.warned_clock = true;
                log::warn!(
                    "{}: buffer timestamps are not CLOCK_MONOTONIC (flags 0x{:x}): pairing with other nodes may be off",
                    self.path.display(),
                    buf.flags
                );
            }
            let timestamp_s = buf.timestamp.tv_sec as f64 + buf.timestamp.tv_usec as f64 * 1e-6;
            return Ok(Some(RawBuffer { data, timestamp_s, sequence: buf.sequence }));
        }
    }

    fn vanished(&self, detail: &str) -> Error {
        Error::device(&self.path, format!("device vanished ({detail}): unplugged, or its driver was unloaded"))
    }

    /// `poll` for readability until `deadline` (`None`: no limit); false on timeout.
    fn wait_readable(&self, deadline: Option<Instant>) -> Result<bool> {
        let mut pfd = libc::pollfd { fd: self.file.as_raw_fd(), events: libc::POLLIN, revents: 0 };
        loop {
            let timeout_ms: libc::c_int = match deadline {
                None => -1,
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    // Round up so a sub-millisecond remainder still waits.
                    left.as_micros().div_ceil(1000).min(libc::c_int::MAX as u128) as libc::c_int
                }
            };
            // SAFETY: `pfd` is one valid pollfd and nfds is 1.
            let r = unsafe { libc::poll(&mut pfd, 1, timeout_ms) };
            if r < 0 {
                let err = io::Error::last_os_error();
                if err.kind() == io::ErrorKind::Interrupted {
                    continue;
                }
                return Err(Error::device(&self.path, format!("poll: {err}")));
            }
            if r == 0 {
                return Ok(false);
            }
            if pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 {
                return Err(self.vanished(&format!("poll revents 0x{:x}", pfd.revents)));
            }
            return Ok(pfd.revents & libc::POLLIN != 0);
        }
    }

    /// `VIDIOC_REQBUFS`, then `VIDIOC_QUERYBUF` and `mmap` of every buffer granted.
    fn map_buffers(&mut self, count: u32) -> Result<()> {
        let fd = self.file.as_raw_fd();
        let mut req = sys::v4l2_requestbuffers::zeroed();
        req.count = count;
        req.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        req.memory = sys::V4L2_MEMORY_MMAP;
        xioctl(fd, sys::VIDIOC_REQBUFS, &mut req).map_err(|e| ioctl_error(&self.path, "VIDIOC_REQBUFS", &e))?;
        if req.count == 0 {
            return Err(Error::device(&self.path, "VIDIOC_REQBUFS: the driver granted no buffers (out of memory?)"));
        }
        if req.count != count {
            log::debug!("{}: asked for {count} buffers, the driver granted {}", self.path.display(), req.count);
        }
        for index in 0..req.count {
            let mut buf = sys::v4l2_buffer::zeroed();
            buf.index = index;
            buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
            buf.memory = sys::V4L2_MEMORY_MMAP;
            xioctl(fd, sys::VIDIOC_QUERYBUF, &mut buf).map_err(|e| ioctl_error(&self.path, "VIDIOC_QUERYBUF", &e))?;
            // SAFETY: for V4L2_MEMORY_MMAP buffers the driver sets the `offset` member.
            let offset = unsafe { buf.m.offset };
            // Fallible where off_t is 32-bit (armv7 without large-file offsets).
            #[allow(clippy::unnecessary_fallible_conversions)]
            let offset = libc::off_t::try_from(offset)
                .map_err(|_| Error::device(&self.path, format!("buffer {index}: mmap offset {offset} out of range")))?;
            let len = buf.length as usize;
            // SAFETY: a fresh shared mapping of the driver buffer QUERYBUF
            // described (its length and offset) on our open descriptor; the
            // kernel picks the address, and the result is checked below.
            let ptr = unsafe {
                libc::mmap(std::ptr::null_mut(), len, libc::PROT_READ | libc::PROT_WRITE, libc::MAP_SHARED, fd, offset)
            };
            if ptr == libc::MAP_FAILED {
                let err = io::Error::last_os_error();
                return Err(Error::device(&self.path, format!("mmap of buffer {index} ({len} bytes): {err}")));
            }
            self.buffers.push(MappedBuffer { ptr, len });
        }
        Ok(())
    }

    /// Queues every buffer and starts the stream.
    fn start(&mut self) -> Result<()> {
        for index in 0..self.buffers.len() as u32 {
            self.queue(index)?;
        }
        let mut buf_type = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        xioctl(self.file.as_raw_fd(), sys::VIDIOC_STREAMON, &mut buf_type)
            .map_err(|e| ioctl_error(&self.path, "VIDIOC_STREAMON", &e))?;
        self.streaming = true;
        Ok(())
    }

    /// `VIDIOC_QBUF` of buffer `index`.
    fn queue(&self, index: u32) -> Result<()> {
        let mut buf = sys::v4l2_buffer::zeroed();
        buf.index = index;
        buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        buf.memory = sys::V4L2_MEMORY_MMAP;
        xioctl(self.file.as_raw_fd(), sys::VIDIOC_QBUF, &mut buf).map_err(|e| match e.raw_os_error() {
            Some(libc::ENODEV) => self.vanished("VIDIOC_QBUF: ENODEV"),
            _ => ioctl_error(&self.path, "VIDIOC_QBUF", &e),
        })
    }
}

impl Drop for V4l2Stream {
    fn drop(&mut self) {
        if self.streaming {
            let mut buf_type = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
            if let Err(e) = xioctl(self.file.as_raw_fd(), sys::VIDIOC_STREAMOFF, &mut buf_type) {
                log::debug!("{}: VIDIOC_STREAMOFF: {e}", self.path.display());
            }
        }
        for buffer in self.buffers.drain(..) {
            // SAFETY: `ptr` and `len` come from a successful mmap and each
            // mapping is unmapped exactly once (drained here).
            if unsafe { libc::munmap(buffer.ptr, buffer.len) } != 0 {
                log::debug!("{}: munmap: {}", self.path.display(), io::Error::last_os_error());
            }
        }
        // `file` closes the descriptor when it drops, after this.
    }
}

/// `VIDIOC_S_FMT` for single-planar capture; errors if the driver changes the format or size.
fn set_format(fd: RawFd, path: &Path, format: PixelFormat, width: u32, height: u32) -> Result<sys::v4l2_pix_format> {
    let mut fmt = sys::v4l2_format::zeroed();
    fmt.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
    // SAFETY: reading the zero-initialised `pix` member (plain integers).
    let mut pix = unsafe { fmt.fmt.pix };
    pix.width = width;
    pix.height = height;
    pix.pixelformat = format.fourcc();
    pix.field = sys::V4L2_FIELD_NONE;
    fmt.fmt.pix = pix;
    xioctl(fd, sys::VIDIOC_S_FMT, &mut fmt).map_err(|e| ioctl_error(path, "VIDIOC_S_FMT", &e))?;
    // SAFETY: for V4L2_BUF_TYPE_VIDEO_CAPTURE the driver fills the `pix` member.
    let got = unsafe { fmt.fmt.pix };
    if got.pixelformat != format.fourcc() {
        return Err(Error::device(
            path,
            format!(
                "VIDIOC_S_FMT: requested {format}, the driver offers {} instead (`tricons devices` lists what it supports)",
                fourcc_to_string(got.pixelformat).trim_end()
            ),
        ));
    }
    if (got.width, got.height) != (width, height) {
        return Err(Error::device(
            path,
            format!(
                "VIDIOC_S_FMT: requested {format} {width}x{height}, the driver offers {}x{} (`tricons devices` lists the sizes)",
                got.width, got.height
            ),
        ));
    }
    if got.field != sys::V4L2_FIELD_NONE && got.field != sys::V4L2_FIELD_ANY {
        log::warn!(
            "{}: the driver delivers interlaced frames (field {}); rows will alternate fields",
            path.display(),
            got.field
        );
    }
    Ok(got)
}

/// `VIDIOC_S_PARM` for `fps` frames per second; a refusal or another rate is a warning.
fn set_frame_rate(fd: RawFd, path: &Path, fps: u32) {
    let mut parm = sys::v4l2_streamparm::zeroed();
    parm.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if let Err(e) = xioctl(fd, sys::VIDIOC_G_PARM, &mut parm) {
        log::warn!("{}: VIDIOC_G_PARM: {e}; cannot set {fps} fps, keeping the driver's rate", path.display());
        return;
    }
    // SAFETY: for capture buffers the driver fills the `capture` member.
    let mut capture = unsafe { parm.parm.capture };
    if capture.capability & sys::V4L2_CAP_TIMEPERFRAME == 0 {
        log::warn!("{}: the driver cannot set the frame rate; keeping its rate", path.display());
        return;
    }
    capture.timeperframe = sys::v4l2_fract { numerator: 1, denominator: fps };
    parm.parm.capture = capture;
    if let Err(e) = xioctl(fd, sys::VIDIOC_S_PARM, &mut parm) {
        log::warn!("{}: VIDIOC_S_PARM ({fps} fps): {e}; keeping the driver's rate", path.display());
        return;
    }
    // SAFETY: as above, the driver wrote back the `capture` member.
    let got = unsafe { parm.parm.capture }.timeperframe;
    if got.numerator == 0 || got.denominator as u64 != got.numerator as u64 * fps as u64 {
        log::warn!(
            "{}: asked for {fps} fps, the driver set a frame interval of {}/{} s",
            path.display(),
            got.numerator,
            got.denominator
        );
    }
}
