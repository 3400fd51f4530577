"""Reader for the tricons recording format (docs/formats.md, format version 1).

A recording is a directory with ``manifest.json`` and per frame an 8-bit RGB
colour PNG, a 16-bit grayscale depth PNG (units of ``depth_scale_m``, 0 = no
measurement) and optionally ``<id>_gt.json`` with an 8-bit instance mask and a
16-bit RGB NOCS map (65535 = 1.0).

PNGs are decoded by a small pure-numpy decoder (:func:`read_png`): zlib
inflate plus PNG unfiltering (all five filter types). It returns 16-bit
samples exactly (Pillow truncates 48-bit RGB to 8 bits, OpenCV swaps to BGR)
and checks colour type and bit depth against what the format says. After the
chunk and header checks, the formats Pillow decodes exactly (8-bit gray/RGB/
RGBA, 16-bit gray) go through Pillow when it is installed, 20-50x faster than
the numpy unfiltering (training decodes every frame once); the 16-bit RGB
NOCS maps always take the numpy path. Every error is a :class:`RecordingError`
naming the file.
"""

from __future__ import annotations

import json
import math
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMAT = "tricons-recording"
VERSION = 1
#: NOCS category names in NOCS id order (id = index + 1).
CLASSES = ("bottle", "bowl", "camera", "can", "laptop", "mug")

_PNG_SIG = b"\x89PNG\r\n\x1a\n"
# colour type -> (name, channels)
_COLOR_TYPES = {0: ("gray", 1), 2: ("rgb", 3), 3: ("palette", 1), 4: ("gray_alpha", 2), 6: ("rgba", 4)}


class RecordingError(Exception):
    """Bad or unreadable recording content; the message names the file."""


# --------------------------------------------------------------------------- PNG


def _unfilter_rows_fast(x: np.ndarray, ftypes: np.ndarray) -> np.ndarray:
    """Unfilter when every row uses None, Sub or Up (vectorised per row)."""
    out = np.empty_like(x)  # (H, W, bpp) uint8
    prev = np.zeros_like(x[0])
    for r in range(x.shape[0]):
        f = ftypes[r]
        if f == 0:
            out[r] = x[r]
        elif f == 1:
            out[r] = np.cumsum(x[r], axis=0, dtype=np.uint8)
        else:  # 2 = Up
            out[r] = x[r] + prev
        prev = out[r]
    return out


def _unfilter_wavefront(x: np.ndarray, ftypes: np.ndarray) -> np.ndarray:
    """Unfilter any mix of filter types by sweeping anti-diagonals.

    Pixel (r, c) depends on (r, c-1), (r-1, c) and (r-1, c-1), so all pixels
    with the same r + c can be decoded at once. The image is skewed so that an
    anti-diagonal is a contiguous row: S[d + 2, r + 1] = pixel (r, d - r); row
    0, 1 and column 0 are zero padding (PNG's "outside the image = 0").
    """
    h, w, bpp = x.shape
    nd = h + w - 1
    rows = np.arange(h)[:, None]
    cols = rows + np.arange(w)[None, :]  # d = r + c
    sx = np.zeros((nd + 2, h + 1, bpp), np.int16)
    sx[cols + 2, rows + 1] = x
    so = np.zeros_like(sx)
    ft = ftypes.astype(np.int16)[:, None, None]  # (H, 1, 1)
    is_sub, is_up, is_avg, is_paeth = (ft == 1)[:, 0], (ft == 2)[:, 0], (ft == 3)[:, 0], (ft == 4)[:, 0]
    for d in range(nd):
        lo, hi = max(0, d - w + 1), min(h - 1, d)
        r0, r1 = lo + 1, hi + 2  # columns in S
        a = so[d + 1, r0:r1]  # left: (r, c-1) -> diagonal d-1 (+2 padding)
        b = so[d + 1, r0 - 1 : r1 - 1]  # up: (r-1, c) -> diagonal d-1
        c = so[d, r0 - 1 : r1 - 1]  # up-left: (r-1, c-1) -> diagonal d-2
        rs = slice(lo, hi + 1)
        pa = np.abs(b - c)
        pb = np.abs(a - c)
        pc = np.abs(a + b - 2 * c)
        paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
        pred = np.where(
            is_paeth[rs], paeth,
            np.where(is_sub[rs], a, np.where(is_up[rs], b, np.where(is_avg[rs], (a + b) >> 1, 0))),
        )
        so[d + 2, r0:r1] = (sx[d + 2, r0:r1] + pred) & 0xFF
    return so[cols + 2, rows + 1].astype(np.uint8)


