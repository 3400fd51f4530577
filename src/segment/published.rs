//! Published Mask R-CNN detections: the per-image result pickles that every REAL275 /
//! CAMERA25 table since SPD is computed from (`segmentation_results/<split>/
//! results_<split>_<scene>_<id>.pkl`, distributed with SPD, DualPoseNet and AG-Pose), read
//! without Python (`tricons replay --masks results:DIR`).
//!
//! Each file is a pickled dict with `pred_class_ids` (N, NOCS ids 1..6), `pred_scores`
//! (N), `pred_masks` (H, W, N booleans) and `pred_bboxes` (N, 4: y1, x1, y2, x2), numpy
//! arrays (any protocol, Python 2's included). serde-pickle keeps a numpy array's
//! `__setstate__` tuple `(version, shape, dtype, fortran_order, data)`, in which the
//! dtype has lost its kind but keeps its byte order; the kind is the field's (integers,
//! floats, booleans) and the item size is the data length over the element count, checked.
//! Detections of class 0 (background) or unknown ids are left out, as the published
//! evaluations do.

use crate::category::Category;
use crate::error::{Error, Result};
use crate::pipeline::Detection;
use serde_pickle::{DeOptions, HashableValue, Value};
use std::path::{Path, PathBuf};

/// Largest result pickle read (a 640x480 image with 100 masks is about 31 MB).
pub const MAX_RESULT_BYTES: u64 = 512 * 1024 * 1024;

/// A directory of published result pickles.
pub struct PublishedDetections {
    dir: PathBuf,
    names: Vec<String>,
}

impl PublishedDetections {
    /// Lists the `*.pkl` files of `dir`.
    pub fn open(dir: &Path) -> Result<PublishedDetections> {
        let mut names = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let entry = entry.map_err(|e| Error::io(dir, e))?;
            if let Some(name) = entry.file_name().to_str().filter(|n| n.ends_with(".pkl")) {
                names.push(name.to_string());
            }
        }
        if names.is_empty() {
            return Err(Error::parse(dir, None, "no *.pkl result files in this directory"));
        }
        names.sort();
        Ok(PublishedDetections { dir: dir.to_path_buf(), names })
    }

    /// The file of frame `frame_id` of scene `scene`: the one name ending in
    /// `_<scene>_<frame_id>.pkl`, else the one ending in `_<frame_id>.pkl`.
    pub fn file_for(&self, scene: &str, frame_id: &str) -> Result<PathBuf> {
        for suffix in [format!("_{scene}_{frame_id}.pkl"), format!("_{frame_id}.pkl")] {
            let found: Vec<&String> = self.names.iter().filter(|n| n.ends_with(&suffix)).collect();
            match found.as_slice() {
                [one] => return Ok(self.dir.join(one)),
                [] => continue,
                many => {
                    return Err(Error::parse(
                        &self.dir,
                        None,
                        format!("{} result files end in {suffix} ({}, ...)", many.len(), many[0]),
                    ));
                }
            }
        }
        Err(Error::parse(
            &self.dir,
            None,
            format!("no result file for frame {frame_id} of scene {scene} (*_{scene}_{frame_id}.pkl)"),
        ))
    }

    /// The detections of one result file for a `width` x `height` image.
    pub fn read(path: &Path, width: u32, height: u32) -> Result<Vec<Detection>> {
        let len = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
        if len > MAX_RESULT_BYTES {
            return Err(Error::parse(path, None, format!("{len} bytes, more than the {MAX_RESULT_BYTES} read")));
        }
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let value =
            serde_pickle::value_from_slice(&bytes, DeOptions::new().keep_restore_state().replace_unresolved_globals())
                .map_err(|e| Error::parse(path, None, format!("not a readable pickle: {e}")))?;
        detections_from_value(&value, width, height).map_err(|m| Error::parse(path, None, m))
    }
}

/// A numpy array as kept by serde-pickle: shape, byte order, Fortran flag, raw bytes.
struct NpArray<'a> {
    shape: Vec<usize>,
    big_endian: bool,
    fortran: bool,
    data: std::borrow::Cow<'a, [u8]>,
}

