//! Raw V4L2 buffers to images: YUYV, RGB3 and MJPG colour, Z16 depth.
//!
//! Pure functions on byte slices, no device needed: recorded raw buffers
//! decode exactly as live ones do. Every malformed buffer (too short, a row
//! stride smaller than a row, an odd YUYV width, a corrupt JPEG, a size other
//! than the one announced) is an [`Error::Decode`] naming the format and the
//! problem; nothing here panics on bad input.
//!
//! # YUYV colour conversion
//!
//! USB (UVC) cameras send YUYV as ITU-R BT.601 "limited range" (studio
//! swing): Y in 16..=235, U and V in 16..=240 centred on 128. With
//! `Kr = 0.299`, `Kb = 0.114`, `Kg = 1 - Kr - Kb` the conversion is the exact
//! real-valued formula
//!
//! ```text
//! y = (255/219) (Y - 16)
//! R = y + (255/224) 2 (1 - Kr) (V - 128)                                 [1.164383 (Y-16) + 1.596027 (V-128)]
//! G = y - (255/224) 2 (1 - Kr) Kr/Kg (V - 128) - (255/224) 2 (1 - Kb) Kb/Kg (U - 128)
//!                                                                        [- 0.812968 (V-128) - 0.391762 (U-128)]
//! B = y + (255/224) 2 (1 - Kb) (U - 128)                                 [2.017232 (U-128)]
//! ```
//!
//! rounded to nearest and clamped to 0..=255. It is evaluated in integers:
//! each term is tabulated per input byte as `round(term * 2^24)` (computed
//! exactly from the rational coefficients at compile time), the three terms are
//! summed in `i64` and rounded with `(sum + 2^23) >> 24`. The tables' error
//! (at most 1.5 * 2^-24) is smaller than the distance of any exact value from a
//! rounding tie, so the integer result equals the rounded real formula for all
//! 2^24 (Y, U, V) triples (checked exhaustively in tests/capture/decode.rs).
//! Values outside the nominal range (Y < 16, Y > 235, ...) are converted by
//! the same formula and clamped, as cameras do send them.
//!
//! # MJPG
//!
//! Decoded with `zune-jpeg` (strict mode: a truncated or corrupt entropy-coded
//! segment is an error, not a grey tail) to RGB. UVC cameras usually omit the
//! Huffman tables (no DHT segment) and rely on the standard tables of JPEG
//! Annex K.3; zune-jpeg fills those in only when the frame carries an
//! `AVI1` APP0 segment, so [`decode_color`] inserts them itself after SOI when
//! a frame has no DHT before its first scan.

use crate::error::{Error, Result};
use crate::frame::ColorImage;
use std::borrow::Cow;
use std::fmt;
use std::str::FromStr;
use zune_jpeg::JpegDecoder;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;

/// A pixel format tricons can decode, by its V4L2 fourcc.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// `YUYV`: packed 4:2:2 Y0 U Y1 V, 2 bytes per pixel, BT.601 limited range.
    Yuyv,
    /// `MJPG`: one baseline JPEG per frame (Huffman tables possibly omitted).
    Mjpg,
    /// `RGB3`: packed 8-bit R G B, 3 bytes per pixel.
    Rgb3,
    /// `Z16 `: 16-bit little-endian depth in device units (RealSense: usually 1 mm).
    Z16,
}

/// The V4L2 fourcc code of four ASCII bytes (`v4l2_fourcc` in videodev2.h: first byte lowest).
pub const fn fourcc(code: &[u8; 4]) -> u32 {
    u32::from_le_bytes(*code)
}

/// A fourcc code as its four characters, e.g. "YUYV", "Z16 " (non-printable bytes as '?').
pub fn fourcc_to_string(code: u32) -> String {
    code.to_le_bytes().iter().map(|&b| if b.is_ascii_graphic() || b == b' ' { b as char } else { '?' }).collect()
}

impl PixelFormat {
    /// Every format tricons decodes.
    pub const ALL: [PixelFormat; 4] = [PixelFormat::Yuyv, PixelFormat::Mjpg, PixelFormat::Rgb3, PixelFormat::Z16];

