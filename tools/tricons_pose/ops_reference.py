"""Brute-force numpy references of the ``tricons`` custom operators.

Written straight from the definitions in ``tools/CONTRACT.md`` with plain loops
(slow; for tests and for the ONNX reference evaluator on small inputs). They
use the same floating-point formulas as ``ops.py`` and the Rust runtime:

* squared distance ``(dx*dx + dy*dy) + dz*dz`` with ``d = a - b`` in the input
  dtype (float32 stays float32), so index results are bit-exact;
* ties -> lower index; int64 indices, base 0.
"""
from __future__ import annotations

import math

import numpy as np

#: Must equal ``ops.TRIANGLE_NORM_EPS2``.
TRIANGLE_NORM_EPS2 = 1e-12


def _sqdist(a: np.ndarray, b: np.ndarray):
    """Squared distance of two 3-vectors in their dtype, fixed summation order."""
    dx = a[0] - b[0]
    dy = a[1] - b[1]
    dz = a[2] - b[2]
    return (dx * dx + dy * dy) + dz * dz


def furthest_point_sample(xyz: np.ndarray, npoint: int) -> np.ndarray:
    """(B, N, 3) -> (B, npoint) int64; start at 0, greedy max-min distance, ties -> lowest index."""
    B, N, _ = xyz.shape
    out = np.zeros((B, npoint), dtype=np.int64)
    for b in range(B):
        if N == 0:
            continue
        mind = [math.inf] * N
        cur = 0
        for i in range(npoint):
            out[b, i] = cur
            best, besti = -1.0, 0
            for n in range(N):
                d = _sqdist(xyz[b, n], xyz[b, cur])
                if d < mind[n]:
                    mind[n] = d
                if mind[n] > best:  # strict: the first maximum wins
                    best, besti = mind[n], n
            cur = besti
    return out


def gather_points(features: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(B, C, N), (B, S) -> (B, C, S): out[b,c,s] = features[b,c,idx[b,s]]."""
    B, C, _ = features.shape
    S = idx.shape[1]
    out = np.zeros((B, C, S), dtype=features.dtype)
    for b in range(B):
        for s in range(S):
            out[b, :, s] = features[b, :, idx[b, s]]
    return out


def ball_query(xyz: np.ndarray, new_xyz: np.ndarray, radius: float, nsample: int) -> np.ndarray:
    """(B, N, 3), (B, S, 3) -> (B, S, nsample) int64.

    First nsample indices (index order) with d^2 < r^2 (r cast to the input
    dtype, r*r in that dtype), padded with the first hit; no hit -> all 0.
    """
    B, N, _ = xyz.shape
    S = new_xyz.shape[1]
    r = xyz.dtype.type(radius)
    r2 = r * r
    out = np.zeros((B, S, nsample), dtype=np.int64)
    for b in range(B):
        for s in range(S):
            hits = []
            for n in range(N):
                if _sqdist(new_xyz[b, s], xyz[b, n]) < r2:
                    hits.append(n)
                    if len(hits) == nsample:
                        break
            if hits:
                hits = hits + [hits[0]] * (nsample - len(hits))
                out[b, s, :] = hits
    return out


def group_points(features: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(B, C, N), (B, S, K) -> (B, C, S, K): out[b,c,s,k] = features[b,c,idx[b,s,k]]."""
    B, C, _ = features.shape
    _, S, K = idx.shape
    out = np.zeros((B, C, S, K), dtype=features.dtype)
    for b in range(B):
        for s in range(S):
            for k in range(K):
                out[b, :, s, k] = features[b, :, idx[b, s, k]]
    return out


def _knn(query: np.ndarray, points: np.ndarray, k: int):
    """k nearest of one query among (N, 3): list of (d2, index), ascending, ties -> lower index."""
    pairs = [(_sqdist(query, points[n]), n) for n in range(points.shape[0])]
    pairs.sort(key=lambda t: (t[0], t[1]))
    return pairs[:k]


def three_nn(unknown: np.ndarray, known: np.ndarray):
    """(B, n, 3), (B, m, 3) -> dist (B, n, 3) = sqrt(d^2) ascending, idx (B, n, 3) int64."""
    B, n, _ = unknown.shape
    dist = np.zeros((B, n, 3), dtype=unknown.dtype)
    idx = np.zeros((B, n, 3), dtype=np.int64)
    for b in range(B):
        for j in range(n):
            for t, (d2, i) in enumerate(_knn(unknown[b, j], known[b], 3)):
                dist[b, j, t] = np.sqrt(d2)
                idx[b, j, t] = i
    return dist, idx


def three_interpolate(features: np.ndarray, idx: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(B, C, m), (B, n, 3), (B, n, 3) -> (B, C, n): sum_k features[b,c,idx[b,j,k]] * weight[b,j,k]."""
    B, C, _ = features.shape
    n = idx.shape[1]
    out = np.zeros((B, C, n), dtype=features.dtype)
    for b in range(B):
        for j in range(n):
            acc = np.zeros((C,), dtype=features.dtype)
            for k in range(3):
                acc = acc + features[b, :, idx[b, j, k]] * weight[b, j, k]
            out[b, :, j] = acc
    return out


def _angle(u, v) -> float:
    """Angle between u and v from the clipped cosine with epsilon norms (float64)."""
    nu = math.sqrt(float(np.dot(u, u)) + TRIANGLE_NORM_EPS2)
    nv = math.sqrt(float(np.dot(v, v)) + TRIANGLE_NORM_EPS2)
    c = float(np.dot(u, v)) / (nu * nv)
    return math.acos(min(1.0, max(-1.0, c)))


def triangle_descriptor(query: np.ndarray, points: np.ndarray, k: int):
    """(B, M, 3), (B, N, 3), k -> phi (B, M, k(k-1)/2, 3), knn_idx (B, M, k) int64.

    kNN on squared distance in the input dtype (ties -> lower index); geometry
    evaluated in float64, phi returned in the input dtype.
    """
    B, M, _ = query.shape
    T = k * (k - 1) // 2
    phi = np.zeros((B, M, T, 3), dtype=np.float64)
    knn = np.zeros((B, M, k), dtype=np.int64)
    for b in range(B):
        for i in range(M):
            nbr = [n for _, n in _knn(query[b, i], points[b], k)]
            knn[b, i] = nbr
            p = query[b, i].astype(np.float64)
            angles, areas = [], []
            for a in range(k):
                for c in range(a + 1, k):
                    qa = points[b, nbr[a]].astype(np.float64)
                    qb = points[b, nbr[c]].astype(np.float64)
                    angles.append((_angle(qa - p, qb - p), _angle(p - qa, qb - qa), _angle(p - qb, qa - qb)))
                    areas.append(0.5 * float(np.linalg.norm(np.cross(qa - p, qb - p))))
            if T == 0:
                continue
            e = np.exp(np.array(areas) - max(areas))
            w = e / e.sum()
            phi[b, i] = w[:, None] * np.array(angles)
    return phi.astype(query.dtype), knn
