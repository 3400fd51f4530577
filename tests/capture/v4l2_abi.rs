//! The hand-written V4L2 ABI (src/capture/v4l2/sys.rs) against the kernel
//! header as compiled for this target (tests/fixtures/capture/abi/<target>.json,
//! from abi/v4l2_abi.c: sizes, alignments, field offsets, constants, ioctl
//! numbers), and what the V4L2 layer does without any camera: listing an empty
//! directory, opening missing nodes and files that are not V4L2 devices.
//! CI runs this on x86_64 and, under qemu, aarch64; cross/check.sh adds armv7.

#![cfg(all(feature = "v4l", target_os = "linux"))]

use std::mem::{align_of, offset_of, size_of};
use std::path::{Path, PathBuf};

use serde_json::Value;
use tricons::Error;
use tricons::capture::decode::PixelFormat;
use tricons::capture::v4l2::sys::*;
use tricons::capture::v4l2::{V4l2Stream, list_devices, list_devices_in};

/// The fixture for this target, `None` where none was generated.
fn abi_fixture() -> Option<Value> {
    let name = if cfg!(target_arch = "x86_64") {
        "x86_64"
    } else if cfg!(target_arch = "aarch64") {
        "aarch64"
    } else if cfg!(target_arch = "arm") {
        if size_of::<libc::time_t>() == 8 { "armv7-time64" } else { "armv7" }
    } else {
        return None;
    };
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("tests/fixtures/capture/abi/{name}.json"));
    Some(serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap())
}

/// `(C field name, offset, size)` of a field, its Rust type checked at compile time.
macro_rules! field {
    ($t:ty, $c:literal, $ft:ty, $($path:ident).+) => {{
        #[allow(unused_unsafe, dead_code)]
        fn type_check(x: &$t) -> &$ft {
            // SAFETY: never called; borrowing a union field only needs `unsafe` to compile.
            unsafe { &x.$($path).+ }
        }
        ($c, offset_of!($t, $($path).+), size_of::<$ft>())
    }};
}

/// Struct name, size, alignment, fields.
type Layout = (&'static str, usize, usize, Vec<(&'static str, usize, usize)>);