#: (colour, bit depth) -> (Pillow mode, dtype) for the formats Pillow decodes exactly.
_PIL_EXACT = {("gray", 8): ("L", np.uint8), ("rgb", 8): ("RGB", np.uint8), ("rgba", 8): ("RGBA", np.uint8),
              ("gray", 16): ("I;16", np.uint16)}


def _decode_with_pillow(data: bytes, color: str, depth: int, width: int, height: int) -> np.ndarray | None:
    """Pixels by Pillow for the formats it decodes exactly, else None (numpy path)."""
    want = _PIL_EXACT.get((color, depth))
    if want is None:
        return None
    try:
        import io

        from PIL import Image
    except ImportError:
        return None
    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.mode != want[0] or im.size != (width, height):
                return None
            arr = np.asarray(im)
    except Exception:  # anything Pillow refuses: the numpy path gives the precise error
        return None
    if arr.dtype != want[1]:
        return None
    return np.ascontiguousarray(arr)


@dataclass
class PngImage:
    """A decoded PNG: ``array`` is (H, W) or (H, W, C), uint8 or uint16."""

    width: int
    height: int
    color: str  # "gray", "rgb", "gray_alpha", "rgba"
    bit_depth: int
    array: np.ndarray


def decode_png(data: bytes, name: str = "<bytes>") -> PngImage:
    """Decode PNG bytes (8/16-bit gray, gray+alpha, RGB, RGBA; not interlaced).

    16-bit samples are returned exactly as stored (big-endian in the file,
    native uint16 here). Palette, sub-byte and interlaced images are rejected
    with a :class:`RecordingError` naming ``name``.
    """
    if not data.startswith(_PNG_SIG):
        raise RecordingError(f"{name}: not a PNG file (bad signature)")
    pos = len(_PNG_SIG)
    ihdr = None
    idat = []
    while True:
        if pos + 8 > len(data):
            raise RecordingError(f"{name}: truncated PNG (no IEND chunk)")
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        if len(body) != length or pos + 12 + length > len(data):
            raise RecordingError(f"{name}: truncated PNG chunk {ctype!r}")
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        if zlib.crc32(ctype + body) & 0xFFFFFFFF != crc:
            raise RecordingError(f"{name}: PNG chunk {ctype!r} has a bad CRC")
        pos += 12 + length
        if ctype == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif ctype == b"IDAT":
            idat.append(body)
        elif ctype == b"IEND":
            break
    if ihdr is None:
        raise RecordingError(f"{name}: PNG without IHDR")
    width, height, depth, ctype_id, _comp, _filt, interlace = ihdr
    if ctype_id not in _COLOR_TYPES or ctype_id == 3:
        raise RecordingError(f"{name}: unsupported PNG colour type {ctype_id} (palette images are not used)")
    if depth not in (8, 16):
        raise RecordingError(f"{name}: unsupported PNG bit depth {depth} (8 or 16 expected)")
    if interlace != 0:
        raise RecordingError(f"{name}: interlaced PNGs are not supported")
    color, channels = _COLOR_TYPES[ctype_id]
    fast = _decode_with_pillow(data, color, depth, width, height)
    if fast is not None:
        return PngImage(width, height, color, depth, fast)
    bpp = channels * depth // 8
    stride = width * bpp
    try:
        raw = zlib.decompress(b"".join(idat))
    except zlib.error as e:
        raise RecordingError(f"{name}: corrupt PNG data: {e}") from None
    if len(raw) != height * (stride + 1):
        raise RecordingError(f"{name}: PNG data has {len(raw)} bytes, expected {height * (stride + 1)}")
    rows = np.frombuffer(raw, np.uint8).reshape(height, stride + 1)
    ftypes = rows[:, 0]
    if ftypes.max(initial=0) > 4:
        raise RecordingError(f"{name}: invalid PNG filter type {int(ftypes.max())}")
    x = rows[:, 1:].reshape(height, width, bpp)
    if np.all(ftypes <= 2):
        pix = _unfilter_rows_fast(x, ftypes)
    else:
        pix = _unfilter_wavefront(x, ftypes)
    if depth == 16:
        arr = pix.reshape(height, width * bpp).view(">u2").astype(np.uint16)
    else:
        arr = pix.reshape(height, width * bpp)
    arr = arr.reshape(height, width, channels) if channels > 1 else arr.reshape(height, width)
    return PngImage(width, height, color, depth, np.ascontiguousarray(arr))


