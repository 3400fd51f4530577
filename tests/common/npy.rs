//! Minimal reader of NumPy `.npy` files (format 1.0/2.0, little-endian, C order) and of the
//! golden-fixture cases written by `tools/golden/make_pose_fixtures.py` (docs/formats.md).
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A tensor read from a `.npy` file.
#[derive(Debug, Clone, PartialEq)]
pub enum Array {
    /// `<f4`
    F32 { shape: Vec<usize>, data: Vec<f32> },
    /// `<i8`
    I64 { shape: Vec<usize>, data: Vec<i64> },
}

impl Array {
    pub fn shape(&self) -> &[usize] {
        match self {
            Array::F32 { shape, .. } | Array::I64 { shape, .. } => shape,
        }
    }
    pub fn f32(&self) -> &[f32] {
        match self {
            Array::F32 { data, .. } => data,
            _ => panic!("expected a float32 array"),
        }
    }
    pub fn i64(&self) -> &[i64] {
        match self {
            Array::I64 { data, .. } => data,
            _ => panic!("expected an int64 array"),
        }
    }
}

/// Read one `.npy` file.
pub fn read_npy(path: &Path) -> Array {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "{}: not a .npy file", path.display());
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => panic!("{}: unsupported .npy version {v}", path.display()),
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len]).expect("ascii header");
    let field = |key: &str| -> &str {
        let at = header.find(&format!("'{key}'")).unwrap_or_else(|| panic!("{}: no {key}", path.display()));
        header[at + key.len() + 3..].trim_start()
    };
    assert!(field("fortran_order").starts_with("False"), "{}: Fortran order", path.display());
    let descr = field("descr");
    let descr = &descr[1..descr[1..].find('\'').unwrap() + 1];
    let shape_txt = field("shape");
    let shape: Vec<usize> = shape_txt[1..shape_txt.find(')').unwrap()]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    let count: usize = shape.iter().product();
    let body = &bytes[start + header_len..];
    match descr {
        "<f4" => Array::F32 {
            shape,
            data: body[..4 * count].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect(),
        },
        "<i8" => Array::I64 {
            shape,
            data: body[..8 * count].chunks_exact(8).map(|c| i64::from_le_bytes(c.try_into().unwrap())).collect(),
        },
        d => panic!("{}: unsupported dtype {d}", path.display()),
    }
}

/// One fixture case: its `case.json` and every tensor it names.
pub struct Case {
    pub dir: PathBuf,
    pub meta: serde_json::Value,
    pub arrays: HashMap<String, Array>,
}

impl Case {
    pub fn load(dir: &Path) -> Case {
        let text = std::fs::read_to_string(dir.join("case.json")).unwrap();
        let meta: serde_json::Value = serde_json::from_str(&text).unwrap();
        let mut arrays = HashMap::new();
        for list in ["inputs", "outputs"] {
            for e in meta[list].as_array().unwrap() {
                let a = read_npy(&dir.join(e["file"].as_str().unwrap()));
                let shape: Vec<usize> =
                    e["shape"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
                assert_eq!(a.shape(), shape.as_slice(), "{}: {}", dir.display(), e["name"]);
                arrays.insert(e["name"].as_str().unwrap().to_string(), a);
            }
        }
        Case { dir: dir.to_path_buf(), meta, arrays }
    }
    pub fn get(&self, name: &str) -> &Array {
        self.arrays.get(name).unwrap_or_else(|| panic!("{}: no tensor {name}", self.dir.display()))
    }
    pub fn op(&self) -> &str {
        self.meta["op"].as_str().unwrap_or("")
    }
    pub fn attr_f(&self, name: &str) -> f64 {
        self.meta["attributes"][name].as_f64().unwrap()
    }
    pub fn attr_u(&self, name: &str) -> usize {
        self.meta["attributes"][name].as_u64().unwrap() as usize
    }
}

/// Every case directory under `tests/fixtures/<set>`, sorted.
pub fn cases(set: &str) -> Vec<Case> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(set);
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("{}: {e}", root.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("case.json").is_file())
        .collect();
    dirs.sort();
    dirs.iter().map(|d| Case::load(d)).collect()
}