    /// The V4L2 fourcc (`V4L2_PIX_FMT_*`).
    pub const fn fourcc(self) -> u32 {
        match self {
            PixelFormat::Yuyv => fourcc(b"YUYV"),
            PixelFormat::Mjpg => fourcc(b"MJPG"),
            PixelFormat::Rgb3 => fourcc(b"RGB3"),
            PixelFormat::Z16 => fourcc(b"Z16 "),
        }
    }

    /// The format of a V4L2 fourcc, `None` for formats tricons cannot decode.
    pub fn from_fourcc(code: u32) -> Option<PixelFormat> {
        PixelFormat::ALL.into_iter().find(|f| f.fourcc() == code)
    }

    /// Short name: "YUYV", "MJPG", "RGB3" or "Z16".
    pub const fn name(self) -> &'static str {
        match self {
            PixelFormat::Yuyv => "YUYV",
            PixelFormat::Mjpg => "MJPG",
            PixelFormat::Rgb3 => "RGB3",
            PixelFormat::Z16 => "Z16",
        }
    }

    /// True for depth formats (decoded by [`decode_depth_z16`], not [`decode_color`]).
    pub const fn is_depth(self) -> bool {
        matches!(self, PixelFormat::Z16)
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for PixelFormat {
    type Err = String;

    /// Case-insensitive: "yuyv", "mjpg" / "mjpeg", "rgb3" / "rgb24", "z16".
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "yuyv" => Ok(PixelFormat::Yuyv),
            "mjpg" | "mjpeg" => Ok(PixelFormat::Mjpg),
            "rgb3" | "rgb24" => Ok(PixelFormat::Rgb3),
            "z16" => Ok(PixelFormat::Z16),
            _ => Err(format!("unknown pixel format {s:?} (expected yuyv, mjpg, rgb3 or z16)")),
        }
    }
}

/// Decodes one colour frame to RGB8.
///
/// `bytes_per_line` is the row stride of packed formats (V4L2 `bytesperline`,
/// at least one row's bytes; rows may be padded) and is ignored for MJPG, whose
/// decoded size must equal `width` x `height`. Z16 is not a colour format.
pub fn decode_color(
    format: PixelFormat,
    data: &[u8],
    width: u32,
    height: u32,
    bytes_per_line: u32,
) -> Result<ColorImage> {
    match format {
        PixelFormat::Yuyv => decode_yuyv(data, width, height, bytes_per_line),
        PixelFormat::Rgb3 => decode_rgb3(data, width, height, bytes_per_line),
        PixelFormat::Mjpg => decode_mjpg(data, width, height),
        PixelFormat::Z16 => Err(Error::decode(format.name(), "is a depth format: use decode_depth_z16")),
    }
}

/// Decodes one Z16 depth frame: little-endian u16 per pixel in device units,
/// rows `bytes_per_line` apart (at least `2 * width`). Returns `width * height` values, row-major.
pub fn decode_depth_z16(data: &[u8], width: u32, height: u32, bytes_per_line: u32) -> Result<Vec<u16>> {
    let layout = PackedLayout::check(PixelFormat::Z16, data, width, height, bytes_per_line, 2)?;
    let mut out = Vec::with_capacity(layout.width * layout.height);
    for row in layout.rows(data) {
        out.extend(row.chunks_exact(2).map(|p| u16::from_le_bytes([p[0], p[1]])));
    }
    Ok(out)
}

/// The validated geometry of a packed (uncompressed) buffer.
struct PackedLayout {
    width: usize,
    height: usize,
    row_bytes: usize,
    stride: usize,
}