def read_png(path: str | os.PathLike) -> PngImage:
    """Read and decode a PNG file (see :func:`decode_png`)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from None
    return decode_png(data, str(path))


def _expect(img: PngImage, path, color: str, depth: int, size: tuple[int, int] | None, what: str) -> np.ndarray:
    if (img.color, img.bit_depth) != (color, depth):
        raise RecordingError(f"{path}: expected {depth}-bit {color} {what}, found {img.bit_depth}-bit {img.color}")
    if size is not None and (img.width, img.height) != size:
        raise RecordingError(
            f"{path}: image is {img.width}x{img.height}, the manifest says {size[0]}x{size[1]}"
        )
    return img.array


# --------------------------------------------------------------------- recording


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the colour camera (pixel centres at integers)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class Instance:
    """One ground-truth instance (``camera_from_object``: p_cam = R p_obj + t)."""

    id: int  # value in the mask, 1..255
    cls: str  # class name
    class_id: int  # 0-based index into CLASSES
    R: np.ndarray = field(repr=False)  # (3, 3) float64
    t: np.ndarray = field(repr=False)  # (3,) float64, metres
    s: np.ndarray = field(repr=False)  # (3,) float64, metres
    handle_visible: bool = True


@dataclass
class Annotations:
    """A frame's ground truth: instances and relative mask / NOCS file names."""

    instances: list[Instance]
    mask: str | None
    nocs: str | None


@dataclass(frozen=True)
class FrameEntry:
    """A manifest frame entry (file names relative to the recording)."""

    id: str
    timestamp_s: float
    color: str
    depth: str
    annotations: str | None


def _num(value, path, fld) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RecordingError(f"{path}: field {fld}: expected a finite number, got {value!r}")
    return float(value)


def _matrix(value, shape, path, fld) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordingError(f"{path}: field {fld}: expected a {shape} array of numbers") from None
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise RecordingError(f"{path}: field {fld}: expected a finite {shape} array, got shape {arr.shape}")
    return arr


def _relative(name, path, fld) -> str:
    if not isinstance(name, str) or not name:
        raise RecordingError(f"{path}: field {fld}: expected a file name")
    if os.path.isabs(name) or ".." in name:
        raise RecordingError(f"{path}: field {fld}: file {name!r} must be relative to the recording")
    return name


