"""Training samples from tricons recordings, with AG-Pose's preprocessing.

One sample per annotated instance of every frame. The deterministic part
(:func:`prepare_instance`: valid pixels, square crop window, crop) is cached;
the random part (:func:`make_sample`: point sampling, colour jitter, two
augmented views) is drawn per (seed, epoch, index) so a run is reproducible
and resumable. The exact specification (rounding, pixel centres, resize, RNG
draw order) is in tools/README.md, section "Preprocessing"; the Rust runtime
reproduces the deterministic part bit for bit.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from .nocs_layout import open_any
from .recording import CLASSES, Instance, Intrinsics, Recording, RecordingError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: AG-Pose keeps an instance only with MORE than this many valid pixels in its crop.
MIN_VALID_PIXELS = 16
CROP_STEP = 40
MAX_CROP = 440


# ------------------------------------------------------------------ crop window


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """Bounding box ``(y0, y1, x0, x1)`` of the True pixels, end-exclusive; None if empty."""
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def crop_side(bbox_h: int, bbox_w: int, img_h: int = 480, img_w: int = 640) -> int:
    """AG-Pose crop side: ``(max(h, w) // 40 + 1) * 40``, at most 440 (and the image)."""
    side = (max(bbox_h, bbox_w) // CROP_STEP + 1) * CROP_STEP
    return min(side, MAX_CROP, img_h, img_w)


def crop_window(bbox: tuple[int, int, int, int], img_h: int, img_w: int) -> tuple[int, int, int, int]:
    """Square crop ``(rmin, rmax, cmin, cmax)`` (end-exclusive) around an end-exclusive bbox.

    Centre ``((y0 + y1) // 2, (x0 + x1) // 2)``; the window spans
    ``[centre - side // 2, centre - side // 2 + side)`` and is then shifted
    (not shrunk) to lie inside the image.
    """
    y0, y1, x0, x1 = bbox
    side = crop_side(y1 - y0, x1 - x0, img_h, img_w)
    cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
    rmin, cmin = cy - side // 2, cx - side // 2
    rmin = min(max(rmin, 0), img_h - side)
    cmin = min(max(cmin, 0), img_w - side)
    return rmin, rmin + side, cmin, cmin + side


# ---------------------------------------------------------------- deterministic


@dataclass
class PreparedInstance:
    """Deterministic per-instance preprocessing (cached).

    ``choose_all``: row-major indices into the ``side x side`` crop of the valid
    pixels (instance mask AND depth > 0), ascending. ``depth_all`` (raw sensor
    units) and ``nocs_all`` (raw uint16, or None without a NOCS map) are the
    values at those pixels.
    """

    window: tuple[int, int, int, int]  # rmin, rmax, cmin, cmax
    rgb_crop: np.ndarray  # (side, side, 3) uint8
    choose_all: np.ndarray  # (K,) int64
    depth_all: np.ndarray  # (K,) uint16
    nocs_all: np.ndarray | None  # (K, 3) uint16
    instance: Instance
    depth_scale_m: float
    intrinsics: Intrinsics
    # the whole crop window, kept for mask perturbation (``keep_crop``): raw depth
    # (side, side) uint16 and the instance mask there (side, side) bool
    depth_crop: np.ndarray | None = None
    mask_crop: np.ndarray | None = None

    @property
    def side(self) -> int:
        return self.window[1] - self.window[0]

    @property
    def n_valid(self) -> int:
        return int(self.choose_all.size)


def prepare_instance(
    color: np.ndarray,
    depth_raw: np.ndarray,
    mask: np.ndarray,
    nocs_raw: np.ndarray | None,
    inst: Instance,
    intrinsics: Intrinsics,
    depth_scale_m: float,
    keep_crop: bool = False,
) -> PreparedInstance | None:
    """Crop window and valid pixels of one instance; None if its mask is empty.

    ``mask`` is the frame's instance-id image. The bbox is that of the
    instance mask (not of mask AND depth); valid pixels are mask AND depth > 0.
    ``keep_crop`` also keeps the window's raw depth and instance mask
    (``depth_crop``, ``mask_crop``: what :func:`perturb_mask` needs).
    """
    h, w = mask.shape
    inst_mask = mask == inst.id
    bbox = mask_bbox(inst_mask)
    if bbox is None:
        return None
    rmin, rmax, cmin, cmax = crop_window(bbox, h, w)
    valid = inst_mask[rmin:rmax, cmin:cmax] & (depth_raw[rmin:rmax, cmin:cmax] > 0)
    choose = np.flatnonzero(valid).astype(np.int64)
    side = rmax - rmin
    rows, cols = choose // side + rmin, choose % side + cmin
    return PreparedInstance(
        window=(rmin, rmax, cmin, cmax),
        rgb_crop=np.ascontiguousarray(color[rmin:rmax, cmin:cmax]),
        choose_all=choose,
        depth_all=depth_raw[rows, cols].astype(np.uint16),
        nocs_all=None if nocs_raw is None else nocs_raw[rows, cols].astype(np.uint16),
        instance=inst,
        depth_scale_m=depth_scale_m,
        intrinsics=intrinsics,
        depth_crop=np.ascontiguousarray(depth_raw[rmin:rmax, cmin:cmax]).astype(np.uint16) if keep_crop else None,
        mask_crop=np.ascontiguousarray(inst_mask[rmin:rmax, cmin:cmax]) if keep_crop else None,
    )


def backproject(choose: np.ndarray, depth: np.ndarray, window, intrinsics: Intrinsics, depth_scale_m: float) -> np.ndarray:
    """Camera-frame points (float32, metres) of crop pixels ``choose`` with raw depths ``depth``.

    Pixel (v, u) = (rmin + choose // side, cmin + choose % side); pixel centres
    at integer coordinates; in float64: z = depth * depth_scale_m,
    x = (u - cx) * z / fx, y = (v - cy) * z / fy; then rounded to float32.
    """
    rmin, rmax, cmin, _ = window
    side = rmax - rmin
    v = (choose // side + rmin).astype(np.float64)
    u = (choose % side + cmin).astype(np.float64)
    z = depth.astype(np.float64) * depth_scale_m
    x = (u - intrinsics.cx) * z / intrinsics.fx
    y = (v - intrinsics.cy) * z / intrinsics.fy
    return np.stack([x, y, z], axis=1).astype(np.float32)


def resize_bilinear(img: np.ndarray, out: int) -> np.ndarray:
    """Bilinear resize of a square (s, s, C) image to (out, out, C), float64, no antialiasing.

    Half-pixel centres (``align_corners=False``): source coordinate
    ``max((i + 0.5) * (s / out) - 0.5, 0)``; i0 = floor, i1 = min(i0 + 1, s - 1),
    weight l = coordinate - i0; value = (1 - ly) * ((1 - lx) * p00 + lx * p01)
    + ly * ((1 - lx) * p10 + lx * p11). Same as torch ``F.interpolate(...,
    mode="bilinear", align_corners=False)`` and cv2 INTER_LINEAR up to rounding.
    """
    s = img.shape[0]
    assert img.shape[1] == s, "square crops only"
    scale = s / out
    c = np.maximum((np.arange(out, dtype=np.float64) + 0.5) * scale - 0.5, 0.0)
    i0 = np.minimum(np.floor(c).astype(np.int64), s - 1)
    i1 = np.minimum(i0 + 1, s - 1)
    lam = c - i0
    f = img.astype(np.float64)
    ly, lx = lam[:, None, None], lam[None, :, None]
    r0, r1 = f[i0], f[i1]
    top = (1.0 - lx) * r0[:, i0] + lx * r0[:, i1]
    bot = (1.0 - lx) * r1[:, i0] + lx * r1[:, i1]
    return (1.0 - ly) * top + ly * bot


def normalise_rgb(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) values in [0, 255] (float64) -> (3, H, W) float32 ``(v / 255 - mean) / std`` (ImageNet)."""
    mean = np.asarray(IMAGENET_MEAN, np.float64)
    std = np.asarray(IMAGENET_STD, np.float64)
    return np.ascontiguousarray(((rgb / 255.0 - mean) / std).transpose(2, 0, 1)).astype(np.float32)


def remap_choose(choose: np.ndarray, side: int, crop_size: int) -> np.ndarray:
    """Map row-major indices on the side x side crop to the crop_size x crop_size grid.

    (row, col) -> (row * crop_size // side) * crop_size + col * crop_size // side
    (exact integer floor of row * crop_size / side).
    """
    row, col = choose // side, choose % side
    return (row * crop_size // side) * crop_size + (col * crop_size // side)


def sample_indices(n_valid: int, n_points: int, rng) -> np.ndarray:
    """``rng.choice(n_valid, n_points, replace=n_valid < n_points)``: the only draw for sampling.

    ``rng`` is a ``numpy.random.Generator`` (training) or a
    :class:`tricons_rng.TriconsRng`, which draws exactly as ``tricons replay`` does.
    """
    if hasattr(rng, "sample_indices"):
        return rng.sample_indices(n_valid, n_points)
    return rng.choice(n_valid, n_points, replace=n_valid < n_points)


# --------------------------------------------------------------------- augment


def euler_xyz(ax: float, ay: float, az: float) -> np.ndarray:
    """Rx(ax) @ Ry(ay) @ Rz(az), angles in radians (float64)."""
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


@dataclass(frozen=True)
class AugmentConfig:
    """Paper's 3D augmentation (per view) and AG-Pose's colour jitter.

    Per view: translation dt ~ U(-0.02, 0.02) m per axis, scale factors
    e ~ U(0.8, 1.2) per axis (views in ``isotropic_views`` use e[0] for all
    three), angles ~ U(0, 20) degrees about x, y, z composed as dR = Rx Ry Rz,
    all about the centroid c of the sampled points:
    ``y = dS dR (x - c) + c + dt``. ``scale_axes="camera"``: dS = diag(e) in
    camera axes (the paper's P^v = dS dR P + dT, the model's convention).
    ``scale_axes="object"``: dS scales along the object's own axes (needs the
    ground-truth R; keeps the view's pose, size and NOCS targets exact, which
    the sample then carries as ``aug_gt_*``).
    """

    translation_m: float = 0.02
    scale_range: tuple[float, float] = (0.8, 1.2)
    angle_range_deg: tuple[float, float] = (0.0, 20.0)
    n_views: int = 2
    isotropic_views: tuple[int, ...] = ()
    scale_axes: str = "camera"  # "camera" | "object"
    color_jitter: bool = True
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    hue: float = 0.05
    # mask perturbation (off at 0): with probability ``mask_perturb`` the instance mask is
    # dilated (radius > 0) or eroded (< 0) by a radius ~ U{-mask_erode_px..mask_dilate_px}
    # pixels, then shifted by (dy, dx) ~ U{-mask_shift_px..mask_shift_px}^2, inside the crop
    # window, before the points are chosen: the loose and offset masks a segmenter gives
    mask_perturb: float = 0.0
    mask_dilate_px: int = 4
    mask_erode_px: int = 2
    mask_shift_px: int = 2

    def __post_init__(self):
        if self.scale_axes not in ("camera", "object"):
            raise ValueError(f"scale_axes must be 'camera' or 'object', got {self.scale_axes!r}")
        if not 0.0 <= self.mask_perturb <= 1.0:
            raise ValueError(f"mask_perturb must lie in [0, 1], got {self.mask_perturb}")
        if min(self.mask_dilate_px, self.mask_erode_px, self.mask_shift_px) < 0:
            raise ValueError("mask_dilate_px, mask_erode_px and mask_shift_px must be >= 0")


def draw_view(rng: np.random.Generator, cfg: AugmentConfig, isotropic: bool = False):
    """Draw one view's (translation (3,), scale factors (3,), rotation (3, 3)), in that order (9 uniforms)."""
    dt = rng.uniform(-cfg.translation_m, cfg.translation_m, 3)
    e = rng.uniform(cfg.scale_range[0], cfg.scale_range[1], 3)
    if isotropic:
        e = np.full(3, e[0])
    ang = np.deg2rad(rng.uniform(cfg.angle_range_deg[0], cfg.angle_range_deg[1], 3))
    return dt, e, euler_xyz(*ang)


def view_transform(R: np.ndarray | None, centroid: np.ndarray, dt: np.ndarray, e: np.ndarray, dR: np.ndarray):
    """The view's affine map y = dS @ dR @ x + dT, returned as (dR, dS, dT) (float64).

    ``y = dS dR (x - c) + c + dt`` with dS = diag(e) (``R`` None: camera axes)
    or dS = R' diag(e) R'^T with R' = dR R (scale along the object's axes; then
    dS dR = dR R diag(e) R^T). dT = c + dt - dS dR c. Inverse:
    x = dR^T dS^-1 (y - dT).
    """
    if R is None:
        dS = np.diag(e)
    else:
        Rv = dR @ R
        dS = Rv @ np.diag(e) @ Rv.T
    dT = centroid + dt - dS @ dR @ centroid
    return dR, dS, dT


def color_jitter(rgb: np.ndarray, rng: np.random.Generator, cfg: AugmentConfig) -> np.ndarray:
    """Brightness, contrast, saturation, hue (fixed order) on float RGB in [0, 255]; draws 4 uniforms.

    Factors b, c, s ~ U(1 - x, 1 + x), hue shift h ~ U(-hue, hue) turns (a
    rotation of the chroma plane in YIQ space); clipped to [0, 255] after each step.
    """
    b, c, s = rng.uniform(1 - cfg.brightness, 1 + cfg.brightness), rng.uniform(1 - cfg.contrast, 1 + cfg.contrast), rng.uniform(1 - cfg.saturation, 1 + cfg.saturation)
    h = rng.uniform(-cfg.hue, cfg.hue)
    x = np.clip(rgb * b, 0, 255)
    gray = x @ np.array([0.299, 0.587, 0.114])
    x = np.clip((x - gray.mean()) * c + gray.mean(), 0, 255)
    gray = (x @ np.array([0.299, 0.587, 0.114]))[..., None]
    x = np.clip((x - gray) * s + gray, 0, 255)
    to_yiq = np.array([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
    th = 2 * math.pi * h
    rot = np.array([[1, 0, 0], [0, math.cos(th), -math.sin(th)], [0, math.sin(th), math.cos(th)]])
    m = np.linalg.inv(to_yiq) @ rot @ to_yiq
    return np.clip(x @ m.T, 0, 255)


def _dilate_axis(m: np.ndarray, r: int, axis: int) -> np.ndarray:
    """OR of ``m`` shifted by -r..r along ``axis`` (outside the array: False)."""
    n = m.shape[axis]
    pad = [(r, r) if a == axis else (0, 0) for a in range(m.ndim)]
    p = np.pad(m, pad)
    out = np.zeros_like(m)
    for k in range(2 * r + 1):
        out |= np.take(p, np.arange(k, k + n), axis=axis)
    return out


def perturb_mask(mask: np.ndarray, radius: int, dy: int, dx: int) -> np.ndarray:
    """``mask`` (H, W) bool dilated (radius > 0) or eroded (radius < 0) by a
    (2|radius| + 1)-square, then shifted by (dy, dx) pixels (rows, columns; False enters).

    Dilation treats the outside of the array as background, erosion as mask (so a mask
    cut by the window is not eroded from the cut).
    """
    m = np.asarray(mask, bool)
    r = abs(int(radius))
    if radius > 0:
        m = _dilate_axis(_dilate_axis(m, r, 0), r, 1)
    elif radius < 0:
        m = ~_dilate_axis(_dilate_axis(~m, r, 0), r, 1)
    h, w = m.shape
    out = np.zeros_like(m)
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = m[ys, xs]
    return out


def perturbed_pixels(prep: PreparedInstance, rng, cfg: AugmentConfig):
    """Valid pixels of a perturbed mask; draws 1 uniform and 3 integers whatever it returns.

    Returns None (use the instance's own pixels) when the draw keeps the mask (probability
    1 - ``mask_perturb``) or the perturbed mask has at most 16 valid pixels; else
    ``(choose, depth, nocs_pos)``: row-major crop indices of perturbed mask AND depth > 0
    (ascending), their raw depths, and for each the index of the same pixel in
    ``prep.choose_all`` (its NOCS map value) or -1 for a pixel off the instance.
    """
    u = rng.random()
    radius = int(rng.integers(-cfg.mask_erode_px, cfg.mask_dilate_px + 1))
    dy, dx = (int(v) for v in rng.integers(-cfg.mask_shift_px, cfg.mask_shift_px + 1, 2))
    if prep.mask_crop is None or prep.depth_crop is None:
        raise ValueError("mask perturbation needs the crop window's depth and mask (prepare_instance(keep_crop=True))")
    if u >= cfg.mask_perturb:
        return None
    valid = perturb_mask(prep.mask_crop, radius, dy, dx) & (prep.depth_crop > 0)
    choose = np.flatnonzero(valid).astype(np.int64)
    if choose.size <= MIN_VALID_PIXELS:
        return None
    depth = prep.depth_crop.reshape(-1)[choose]
    k = prep.choose_all.size
    pos = np.minimum(np.searchsorted(prep.choose_all, choose), max(k - 1, 0))
    inside = (k > 0) & (prep.choose_all[pos] == choose) if k else np.zeros(choose.size, bool)
    return choose, depth, np.where(inside, pos, -1)


# ---------------------------------------------------------------------- sample


def make_sample(
    prep: PreparedInstance,
    n_points: int,
    crop_size: int,
    rng: np.random.Generator,
    augment: AugmentConfig | None = None,
) -> dict:
    """The random part of preprocessing: a dict of tensors for one instance.

    RNG draws, in order: with ``augment.mask_perturb > 0``, the mask perturbation
    (:func:`perturbed_pixels`: 1 uniform, 3 integers); point sampling
    (:func:`sample_indices`); if ``augment``: colour jitter (4 uniforms, when
    enabled), then per view translation (3), scale (3), angles (3). Points of a
    perturbed mask off the instance get the pose's NOCS R^T (p - t) / |s| (so the
    heatmap's keypoint target stays that of the pose), the others the map's.

    Keys: ``rgb`` (3, S, S) float32, ``pts`` (N, 3) float32 camera frame,
    ``choose`` (N,) int64 on the S x S grid, ``nocs`` (N, 3) float32 (NOCS
    minus 0.5; zeros without a NOCS map), ``R`` (3, 3), ``t`` (3,), ``s`` (3,),
    ``class_id`` int64 (0-based), ``handle_visible`` bool, ``sym`` bool
    (rotational symmetry about y: bottle/bowl/can, mug with hidden handle).
    With ``augment`` (see :class:`AugmentConfig`): ``aug_R`` (V, 3, 3),
    ``aug_S`` (V, 3, 3), ``aug_T`` (V, 3) with view points
    ``aug_pts[v] = aug_S[v] @ aug_R[v] @ pts + aug_T[v]`` (V, N, 3), the
    drawn factors ``aug_scale`` (V, 3) and translation ``aug_dt`` (V, 3) (the
    model's centred convention: P^v = aug_scale * (aug_R P) + aug_dt with
    P = pts - centroid, camera axes); with ``scale_axes="object"`` also the
    exact view targets ``aug_gt_R`` (V, 3, 3), ``aug_gt_t`` (V, 3),
    ``aug_gt_s`` (V, 3), ``aug_nocs`` (V, N, 3).
    """
    inst = prep.instance
    pert = perturbed_pixels(prep, rng, augment) if augment is not None and augment.mask_perturb > 0 else None
    if pert is None:
        idx = sample_indices(prep.n_valid, n_points, rng)
        choose = prep.choose_all[idx]
        pts64 = backproject(choose, prep.depth_all[idx], prep.window, prep.intrinsics, prep.depth_scale_m)
        if prep.nocs_all is not None:
            nocs = (prep.nocs_all[idx].astype(np.float64) / 65535.0 - 0.5).astype(np.float32)
        else:
            nocs = np.zeros((n_points, 3), np.float32)
    else:
        p_choose, p_depth, p_pos = pert
        idx = sample_indices(p_choose.size, n_points, rng)
        choose = p_choose[idx]
        pts64 = backproject(choose, p_depth[idx], prep.window, prep.intrinsics, prep.depth_scale_m)
        # R^T (p - t) / |s| as rows: (p - t) @ R
        nocs64 = (pts64.astype(np.float64) - inst.t) @ inst.R / np.linalg.norm(inst.s)
        pos = p_pos[idx]
        on = pos >= 0
        if prep.nocs_all is not None and on.any():
            nocs64[on] = prep.nocs_all[pos[on]].astype(np.float64) / 65535.0 - 0.5
        nocs = nocs64.astype(np.float32)
    rgb = resize_bilinear(prep.rgb_crop, crop_size)
    if augment is not None and augment.color_jitter:
        rgb = color_jitter(rgb, rng, augment)
    out = {
        "rgb": torch.from_numpy(normalise_rgb(rgb)),
        "pts": torch.from_numpy(pts64),
        "choose": torch.from_numpy(remap_choose(choose, prep.side, crop_size).astype(np.int64)),
        "nocs": torch.from_numpy(nocs),
        "R": torch.from_numpy(inst.R.astype(np.float32)),
        "t": torch.from_numpy(inst.t.astype(np.float32)),
        "s": torch.from_numpy(inst.s.astype(np.float32)),
        "class_id": torch.tensor(inst.class_id, dtype=torch.int64),
        "handle_visible": torch.tensor(inst.handle_visible),
        "sym": torch.tensor(inst.cls in ("bottle", "bowl", "can") or (inst.cls == "mug" and not inst.handle_visible)),
    }
    if augment is not None:
        x = pts64.astype(np.float64)
        c = x.mean(axis=0)
        obj = augment.scale_axes == "object"
        keys = ["aug_R", "aug_S", "aug_T", "aug_pts", "aug_scale", "aug_dt"]
        if obj:
            keys += ["aug_gt_R", "aug_gt_t", "aug_gt_s", "aug_nocs"]
        acc = {k: [] for k in keys}
        p_obj = nocs.astype(np.float64) * np.linalg.norm(inst.s)  # metric object-frame coordinates
        for v in range(augment.n_views):
            dt, e, rot = draw_view(rng, augment, v in augment.isotropic_views)
            dR, dS, dT = view_transform(inst.R if obj else None, c, dt, e, rot)
            A = dS @ dR
            vals = [dR, dS, dT, x @ A.T + dT, e, dt]
            if obj:
                s_v = inst.s * e
                vals += [dR @ inst.R, A @ inst.t + dT, s_v, p_obj * e / np.linalg.norm(s_v)]
            for k, val in zip(keys, vals):
                acc[k].append(val)
        for k in keys:
            out[k] = torch.from_numpy(np.stack(acc[k]).astype(np.float32))
    return out


# --------------------------------------------------------------------- dataset


@dataclass(frozen=True)
class InstanceRef:
    """Where one annotated instance lives: recording index, frame index, position in gt.json."""

    rec: int
    frame: int
    pos: int


def _load_npz(path: Path):
    """``np.load`` of a cached .npz read whole first: one read instead of a few per array
    (the same arrays; about a quarter faster per frame from the page cache)."""
    return np.load(io.BytesIO(path.read_bytes()))


class InstanceDataset(Dataset):
    """All annotated instances of one or more recordings, one sample each.

    ``dataset[i]`` is :func:`make_sample` of instance ``i`` with the RNG
    ``numpy.random.default_rng((seed, epoch, i))`` (set ``epoch`` with
    :meth:`set_epoch`). An instance with at most 16 valid pixels (mask AND
    depth > 0 in its crop) is replaced by the next usable index (cyclically),
    as AG-Pose does; :attr:`skipped` counts them as they are found.

    Frames are decoded when first needed; the deterministic per-instance data
    is kept in memory (``cache=True``) and, with ``cache_dir``, in ``.npz``
    files keyed by recording, frame and file sizes/mtimes.
    """

    def __init__(
        self,
        recordings: Sequence[str | os.PathLike | Recording],
        n_points: int = 1024,
        crop_size: int = 192,
        seed: int = 0,
        augment: AugmentConfig | None = None,
        cache: bool = True,
        cache_dir: str | os.PathLike | None = None,
    ):
        # tricons recordings, NOCS scenes, or NOCS split directories (one recording per scene)
        self.recordings = [rec for r in recordings for rec in open_any(r)]
        self.n_points = n_points
        self.crop_size = crop_size
        self.seed = seed
        self.augment = augment
        self.epoch = 0
        self.cache = cache
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._mem: dict[tuple[int, int], list[PreparedInstance | None]] = {}
        self._anns: dict[tuple[int, int], list[Instance]] = {}
        # mask perturbation needs each crop window's depth and mask (a second cache file)
        self.keep_crop = augment is not None and augment.mask_perturb > 0
        self.skipped: set[int] = set()
        self.index: list[InstanceRef] = []
        for ri, rec in enumerate(self.recordings):
            for fi in range(len(rec)):
                ann = rec.annotations(fi)
                if ann is None or ann.mask is None:
                    continue
                self._anns[(ri, fi)] = ann.instances
                self.index.extend(InstanceRef(ri, fi, k) for k in range(len(ann.instances)))
        if not self.index:
            raise RecordingError("no annotated instances (with masks) in " + ", ".join(str(r.root) for r in self.recordings))

    def __len__(self) -> int:
        return len(self.index)

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch part of the per-sample RNG seed."""
        self.epoch = int(epoch)

    def _cache_path(self, ri: int, fi: int) -> Path | None:
        if self.cache_dir is None:
            return None
        rec = self.recordings[ri]
        fr = rec.frames[fi]
        ann = rec.annotations(fi)
        key = [str(rec.root.resolve()), fr.id]
        for name in (fr.color, fr.depth, fr.annotations, ann.mask, ann.nocs):
            if name is not None:
                st = (rec.root / name).stat()
                key.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
        h = hashlib.sha256("\n".join(key).encode()).hexdigest()[:24]
        return self.cache_dir / f"{h}.npz"

    def _load_frame(self, ri: int, fi: int) -> list[PreparedInstance | None]:
        rec = self.recordings[ri]
        insts = self._anns[(ri, fi)]
        cpath = self._cache_path(ri, fi)
        if cpath is not None and cpath.exists():
            try:
                preps = self._from_npz(cpath, rec, insts)
            except Exception:  # corrupt or stale cache entry: rebuild it
                preps = None
            if preps is not None:
                if self.keep_crop:
                    self._add_crops(ri, fi, preps, cpath.with_name(cpath.stem + ".crop.npz"))
                return preps
        ann = rec.annotations(fi)
        mask = rec.mask(fi, ann)
        depth = rec.depth_raw(fi)
        color = rec.color(fi)
        nocs = rec.nocs_raw(fi, ann)
        preps = [prepare_instance(color, depth, mask, nocs, inst, rec.intrinsics, rec.depth_scale_m, self.keep_crop)
                 for inst in insts]
        if cpath is not None:
            self._to_npz(cpath, preps)
            if self.keep_crop:
                self._save_crops(cpath.with_name(cpath.stem + ".crop.npz"), preps)
        return preps

    def _add_crops(self, ri: int, fi: int, preps: list[PreparedInstance | None], path: Path) -> None:
        """Fill ``depth_crop`` / ``mask_crop`` of cached instances from ``path``, or from the
        frame's depth and mask images (then written to ``path``)."""
        if path.exists():
            try:
                with _load_npz(path) as z:
                    for k, p in enumerate(preps):
                        if p is not None:
                            p.depth_crop, p.mask_crop = z[f"{k}_depthcrop"], z[f"{k}_maskcrop"]
                return
            except Exception:  # corrupt or stale: rebuild it
                pass
        rec = self.recordings[ri]
        ann = rec.annotations(fi)
        mask, depth = rec.mask(fi, ann), rec.depth_raw(fi)
        insts = self._anns[(ri, fi)]
        for p, inst in zip(preps, insts):
            if p is not None:
                rmin, rmax, cmin, cmax = p.window
                p.depth_crop = np.ascontiguousarray(depth[rmin:rmax, cmin:cmax]).astype(np.uint16)
                p.mask_crop = np.ascontiguousarray(mask[rmin:rmax, cmin:cmax] == inst.id)
        self._save_crops(path, preps)

    @staticmethod
    def _save_crops(path: Path, preps: list[PreparedInstance | None]) -> None:
        arrays = {}
        for k, p in enumerate(preps):
            if p is not None and p.depth_crop is not None:
                arrays[f"{k}_depthcrop"] = p.depth_crop
                arrays[f"{k}_maskcrop"] = p.mask_crop
        InstanceDataset._write_npz(path, arrays)

    @staticmethod
    def _to_npz(path: Path, preps: list[PreparedInstance | None]) -> None:
        arrays = {}
        for k, p in enumerate(preps):
            if p is None:
                continue
            arrays[f"{k}_window"] = np.array(p.window, np.int64)
            arrays[f"{k}_rgb"] = p.rgb_crop
            arrays[f"{k}_choose"] = p.choose_all
            arrays[f"{k}_depth"] = p.depth_all
            if p.nocs_all is not None:
                arrays[f"{k}_nocs"] = p.nocs_all
        InstanceDataset._write_npz(path, arrays)

    @staticmethod
    def _write_npz(path: Path, arrays: dict) -> None:
        """``np.savez`` to a temporary file, then renamed over ``path``."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)

    @staticmethod
    def _from_npz(path: Path, rec: Recording, insts: list[Instance]) -> list[PreparedInstance | None]:
        out: list[PreparedInstance | None] = []
        with _load_npz(path) as z:
            for k, inst in enumerate(insts):
                if f"{k}_window" not in z:
                    out.append(None)
                    continue
                out.append(
                    PreparedInstance(
                        tuple(int(v) for v in z[f"{k}_window"]),
                        z[f"{k}_rgb"],
                        z[f"{k}_choose"],
                        z[f"{k}_depth"],
                        z[f"{k}_nocs"] if f"{k}_nocs" in z else None,
                        inst,
                        rec.depth_scale_m,
                        rec.intrinsics,
                    )
                )
        return out

    def prepared(self, i: int) -> PreparedInstance | None:
        """Deterministic preprocessing of instance ``i`` (None if its mask is empty)."""
        ref = self.index[i]
        key = (ref.rec, ref.frame)
        preps = self._mem.get(key)
        if preps is None:
            preps = self._load_frame(*key)
            if self.cache:
                self._mem[key] = preps
        return preps[ref.pos]

    def usable_index(self, i: int) -> int:
        """``i`` or the next index (cyclically) whose instance has > 16 valid pixels."""
        for k in range(len(self)):
            j = (i + k) % len(self)
            p = self.prepared(j)
            if p is not None and p.n_valid > MIN_VALID_PIXELS:
                return j
            self.skipped.add(j)
        raise RecordingError("no instance with more than 16 valid pixels")

    def __getitem__(self, i: int) -> dict:
        if not 0 <= i < len(self):
            raise IndexError(i)
        j = self.usable_index(i)
        rng = np.random.default_rng((self.seed, self.epoch, i))
        out = make_sample(self.prepared(j), self.n_points, self.crop_size, rng, self.augment)
        out["index"] = torch.tensor(j, dtype=torch.int64)
        return out

    def describe(self, i: int) -> str:
        """Human-readable location of instance ``i``."""
        ref = self.index[i]
        rec = self.recordings[ref.rec]
        inst = self._anns[(ref.rec, ref.frame)][ref.pos]
        return f"{rec.root}/{rec.frames[ref.frame].id} instance {inst.id} ({inst.cls})"


def split_batch(batch: dict) -> tuple[dict, dict | None, dict]:
    """Split a collated batch into (inputs, aug, targets) for ``forward_train(inputs, aug)``.

    inputs: rgb, pts, choose, class_id (read only by a ``nocs_per_class``
    model). aug (None without augmentation): the ``aug_``
    keys without the prefix ((B, V, ...) each), plus the model's
    ``forward_train`` keys ``dR`` = R, ``dS`` = scale, ``dT`` = dt (centred
    cloud, camera axes; meaningful for ``scale_axes="camera"``). targets: R,
    t, s, nocs, class_id, handle_visible, sym.
    """
    inputs = {k: batch[k] for k in ("rgb", "pts", "choose", "class_id")}
    aug = {k[4:]: v for k, v in batch.items() if k.startswith("aug_")} or None
    if aug is not None:
        aug.update(dR=aug["R"], dS=aug["scale"], dT=aug["dt"])
    targets = {k: batch[k] for k in ("R", "t", "s", "nocs", "class_id", "handle_visible", "sym")}
    return inputs, aug, targets


__all__ = [
    "CLASSES",
    "AugmentConfig",
    "InstanceDataset",
    "PreparedInstance",
    "backproject",
    "crop_side",
    "crop_window",
    "euler_xyz",
    "make_sample",
    "mask_bbox",
    "normalise_rgb",
    "prepare_instance",
    "remap_choose",
    "resize_bilinear",
    "sample_indices",
    "split_batch",
    "view_transform",
]