impl PackedLayout {
    /// Checks sizes, stride and buffer length for `bytes_per_pixel`-byte pixels.
    fn check(
        format: PixelFormat,
        data: &[u8],
        width: u32,
        height: u32,
        bytes_per_line: u32,
        bytes_per_pixel: usize,
    ) -> Result<PackedLayout> {
        let err = |msg: String| Error::decode(format.name(), msg);
        if width == 0 || height == 0 {
            return Err(err(format!("empty frame size {width}x{height}")));
        }
        let (w, h, stride) = (width as usize, height as usize, bytes_per_line as usize);
        let row_bytes = w.checked_mul(bytes_per_pixel).ok_or_else(|| err(format!("width {width} too large")))?;
        if stride < row_bytes {
            return Err(err(format!(
                "bytes_per_line {bytes_per_line} is smaller than a row of {width} pixels ({row_bytes} bytes)"
            )));
        }
        let needed = stride.checked_mul(h).ok_or_else(|| err(format!("frame size {width}x{height} too large")))?;
        if data.len() < needed {
            return Err(err(format!(
                "buffer too short: {} bytes, {width}x{height} with {bytes_per_line} bytes per line needs {needed}",
                data.len()
            )));
        }
        Ok(PackedLayout { width: w, height: h, row_bytes, stride })
    }

    /// The `height` rows of `data`, each `row_bytes` long (padding dropped).
    fn rows<'a>(&self, data: &'a [u8]) -> impl Iterator<Item = &'a [u8]> + use<'a> {
        let row_bytes = self.row_bytes;
        data.chunks(self.stride).take(self.height).map(move |row| &row[..row_bytes])
    }
}

fn decode_rgb3(data: &[u8], width: u32, height: u32, bytes_per_line: u32) -> Result<ColorImage> {
    let layout = PackedLayout::check(PixelFormat::Rgb3, data, width, height, bytes_per_line, 3)?;
    let mut out = Vec::with_capacity(layout.row_bytes * layout.height);
    for row in layout.rows(data) {
        out.extend_from_slice(row);
    }
    Ok(ColorImage { width, height, data: out })
}

/// Fixed-point precision of the YUYV tables (fraction bits).
const YUV_SHIFT: u32 = 24;

/// `round(num * k * 2^YUV_SHIFT / den)` for `k = index - offset`, exact integer rounding (half away from zero).
const fn yuv_table(num: i64, den: i64, offset: i64) -> [i64; 256] {
    let mut table = [0i64; 256];
    let mut i = 0;
    while i < 256 {
        let scaled = num * (i as i64 - offset) * (1 << YUV_SHIFT);
        let half = den / 2;
        table[i] = if scaled >= 0 { (scaled + half) / den } else { -((-scaled + half) / den) };
        i += 1;
    }
    table
}

// Rational forms of the BT.601 limited-range coefficients (module docs):
// 255/219; (255/224)*1.402; (255/224)*1.772; (255/224)*1.402*0.299/0.587; (255/224)*1.772*0.114/0.587.
/// `(255/219) (Y - 16)`.
const Y_TERM: [i64; 256] = yuv_table(255, 219, 16);
/// `R` term of V: `(255/224) 1.402 (V - 128)`.
const RV_TERM: [i64; 256] = yuv_table(255 * 1402, 224 * 1000, 128);
/// `B` term of U: `(255/224) 1.772 (U - 128)`.
const BU_TERM: [i64; 256] = yuv_table(255 * 1772, 224 * 1000, 128);
/// `G` term of V (subtracted): `(255/224) 1.402 (0.299/0.587) (V - 128)`.
const GV_TERM: [i64; 256] = yuv_table(255 * 1402 * 299, 224 * 1000 * 587, 128);
/// `G` term of U (subtracted): `(255/224) 1.772 (0.114/0.587) (U - 128)`.
const GU_TERM: [i64; 256] = yuv_table(255 * 1772 * 114, 224 * 1000 * 587, 128);

/// Rounds a fixed-point sum to a clamped 8-bit value.
#[inline(always)]
fn to_u8(sum: i64) -> u8 {
    ((sum + (1 << (YUV_SHIFT - 1))) >> YUV_SHIFT).clamp(0, 255) as u8
}