def parse_instance(obj: dict, path, i: int) -> Instance:
    """Parse one ``instances[i]`` entry of a gt.json (``R``/``t`` or 4x4 ``RT``)."""
    where = f"instances[{i}]"
    if not isinstance(obj, dict):
        raise RecordingError(f"{path}: {where}: expected an object")
    iid = obj.get("id")
    if isinstance(iid, bool) or not isinstance(iid, int) or not 1 <= iid <= 255:
        raise RecordingError(f"{path}: {where}.id: expected an integer in 1..=255, got {iid!r}")
    cls = obj.get("class")
    if cls not in CLASSES:
        raise RecordingError(f"{path}: {where}.class: unknown class {cls!r} (one of {', '.join(CLASSES)})")
    if "RT" in obj:
        rt = _matrix(obj["RT"], (4, 4), path, f"{where}.RT")
        det = np.linalg.det(rt[:3, :3])
        if not det > 0:
            raise RecordingError(f"{path}: {where}.RT: rotation block has non-positive determinant")
        R = rt[:3, :3] / np.cbrt(det)
        t = rt[:3, 3].copy()
    else:
        if "R" not in obj or "t" not in obj:
            raise RecordingError(f"{path}: {where}: needs R and t (or RT)")
        R = _matrix(obj["R"], (3, 3), path, f"{where}.R")
        t = _matrix(obj["t"], (3,), path, f"{where}.t")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise RecordingError(f"{path}: {where}.R: not a proper rotation (tolerance 1e-3)")
    if "s" not in obj:
        raise RecordingError(f"{path}: {where}: missing field s")
    s = _matrix(obj["s"], (3,), path, f"{where}.s")
    if not np.all(s > 0):
        raise RecordingError(f"{path}: {where}.s: sizes must be positive, got {s.tolist()}")
    hv = obj.get("handle_visible", True)
    if not isinstance(hv, bool):
        raise RecordingError(f"{path}: {where}.handle_visible: expected true or false")
    return Instance(iid, cls, CLASSES.index(cls), R, t, s, hv)


def read_annotations(path: str | os.PathLike) -> Annotations:
    """Read a ``<id>_gt.json`` file."""
    try:
        obj = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise RecordingError(f"{path}: invalid JSON: {e}") from None
    if not isinstance(obj, dict) or not isinstance(obj.get("instances"), list):
        raise RecordingError(f"{path}: expected an object with an 'instances' list")
    inst = [parse_instance(o, path, i) for i, o in enumerate(obj["instances"])]
    ids = [x.id for x in inst]
    if len(set(ids)) != len(ids):
        raise RecordingError(f"{path}: duplicate instance ids {ids}")
    mask = obj.get("mask")
    nocs = obj.get("nocs")
    mask = None if mask is None else _relative(mask, path, "mask")
    nocs = None if nocs is None else _relative(nocs, path, "nocs")
    return Annotations(inst, mask, nocs)


