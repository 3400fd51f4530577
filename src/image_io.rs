//! PNG reading and writing for the image types of [`crate::frame`].
//!
//! Readers check colour type and bit depth and name the file in every error;
//! writers are atomic (see [`crate::atomic`]) and deterministic.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::frame::{ColorImage, DepthImage, LabelImage, NocsMap};
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// A decoded PNG before interpretation: size, layout and raw samples
/// (16-bit samples are big-endian pairs, as PNG stores them).
#[derive(Debug)]
pub struct RawPng {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Colour type after palette / low-bit expansion.
    pub color_type: png::ColorType,
    /// Bits per sample (8 or 16).
    pub bit_depth: png::BitDepth,
    /// Sample bytes, row-major, no padding.
    pub data: Vec<u8>,
}

impl RawPng {
    /// Human-readable layout, e.g. "8-bit Grayscale".
    pub fn describe(&self) -> String {
        format!("{}-bit {:?}", self.bit_depth as u8, self.color_type)
    }

    /// The samples as u16 (16-bit images only).
    pub fn samples_u16(&self) -> Vec<u16> {
        self.data.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect()
    }
}

/// The most pixels a PNG may declare when no exact size is expected: 8K UHD (7680 x 4320)
/// fits; one decode then allocates at most 256 MiB (16-bit RGBA).
pub const MAX_PIXELS: u64 = 1 << 25;

/// The size a PNG may declare, checked against its header before any pixel buffer is
/// allocated (a 60-byte file can claim 60000 x 60000 pixels).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SizeLimit {
    /// Exactly this width and height, e.g. a recording's frame size from its manifest.
    Exactly {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Where the size comes from, for the error ("as in the manifest").
        source: &'static str,
    },
    /// Any size up to [`MAX_PIXELS`] pixels (the cap holds for `Exactly` too).
    Capped,
}

impl SizeLimit {
    /// `Exactly` the size of an image already read (e.g. the colour image of the same frame).
    pub fn like(width: u32, height: u32, source: &'static str) -> SizeLimit {
        SizeLimit::Exactly { width, height, source }
    }

    fn check(self, path: &Path, width: u32, height: u32) -> Result<()> {
        if let SizeLimit::Exactly { width: w, height: h, source } = self
            && (width, height) != (w, h)
        {
            return Err(Error::ImageFormat {
                path: path.to_path_buf(),
                expected: format!("{w}x{h} {source}"),
                found: format!("{width}x{height}"),
            });
        }
        // The cap holds whatever size is expected: an expected size comes from a file too
        // (a manifest declaring 60000 x 60000 beside a bomb of that size).
        if u64::from(width) * u64::from(height) > MAX_PIXELS {
            return Err(Error::ImageFormat {
                path: path.to_path_buf(),
                expected: format!("at most {MAX_PIXELS} pixels"),
                found: format!("a header declaring {width}x{height}"),
            });
        }
        Ok(())
    }
}

/// Decodes any PNG, expanding palettes and sub-byte grayscale to 8 bits. The header's
/// size is checked against `limit` before the pixels are allocated, and the decoder's own
/// allocations (metadata chunks) are bounded by the png crate's default limit.
pub fn read_png(path: &Path, limit: SizeLimit) -> Result<RawPng> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let png_err = |e: png::DecodingError| match e {
        png::DecodingError::IoError(io) => Error::io(path, io),
        other => Error::Png { path: path.to_path_buf(), message: other.to_string() },
    };
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(png_err)?;
    let (width, height) = (reader.info().width, reader.info().height);
    limit.check(path, width, height)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| Error::Png { path: path.to_path_buf(), message: "image too large".into() })?;
    let mut data = vec![0; size];
    let info = reader.next_frame(&mut data).map_err(png_err)?;
    data.truncate(info.buffer_size());
    Ok(RawPng { width: info.width, height: info.height, color_type: info.color_type, bit_depth: info.bit_depth, data })
}

fn wrong_format(path: &Path, expected: &str, raw: &RawPng) -> Error {
    Error::ImageFormat { path: path.to_path_buf(), expected: expected.into(), found: raw.describe() }
}

/// Reads an 8-bit RGB (or RGBA, alpha dropped) colour PNG.
pub fn read_color_png(path: &Path, limit: SizeLimit) -> Result<ColorImage> {
    let raw = read_png(path, limit)?;
    let data = match (raw.color_type, raw.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => raw.data,
        (png::ColorType::Rgba, png::BitDepth::Eight) => {
            raw.data.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect()
        }
        _ => return Err(wrong_format(path, "8-bit RGB colour", &raw)),
    };
    Ok(ColorImage { width: raw.width, height: raw.height, data })
}