fn layouts() -> Vec<Layout> {
    macro_rules! layout {
        ($t:ident, [$($f:expr),* $(,)?]) => {
            (stringify!($t), size_of::<$t>(), align_of::<$t>(), vec![$($f),*])
        };
    }
    vec![
        layout!(
            v4l2_capability,
            [
                field!(v4l2_capability, "driver", [u8; 16], driver),
                field!(v4l2_capability, "card", [u8; 32], card),
                field!(v4l2_capability, "bus_info", [u8; 32], bus_info),
                field!(v4l2_capability, "version", u32, version),
                field!(v4l2_capability, "capabilities", u32, capabilities),
                field!(v4l2_capability, "device_caps", u32, device_caps),
                field!(v4l2_capability, "reserved", [u32; 3], reserved),
            ]
        ),
        layout!(
            v4l2_fmtdesc,
            [
                field!(v4l2_fmtdesc, "index", u32, index),
                field!(v4l2_fmtdesc, "type", u32, type_),
                field!(v4l2_fmtdesc, "flags", u32, flags),
                field!(v4l2_fmtdesc, "description", [u8; 32], description),
                field!(v4l2_fmtdesc, "pixelformat", u32, pixelformat),
                field!(v4l2_fmtdesc, "mbus_code", u32, mbus_code),
                field!(v4l2_fmtdesc, "reserved", [u32; 3], reserved),
            ]
        ),
        layout!(
            v4l2_frmsizeenum,
            [
                field!(v4l2_frmsizeenum, "index", u32, index),
                field!(v4l2_frmsizeenum, "pixel_format", u32, pixel_format),
                field!(v4l2_frmsizeenum, "type", u32, type_),
                field!(v4l2_frmsizeenum, "discrete", v4l2_frmsize_discrete, size.discrete),
                field!(v4l2_frmsizeenum, "stepwise", v4l2_frmsize_stepwise, size.stepwise),
                field!(v4l2_frmsizeenum, "reserved", [u32; 2], reserved),
            ]
        ),
        layout!(
            v4l2_frmsize_stepwise,
            [
                field!(v4l2_frmsize_stepwise, "min_width", u32, min_width),
                field!(v4l2_frmsize_stepwise, "max_width", u32, max_width),
                field!(v4l2_frmsize_stepwise, "step_width", u32, step_width),
                field!(v4l2_frmsize_stepwise, "min_height", u32, min_height),
                field!(v4l2_frmsize_stepwise, "max_height", u32, max_height),
                field!(v4l2_frmsize_stepwise, "step_height", u32, step_height),
            ]
        ),
        layout!(
            v4l2_pix_format,
            [
                field!(v4l2_pix_format, "width", u32, width),
                field!(v4l2_pix_format, "height", u32, height),
                field!(v4l2_pix_format, "pixelformat", u32, pixelformat),
                field!(v4l2_pix_format, "field", u32, field),
                field!(v4l2_pix_format, "bytesperline", u32, bytesperline),
                field!(v4l2_pix_format, "sizeimage", u32, sizeimage),
                field!(v4l2_pix_format, "colorspace", u32, colorspace),
                field!(v4l2_pix_format, "priv", u32, priv_),
                field!(v4l2_pix_format, "flags", u32, flags),
                field!(v4l2_pix_format, "ycbcr_enc", u32, ycbcr_enc),
                field!(v4l2_pix_format, "quantization", u32, quantization),
                field!(v4l2_pix_format, "xfer_func", u32, xfer_func),
            ]
        ),
        layout!(
            v4l2_format,
            [field!(v4l2_format, "type", u32, type_), field!(v4l2_format, "fmt", v4l2_format_fmt, fmt),]
        ),
        layout!(
            v4l2_requestbuffers,
            [
                field!(v4l2_requestbuffers, "count", u32, count),
                field!(v4l2_requestbuffers, "type", u32, type_),
                field!(v4l2_requestbuffers, "memory", u32, memory),
                field!(v4l2_requestbuffers, "capabilities", u32, capabilities),
            ]
        ),
        layout!(
            v4l2_timecode,
            [
                field!(v4l2_timecode, "type", u32, type_),
                field!(v4l2_timecode, "flags", u32, flags),
                field!(v4l2_timecode, "frames", u8, frames),
                field!(v4l2_timecode, "userbits", [u8; 4], userbits),
            ]
        ),
        layout!(
            v4l2_buffer,
            [
                field!(v4l2_buffer, "index", u32, index),
                field!(v4l2_buffer, "type", u32, type_),
                field!(v4l2_buffer, "bytesused", u32, bytesused),
                field!(v4l2_buffer, "flags", u32, flags),
                field!(v4l2_buffer, "field", u32, field),
                field!(v4l2_buffer, "timestamp", libc::timeval, timestamp),
                field!(v4l2_buffer, "timecode", v4l2_timecode, timecode),
                field!(v4l2_buffer, "sequence", u32, sequence),
                field!(v4l2_buffer, "memory", u32, memory),
                field!(v4l2_buffer, "m", v4l2_buffer_m, m),
                field!(v4l2_buffer, "length", u32, length),
                field!(v4l2_buffer, "reserved2", u32, reserved2),
                field!(v4l2_buffer, "request_fd", i32, request_fd),
            ]
        ),
        layout!(
            v4l2_captureparm,
            [
                field!(v4l2_captureparm, "capability", u32, capability),
                field!(v4l2_captureparm, "capturemode", u32, capturemode),
                field!(v4l2_captureparm, "timeperframe", v4l2_fract, timeperframe),
                field!(v4l2_captureparm, "extendedmode", u32, extendedmode),
                field!(v4l2_captureparm, "readbuffers", u32, readbuffers),
                field!(v4l2_captureparm, "reserved", [u32; 4], reserved),
            ]
        ),
        layout!(
            v4l2_streamparm,
            [field!(v4l2_streamparm, "type", u32, type_), field!(v4l2_streamparm, "parm", v4l2_streamparm_parm, parm),]
        ),
    ]
}

