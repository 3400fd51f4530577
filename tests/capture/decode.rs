//! Raw V4L2 buffers to images (src/capture/decode.rs) against fixtures made by
//! an independent generator (tests/fixtures/capture/make_fixtures.py: the
//! BT.601 formula in numpy, JPEGs encoded and decoded by PIL/libjpeg-turbo),
//! malformed buffers, and the `tricons devices` command on a machine without cameras.

use std::path::PathBuf;
use std::str::FromStr;

use crate::common::cli::{stderr, tricons};
use serde_json::Value;
use tricons::Error;
use tricons::capture::decode::{PixelFormat, annex_k, decode_color, decode_depth_z16};

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/capture")
}

fn fixture(name: &str) -> Vec<u8> {
    let path = fixture_dir().join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn expected() -> Value {
    serde_json::from_slice(&fixture("expected.json")).unwrap()
}

fn u32_of(v: &Value, key: &str) -> u32 {
    v[key].as_u64().unwrap() as u32
}

fn bytes_of(v: &Value, key: &str) -> Vec<u8> {
    v[key].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u8).collect()
}

/// The error must be a decode error for `format` whose message contains `needle`.
fn assert_decode_error<T: std::fmt::Debug>(result: tricons::Result<T>, format: &str, needle: &str) {
    match result {
        Err(Error::Decode { format: f, message }) => {
            assert_eq!(f, format, "message: {message}");
            assert!(message.contains(needle), "{format} error {message:?} does not mention {needle:?}");
        }
        other => panic!("expected a {format} decode error mentioning {needle:?}, got {other:?}"),
    }
}

#[test]
fn pixel_formats_have_v4l2_fourccs_names_and_parse_from_cli_spellings() {
    let cases = [
        (PixelFormat::Yuyv, *b"YUYV", "YUYV", 0x5659_5559_u32),
        (PixelFormat::Mjpg, *b"MJPG", "MJPG", 0x4750_4a4d),
        (PixelFormat::Rgb3, *b"RGB3", "RGB3", 0x3342_4752),
        (PixelFormat::Z16, *b"Z16 ", "Z16", 0x2036_315a),
    ];
    for (format, chars, name, code) in cases {
        assert_eq!(format.fourcc(), code, "{name}");
        assert_eq!(format.fourcc(), u32::from_le_bytes(chars));
        assert_eq!(PixelFormat::from_fourcc(code), Some(format));
        assert_eq!(format.name(), name);
        assert_eq!(format.to_string(), name);
        assert_eq!(format.is_depth(), format == PixelFormat::Z16);
    }
    assert_eq!(PixelFormat::from_fourcc(u32::from_le_bytes(*b"NV12")), None);
    for (text, format) in [
        ("yuyv", PixelFormat::Yuyv),
        ("YUYV", PixelFormat::Yuyv),
        ("mjpg", PixelFormat::Mjpg),
        ("MJPEG", PixelFormat::Mjpg),
        ("rgb3", PixelFormat::Rgb3),
        ("Rgb24", PixelFormat::Rgb3),
        ("z16", PixelFormat::Z16),
        ("Z16", PixelFormat::Z16),
    ] {
        assert_eq!(PixelFormat::from_str(text), Ok(format), "{text}");
    }
    let err = PixelFormat::from_str("nv12").unwrap_err();
    assert!(err.contains("nv12") && err.contains("yuyv"), "{err}");
    assert_eq!(serde_json::to_string(&PixelFormat::Z16).unwrap(), "\"Z16\"");
    assert_eq!(serde_json::from_str::<PixelFormat>("\"mjpeg\"").unwrap(), PixelFormat::Mjpg);
}

