//! `#[repr(C)]` mirrors of the `<linux/videodev2.h>` structs tricons uses,
//! their constants, and the `VIDIOC_*` request numbers, written by hand (no
//! bindgen).
//!
//! Request numbers are computed from the `_IOC` encoding with the `size_of` of
//! these structs, so they follow the target's ABI (pointer size, `time_t`)
//! automatically. tests/capture/v4l2_abi.rs checks every size, alignment, field
//! offset, constant and request number against the C header's, as compiled by
//! tests/fixtures/capture/abi/v4l2_abi.c for x86_64, aarch64 and armv7.
//!
//! Names follow the kernel's (`type` is `type_`, `priv` is `priv_`); unions the
//! kernel leaves anonymous are named `<struct>_<member>`.

#![allow(non_camel_case_types)]

use libc::{c_int, c_ulong, c_void};
use std::mem::size_of;

/// `V4L2_BUF_TYPE_VIDEO_CAPTURE`: single-planar video capture.
pub const V4L2_BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
/// `V4L2_MEMORY_MMAP`: driver buffers mapped into the process.
pub const V4L2_MEMORY_MMAP: u32 = 1;
/// `V4L2_FIELD_ANY`: the driver chooses the field order.
pub const V4L2_FIELD_ANY: u32 = 0;
/// `V4L2_FIELD_NONE`: progressive frames.
pub const V4L2_FIELD_NONE: u32 = 1;

/// `V4L2_CAP_VIDEO_CAPTURE`: single-planar capture.
pub const V4L2_CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
/// `V4L2_CAP_VIDEO_CAPTURE_MPLANE`: multi-planar capture (not supported by tricons).
pub const V4L2_CAP_VIDEO_CAPTURE_MPLANE: u32 = 0x0000_1000;
/// `V4L2_CAP_META_CAPTURE`: metadata node (uvcvideo creates one per camera).
pub const V4L2_CAP_META_CAPTURE: u32 = 0x0080_0000;
/// `V4L2_CAP_STREAMING`: streaming I/O (mmap buffers).
pub const V4L2_CAP_STREAMING: u32 = 0x0400_0000;
/// `V4L2_CAP_DEVICE_CAPS`: `device_caps` describes this node (`capabilities` the whole device).
pub const V4L2_CAP_DEVICE_CAPS: u32 = 0x8000_0000;
/// `V4L2_CAP_TIMEPERFRAME` in `v4l2_captureparm::capability`: the frame rate can be set.
pub const V4L2_CAP_TIMEPERFRAME: u32 = 0x1000;

/// `V4L2_FRMSIZE_TYPE_DISCRETE`.
pub const V4L2_FRMSIZE_TYPE_DISCRETE: u32 = 1;
/// `V4L2_FRMSIZE_TYPE_CONTINUOUS` (stepwise with steps of 1).
pub const V4L2_FRMSIZE_TYPE_CONTINUOUS: u32 = 2;
/// `V4L2_FRMSIZE_TYPE_STEPWISE`.
pub const V4L2_FRMSIZE_TYPE_STEPWISE: u32 = 3;

/// `V4L2_BUF_FLAG_ERROR`: the buffer's data may be corrupt.
pub const V4L2_BUF_FLAG_ERROR: u32 = 0x0000_0040;
/// `V4L2_BUF_FLAG_TIMESTAMP_MASK`: the timestamp clock bits.
pub const V4L2_BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
/// `V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`: timestamps are `CLOCK_MONOTONIC`.
pub const V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;

/// `V4L2_FMT_FLAG_COMPRESSED`.
pub const V4L2_FMT_FLAG_COMPRESSED: u32 = 0x0001;
/// `V4L2_FMT_FLAG_EMULATED`: converted in software by libv4l, not by the device.
pub const V4L2_FMT_FLAG_EMULATED: u32 = 0x0002;

/// `struct v4l2_capability` (`VIDIOC_QUERYCAP`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_capability {
    /// Driver name, NUL-terminated (e.g. "uvcvideo").
    pub driver: [u8; 16],
    /// Device name, NUL-terminated.
    pub card: [u8; 32],
    /// Bus location, NUL-terminated (e.g. "usb-0000:00:14.0-1").
    pub bus_info: [u8; 32],
    /// `KERNEL_VERSION` of the driver.
    pub version: u32,
    /// Capabilities of the whole physical device.
    pub capabilities: u32,
    /// Capabilities of this node (valid with `V4L2_CAP_DEVICE_CAPS`).
    pub device_caps: u32,
    /// Reserved, zero.
    pub reserved: [u32; 3],
}