#[test]
fn struct_layouts_match_the_kernel_header_for_this_target() {
    let Some(abi) = abi_fixture() else {
        eprintln!("no ABI fixture for this target: skipped");
        return;
    };
    assert_eq!(abi["pointer_bytes"].as_u64().unwrap() as usize, size_of::<usize>());
    assert_eq!(abi["time_t_bytes"].as_u64().unwrap() as usize, size_of::<libc::time_t>());
    let structs = abi["structs"].as_object().unwrap();
    let ours = layouts();
    assert_eq!(ours.len(), structs.len(), "every struct of the fixture is checked");
    for (name, size, align, fields) in ours {
        let c = &structs[name];
        assert_eq!(size as u64, c["size"].as_u64().unwrap(), "size of {name}");
        assert_eq!(align as u64, c["align"].as_u64().unwrap(), "alignment of {name}");
        let c_fields = c["fields"].as_object().unwrap();
        assert_eq!(fields.len(), c_fields.len(), "fields of {name}");
        for (field, offset, field_size) in fields {
            let want = &c_fields[field];
            assert_eq!(offset as u64, want[0].as_u64().unwrap(), "offset of {name}.{field}");
            assert_eq!(field_size as u64, want[1].as_u64().unwrap(), "size of {name}.{field}");
        }
    }
}

#[test]
fn ioctl_numbers_and_constants_match_the_kernel_header_for_this_target() {
    let Some(abi) = abi_fixture() else {
        eprintln!("no ABI fixture for this target: skipped");
        return;
    };
    // `libc::Ioctl` is c_ulong (glibc) or c_int (musl): compare the 32-bit code.
    let ioctls: [(&str, libc::Ioctl); 13] = [
        ("VIDIOC_QUERYCAP", VIDIOC_QUERYCAP),
        ("VIDIOC_ENUM_FMT", VIDIOC_ENUM_FMT),
        ("VIDIOC_G_FMT", VIDIOC_G_FMT),
        ("VIDIOC_S_FMT", VIDIOC_S_FMT),
        ("VIDIOC_REQBUFS", VIDIOC_REQBUFS),
        ("VIDIOC_QUERYBUF", VIDIOC_QUERYBUF),
        ("VIDIOC_QBUF", VIDIOC_QBUF),
        ("VIDIOC_DQBUF", VIDIOC_DQBUF),
        ("VIDIOC_STREAMON", VIDIOC_STREAMON),
        ("VIDIOC_STREAMOFF", VIDIOC_STREAMOFF),
        ("VIDIOC_G_PARM", VIDIOC_G_PARM),
        ("VIDIOC_S_PARM", VIDIOC_S_PARM),
        ("VIDIOC_ENUM_FRAMESIZES", VIDIOC_ENUM_FRAMESIZES),
    ];
    let c_ioctls = abi["ioctls"].as_object().unwrap();
    assert_eq!(c_ioctls.len(), ioctls.len());
    for (name, value) in ioctls {
        assert_eq!(u64::from(value as u32), c_ioctls[name].as_u64().unwrap(), "{name}");
    }
    let constants: [(&str, u32); 22] = [
        ("V4L2_BUF_TYPE_VIDEO_CAPTURE", V4L2_BUF_TYPE_VIDEO_CAPTURE),
        ("V4L2_MEMORY_MMAP", V4L2_MEMORY_MMAP),
        ("V4L2_FIELD_ANY", V4L2_FIELD_ANY),
        ("V4L2_FIELD_NONE", V4L2_FIELD_NONE),
        ("V4L2_CAP_VIDEO_CAPTURE", V4L2_CAP_VIDEO_CAPTURE),
        ("V4L2_CAP_VIDEO_CAPTURE_MPLANE", V4L2_CAP_VIDEO_CAPTURE_MPLANE),
        ("V4L2_CAP_META_CAPTURE", V4L2_CAP_META_CAPTURE),
        ("V4L2_CAP_STREAMING", V4L2_CAP_STREAMING),
        ("V4L2_CAP_DEVICE_CAPS", V4L2_CAP_DEVICE_CAPS),
        ("V4L2_CAP_TIMEPERFRAME", V4L2_CAP_TIMEPERFRAME),
        ("V4L2_FRMSIZE_TYPE_DISCRETE", V4L2_FRMSIZE_TYPE_DISCRETE),
        ("V4L2_FRMSIZE_TYPE_CONTINUOUS", V4L2_FRMSIZE_TYPE_CONTINUOUS),
        ("V4L2_FRMSIZE_TYPE_STEPWISE", V4L2_FRMSIZE_TYPE_STEPWISE),
        ("V4L2_BUF_FLAG_ERROR", V4L2_BUF_FLAG_ERROR),
        ("V4L2_BUF_FLAG_TIMESTAMP_MASK", V4L2_BUF_FLAG_TIMESTAMP_MASK),
        ("V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC", V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC),
        ("V4L2_FMT_FLAG_COMPRESSED", V4L2_FMT_FLAG_COMPRESSED),
        ("V4L2_FMT_FLAG_EMULATED", V4L2_FMT_FLAG_EMULATED),
        ("V4L2_PIX_FMT_YUYV", PixelFormat::Yuyv.fourcc()),
        ("V4L2_PIX_FMT_MJPEG", PixelFormat::Mjpg.fourcc()),
        ("V4L2_PIX_FMT_RGB24", PixelFormat::Rgb3.fourcc()),
        ("V4L2_PIX_FMT_Z16", PixelFormat::Z16.fourcc()),
    ];
    let c_constants = abi["constants"].as_object().unwrap();
    assert_eq!(c_constants.len(), constants.len());
    for (name, value) in constants {
        assert_eq!(u64::from(value), c_constants[name].as_u64().unwrap(), "{name}");
    }
}