/// Reads a 16-bit grayscale depth PNG; `depth_scale_m` is metres per unit.
pub fn read_depth_png(path: &Path, depth_scale_m: f64, limit: SizeLimit) -> Result<DepthImage> {
    let raw = read_png(path, limit)?;
    if (raw.color_type, raw.bit_depth) != (png::ColorType::Grayscale, png::BitDepth::Sixteen) {
        return Err(wrong_format(path, "16-bit grayscale depth", &raw));
    }
    Ok(DepthImage { width: raw.width, height: raw.height, data: raw.samples_u16(), depth_scale_m })
}

/// Reads an 8-bit grayscale label (instance mask) PNG.
pub fn read_label_png(path: &Path, limit: SizeLimit) -> Result<LabelImage> {
    let raw = read_png(path, limit)?;
    if (raw.color_type, raw.bit_depth) != (png::ColorType::Grayscale, png::BitDepth::Eight) {
        return Err(wrong_format(path, "8-bit grayscale instance mask", &raw));
    }
    Ok(LabelImage { width: raw.width, height: raw.height, data: raw.data })
}

/// Reads a NOCS map: 16-bit RGB (tricons) or 8-bit RGB (NOCS dataset, rescaled).
pub fn read_nocs_png(path: &Path, limit: SizeLimit) -> Result<NocsMap> {
    let raw = read_png(path, limit)?;
    let data = match (raw.color_type, raw.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Sixteen) => raw.samples_u16(),
        (png::ColorType::Rgb, png::BitDepth::Eight) => raw.data.iter().map(|&v| u16::from(v) * 257).collect(),
        _ => return Err(wrong_format(path, "RGB NOCS map (8 or 16 bits)", &raw)),
    };
    Ok(NocsMap { width: raw.width, height: raw.height, data })
}

/// Encodes raw samples as PNG bytes (fast deflate; deterministic).
pub fn encode_png(
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let enc_err = |e: png::EncodingError| Error::InvalidArgument(format!("PNG encoding failed: {e}"));
    {
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(color);
        encoder.set_depth(depth);
        encoder.set_compression(png::Compression::Fast);
        let mut writer = encoder.write_header().map_err(enc_err)?;
        writer.write_image_data(data).map_err(enc_err)?;
        writer.finish().map_err(enc_err)?;
    }
    Ok(out)
}

fn u16_to_be(samples: &[u16]) -> Vec<u8> {
    samples.iter().flat_map(|v| v.to_be_bytes()).collect()
}

/// Writes an 8-bit RGB colour PNG atomically.
pub fn write_color_png(path: &Path, img: &ColorImage) -> Result<()> {
    let bytes = encode_png(img.width, img.height, png::ColorType::Rgb, png::BitDepth::Eight, &img.data)?;
    write_atomic(path, &bytes)
}

/// Writes a 16-bit grayscale depth PNG atomically.
pub fn write_depth_png(path: &Path, img: &DepthImage) -> Result<()> {
    let bytes =
        encode_png(img.width, img.height, png::ColorType::Grayscale, png::BitDepth::Sixteen, &u16_to_be(&img.data))?;
    write_atomic(path, &bytes)
}

/// Writes an 8-bit grayscale label PNG atomically.
pub fn write_label_png(path: &Path, img: &LabelImage) -> Result<()> {
    let bytes = encode_png(img.width, img.height, png::ColorType::Grayscale, png::BitDepth::Eight, &img.data)?;
    write_atomic(path, &bytes)
}