/// `struct v4l2_fmtdesc` (`VIDIOC_ENUM_FMT`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_fmtdesc {
    /// Format number, set by the caller.
    pub index: u32,
    /// Buffer type, set by the caller.
    pub type_: u32,
    /// `V4L2_FMT_FLAG_*`.
    pub flags: u32,
    /// Human-readable description, NUL-terminated.
    pub description: [u8; 32],
    /// The fourcc.
    pub pixelformat: u32,
    /// Media bus code filter (0: none).
    pub mbus_code: u32,
    /// Reserved, zero.
    pub reserved: [u32; 3],
}

/// `struct v4l2_frmsize_discrete`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_frmsize_discrete {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

/// `struct v4l2_frmsize_stepwise`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_frmsize_stepwise {
    /// Minimum width.
    pub min_width: u32,
    /// Maximum width.
    pub max_width: u32,
    /// Width step.
    pub step_width: u32,
    /// Minimum height.
    pub min_height: u32,
    /// Maximum height.
    pub max_height: u32,
    /// Height step.
    pub step_height: u32,
}

/// The anonymous union of `struct v4l2_frmsizeenum`.
#[repr(C)]
#[derive(Clone, Copy)]
pub union v4l2_frmsizeenum_size {
    /// Valid for `V4L2_FRMSIZE_TYPE_DISCRETE`.
    pub discrete: v4l2_frmsize_discrete,
    /// Valid for the stepwise and continuous types.
    pub stepwise: v4l2_frmsize_stepwise,
}

/// `struct v4l2_frmsizeenum` (`VIDIOC_ENUM_FRAMESIZES`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct v4l2_frmsizeenum {
    /// Size number, set by the caller.
    pub index: u32,
    /// Fourcc, set by the caller.
    pub pixel_format: u32,
    /// `V4L2_FRMSIZE_TYPE_*`.
    pub type_: u32,
    /// The size(s), by `type_`.
    pub size: v4l2_frmsizeenum_size,
    /// Reserved, zero.
    pub reserved: [u32; 2],
}

/// `struct v4l2_pix_format`: single-planar image format.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_pix_format {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Fourcc.
    pub pixelformat: u32,
    /// `V4L2_FIELD_*`.
    pub field: u32,
    /// Row stride in bytes (0 or unused for compressed formats).
    pub bytesperline: u32,
    /// Buffer size needed for one frame.
    pub sizeimage: u32,
    /// `V4L2_COLORSPACE_*`.
    pub colorspace: u32,
    /// Private; `V4L2_PIX_FMT_PRIV_MAGIC` when the extended fields are valid.
    pub priv_: u32,
    /// `V4L2_PIX_FMT_FLAG_*`.
    pub flags: u32,
    /// `ycbcr_enc` / `hsv_enc` (a union of two u32 in the kernel).
    pub ycbcr_enc: u32,
    /// `V4L2_QUANTIZATION_*` (full or limited range).
    pub quantization: u32,
    /// `V4L2_XFER_FUNC_*`.
    pub xfer_func: u32,
}

/// The `fmt` union of `struct v4l2_format`: 200 bytes, aligned like a pointer
/// (the kernel's union holds `struct v4l2_window`, which has pointers).
#[repr(C)]
#[derive(Clone, Copy)]
pub union v4l2_format_fmt {
    /// `V4L2_BUF_TYPE_VIDEO_CAPTURE`.
    pub pix: v4l2_pix_format,
    /// The union's full size.
    pub raw_data: [u8; 200],
    /// Pointer alignment, as in the kernel's union (8 on 64-bit, 4 on 32-bit targets).
    pub _align: [usize; 0],
}

/// `struct v4l2_format` (`VIDIOC_G_FMT`, `VIDIOC_S_FMT`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct v4l2_format {
    /// Buffer type.
    pub type_: u32,
    /// The format, by `type_`.
    pub fmt: v4l2_format_fmt,
}

/// `struct v4l2_requestbuffers` (`VIDIOC_REQBUFS`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_requestbuffers {
    /// Buffers wanted; the driver writes how many it allocated.
    pub count: u32,
    /// Buffer type.
    pub type_: u32,
    /// `V4L2_MEMORY_*`.
    pub memory: u32,
    /// `V4L2_BUF_CAP_*`, set by the driver.
    pub capabilities: u32,
    /// `V4L2_MEMORY_FLAG_*`.
    pub flags: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
}

/// `struct v4l2_timecode`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_timecode {
    /// `V4L2_TC_TYPE_*`.
    pub type_: u32,
    /// `V4L2_TC_FLAG_*`.
    pub flags: u32,
    /// Frames.
    pub frames: u8,
    /// Seconds.
    pub seconds: u8,
    /// Minutes.
    pub minutes: u8,
    /// Hours.
    pub hours: u8,
    /// User bits.
    pub userbits: [u8; 4],
}