fn decode_yuyv(data: &[u8], width: u32, height: u32, bytes_per_line: u32) -> Result<ColorImage> {
    if !width.is_multiple_of(2) {
        return Err(Error::decode(
            PixelFormat::Yuyv.name(),
            format!("odd width {width}: YUYV packs pixels in pairs sharing U and V"),
        ));
    }
    let layout = PackedLayout::check(PixelFormat::Yuyv, data, width, height, bytes_per_line, 2)?;
    let mut out = vec![0u8; layout.width * layout.height * 3];
    for (row, dst_row) in layout.rows(data).zip(out.chunks_exact_mut(layout.width * 3)) {
        for (src, dst) in row.chunks_exact(4).zip(dst_row.chunks_exact_mut(6)) {
            let (u, v) = (src[1] as usize, src[3] as usize);
            let r = RV_TERM[v];
            let g = -GU_TERM[u] - GV_TERM[v];
            let b = BU_TERM[u];
            let y0 = Y_TERM[src[0] as usize];
            let y1 = Y_TERM[src[2] as usize];
            dst[0] = to_u8(y0 + r);
            dst[1] = to_u8(y0 + g);
            dst[2] = to_u8(y0 + b);
            dst[3] = to_u8(y1 + r);
            dst[4] = to_u8(y1 + g);
            dst[5] = to_u8(y1 + b);
        }
    }
    Ok(ColorImage { width, height, data: out })
}

