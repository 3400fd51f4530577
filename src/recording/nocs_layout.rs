//! Reader for the NOCS dataset layout (REAL275 / CAMERA25 scene folders):
//! `<id>_color.png`, `<id>_depth.png` (CAMERA: `<id>_composed.png`, in the scene folder
//! or in `camera_full_depths/<split>/<scene>/` as SPD and AG-Pose keep it; 32001 = no
//! depth), `<id>_mask.png`, `<id>_coord.png`, `<id>_meta.txt` (three words a line in
//! Real, four in CAMERA: `instance_id class_id synset model_id`).
//!
//! The dataset keeps its ground-truth poses in Python pickles, which a
//! Python-free runtime does not read. Poses are instead recovered from the
//! NOCS map and the depth by a similarity fit ([`fit_similarity`]), which is
//! how the NOCS authors annotated their real scenes; sizes are the symmetric
//! extents of the observed NOCS coordinates times the fitted scale. Mug handle
//! visibility is not in these files and is reported as visible.

use super::Recording;
use super::annotations::{FrameAnnotations, GtInstance};
use crate::category::Category;
use crate::error::{Error, Result};
use crate::frame::{DEPTH_SCALE_MM, DepthImage, Intrinsics, LabelImage, NOCS_MAP_MAX, NocsMap, RgbdFrame};
use crate::geometry::{Vec3, fit_similarity_robust};
use crate::image_io::{SizeLimit, read_color_png, read_nocs_png, read_png};
use std::path::{Path, PathBuf};

/// Background value of NOCS dataset masks.
pub const NOCS_MASK_BACKGROUND: u8 = 255;
/// Fewest pixels with depth and NOCS coordinates needed to fit a pose.
pub const MIN_FIT_PIXELS: usize = 16;

const COLOR_SUFFIX: &str = "_color.png";

/// A `_composed.png` pixel without depth (SPD / AG-Pose read it as 0).
pub const COMPOSED_NO_DEPTH: u16 = 32001;

/// A NOCS dataset scene directory opened for reading.
pub struct NocsLayout {
    root: PathBuf,
    ids: Vec<String>,
    intrinsics: Intrinsics,
    /// `ROOT/camera_full_depths/<split>/<scene>` for a scene of `ROOT/CAMERA/<split>/`
    /// (any case): where SPD / AG-Pose keep CAMERA's composed depth.
    full_depths: Option<PathBuf>,
}

/// `ROOT/camera_full_depths/<split>/<scene>` when `scene` is `ROOT/CAMERA/<split>/<scene>`
/// (or `camera/...`, as DualPoseNet and AG-Pose spell it).
fn camera_full_depths(scene: &Path) -> Option<PathBuf> {
    let split = scene.parent()?;
    let group = split.parent()?;
    if !group.file_name()?.to_str()?.eq_ignore_ascii_case("camera") {
        return None;
    }
    Some(group.parent()?.join("camera_full_depths").join(split.file_name()?).join(scene.file_name()?))
}

impl NocsLayout {
    /// Whether `dir` holds `*_color.png` files.
    pub fn looks_like(dir: &Path) -> Result<bool> {
        Ok(!Self::scan(dir)?.is_empty())
    }