impl NpArray<'_> {
    fn count(&self) -> usize {
        self.shape.iter().product()
    }

    fn item_size(&self, field: &str) -> std::result::Result<usize, String> {
        let n = self.count();
        if n == 0 {
            return Ok(0);
        }
        if !self.data.len().is_multiple_of(n) {
            return Err(format!("field {field}: {} data bytes for {n} elements", self.data.len()));
        }
        Ok(self.data.len() / n)
    }

    fn bytes_le(&self, chunk: &[u8]) -> [u8; 8] {
        let mut b = [0u8; 8];
        if self.big_endian {
            for (k, v) in chunk.iter().rev().enumerate() {
                b[k] = *v;
            }
        } else {
            b[..chunk.len()].copy_from_slice(chunk);
        }
        b
    }

    /// Integers (1, 2, 4 or 8 bytes, signed), C order.
    fn ints(&self, field: &str) -> std::result::Result<Vec<i64>, String> {
        let size = self.item_size(field)?;
        if self.count() == 0 {
            return Ok(Vec::new());
        }
        if ![1, 2, 4, 8].contains(&size) {
            return Err(format!("field {field}: {size}-byte items are not integers"));
        }
        let shift = 64 - 8 * size as u32;
        let v: Vec<i64> =
            self.data.chunks_exact(size).map(|c| (i64::from_le_bytes(self.bytes_le(c)) << shift) >> shift).collect();
        Ok(self.c_order(v))
    }

    /// Floats (4 or 8 bytes), C order.
    fn floats(&self, field: &str) -> std::result::Result<Vec<f64>, String> {
        let size = self.item_size(field)?;
        let v: Vec<f64> = match size {
            0 => Vec::new(),
            4 => self
                .data
                .chunks_exact(4)
                .map(|c| {
                    let b = self.bytes_le(c);
                    f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                })
                .collect(),
            8 => self.data.chunks_exact(8).map(|c| f64::from_le_bytes(self.bytes_le(c))).collect(),
            s => return Err(format!("field {field}: {s}-byte items are not floats")),
        };
        Ok(self.c_order(v))
    }

    /// Row-major order of the elements (a Fortran-ordered array reversed into it).
    fn c_order<T: Copy>(&self, v: Vec<T>) -> Vec<T> {
        if !self.fortran || self.shape.len() < 2 || v.is_empty() {
            return v;
        }
        let dims = &self.shape;
        // Fortran strides: the first axis varies fastest
        let mut strides = vec![1usize; dims.len()];
        for k in 1..dims.len() {
            strides[k] = strides[k - 1] * dims[k - 1];
        }
        // walk the C-order multi-index (last axis fastest), tracking its Fortran offset
        let mut idx = vec![0usize; dims.len()];
        let (mut off, mut out) = (0usize, Vec::with_capacity(v.len()));
        for _ in 0..v.len() {
            out.push(v[off]);
            for k in (0..dims.len()).rev() {
                idx[k] += 1;
                off += strides[k];
                if idx[k] < dims[k] {
                    break;
                }
                off -= strides[k] * dims[k];
                idx[k] = 0;
            }
        }
        out
    }
}

fn dict_get<'a>(d: &'a std::collections::BTreeMap<HashableValue, Value>, key: &str) -> Option<&'a Value> {
    d.get(&HashableValue::String(key.to_string())).or_else(|| d.get(&HashableValue::Bytes(key.as_bytes().to_vec())))
}

fn as_usize(v: &Value) -> Option<usize> {
    match v {
        Value::I64(i) => usize::try_from(*i).ok(),
        _ => None,
    }
}

/// A numpy array's restore state `(version, shape, dtype, fortran, data)`.
fn np_array<'a>(v: &'a Value, field: &str) -> std::result::Result<NpArray<'a>, String> {
    let Value::Tuple(t) = v else {
        return Err(format!("field {field}: expected a numpy array"));
    };
    let [_, shape, dtype, fortran, data] = t.as_slice() else {
        return Err(format!("field {field}: expected a numpy array (a 5-element state), found {} elements", t.len()));
    };
    let shape = match shape {
        Value::Tuple(s) | Value::List(s) => {
            s.iter().map(as_usize).collect::<Option<Vec<_>>>().ok_or(format!("field {field}: shape is not integers"))?
        }
        _ => return Err(format!("field {field}: shape is not a tuple")),
    };
    // the dtype's state (3, '<' | '>' | '|' | '=', ...): only the byte order survives
    let big_endian = match dtype {
        Value::Tuple(d) => matches!(d.get(1), Some(Value::String(o)) if o == ">"),
        _ => false,
    };
    let fortran = matches!(fortran, Value::Bool(true));
    let data: std::borrow::Cow<'a, [u8]> = match data {
        Value::Bytes(b) => std::borrow::Cow::Borrowed(b.as_slice()),
        // protocol 0-2 byte strings may arrive as text (latin-1: one char per byte)
        Value::String(text) => std::borrow::Cow::Owned(
            text.chars()
                .map(|c| u8::try_from(u32::from(c)).ok())
                .collect::<Option<Vec<u8>>>()
                .ok_or(format!("field {field}: array data is text beyond latin-1"))?,
        ),
        // `bytes()` (protocol 2's empty data) is a call with no arguments
        Value::Tuple(args) if args.is_empty() => std::borrow::Cow::Borrowed(&[][..]),
        _ => return Err(format!("field {field}: array data is not bytes (an object array?)")),
    };
    let count =
        shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or(format!("field {field}: shape too large"))?;
    if count > 0 && data.len() < count {
        return Err(format!("field {field}: {} data bytes for {count} elements", data.len()));
    }
    Ok(NpArray { shape, big_endian, fortran, data })
}