#[test]
fn yuyv_with_row_padding_matches_the_independent_bt601_reference_exactly() {
    let e = &expected()["yuyv"];
    let (w, h, bpl) = (u32_of(e, "width"), u32_of(e, "height"), u32_of(e, "bytes_per_line"));
    assert!(bpl > 2 * w, "the fixture must have row padding");
    let img = decode_color(PixelFormat::Yuyv, &fixture(e["file"].as_str().unwrap()), w, h, bpl).unwrap();
    assert_eq!((img.width, img.height), (w, h));
    assert_eq!(img.data, bytes_of(e, "rgb"));
}

/// BT.601 limited range from its definition, in f64 (see the decode.rs module docs).
fn bt601_reference(y: u8, u: u8, v: u8) -> [u8; 3] {
    let (kr, kb) = (0.299, 0.114);
    let kg = 1.0 - kr - kb;
    let luma = 255.0 / 219.0 * (f64::from(y) - 16.0);
    let (cu, cv) = (f64::from(u) - 128.0, f64::from(v) - 128.0);
    let s = 255.0 / 224.0;
    let r = luma + s * 2.0 * (1.0 - kr) * cv;
    let g = luma - s * 2.0 * (1.0 - kr) * kr / kg * cv - s * 2.0 * (1.0 - kb) * kb / kg * cu;
    let b = luma + s * 2.0 * (1.0 - kb) * cu;
    [r, g, b].map(|x| (x + 0.5).floor().clamp(0.0, 255.0) as u8)
}

/// The integer tables equal the rounded real formula for all 2^24 (Y, U, V):
/// one 256x256 frame per U value, each row one V value holding Y = 0..=255.
#[test]
fn yuyv_integer_conversion_equals_the_real_formula_for_every_yuv_triple() {
    let (w, h) = (256u32, 256u32);
    let mut frame = vec![0u8; (w * 2 * h) as usize];
    let mut mismatches = 0usize;
    for u in 0..=255u8 {
        for (v, row) in frame.chunks_exact_mut((w * 2) as usize).enumerate() {
            for (pair, px) in row.chunks_exact_mut(4).enumerate() {
                px.copy_from_slice(&[(2 * pair) as u8, u, (2 * pair + 1) as u8, v as u8]);
            }
        }
        let img = decode_color(PixelFormat::Yuyv, &frame, w, h, w * 2).unwrap();
        for (v, row) in img.data.chunks_exact((w * 3) as usize).enumerate() {
            for (y, rgb) in row.chunks_exact(3).enumerate() {
                if rgb != bt601_reference(y as u8, u, v as u8) {
                    mismatches += 1;
                }
            }
        }
    }
    assert_eq!(mismatches, 0);
}

#[test]
fn rgb3_with_row_padding_is_copied_without_the_padding() {
    let e = &expected()["rgb3"];
    let (w, h, bpl) = (u32_of(e, "width"), u32_of(e, "height"), u32_of(e, "bytes_per_line"));
    assert!(bpl > 3 * w);
    let img = decode_color(PixelFormat::Rgb3, &fixture(e["file"].as_str().unwrap()), w, h, bpl).unwrap();
    assert_eq!(img.data, bytes_of(e, "rgb"));
}

#[test]
fn z16_with_row_padding_is_little_endian_depth_exactly() {
    let e = &expected()["z16"];
    let (w, h, bpl) = (u32_of(e, "width"), u32_of(e, "height"), u32_of(e, "bytes_per_line"));
    assert!(bpl > 2 * w);
    let depth = decode_depth_z16(&fixture(e["file"].as_str().unwrap()), w, h, bpl).unwrap();
    let want: Vec<u16> = e["depth"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u16).collect();
    assert_eq!(depth, want);
    assert_eq!(&depth[..3], &[0, 1, 65535]);
}

#[test]
fn mjpg_444_flat_blocks_decode_to_the_exact_jfif_colours() {
    let e = &expected()["mjpg_444"];
    let (w, h) = (u32_of(e, "width"), u32_of(e, "height"));
    // bytes_per_line is meaningless for MJPG (drivers report 0).
    let img = decode_color(PixelFormat::Mjpg, &fixture(e["file"].as_str().unwrap()), w, h, 0).unwrap();
    assert_eq!((img.width, img.height), (w, h));
    assert_eq!(img.data, bytes_of(e, "rgb"));
}