    fn scan(dir: &Path) -> Result<Vec<String>> {
        let mut ids = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let entry = entry.map_err(|e| Error::io(dir, e))?;
            if let Some(id) = entry.file_name().to_str().and_then(|n| n.strip_suffix(COLOR_SUFFIX)) {
                ids.push(id.to_string());
            }
        }
        ids.sort();
        Ok(ids)
    }

    /// Opens a scene directory. Without explicit intrinsics, CAMERA25's are used for a
    /// scene of a `CAMERA/<split>/` folder or one with `_composed.png` depth files,
    /// REAL275's otherwise.
    pub fn open(root: &Path, intrinsics: Option<Intrinsics>) -> Result<NocsLayout> {
        let ids = Self::scan(root)?;
        if ids.is_empty() {
            return Err(Error::parse(root, None, "no *_color.png frames in this NOCS layout directory"));
        }
        let full_depths = camera_full_depths(root);
        let intrinsics = intrinsics.unwrap_or_else(|| {
            if full_depths.is_some() || root.join(format!("{}_composed.png", ids[0])).exists() {
                Intrinsics::CAMERA25
            } else {
                Intrinsics::REAL275
            }
        });
        Ok(NocsLayout { root: root.to_path_buf(), ids, intrinsics, full_depths })
    }

    /// The frame's depth file: CAMERA's composed depth (the scene folder, then
    /// `camera_full_depths/`) where there is one, else `_depth.png`. A CAMERA scene's
    /// `_depth.png` holds the rendered objects only, so there it is never the answer: the
    /// path returned is the composed file that is missing, and reading it names it.
    fn depth_path(&self, index: usize) -> PathBuf {
        let name = format!("{}_composed.png", self.ids[index]);
        let mut composed = vec![self.root.join(&name)];
        if let Some(dir) = &self.full_depths {
            composed.push(dir.join(&name));
        }
        if let Some(found) = composed.iter().find(|p| p.exists()) {
            return found.clone();
        }
        let depth = self.path(index, "_depth.png");
        if self.full_depths.is_some() || !depth.exists() { composed.pop().unwrap_or(depth) } else { depth }
    }

    /// Every image of a frame has the intrinsics' size (checked before decoding).
    fn frame_size(&self) -> SizeLimit {
        let k = &self.intrinsics;
        SizeLimit::Exactly { width: k.width, height: k.height, source: "as in the layout's intrinsics" }
    }

    fn path(&self, index: usize, suffix: &str) -> PathBuf {
        self.root.join(format!("{}{suffix}", self.ids[index]))
    }

    fn check_index(&self, index: usize) -> Result<()> {
        if index >= self.ids.len() {
            return Err(Error::InvalidArgument(format!(
                "frame index {index} out of range ({} frames in {})",
                self.ids.len(),
                self.root.display()
            )));
        }
        Ok(())
    }

    fn read_depth(&self, index: usize) -> Result<DepthImage> {
        let path = self.depth_path(index);
        if !path.exists() && self.full_depths.is_some() {
            return Err(Error::parse(
                &path,
                None,
                "no such file: a CAMERA frame's depth is its _composed.png (camera_full_depths/ of SPD / AG-Pose; \
                 _depth.png holds the rendered objects only)",
            ));
        }
        let raw = read_png(&path, self.frame_size())?;
        let data = match (raw.color_type, raw.bit_depth) {
            (png::ColorType::Grayscale, png::BitDepth::Sixteen) => raw.samples_u16(),
            // CAMERA25 composed depth: 8-bit, depth = G * 256 + R (file RGB order).
            (png::ColorType::Rgb, png::BitDepth::Eight) => raw
                .data
                .chunks_exact(3)
                .map(|p| u16::from(p[1]) * 256 + u16::from(p[0]))
                .map(|d| if d == COMPOSED_NO_DEPTH { 0 } else { d })
                .collect(),
            _ => {
                return Err(Error::ImageFormat {
                    path,
                    expected: "16-bit grayscale depth (or CAMERA25's 8-bit RGB composed depth)".into(),
                    found: raw.describe(),
                });
            }
        };
        Ok(DepthImage { width: raw.width, height: raw.height, data, depth_scale_m: DEPTH_SCALE_MM })
    }

    /// Reads `<id>_meta.txt`: lines `instance_id class_id model...`; class 0 (distractors) is skipped.
    fn read_meta(&self, index: usize) -> Result<Option<Vec<(u8, Category)>>> {
        let path = self.path(index, "_meta.txt");
        if !path.exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let mut out = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let fields: Vec<&str> = line.split_whitespace().collect();
            if fields.is_empty() {
                continue;
            }
            let bad = |m: &str| Error::parse(&path, Some(i + 1), m.to_string());
            if fields.len() < 3 {
                return Err(bad("expected `instance_id class_id model_name`"));
            }
            let inst: u8 = fields[0].parse().map_err(|_| bad("instance_id is not an integer in 0..=254"))?;
            let class: u8 = fields[1].parse().map_err(|_| bad("class_id is not an integer"))?;
            if class == 0 {
                continue;
            }
            let class = Category::from_id(class).ok_or_else(|| bad("class_id must be 0..=6"))?;
            out.push((inst, class));
        }
        Ok(Some(out))
    }

    fn read_mask(&self, index: usize) -> Result<LabelImage> {
        let path = self.path(index, "_mask.png");
        let raw = read_png(&path, self.frame_size())?;
        let channels = match (raw.color_type, raw.bit_depth) {
            (png::ColorType::Grayscale, png::BitDepth::Eight) => 1,
            (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
            _ => {
                return Err(Error::ImageFormat { path, expected: "8-bit instance mask".into(), found: raw.describe() });
            }
        };
        let data =
            raw.data.chunks_exact(channels).map(|p| if p[0] == NOCS_MASK_BACKGROUND { 0 } else { p[0] }).collect();
        Ok(LabelImage { width: raw.width, height: raw.height, data })
    }

    fn read_coord(&self, index: usize) -> Result<NocsMap> {
        let mut map = read_nocs_png(&self.path(index, "_coord.png"), self.frame_size())?;
        // The dataset stores z flipped (its loader uses 1 - z).
        for z in map.data.iter_mut().skip(2).step_by(3) {
            *z = NOCS_MAP_MAX - *z;
        }
        Ok(map)
    }
}