class Recording:
    """A tricons recording directory (format version 1), read lazily.

    ``Recording(path)`` reads and validates ``manifest.json``; frames are read
    on demand by index with the ``color``/``depth_m``/``annotations``/``mask``/
    ``nocs`` methods. Every image's size and bit depth is checked against the
    manifest.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        mpath = self.root / "manifest.json"
        self.manifest_path = mpath
        try:
            obj = json.loads(mpath.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise RecordingError(f"{mpath}: not found (is {self.root} a tricons recording?)") from None
        except OSError as e:
            raise RecordingError(f"{mpath}: cannot read: {e.strerror or e}") from None
        except json.JSONDecodeError as e:
            raise RecordingError(f"{mpath}: invalid JSON: {e}") from None
        if not isinstance(obj, dict):
            raise RecordingError(f"{mpath}: expected a JSON object")
        if obj.get("version") != VERSION:
            raise RecordingError(f"{mpath}: unsupported recording version {obj.get('version')!r} (this reader: {VERSION})")
        if obj.get("format") != FORMAT:
            raise RecordingError(f"{mpath}: field format: {obj.get('format')!r}, expected {FORMAT!r}")
        k = obj.get("intrinsics")
        if not isinstance(k, dict):
            raise RecordingError(f"{mpath}: missing field intrinsics")
        try:
            w, h = int(k["width"]), int(k["height"])
            self.intrinsics = Intrinsics(
                w, h, *(_num(k[n], mpath, f"intrinsics.{n}") for n in ("fx", "fy", "cx", "cy"))
            )
        except KeyError as e:
            raise RecordingError(f"{mpath}: missing field intrinsics.{e.args[0]}") from None
        if w <= 0 or h <= 0 or self.intrinsics.fx <= 0 or self.intrinsics.fy <= 0:
            raise RecordingError(f"{mpath}: field intrinsics: size and focal lengths must be positive")
        self.depth_scale_m = _num(obj.get("depth_scale_m"), mpath, "depth_scale_m")
        if self.depth_scale_m <= 0:
            raise RecordingError(f"{mpath}: field depth_scale_m must be positive")
        self.source = obj.get("source")
        frames = obj.get("frames")
        if not isinstance(frames, list):
            raise RecordingError(f"{mpath}: missing field frames")
        self.frames: list[FrameEntry] = []
        seen = set()
        for i, f in enumerate(frames):
            if not isinstance(f, dict) or not isinstance(f.get("id"), str):
                raise RecordingError(f"{mpath}: frames[{i}]: expected an object with a string id")
            if f["id"] in seen:
                raise RecordingError(f"{mpath}: frames[{i}].id: duplicate id {f['id']!r}")
            seen.add(f["id"])
            ann = f.get("annotations")
            self.frames.append(
                FrameEntry(
                    f["id"],
                    _num(f.get("timestamp_s", 0.0), mpath, f"frames[{i}].timestamp_s"),
                    _relative(f.get("color"), mpath, f"frames[{i}].color"),
                    _relative(f.get("depth"), mpath, f"frames[{i}].depth"),
                    None if ann is None else _relative(ann, mpath, f"frames[{i}].annotations"),
                )
            )

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"Recording({str(self.root)!r}, frames={len(self.frames)})"

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of every image."""
        return (self.intrinsics.width, self.intrinsics.height)

    def color(self, i: int) -> np.ndarray:
        """Frame ``i``'s colour image, (H, W, 3) uint8 RGB (RGBA: alpha dropped)."""
        p = self.root / self.frames[i].color
        img = read_png(p)
        if img.color == "rgba" and img.bit_depth == 8:
            img = PngImage(img.width, img.height, "rgb", 8, np.ascontiguousarray(img.array[..., :3]))
        return _expect(img, p, "rgb", 8, self.size, "colour image")

    def depth_raw(self, i: int) -> np.ndarray:
        """Frame ``i``'s depth in sensor units, (H, W) uint16, 0 = no measurement."""
        p = self.root / self.frames[i].depth
        return _expect(read_png(p), p, "gray", 16, self.size, "depth image")

    def depth_m(self, i: int) -> np.ndarray:
        """Frame ``i``'s depth in metres, (H, W) float32 (raw * depth_scale_m in float64, then rounded)."""
        return (self.depth_raw(i).astype(np.float64) * self.depth_scale_m).astype(np.float32)

    def annotations(self, i: int) -> Annotations | None:
        """Frame ``i``'s ground truth, or None when the frame is not annotated."""
        a = self.frames[i].annotations
        return None if a is None else read_annotations(self.root / a)

    def mask(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        """Frame ``i``'s instance mask, (H, W) uint8 (value = instance id), or None."""
        ann = ann if ann is not None else self.annotations(i)
        if ann is None or ann.mask is None:
            return None
        p = self.root / ann.mask
        return _expect(read_png(p), p, "gray", 8, self.size, "instance mask")

    def nocs_raw(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        """Frame ``i``'s NOCS map as stored, (H, W, 3) uint16 (65535 = 1.0), or None."""
        ann = ann if ann is not None else self.annotations(i)
        if ann is None or ann.nocs is None:
            return None
        p = self.root / ann.nocs
        return _expect(read_png(p), p, "rgb", 16, self.size, "NOCS map")

    def nocs(self, i: int, ann: Annotations | None = None) -> np.ndarray | None:
        """Frame ``i``'s NOCS map in [0, 1], (H, W, 3) float32 (raw / 65535), or None."""
        raw = self.nocs_raw(i, ann)
        return None if raw is None else (raw.astype(np.float32) / np.float32(65535.0))
