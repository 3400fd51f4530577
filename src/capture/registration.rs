//! The camera config and depth-to-colour registration.
//!
//! An RGB-D camera such as a RealSense D4xx exposes colour and depth on two
//! V4L2 nodes: two sensors with their own intrinsics, a rigid transform
//! between them, and a depth unit. The pose pipeline needs depth in the colour
//! camera's pixels ("registered"): [`register_depth`] moves every depth pixel
//! into the colour image. The config's file format is in docs/formats.md.

use crate::error::{Error, Result};
use crate::frame::{DepthImage, Intrinsics};
use crate::geometry::{Pose, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Value of the camera config's `format` field.
pub const CAMERA_CONFIG_FORMAT: &str = "tricons-camera";
/// The camera config version this build reads and writes.
pub const CAMERA_CONFIG_VERSION: u32 = 1;

/// Calibration of an RGB-D camera: what registration needs.
///
/// Intrinsics describe undistorted images (D4xx depth is rectified by the
/// device; colour lens distortion is not modelled).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraConfig {
    /// Always [`CAMERA_CONFIG_FORMAT`].
    pub format: String,
    /// Format version, [`CAMERA_CONFIG_VERSION`].
    pub version: u32,
    /// Intrinsics of the colour camera (and the size of its images).
    pub color: Intrinsics,
    /// Intrinsics of the depth sensor (and the size of its images).
    pub depth: Intrinsics,
    /// Maps points in the depth sensor's frame to the colour camera's frame (metres).
    pub color_from_depth: Pose,
    /// Metres per raw depth unit (0.001 for the D4xx default of millimetres).
    pub depth_scale_m: f64,
    /// Name of the colour camera's optical frame: the `frame_id` of what tricons publishes
    /// over ROS 2 and writes to MCAP (poses are in this frame) [default: `camera_color_optical_frame`].
    #[serde(default = "default_frame_id")]
    pub frame_id: String,
}

/// The RealSense ROS wrapper's name of the colour optical frame.
pub const DEFAULT_FRAME_ID: &str = "camera_color_optical_frame";

fn default_frame_id() -> String {
    DEFAULT_FRAME_ID.to_string()
}

impl CameraConfig {
    /// A config for a camera whose depth is already registered to colour
    /// (same intrinsics, identity extrinsics).
    pub fn registered(intrinsics: Intrinsics, depth_scale_m: f64) -> CameraConfig {
        CameraConfig {
            format: CAMERA_CONFIG_FORMAT.into(),
            version: CAMERA_CONFIG_VERSION,
            color: intrinsics,
            depth: intrinsics,
            color_from_depth: Pose::IDENTITY,
            depth_scale_m,
            frame_id: default_frame_id(),
        }
    }

    /// Reads and validates a camera config file (JSON).
    pub fn read(path: &Path) -> Result<CameraConfig> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| Error::parse(path, None, e.to_string()))?;
        if let Some(found) = value.get("version").and_then(|v| v.as_u64())
            && found != u64::from(CAMERA_CONFIG_VERSION)
        {
            return Err(Error::parse(
                path,
                None,
                format!("field version: {found} is not supported (this build reads {CAMERA_CONFIG_VERSION})"),
            ));
        }
        let config: CameraConfig = crate::error::from_json_value(path, value)?;
        config.validate().map_err(|m| Error::parse(path, None, m))?;
        Ok(config)
    }

    /// Checks the fields that serde cannot.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.format != CAMERA_CONFIG_FORMAT {
            return Err(format!("field format: {:?}, expected {CAMERA_CONFIG_FORMAT:?}", self.format));
        }
        self.color.validate().map_err(|m| format!("field color: {m}"))?;
        self.depth.validate().map_err(|m| format!("field depth: {m}"))?;
        if !(self.depth_scale_m.is_finite() && self.depth_scale_m > 0.0) {
            return Err(format!("field depth_scale_m: {} must be positive", self.depth_scale_m));
        }
        if !self.color_from_depth.translation_m.iter().all(|v| v.is_finite()) {
            return Err("field color_from_depth.t: must be finite".into());
        }
        Ok(())
    }

    /// Whether depth is already in the colour camera's pixels (registration is a copy).
    pub fn is_registered(&self) -> bool {
        self.color == self.depth && self.color_from_depth == Pose::IDENTITY
    }

    /// Serialises the config (pretty JSON, trailing newline).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).unwrap_or_default();
        s.push('\n');
        s
    }
}