/// The `m` union of `struct v4l2_buffer`: where the buffer's memory is.
#[repr(C)]
#[derive(Clone, Copy)]
pub union v4l2_buffer_m {
    /// `V4L2_MEMORY_MMAP`: the offset to pass to `mmap`.
    pub offset: u32,
    /// `V4L2_MEMORY_USERPTR`: the user address.
    pub userptr: c_ulong,
    /// Multi-planar buffers: `struct v4l2_plane *` (not used by tricons).
    pub planes: *mut c_void,
    /// `V4L2_MEMORY_DMABUF`: the file descriptor.
    pub fd: i32,
}

/// `struct v4l2_buffer` (`VIDIOC_QUERYBUF`, `VIDIOC_QBUF`, `VIDIOC_DQBUF`).
/// `timestamp` is the C library's `struct timeval` ([`libc::timeval`]): its
/// size (32- or 64-bit `time_t` on 32-bit targets) is part of the ABI and of
/// the request numbers.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct v4l2_buffer {
    /// Buffer number.
    pub index: u32,
    /// Buffer type.
    pub type_: u32,
    /// Bytes of data in the buffer.
    pub bytesused: u32,
    /// `V4L2_BUF_FLAG_*`.
    pub flags: u32,
    /// `V4L2_FIELD_*`.
    pub field: u32,
    /// Capture time (clock given by the `V4L2_BUF_FLAG_TIMESTAMP_*` flags).
    pub timestamp: libc::timeval,
    /// Timecode (rarely set).
    pub timecode: v4l2_timecode,
    /// Frame counter set by the driver.
    pub sequence: u32,
    /// `V4L2_MEMORY_*`.
    pub memory: u32,
    /// Where the memory is, by `memory`.
    pub m: v4l2_buffer_m,
    /// Buffer size in bytes.
    pub length: u32,
    /// Reserved, zero.
    pub reserved2: u32,
    /// `request_fd` / `reserved` (a union of two 32-bit fields in the kernel).
    pub request_fd: i32,
}

/// `struct v4l2_fract`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_fract {
    /// Numerator.
    pub numerator: u32,
    /// Denominator.
    pub denominator: u32,
}

/// `struct v4l2_captureparm`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct v4l2_captureparm {
    /// `V4L2_CAP_TIMEPERFRAME` when the frame interval can be set.
    pub capability: u32,
    /// `V4L2_MODE_*`.
    pub capturemode: u32,
    /// Frame interval in seconds (1/fps).
    pub timeperframe: v4l2_fract,
    /// Driver-specific.
    pub extendedmode: u32,
    /// Read-I/O buffers.
    pub readbuffers: u32,
    /// Reserved, zero.
    pub reserved: [u32; 4],
}

/// The `parm` union of `struct v4l2_streamparm` (200 bytes, no pointers).
#[repr(C)]
#[derive(Clone, Copy)]
pub union v4l2_streamparm_parm {
    /// Capture parameters.
    pub capture: v4l2_captureparm,
    /// The union's full size.
    pub raw_data: [u8; 200],
}

/// `struct v4l2_streamparm` (`VIDIOC_G_PARM`, `VIDIOC_S_PARM`).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct v4l2_streamparm {
    /// Buffer type.
    pub type_: u32,
    /// The parameters, by `type_`.
    pub parm: v4l2_streamparm_parm,
}

/// Zero-initialised kernel structs, as the V4L2 API expects them before the
/// caller fills in its fields.
pub trait Zeroed: Sized {
    /// All bytes zero.
    fn zeroed() -> Self;
}

macro_rules! impl_zeroed {
    ($($t:ty),* $(,)?) => {$(
        impl Zeroed for $t {
            fn zeroed() -> Self {
                // SAFETY: the type is plain data (integers, byte arrays, raw
                // pointers, `libc::timeval` and unions of those), for which all
                // zero bits is a valid value.
                unsafe { std::mem::zeroed() }
            }
        }
    )*};
}

impl_zeroed!(
    v4l2_capability,
    v4l2_fmtdesc,
    v4l2_frmsizeenum,
    v4l2_format,
    v4l2_requestbuffers,
    v4l2_buffer,
    v4l2_streamparm,
);

// `_IOC` encoding of ioctl request numbers (include/uapi/asm-generic/ioctl.h,
// used by x86, arm and arm64): nr in bits 0..8, type in 8..16, argument size in
// 16..30, direction in 30..32. powerpc, mips and sparc use 13 size bits and 3
// direction bits with other direction values.
#[cfg(not(any(
    target_arch = "powerpc",
    target_arch = "powerpc64",
    target_arch = "mips",
    target_arch = "mips64",
    target_arch = "sparc64"
)))]
mod ioc {
    pub const SIZEBITS: u32 = 14;
    pub const WRITE: u32 = 1;
    pub const READ: u32 = 2;
}
#[cfg(any(
    target_arch = "powerpc",
    target_arch = "powerpc64",
    target_arch = "mips",
    target_arch = "mips64",
    target_arch = "sparc64"
))]
mod ioc {
    pub const SIZEBITS: u32 = 13;
    pub const WRITE: u32 = 4;
    pub const READ: u32 = 2;
}
const IOC_NRSHIFT: u32 = 0;
const IOC_TYPESHIFT: u32 = 8;
const IOC_SIZESHIFT: u32 = 16;
const IOC_DIRSHIFT: u32 = IOC_SIZESHIFT + ioc::SIZEBITS;