#[test]
fn a_directory_without_video_nodes_lists_nothing() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("video"), b"").unwrap(); // no number
    std::fs::write(dir.path().join("videoX"), b"").unwrap();
    std::fs::write(dir.path().join("media0"), b"").unwrap();
    assert!(list_devices_in(dir.path()).unwrap().is_empty());
    assert!(matches!(list_devices_in(&dir.path().join("missing")), Err(Error::Io { .. })));
    // The real /dev: whatever is there, listing succeeds.
    list_devices().unwrap();
}

#[test]
fn nodes_that_are_not_v4l2_are_listed_with_their_error_in_numeric_order() {
    let dir = tempfile::tempdir().unwrap();
    for n in [10, 2, 1] {
        std::fs::write(dir.path().join(format!("video{n}")), b"not a device").unwrap();
    }
    let devices = list_devices_in(dir.path()).unwrap();
    let names: Vec<_> = devices.iter().map(|d| d.path.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, ["video1", "video2", "video10"]);
    for d in &devices {
        assert!(!d.capture);
        assert!(d.formats.is_empty());
        let err = d.error.as_deref().unwrap();
        assert!(err.starts_with("VIDIOC_QUERYCAP: ") && is_not_v4l2(err), "{err}");
    }
}

/// The kernel answers ENOTTY to a V4L2 ioctl on a file that is not a V4L2
/// device; qemu-user (the aarch64 run in CI) answers ENOSYS for ioctls it does
/// not translate, V4L2's included.
fn is_not_v4l2(message: &str) -> bool {
    message.contains("not a V4L2 device") || message.contains("running under an emulator")
}

fn open_error(path: &Path) -> (PathBuf, String) {
    match V4l2Stream::open(path, PixelFormat::Yuyv, 640, 480, Some(30), 4) {
        Err(Error::Device { path, message }) => (path, message),
        Err(other) => panic!("expected a device error, got {other}"),
        Ok(_) => panic!("{} opened as a camera", path.display()),
    }
}

#[test]
fn opening_a_missing_node_is_a_device_error_naming_it() {
    let (path, message) = open_error(Path::new("/dev/video-does-not-exist"));
    assert_eq!(path, Path::new("/dev/video-does-not-exist"));
    assert!(message.contains("cannot open") && message.contains("No such file"), "{message}");
}

#[test]
fn opening_something_that_is_not_a_v4l2_device_fails_at_querycap() {
    let file = tempfile::NamedTempFile::new().unwrap();
    for path in [Path::new("/dev/null"), file.path()] {
        let (got, message) = open_error(path);
        assert_eq!(got, path);
        assert!(message.starts_with("VIDIOC_QUERYCAP: ") && is_not_v4l2(&message), "{message}");
    }
}

#[test]
fn invalid_stream_parameters_are_rejected_before_touching_the_device() {
    for (w, h, fps, buffers) in [(0, 480, None, 4), (640, 480, Some(0), 4), (640, 480, None, 0), (640, 480, None, 33)] {
        let r = V4l2Stream::open(Path::new("/dev/null"), PixelFormat::Mjpg, w, h, fps, buffers);
        assert!(matches!(r, Err(Error::InvalidArgument(_))), "{w}x{h} fps {fps:?} buffers {buffers}");
    }
}
