"""The custom operators written with standard ONNX ops only, for runtimes without ``ai.tricons``.

``python -m tricons_pose.export --standard-ops`` exports the network inside
:func:`standard_ops`, which swaps the ``torch.library`` ops for these traceable
pure-torch forms, so the graph runs in onnxruntime (or any ONNX runtime) and the
benchmark can compare tract with onnxruntime on the same network. Same
semantics as the custom nodes (``onnx_export_ops``) except that ties in the
k-nearest searches follow the runtime's TopK, and:

* FurthestPointSample is unrolled: one small group of nodes per sample (the graph
  grows with ``npoint``);
* the triangle descriptor's acos runs in float32 (onnxruntime has no float64
  Acos; the rest of its geometry stays float64): ~1e-4 rad off for near-degenerate
  triangles;
* BallQuery and the k-NN searches build the full (B, S, N) distance matrix and
  take TopK, which is what a general-purpose runtime can do without a custom kernel.

Forward only (inference); not for training.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch
from torch import Tensor

from . import model as _model
from . import ops as _ops
from . import pointnet2 as _pointnet2
from .ops import triangle_descriptor_torch


def _sqdist(a: Tensor, b: Tensor) -> Tensor:
    """(B, S, 3), (B, N, 3) -> (B, S, N) as ``(dx*dx + dy*dy) + dz*dz``."""
    d = a.unsqueeze(2) - b.unsqueeze(1)
    return (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]


def furthest_point_sample(xyz: Tensor, npoint: int) -> Tensor:
    """FPS as ``npoint`` unrolled steps of min/argmax (first maximum: lowest index)."""
    mind = torch.full_like(xyz[..., 0], float("inf"))                   # (B, N)
    far = torch.zeros_like(xyz[:, 0, 0], dtype=torch.int64)             # (B,)
    picks = []
    for _ in range(int(npoint)):
        picks.append(far)
        c = torch.gather(xyz, 1, far.view(-1, 1, 1).expand(-1, 1, 3))  # (B, 1, 3)
        d = xyz - c
        mind = torch.minimum(mind, (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2])
        far = torch.argmax(mind, dim=1)
    return torch.stack(picks, dim=1)


def gather_points(features: Tensor, idx: Tensor) -> Tensor:
    """(B, C, N), (B, S) -> (B, C, S) (GatherElements)."""
    return torch.gather(features, 2, idx.unsqueeze(1).expand(-1, features.shape[1], -1))


def group_points(features: Tensor, idx: Tensor) -> Tensor:
    """(B, C, N), (B, S, K) -> (B, C, S, K)."""
    s, k = idx.shape[1], idx.shape[2]
    flat = idx.reshape(idx.shape[0], 1, s * k).expand(-1, features.shape[1], -1)
    return torch.gather(features, 2, flat).reshape(features.shape[0], features.shape[1], s, k)


def ball_query(xyz: Tensor, new_xyz: Tensor, radius: float, nsample: int) -> Tensor:
    """The first ``nsample`` indices within ``radius`` (strict) in index order, unfilled
    slots repeating the first hit, no hit -> 0: TopK of the smallest keys
    ``where(inside, n, N)``."""
    r = torch.tensor(float(radius), dtype=torch.float32)
    d2 = _sqdist(new_xyz, xyz)                                          # (B, S, N)
    n = xyz.shape[1]
    ar = torch.arange(n, dtype=torch.int64)
    key = torch.where(d2 < r * r, ar, torch.full_like(ar, n))
    vals, _ = torch.topk(key, int(nsample), dim=-1, largest=False, sorted=True)
    first = vals[..., :1]
    first = torch.where(first == n, torch.zeros_like(first), first)
    return torch.where(vals == n, first.expand_as(vals), vals)


def three_nn(unknown: Tensor, known: Tensor) -> tuple[Tensor, Tensor]:
    """The 3 nearest known points: (distance, index), ascending."""
    vals, idx = torch.topk(_sqdist(unknown, known), 3, dim=-1, largest=False, sorted=True)
    return torch.sqrt(vals), idx


def three_interpolate(features: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    """(B, C, m), (B, n, 3), (B, n, 3) -> (B, C, n)."""
    g = group_points(features, idx)                                     # (B, C, n, 3)
    w = weight.unsqueeze(1)
    return (g[..., 0] * w[..., 0] + g[..., 1] * w[..., 1]) + g[..., 2] * w[..., 2]


def triangle_descriptor(query: Tensor, points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """k-NN by TopK, then the pure-torch descriptor (float64 geometry, as the custom node)."""
    _, idx = torch.topk(_sqdist(query, points), int(k), dim=-1, largest=False, sorted=True)
    return triangle_descriptor_torch(query, points, idx), idx


def _safe_acos(x: Tensor) -> Tensor:
    """acos(clip(x, -1, 1)) evaluated in float32 (forward only)."""
    return torch.acos(torch.clamp(x, -1.0, 1.0).to(torch.float32)).to(x.dtype)


_SWAPS = {
    _ops: ("_safe_acos",),
    _pointnet2: ("furthest_point_sample", "gather_points", "ball_query", "group_points", "three_nn",
                 "three_interpolate"),
    _model: ("group_points", "triangle_descriptor"),
}


@contextlib.contextmanager
def standard_ops() -> Iterator[None]:
    """Within this context the network calls the standard-op forms above."""
    saved = {(mod, name): getattr(mod, name) for mod, names in _SWAPS.items() for name in names}
    try:
        for mod, name in saved:
            setattr(mod, name, globals()[name])
        yield
    finally:
        for (mod, name), fn in saved.items():
            setattr(mod, name, fn)


__all__ = ["standard_ops", "furthest_point_sample", "gather_points", "group_points", "ball_query", "three_nn",
           "three_interpolate", "triangle_descriptor"]