/// The 4:2:2 frame is compared with libjpeg-turbo within 2 levels, not exactly:
/// decoders may legitimately differ by rounding in the IDCT (libjpeg's islow
/// vs zune-jpeg's), in upsampling the half-width chroma (both interpolate,
/// with different fixed-point rounding) and in the YCbCr->RGB fixed point.
/// The DHT-stripped frame must decode identically to the original: the
/// inserted Annex K tables are the ones libjpeg encoded it with.
#[test]
fn mjpg_422_camera_frame_matches_libjpeg_and_decodes_identically_without_its_dht() {
    let e = &expected()["mjpg_422"];
    let (w, h) = (u32_of(e, "width"), u32_of(e, "height"));
    let original = fixture(e["file"].as_str().unwrap());
    let stripped = fixture(e["file_without_dht"].as_str().unwrap());
    assert!(!stripped.windows(2).any(|m| m == [0xFF, 0xC4]), "the stripped fixture still has a DHT");

    let a = decode_color(PixelFormat::Mjpg, &original, w, h, 0).unwrap();
    let b = decode_color(PixelFormat::Mjpg, &stripped, w, h, 0).unwrap();
    assert_eq!(a.data, b.data, "DHT-stripped frame decodes differently");

    let libjpeg = bytes_of(e, "rgb_libjpeg");
    let max_diff = a.data.iter().zip(&libjpeg).map(|(&x, &y)| x.abs_diff(y)).max().unwrap();
    assert!(max_diff <= 2, "zune-jpeg differs from libjpeg-turbo by {max_diff} levels");
}

/// zune-jpeg alone refuses a frame without Huffman tables (it fills in the
/// standard ones only after an `AVI1` APP0 segment), which is why decode_color
/// inserts them.
#[test]
fn zune_jpeg_alone_rejects_frames_without_dht() {
    use zune_jpeg::JpegDecoder;
    use zune_jpeg::zune_core::bytestream::ZCursor;
    let stripped = fixture(expected()["mjpg_422"]["file_without_dht"].as_str().unwrap());
    assert!(JpegDecoder::new(ZCursor::new(&stripped)).decode().is_err());
}

/// Parses the DHT segments of a JPEG into `(Tc<<4|Th, BITS, HUFFVAL)`.
fn dht_tables(jpeg: &[u8]) -> Vec<(u8, Vec<u8>, Vec<u8>)> {
    let mut tables = Vec::new();
    let mut pos = 2;
    while jpeg[pos + 1] != 0xDA {
        let len = u16::from_be_bytes([jpeg[pos + 2], jpeg[pos + 3]]) as usize;
        if jpeg[pos + 1] == 0xC4 {
            let mut p = pos + 4;
            while p < pos + 2 + len {
                let bits = jpeg[p + 1..p + 17].to_vec();
                let n: usize = bits.iter().map(|&b| b as usize).sum();
                tables.push((jpeg[p], bits, jpeg[p + 17..p + 17 + n].to_vec()));
                p += 17 + n;
            }
        }
        pos += 2 + len;
    }
    tables
}

#[test]
fn annex_k_tables_equal_the_standard_tables_libjpeg_encodes_with() {
    let libjpeg = dht_tables(&fixture(expected()["mjpg_422"]["file"].as_str().unwrap()));
    assert_eq!(libjpeg.len(), 4);
    for (class_id, bits, vals) in annex_k::TABLES {
        let found = libjpeg.iter().find(|t| t.0 == class_id).unwrap_or_else(|| panic!("table {class_id:#04x}"));
        assert_eq!(&found.1[..], &bits[..], "BITS of table {class_id:#04x}");
        assert_eq!(&found.2[..], vals, "HUFFVAL of table {class_id:#04x}");
    }
    // The segment we insert parses back to the same four tables.
    let mut jpeg = vec![0xFF, 0xD8];
    jpeg.extend(annex_k::dht_segment());
    jpeg.extend([0xFF, 0xDA]);
    assert_eq!(dht_tables(&jpeg), libjpeg);
}