/// Registers a raw depth image (the depth sensor's pixels, `config.depth`
/// size, units of `config.depth_scale_m`, 0 = no measurement) to the colour
/// camera: returns a depth image of `config.color`'s size whose pixel (u, v)
/// holds the z, in the colour camera's frame and the same units, of the
/// surface seen at colour pixel (u, v).
///
/// Every depth pixel is back-projected, moved by `color_from_depth`, and its
/// footprint (the projections of its corners) is filled in the colour image,
/// keeping the nearest surface where several land on one pixel. Colour pixels
/// that no depth pixel reaches stay 0. With an identity transform and equal
/// intrinsics the result equals the input.
pub fn register_depth(raw: &[u16], config: &CameraConfig) -> Result<DepthImage> {
    let (kd, kc) = (&config.depth, &config.color);
    let (wd, hd) = (kd.width as usize, kd.height as usize);
    if raw.len() != wd * hd {
        return Err(Error::InvalidArgument(format!(
            "depth buffer has {} pixels, the camera config's depth sensor is {wd}x{hd}",
            raw.len()
        )));
    }
    let mut out = DepthImage::new(kc.width, kc.height, config.depth_scale_m);
    if config.is_registered() {
        out.data.copy_from_slice(raw);
        return Ok(out);
    }
    let (wc, hc) = (kc.width as i64, kc.height as i64);
    let scale = config.depth_scale_m;
    let max_raw = f64::from(u16::MAX);
    let r = config.color_from_depth.rotation;
    let t = config.color_from_depth.translation_m;
    // Per-pixel rays of the depth sensor's corners are precomputed per row/column
    // (x = (u - cx) / fx does not depend on v).
    let ray_x = |u: f64| (u - kd.cx) / kd.fx;
    let ray_y = |v: f64| (v - kd.cy) / kd.fy;
    for v in 0..hd {
        for u in 0..wd {
            let d = raw[v * wd + u];
            if d == 0 {
                continue;
            }
            let z_m = f64::from(d) * scale;
            // The pixel's two opposite corners, moved to the colour frame and projected.
            let corner = |du: f64, dv: f64| -> Option<(f64, f64, f64)> {
                let p = Vec3::new(ray_x(u as f64 + du) * z_m, ray_y(v as f64 + dv) * z_m, z_m);
                let q = r * p + t;
                (q.z > 0.0).then(|| (kc.fx * q.x / q.z + kc.cx, kc.fy * q.y / q.z + kc.cy, q.z))
            };
            let (Some((u0, v0, z0)), Some((u1, v1, z1))) = (corner(-0.5, -0.5), corner(0.5, 0.5)) else {
                continue;
            };
            let z_units = (0.5 * (z0 + z1) / scale).round();
            if !(z_units >= 1.0 && z_units <= max_raw) {
                continue;
            }
            let z_units = z_units as u16;
            // Colour pixel centres inside the footprint (at least the nearest one).
            let span = |a: f64, b: f64, len: i64| -> Option<(usize, usize)> {
                let (lo, hi) = (a.min(b), a.max(b));
                let (mut first, mut last) = (lo.ceil(), hi.floor());
                if first > last {
                    first = (0.5 * (lo + hi)).round();
                    last = first;
                }
                let (first, last) = (first.max(0.0), last.min((len - 1) as f64));
                (first <= last).then_some((first as usize, last as usize))
            };
            let (Some((x0, x1)), Some((y0, y1))) = (span(u0, u1, wc), span(v0, v1, hc)) else {
                continue;
            };
            for y in y0..=y1 {
                for px in &mut out.data[y * wc as usize + x0..=y * wc as usize + x1] {
                    if *px == 0 || z_units < *px {
                        *px = z_units;
                    }
                }
            }
        }
    }
    Ok(out)
}
