//! RGB-D frames: colour, depth with its metric scale, pinhole intrinsics and a
//! timestamp, plus the per-pixel label and NOCS images that ground truth uses.

use crate::geometry::Vec3;
use serde::{Deserialize, Serialize};

/// Millimetre depth units, the NOCS and RealSense default.
pub const DEPTH_SCALE_MM: f64 = 0.001;

/// Pinhole camera intrinsics for an image of `width` x `height` pixels.
/// Pixel centres are at integer coordinates (u right, v down).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// REAL275 (NOCS real) intrinsics, 640x480.
    pub const REAL275: Intrinsics =
        Intrinsics { width: 640, height: 480, fx: 591.0125, fy: 590.16775, cx: 322.525, cy: 244.11084 };

    /// CAMERA25 (NOCS synthetic) intrinsics, 640x480.
    pub const CAMERA25: Intrinsics = Intrinsics { width: 640, height: 480, fx: 577.5, fy: 577.5, cx: 319.5, cy: 239.5 };

    /// Projects a camera-frame point (metres, z > 0) to pixel coordinates.
    pub fn project(&self, p: &Vec3) -> (f64, f64) {
        (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }

    /// Back-projects pixel (u, v) at depth `depth_m` to a camera-frame point.
    pub fn backproject(&self, u: f64, v: f64, depth_m: f64) -> Vec3 {
        Vec3::new((u - self.cx) * depth_m / self.fx, (v - self.cy) * depth_m / self.fy, depth_m)
    }

    /// Checks that the intrinsics describe a usable camera.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("image size (width x height) {}x{} is empty", self.width, self.height));
        }
        if u64::from(self.width) * u64::from(self.height) > crate::image_io::MAX_PIXELS {
            return Err(format!(
                "image size (width x height) {}x{} is more than the {} pixels a frame may have",
                self.width,
                self.height,
                crate::image_io::MAX_PIXELS
            ));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v} must be a positive number"));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(format!("{name} = {v} must be finite"));
            }
        }
        Ok(())
    }
}

/// An 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColorImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes, R G B per pixel.
    pub data: Vec<u8>,
}

impl ColorImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> ColorImage {
        ColorImage { width, height, data: vec![0; width as usize * height as usize * 3] }
    }

    /// The RGB value at (u, v).
    pub fn pixel(&self, u: u32, v: u32) -> [u8; 3] {
        let i = (v as usize * self.width as usize + u as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// A 16-bit depth image; 0 means no measurement.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Raw depth units, row-major.
    pub data: Vec<u16>,
    /// Metres per depth unit (0.001 for millimetres).
    pub depth_scale_m: f64,
}

impl DepthImage {
    /// An image with no measurements.
    pub fn new(width: u32, height: u32, depth_scale_m: f64) -> DepthImage {
        DepthImage { width, height, data: vec![0; width as usize * height as usize], depth_scale_m }
    }

    /// Quantise a float depth image in metres (ROS `32FC1`, simulators) to `depth_scale_m`
    /// units, row-major. A value that is not a measurement becomes 0 ("no measurement"): NaN,
    /// infinite, zero or negative, or beyond the 16-bit range at this scale. Returns the
    /// image and how many pixels were invalidated that way.
    pub fn from_metres(
        width: u32,
        height: u32,
        depth_m: &[f32],
        depth_scale_m: f64,
    ) -> crate::error::Result<(DepthImage, usize)> {
        let n = width as usize * height as usize;
        if depth_m.len() != n {
            return Err(crate::error::Error::InvalidArgument(format!(
                "float depth has {} values, a {width}x{height} image needs {n}",
                depth_m.len()
            )));
        }
        if !(depth_scale_m.is_finite() && depth_scale_m > 0.0) {
            return Err(crate::error::Error::InvalidArgument(format!(
                "depth scale {depth_scale_m} m/unit is not positive"
            )));
        }
        let mut invalid = 0usize;
        let data = depth_m
            .iter()
            .map(|&d| {
                let units = (f64::from(d) / depth_scale_m).round();
                if units.is_finite() && units >= 1.0 && units <= f64::from(u16::MAX) {
                    units as u16
                } else {
                    invalid += usize::from(d != 0.0);
                    0
                }
            })
            .collect();
        Ok((DepthImage { width, height, data, depth_scale_m }, invalid))
    }

    /// Depth in metres at (u, v), or `None` where there is no measurement.
    pub fn depth_m(&self, u: u32, v: u32) -> Option<f64> {
        let raw = self.data[v as usize * self.width as usize + u as usize];
        (raw != 0).then(|| f64::from(raw) * self.depth_scale_m)
    }
}

/// An 8-bit label image (instance ids; 0 is background).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LabelImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// One label per pixel, row-major.
    pub data: Vec<u8>,
}

impl LabelImage {
    /// An all-background image.
    pub fn new(width: u32, height: u32) -> LabelImage {
        LabelImage { width, height, data: vec![0; width as usize * height as usize] }
    }

    /// The label at (u, v).
    pub fn label(&self, u: u32, v: u32) -> u8 {
        self.data[v as usize * self.width as usize + u as usize]
    }
}

/// Scale of a stored NOCS coordinate: 1.0 is stored as this value.
pub const NOCS_MAP_MAX: u16 = u16::MAX;

/// A NOCS map: per pixel the normalised object coordinate in [0, 1]^3
/// (object-frame point / box diagonal + 0.5), stored as three u16 channels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NocsMap {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` values, x y z per pixel, scaled by [`NOCS_MAP_MAX`].
    pub data: Vec<u16>,
}

impl NocsMap {
    /// An all-zero map.
    pub fn new(width: u32, height: u32) -> NocsMap {
        NocsMap { width, height, data: vec![0; width as usize * height as usize * 3] }
    }

    /// The NOCS coordinate at (u, v), each in [0, 1].
    pub fn coord(&self, u: u32, v: u32) -> [f64; 3] {
        let i = (v as usize * self.width as usize + u as usize) * 3;
        let s = f64::from(NOCS_MAP_MAX);
        [f64::from(self.data[i]) / s, f64::from(self.data[i + 1]) / s, f64::from(self.data[i + 2]) / s]
    }
}

/// One RGB-D frame, depth registered to colour.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbdFrame {
    /// Colour image.
    pub color: ColorImage,
    /// Depth image, same size as `color`.
    pub depth: DepthImage,
    /// Intrinsics of the colour camera.
    pub intrinsics: Intrinsics,
    /// Capture time in seconds (recording-relative or device clock).
    pub timestamp_s: f64,
}
