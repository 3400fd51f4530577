"""Continuous 6D rotation representation (Zhou et al. 2019), AG-Pose convention.

The 6D vector is ``[x_raw (3), y_raw (3)]``. The *second* vector fixes the y
column: ``y = y_raw / |y_raw|``; ``z = normalise(x_raw x y)``; ``x = y x z``. The
rotation matrix has columns ``[x y z]``. The inverse map takes the first two
columns of R: ``[R[:, 0], R[:, 1]]``.
"""
from __future__ import annotations

import torch

_EPS = 1e-8


def _normalise(v: torch.Tensor) -> torch.Tensor:
    # clamp like AG-Pose (max(|v|, 1e-8)); written with sqrt/clamp only (exportable)
    n = torch.sqrt((v * v).sum(dim=-1, keepdim=True)).clamp(min=_EPS)
    return v / n


def rotation_matrix_from_6d(d6: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3) rotation matrices with columns [x y z].

    y = normalise(d6[..., 3:6]); z = normalise(cross(d6[..., 0:3], y)); x = cross(y, z).
    The result is orthonormal with det +1 whenever x_raw is not parallel to y_raw.
    """
    x_raw = d6[..., 0:3]
    y = _normalise(d6[..., 3:6])
    z = _normalise(torch.cross(x_raw, y, dim=-1))
    x = torch.cross(y, z, dim=-1)
    return torch.stack((x, y, z), dim=-1)


def rotation_6d_from_matrix(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): first two columns, ``[R[..., :, 0], R[..., :, 1]]``.

    ``rotation_matrix_from_6d(rotation_6d_from_matrix(R)) == R`` for any rotation R.
    """
    return torch.cat((R[..., :, 0], R[..., :, 1]), dim=-1)