#[test]
fn mjpg_with_padding_after_eoi_decodes_like_the_original() {
    // UVC payloads are often longer than the JPEG: zeros after EOI.
    let e = &expected()["mjpg_444"];
    let mut data = fixture(e["file"].as_str().unwrap());
    data.extend(std::iter::repeat_n(0u8, 300));
    let img = decode_color(PixelFormat::Mjpg, &data, u32_of(e, "width"), u32_of(e, "height"), 0).unwrap();
    assert_eq!(img.data, bytes_of(e, "rgb"));
}

#[test]
fn malformed_packed_buffers_are_decode_errors_naming_the_problem() {
    let e = expected();
    let yuyv = fixture(e["yuyv"]["file"].as_str().unwrap());
    let (w, h, bpl) = (16, 8, 40);
    // One byte short of bytes_per_line * height (the last row's padding included).
    assert_decode_error(decode_color(PixelFormat::Yuyv, &yuyv[..yuyv.len() - 1], w, h, bpl), "YUYV", "too short");
    assert_decode_error(decode_color(PixelFormat::Yuyv, &yuyv, w, h, 2 * w - 2), "YUYV", "smaller than a row");
    assert_decode_error(decode_color(PixelFormat::Yuyv, &yuyv, 15, h, bpl), "YUYV", "odd width 15");
    assert_decode_error(decode_color(PixelFormat::Yuyv, &yuyv, 0, h, bpl), "YUYV", "empty frame size");
    assert_decode_error(decode_color(PixelFormat::Yuyv, &[], w, h, bpl), "YUYV", "0 bytes");
    // Sizes whose byte count overflows are errors, not panics or huge allocations.
    assert_decode_error(decode_color(PixelFormat::Yuyv, &yuyv, u32::MAX - 1, u32::MAX, u32::MAX), "YUYV", "");

    let rgb3 = fixture(e["rgb3"]["file"].as_str().unwrap());
    assert_decode_error(decode_color(PixelFormat::Rgb3, &rgb3[..100], 10, 6, 32), "RGB3", "too short");
    assert_decode_error(decode_color(PixelFormat::Rgb3, &rgb3, 10, 6, 29), "RGB3", "bytes_per_line 29");

    let z16 = fixture(e["z16"]["file"].as_str().unwrap());
    assert_decode_error(decode_depth_z16(&z16[..z16.len() - 2], 12, 5, 28), "Z16", "too short");
    assert_decode_error(decode_depth_z16(&z16, 12, 5, 23), "Z16", "smaller than a row");
    assert_decode_error(decode_depth_z16(&z16, 12, 0, 28), "Z16", "empty frame size");
    assert_decode_error(decode_color(PixelFormat::Z16, &z16, 12, 5, 28), "Z16", "depth format");
}

#[test]
fn corrupt_or_mismatched_jpegs_are_decode_errors() {
    let e = &expected()["mjpg_422"];
    let jpeg = fixture(e["file"].as_str().unwrap());
    let (w, h) = (u32_of(e, "width"), u32_of(e, "height"));
    assert_decode_error(decode_color(PixelFormat::Mjpg, b"not a jpeg", w, h, 0), "MJPG", "no SOI");
    assert_decode_error(decode_color(PixelFormat::Mjpg, &[], w, h, 0), "MJPG", "no SOI");
    // Cut inside the headers, and inside the entropy-coded scan.
    assert_decode_error(decode_color(PixelFormat::Mjpg, &jpeg[..40], w, h, 0), "MJPG", "truncated");
    let cut = decode_color(PixelFormat::Mjpg, &jpeg[..jpeg.len() - 200], w, h, 0);
    assert_decode_error(cut, "MJPG", "corrupt JPEG");
    assert_decode_error(decode_color(PixelFormat::Mjpg, &jpeg, w + 16, h, 0), "MJPG", "JPEG is 48x32, expected 64x32");
    assert_decode_error(decode_color(PixelFormat::Mjpg, &jpeg, w, 0, 0), "MJPG", "empty frame size");
}