/// The standard Huffman tables of JPEG (ITU-T T.81) Annex K.3, as a DHT
/// table body: `Tc<<4 | Th`, the 16 code-length counts `BITS`, then `HUFFVAL`.
pub mod annex_k {
    /// Table K.3: luminance DC code lengths (counts of codes of length 1..=16).
    pub const DC_LUMINANCE_BITS: [u8; 16] = [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
    /// Table K.3: luminance DC values (difference categories).
    pub const DC_LUMINANCE_VALUES: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    /// Table K.4: chrominance DC code lengths.
    pub const DC_CHROMINANCE_BITS: [u8; 16] = [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0];
    /// Table K.4: chrominance DC values.
    pub const DC_CHROMINANCE_VALUES: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    /// Table K.5: luminance AC code lengths.
    pub const AC_LUMINANCE_BITS: [u8; 16] = [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7d];
    /// Table K.5: luminance AC values (run/size bytes) in code order.
    pub const AC_LUMINANCE_VALUES: [u8; 162] = [
        0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07, 0x22, 0x71,
        0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42, 0xb1, 0xc1, 0x15, 0x52, 0xd1, 0xf0, 0x24, 0x33, 0x62, 0x72,
        0x82, 0x09, 0x0a, 0x16, 0x17, 0x18, 0x19, 0x1a, 0x25, 0x26, 0x27, 0x28, 0x29, 0x2a, 0x34, 0x35, 0x36, 0x37,
        0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59,
        0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x83,
        0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3,
        0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3,
        0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2,
        0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf1, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
    ];
    /// Table K.6: chrominance AC code lengths.
    pub const AC_CHROMINANCE_BITS: [u8; 16] = [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77];
    /// Table K.6: chrominance AC values in code order.
    pub const AC_CHROMINANCE_VALUES: [u8; 162] = [
        0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71, 0x13, 0x22,
        0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33, 0x52, 0xf0, 0x15, 0x62, 0x72, 0xd1,
        0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18, 0x19, 0x1a, 0x26, 0x27, 0x28, 0x29, 0x2a, 0x35, 0x36,
        0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58,
        0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a,
        0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a,
        0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba,
        0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda,
        0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
    ];

    /// The four tables as `(Tc<<4 | Th, BITS, HUFFVAL)`: DC and AC luminance
    /// (destination 0), DC and AC chrominance (destination 1).
    pub const TABLES: [(u8, &[u8; 16], &[u8]); 4] = [
        (0x00, &DC_LUMINANCE_BITS, &DC_LUMINANCE_VALUES),
        (0x10, &AC_LUMINANCE_BITS, &AC_LUMINANCE_VALUES),
        (0x01, &DC_CHROMINANCE_BITS, &DC_CHROMINANCE_VALUES),
        (0x11, &AC_CHROMINANCE_BITS, &AC_CHROMINANCE_VALUES),
    ];

    /// A complete DHT marker segment (`FF C4`, length, the four tables).
    pub fn dht_segment() -> Vec<u8> {
        let body: usize = TABLES.iter().map(|(_, bits, vals)| 1 + bits.len() + vals.len()).sum();
        let length = (body + 2) as u16;
        let mut seg = Vec::with_capacity(body + 4);
        seg.extend_from_slice(&[0xFF, 0xC4]);
        seg.extend_from_slice(&length.to_be_bytes());
        for (class_id, bits, vals) in TABLES {
            seg.push(class_id);
            seg.extend_from_slice(bits);
            seg.extend_from_slice(vals);
        }
        seg
    }
}

/// JPEG markers used while scanning headers.
const MARKER_SOI: u8 = 0xD8;
const MARKER_EOI: u8 = 0xD9;
const MARKER_SOS: u8 = 0xDA;
const MARKER_DHT: u8 = 0xC4;

/// Whether a JPEG's header segments (before the first scan) include a DHT.
/// Errors on a buffer that is not a JPEG or whose headers are cut short.
fn has_huffman_tables(data: &[u8]) -> std::result::Result<bool, String> {
    if data.len() < 2 || data[0] != 0xFF || data[1] != MARKER_SOI {
        return Err("not a JPEG (no SOI marker at the start)".into());
    }
    let mut pos = 2;
    loop {
        if pos >= data.len() {
            return Err("headers end before the first scan (truncated frame)".into());
        }
        if data[pos] != 0xFF {
            return Err(format!("corrupt headers: expected a marker at byte {pos}, found 0x{:02X}", data[pos]));
        }
        // Fill bytes: any number of 0xFF may precede a marker code.
        while pos < data.len() && data[pos] == 0xFF {
            pos += 1;
        }
        let Some(&marker) = data.get(pos) else {
            return Err("headers end before the first scan (truncated frame)".into());
        };
        pos += 1;
        match marker {
            MARKER_DHT => return Ok(true),
            MARKER_SOS => return Ok(false),
            MARKER_EOI => return Err("EOI before any scan: the frame holds no image data".into()),
            // Markers without a length field (TEM, RSTn, SOI) carry no segment.
            0x01 | 0xD0..=0xD7 | MARKER_SOI => {}
            _ => {
                let Some(len) = data.get(pos..pos + 2) else {
                    return Err("headers end before the first scan (truncated frame)".into());
                };
                let len = u16::from_be_bytes([len[0], len[1]]) as usize;
                if len < 2 {
                    return Err(format!("corrupt headers: segment 0xFF{marker:02X} has length {len}"));
                }
                pos += len;
            }
        }
    }
}

fn decode_mjpg(data: &[u8], width: u32, height: u32) -> Result<ColorImage> {
    let err = |msg: String| Error::decode(PixelFormat::Mjpg.name(), msg);
    if width == 0 || height == 0 {
        return Err(err(format!("empty frame size {width}x{height}")));
    }
    let jpeg: Cow<[u8]> = match has_huffman_tables(data).map_err(err)? {
        true => Cow::Borrowed(data),
        false => {
            // Standard tables right after SOI; the rest of the frame unchanged.
            let dht = annex_k::dht_segment();
            let mut patched = Vec::with_capacity(data.len() + dht.len());
            patched.extend_from_slice(&data[..2]);
            patched.extend_from_slice(&dht);
            patched.extend_from_slice(&data[2..]);
            Cow::Owned(patched)
        }
    };
    let options = DecoderOptions::default().set_strict_mode(true).jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(jpeg.as_ref()), options);
    // Headers first: the size is checked before any pixel buffer is allocated.
    decoder.decode_headers().map_err(|e| err(format!("corrupt JPEG: {e}")))?;
    let (w, h) = decoder.dimensions().ok_or_else(|| err("corrupt JPEG: no frame header".into()))?;
    if (w, h) != (width as usize, height as usize) {
        return Err(err(format!("JPEG is {w}x{h}, expected {width}x{height}")));
    }
    let pixels = decoder.decode().map_err(|e| err(format!("corrupt JPEG: {e}")))?;
    let expected = w * h * 3;
    if pixels.len() != expected {
        return Err(err(format!("decoder returned {} bytes for {w}x{h} RGB, expected {expected}", pixels.len())));
    }
    Ok(ColorImage { width, height, data: pixels })
}

impl serde::Serialize for PixelFormat {
    /// As its [`PixelFormat::name`].
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for PixelFormat {
    /// From any spelling [`PixelFormat::from_str`] accepts.
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> std::result::Result<Self, D::Error> {
        let s = String::deserialize(deserializer)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}