/// Numbers of a field stored as a numpy array or a plain list.
fn numbers(v: &Value, field: &str, float: bool) -> std::result::Result<(Vec<usize>, Vec<f64>), String> {
    if let Value::List(items) = v {
        let vals = items
            .iter()
            .map(|x| match x {
                Value::I64(i) => Some(*i as f64),
                Value::F64(f) => Some(*f),
                Value::Bool(b) => Some(f64::from(u8::from(*b))),
                _ => None,
            })
            .collect::<Option<Vec<_>>>()
            .ok_or(format!("field {field}: expected numbers"))?;
        return Ok((vec![vals.len()], vals));
    }
    let a = np_array(v, field)?;
    let vals = if float { a.floats(field)? } else { a.ints(field)?.into_iter().map(|i| i as f64).collect() };
    Ok((a.shape.clone(), vals))
}

fn detections_from_value(value: &Value, width: u32, height: u32) -> std::result::Result<Vec<Detection>, String> {
    let Value::Dict(d) = value else {
        return Err("expected a dict with pred_class_ids, pred_scores, pred_masks, pred_bboxes".into());
    };
    let field = |k: &str| {
        dict_get(d, k).ok_or(format!(
            "no field {k} (a segmentation result has pred_class_ids, pred_scores, pred_masks, pred_bboxes)"
        ))
    };
    let (_, ids) = numbers(field("pred_class_ids")?, "pred_class_ids", false)?;
    let (_, scores) = numbers(field("pred_scores")?, "pred_scores", true)?;
    let n = ids.len();
    if scores.len() != n {
        return Err(format!("field pred_scores: {} scores for {n} class ids", scores.len()));
    }
    let masks = np_array(field("pred_masks")?, "pred_masks")?;
    let (h, w) = (height as usize, width as usize);
    if masks.shape != [h, w, n] {
        return Err(format!(
            "field pred_masks: shape {:?}, expected [{h}, {w}, {n}] (image rows, columns, detections)",
            masks.shape
        ));
    }
    if masks.item_size("pred_masks")? > 1 {
        return Err("field pred_masks: expected booleans (1-byte items)".into());
    }
    let bits = masks.c_order(masks.data[..masks.count()].to_vec());
    let boxes = match dict_get(d, "pred_bboxes") {
        Some(v) => {
            let (shape, vals) = numbers(v, "pred_bboxes", false)?;
            if vals.len() != 4 * n || (shape.len() == 2 && shape != [n, 4]) {
                return Err(format!("field pred_bboxes: shape {shape:?}, expected [{n}, 4]"));
            }
            Some(vals)
        }
        None => None,
    };
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let Some(class) = u8::try_from(ids[k] as i64).ok().and_then(Category::from_id) else {
            continue; // background (0) or an id outside the six categories
        };
        let mask: Vec<bool> = (0..h * w).map(|p| bits[p * n + k] != 0).collect();
        // (y1, x1, y2, x2) -> [x0, y0, x1, y1]
        let box2d = boxes.as_ref().map(|b| [b[4 * k + 1], b[4 * k], b[4 * k + 3], b[4 * k + 2]]);
        out.push(Detection { class, score: scores[k], box2d, mask });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pickle numpy writes for `np.array([3, -1], dtype=np.int32)` at protocol 2 has
    /// the same structure; here the restore state is built by hand.
    fn array(shape: &[usize], order: &str, fortran: bool, data: Vec<u8>) -> Value {
        Value::Tuple(vec![
            Value::I64(1),
            Value::Tuple(shape.iter().map(|&d| Value::I64(d as i64)).collect()),
            Value::Tuple(vec![Value::I64(3), Value::String(order.into())]),
            Value::Bool(fortran),
            Value::Bytes(data),
        ])
    }

    #[test]
    fn integers_floats_byte_order_and_fortran_layout() {
        let v = array(&[2], "<", false, [3i32.to_le_bytes(), (-1i32).to_le_bytes()].concat());
        assert_eq!(np_array(&v, "x").unwrap().ints("x").unwrap(), vec![3, -1]);
        let v = array(&[2], ">", false, [3i16.to_be_bytes(), (-2i16).to_be_bytes()].concat());
        assert_eq!(np_array(&v, "x").unwrap().ints("x").unwrap(), vec![3, -2]);
        let v = array(&[1], "<", false, 0.25f32.to_le_bytes().to_vec());
        assert_eq!(np_array(&v, "x").unwrap().floats("x").unwrap(), vec![0.25]);
        // a 2x3 Fortran array [[1,2,3],[4,5,6]] is stored column by column
        let v = array(&[2, 3], "|", true, vec![1, 4, 2, 5, 3, 6]);
        assert_eq!(np_array(&v, "x").unwrap().ints("x").unwrap(), vec![1, 2, 3, 4, 5, 6]);
        let v = array(&[3], "<", false, vec![0; 7]);
        assert!(np_array(&v, "x").unwrap().ints("x").unwrap_err().contains("7 data bytes"));
    }
}