/// `_IOC(dir, type, nr, size)`; fails to compile if `size` does not fit the size field.
const fn ioc_request(dir: u32, ty: u8, nr: u8, size: usize) -> libc::Ioctl {
    assert!(size < 1 << ioc::SIZEBITS, "ioctl argument too large for the _IOC size field");
    let code = (dir << IOC_DIRSHIFT)
        | ((ty as u32) << IOC_TYPESHIFT)
        | ((nr as u32) << IOC_NRSHIFT)
        | ((size as u32) << IOC_SIZESHIFT);
    // `Ioctl` is `c_ulong` on glibc and `c_int` on musl; both take the 32-bit code as is.
    code as libc::Ioctl
}

/// `_IOR('V', nr, T)`: the kernel writes a `T`.
const fn ior<T>(nr: u8) -> libc::Ioctl {
    ioc_request(ioc::READ, b'V', nr, size_of::<T>())
}

/// `_IOW('V', nr, T)`: the kernel reads a `T`.
const fn iow<T>(nr: u8) -> libc::Ioctl {
    ioc_request(ioc::WRITE, b'V', nr, size_of::<T>())
}

/// `_IOWR('V', nr, T)`: both.
const fn iowr<T>(nr: u8) -> libc::Ioctl {
    ioc_request(ioc::READ | ioc::WRITE, b'V', nr, size_of::<T>())
}

/// `VIDIOC_QUERYCAP`: `_IOR('V', 0, struct v4l2_capability)`.
pub const VIDIOC_QUERYCAP: libc::Ioctl = ior::<v4l2_capability>(0);
/// `VIDIOC_ENUM_FMT`: `_IOWR('V', 2, struct v4l2_fmtdesc)`.
pub const VIDIOC_ENUM_FMT: libc::Ioctl = iowr::<v4l2_fmtdesc>(2);
/// `VIDIOC_G_FMT`: `_IOWR('V', 4, struct v4l2_format)`.
pub const VIDIOC_G_FMT: libc::Ioctl = iowr::<v4l2_format>(4);
/// `VIDIOC_S_FMT`: `_IOWR('V', 5, struct v4l2_format)`.
pub const VIDIOC_S_FMT: libc::Ioctl = iowr::<v4l2_format>(5);
/// `VIDIOC_REQBUFS`: `_IOWR('V', 8, struct v4l2_requestbuffers)`.
pub const VIDIOC_REQBUFS: libc::Ioctl = iowr::<v4l2_requestbuffers>(8);
/// `VIDIOC_QUERYBUF`: `_IOWR('V', 9, struct v4l2_buffer)`.
pub const VIDIOC_QUERYBUF: libc::Ioctl = iowr::<v4l2_buffer>(9);
/// `VIDIOC_QBUF`: `_IOWR('V', 15, struct v4l2_buffer)`.
pub const VIDIOC_QBUF: libc::Ioctl = iowr::<v4l2_buffer>(15);
/// `VIDIOC_DQBUF`: `_IOWR('V', 17, struct v4l2_buffer)`.
pub const VIDIOC_DQBUF: libc::Ioctl = iowr::<v4l2_buffer>(17);
/// `VIDIOC_STREAMON`: `_IOW('V', 18, int)`.
pub const VIDIOC_STREAMON: libc::Ioctl = iow::<c_int>(18);
/// `VIDIOC_STREAMOFF`: `_IOW('V', 19, int)`.
pub const VIDIOC_STREAMOFF: libc::Ioctl = iow::<c_int>(19);
/// `VIDIOC_G_PARM`: `_IOWR('V', 21, struct v4l2_streamparm)`.
pub const VIDIOC_G_PARM: libc::Ioctl = iowr::<v4l2_streamparm>(21);
/// `VIDIOC_S_PARM`: `_IOWR('V', 22, struct v4l2_streamparm)`.
pub const VIDIOC_S_PARM: libc::Ioctl = iowr::<v4l2_streamparm>(22);
/// `VIDIOC_ENUM_FRAMESIZES`: `_IOWR('V', 74, struct v4l2_frmsizeenum)`.
pub const VIDIOC_ENUM_FRAMESIZES: libc::Ioctl = iowr::<v4l2_frmsizeenum>(74);

/// A NUL-terminated byte array (driver, card, description fields) as a string.
pub fn c_chars(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}