/// Every truncation and many byte corruptions of both JPEG fixtures give
/// `Ok` or a decode error, never a panic.
#[test]
fn mangled_jpegs_never_panic() {
    let e = expected();
    for key in ["mjpg_444", "mjpg_422"] {
        let jpeg = fixture(e[key]["file"].as_str().unwrap());
        let (w, h) = (u32_of(&e[key], "width"), u32_of(&e[key], "height"));
        let check = |data: &[u8]| match decode_color(PixelFormat::Mjpg, data, w, h, 0) {
            Ok(img) => assert_eq!(img.data.len(), (w * h * 3) as usize),
            Err(Error::Decode { .. }) => {}
            Err(other) => panic!("unexpected error kind: {other}"),
        };
        for len in 0..jpeg.len() {
            check(&jpeg[..len]);
        }
        let mut state = 0x2545_f491_u32;
        for _ in 0..600 {
            // xorshift: deterministic positions and values
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            let mut data = jpeg.clone();
            let pos = state as usize % data.len();
            data[pos] = (state >> 8) as u8;
            check(&data);
        }
    }
}

/// 640x480 YUYV, the common webcam mode, in release builds:
/// `cargo test --release --test capture_tests -- --ignored --nocapture`.
#[test]
#[ignore = "timing; run in release"]
fn yuyv_640x480_decode_time() {
    let (w, h) = (640u32, 480u32);
    let frame: Vec<u8> = (0..w * h * 2).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    let runs = 200;
    let mut best = std::time::Duration::MAX;
    for _ in 0..runs {
        let t = std::time::Instant::now();
        let img = decode_color(PixelFormat::Yuyv, &frame, w, h, w * 2).unwrap();
        best = best.min(t.elapsed());
        std::hint::black_box(img);
    }
    let jpeg_frame = fixture("mjpg_422_48x32.jpg");
    let t = std::time::Instant::now();
    for _ in 0..runs {
        std::hint::black_box(decode_color(PixelFormat::Mjpg, &jpeg_frame, 48, 32, 0).unwrap());
    }
    println!("YUYV 640x480: best of {runs} {:.3} ms", best.as_secs_f64() * 1e3);
    println!("MJPG 48x32 4:2:2: mean {:.1} us", t.elapsed().as_secs_f64() * 1e6 / runs as f64);
}

/// On a machine without cameras (this one, CI) `tricons devices` says so on
/// stderr and succeeds; without capture support it fails saying that.
#[test]
fn devices_command_without_cameras_says_so_and_succeeds() {
    let o = tricons(&["devices"]);
    let err = stderr(&o);
    assert!(!err.contains("panicked"), "{err}");
    if cfg!(all(feature = "v4l", target_os = "linux")) {
        assert!(o.status.success(), "tricons devices failed: {err}");
        let has_nodes = std::fs::read_dir("/dev")
            .map(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with("video")))
            .unwrap_or(false);
        if !has_nodes {
            assert!(err.contains("no V4L2 capture devices found"), "{err}");
            assert!(String::from_utf8_lossy(&o.stdout).trim().is_empty());
            let json = tricons(&["devices", "--json"]);
            assert!(json.status.success());
            assert_eq!(String::from_utf8_lossy(&json.stdout).trim(), "[]");
        }
    } else {
        assert!(!o.status.success());
        assert!(err.contains("capture support is not compiled in"), "{err}");
    }
    let help = tricons(&["devices", "--help"]);
    assert!(help.status.success());
    assert!(String::from_utf8_lossy(&help.stdout).contains("Example"));
}