/// Writes a 16-bit RGB NOCS map PNG atomically.
pub fn write_nocs_png(path: &Path, img: &NocsMap) -> Result<()> {
    let bytes = encode_png(img.width, img.height, png::ColorType::Rgb, png::BitDepth::Sixteen, &u16_to_be(&img.data))?;
    write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_every_image_type() {
        let dir = tempfile::tempdir().unwrap();
        let mut color = ColorImage::new(5, 3);
        color.data.iter_mut().enumerate().for_each(|(i, v)| *v = i as u8);
        let mut depth = DepthImage::new(5, 3, 0.001);
        depth.data.iter_mut().enumerate().for_each(|(i, v)| *v = 1000 + 300 * i as u16);
        let mut label = LabelImage::new(5, 3);
        label.data[7] = 3;
        let mut nocs = NocsMap::new(5, 3);
        nocs.data.iter_mut().enumerate().for_each(|(i, v)| *v = 1234 * i as u16);

        let p = |n: &str| dir.path().join(n);
        write_color_png(&p("c.png"), &color).unwrap();
        write_depth_png(&p("d.png"), &depth).unwrap();
        write_label_png(&p("m.png"), &label).unwrap();
        write_nocs_png(&p("n.png"), &nocs).unwrap();
        assert_eq!(read_color_png(&p("c.png"), SizeLimit::Capped).unwrap(), color);
        assert_eq!(read_depth_png(&p("d.png"), 0.001, SizeLimit::Capped).unwrap(), depth);
        assert_eq!(read_label_png(&p("m.png"), SizeLimit::Capped).unwrap(), label);
        assert_eq!(read_nocs_png(&p("n.png"), SizeLimit::Capped).unwrap(), nocs);
    }

    #[test]
    fn eight_bit_depth_is_rejected_with_the_file_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("000_depth.png");
        write_label_png(&path, &LabelImage::new(4, 4)).unwrap();
        let err = read_depth_png(&path, 0.001, SizeLimit::Capped).unwrap_err().to_string();
        assert!(
            err.contains("000_depth.png") && err.contains("16-bit grayscale depth") && err.contains("8-bit"),
            "{err}"
        );
    }

    #[test]
    fn corrupt_png_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.png");
        let mut bytes = encode_png(4, 4, png::ColorType::Rgb, png::BitDepth::Eight, &[7; 48]).unwrap();
        bytes.truncate(bytes.len() / 2);
        std::fs::write(&path, &bytes).unwrap();
        let err = read_color_png(&path, SizeLimit::Capped).unwrap_err().to_string();
        assert!(err.contains("bad.png"), "{err}");
        std::fs::write(&path, b"not a png at all").unwrap();
        assert!(read_color_png(&path, SizeLimit::Capped).unwrap_err().to_string().contains("bad.png"));
    }

    /// A PNG of an IHDR declaring `width` x `height` (16-bit RGBA), one IDAT holding no
    /// pixels and an IEND: the shape of a size bomb, 77 bytes.
    pub(crate) fn header_only_png(width: u32, height: u32) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Sixteen);
        let mut writer = encoder.write_header().unwrap();
        // zlib stream of nothing
        writer.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]).unwrap();
        drop(writer); // writes the IEND
        out
    }

    #[test]
    fn a_size_bomb_is_refused_before_allocating() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bomb.png");
        std::fs::write(&path, header_only_png(60_000, 60_000)).unwrap();
        // decoding it would allocate 28.8 GB: the header check must refuse it first
        let err = read_png(&path, SizeLimit::Capped).unwrap_err().to_string();
        assert!(err.contains("bomb.png") && err.contains("60000x60000"), "{err}");
        let exact = SizeLimit::Exactly { width: 640, height: 480, source: "as in the manifest" };
        let err = read_png(&path, exact).unwrap_err().to_string();
        assert!(err.contains("640x480 as in the manifest") && err.contains("60000x60000"), "{err}");
        // an expected size beyond the cap (a manifest of the bomb's own size) is refused too
        let same = SizeLimit::Exactly { width: 60_000, height: 60_000, source: "as in the manifest" };
        let err = read_png(&path, same).unwrap_err().to_string();
        assert!(err.contains(&format!("at most {MAX_PIXELS} pixels")), "{err}");
        // within the limits, the same kind of file reaches the decoder (no pixel data: an error, not a panic)
        std::fs::write(&path, header_only_png(640, 480)).unwrap();
        let err = read_png(&path, exact).unwrap_err().to_string();
        assert!(err.contains("not a readable PNG"), "{err}");
    }

    #[test]
    fn the_cap_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.png");
        // one pixel over the cap is refused by the header check ...
        std::fs::write(&path, header_only_png(1 << 13, (1 << 12) + 1)).unwrap();
        assert!(read_png(&path, SizeLimit::Capped).unwrap_err().to_string().contains("at most"));
        // ... the cap itself passes it (and fails later, for lack of pixel data)
        std::fs::write(&path, header_only_png(1 << 13, 1 << 12)).unwrap();
        assert!(!read_png(&path, SizeLimit::Capped).unwrap_err().to_string().contains("at most"));
    }
}