impl Recording for NocsLayout {
    fn describe(&self) -> String {
        format!("NOCS layout {} ({} frames)", self.root.display(), self.ids.len())
    }

    fn len(&self) -> usize {
        self.ids.len()
    }

    fn frame_id(&self, index: usize) -> &str {
        &self.ids[index]
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn read_frame(&self, index: usize) -> Result<RgbdFrame> {
        self.check_index(index)?;
        let color_path = self.path(index, COLOR_SUFFIX);
        let color = read_color_png(&color_path, self.frame_size())?;
        let depth = self.read_depth(index)?;
        if (color.width, color.height) != (depth.width, depth.height) {
            return Err(Error::ImageFormat {
                path: color_path,
                expected: format!("the depth image's size {}x{}", depth.width, depth.height),
                found: format!("{}x{}", color.width, color.height),
            });
        }
        Ok(RgbdFrame { color, depth, intrinsics: self.intrinsics, timestamp_s: index as f64 / 30.0 })
    }

    fn read_instances(&self, index: usize) -> Result<Option<Vec<GtInstance>>> {
        Ok(self.read_annotations(index)?.map(|a| a.instances))
    }

    fn read_annotations(&self, index: usize) -> Result<Option<FrameAnnotations>> {
        self.check_index(index)?;
        let Some(meta) = self.read_meta(index)? else {
            return Ok(None);
        };
        let mut mask = self.read_mask(index)?;
        let nocs = self.read_coord(index)?;
        let depth = self.read_depth(index)?;
        let size = (depth.width, depth.height);
        for (suffix, w, h) in [("_mask.png", mask.width, mask.height), ("_coord.png", nocs.width, nocs.height)] {
            if (w, h) != size {
                return Err(Error::ImageFormat {
                    path: self.path(index, suffix),
                    expected: format!("the depth image's size {}x{}", size.0, size.1),
                    found: format!("{w}x{h}"),
                });
            }
        }
        let instances = recover_instances(&meta, &mask, &nocs, &depth, &self.intrinsics)?;
        // Pixels of instances not in the meta file (distractors) are background.
        let known: Vec<u8> = meta.iter().map(|m| m.0).collect();
        mask.data.iter_mut().filter(|l| !known.contains(l)).for_each(|l| *l = 0);
        Ok(Some(FrameAnnotations { instances, mask: Some(mask), nocs: Some(nocs) }))
    }
}

/// Recovers the pose and size of each `(mask id, class)` instance from a NOCS
/// map and a registered depth image: a robust similarity fit
/// ([`fit_similarity_robust`]) of the NOCS coordinates (centred) onto the
/// back-projected depth; the size is the symmetric extent of the observed NOCS
/// coordinates times the fitted scale. Instances with fewer than
/// [`MIN_FIT_PIXELS`] usable pixels are skipped (with a warning). The three
/// images must have the same size.
pub fn recover_instances(
    instances: &[(u8, Category)],
    mask: &LabelImage,
    nocs: &NocsMap,
    depth: &DepthImage,
    intrinsics: &Intrinsics,
) -> Result<Vec<GtInstance>> {
    let size = (depth.width, depth.height);
    if (mask.width, mask.height) != size || (nocs.width, nocs.height) != size {
        return Err(Error::InvalidArgument(format!(
            "mask {}x{}, NOCS map {}x{} and depth {}x{} must have the same size",
            mask.width, mask.height, nocs.width, nocs.height, size.0, size.1
        )));
    }
    let mut out = Vec::new();
    for &(id, class) in instances {
        let mut nocs_pts = Vec::new();
        let mut cam_pts = Vec::new();
        for v in 0..mask.height {
            for u in 0..mask.width {
                if mask.label(u, v) != id {
                    continue;
                }
                if let Some(z) = depth.depth_m(u, v) {
                    let c = nocs.coord(u, v);
                    nocs_pts.push(Vec3::new(c[0] - 0.5, c[1] - 0.5, c[2] - 0.5));
                    cam_pts.push(intrinsics.backproject(f64::from(u), f64::from(v), z));
                }
            }
        }
        if nocs_pts.len() < MIN_FIT_PIXELS {
            log::warn!("instance {id} has {} pixels with depth, too few to recover its pose; skipped", nocs_pts.len());
            continue;
        }
        let Some(fit) = fit_similarity_robust(&nocs_pts, &cam_pts) else {
            continue;
        };
        let half = nocs_pts.iter().fold(Vec3::zeros(), |m, p| m.zip_map(&p.abs(), f64::max));
        out.push(GtInstance {
            id,
            class,
            camera_from_object: fit.pose,
            size_m: [2.0 * half.x * fit.scale, 2.0 * half.y * fit.scale, 2.0 * half.z * fit.scale],
            handle_visible: true,
        });
    }
    Ok(out)
}
