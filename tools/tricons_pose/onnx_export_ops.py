"""ONNX export of the ``tricons`` custom operators (domain ``ai.tricons``, version 1).

Two parts:

* :func:`register_symbolics` registers TorchScript-exporter symbolics (opset 17)
  so that ``torch.onnx.export(..., dynamo=False, opset_version=17,
  custom_opsets={"ai.tricons": 1})`` turns every ``tricons::*`` op into one
  node of domain ``ai.tricons``.
* :func:`reference_ops` returns ``onnx.reference.op_run.OpRun`` classes that
  evaluate those nodes with the numpy references (``ops_reference``), for
  ``onnx.reference.ReferenceEvaluator(model, new_ops=reference_ops())``.

Node table (what the Rust runtime implements). All float tensors are float32
in exported models (the torch ops also accept float64); all index tensors are
int64, base 0; layouts are row-major as written. B, N, S, n, m, M are dynamic.
Squared distances are ``(dx*dx + dy*dy) + dz*dz`` with ``d = a - b`` evaluated
in float32 without fused multiply-add; ties in distance go to the lower index.

=====================  ==================================  ==============================  ====================================
node (ai.tricons)      inputs                              attributes                      outputs
=====================  ==================================  ==============================  ====================================
FurthestPointSample    xyz f32 (B,N,3)                     npoint: int                     idx i64 (B,npoint)
GatherPoints           features f32 (B,C,N),               -                               out f32 (B,C,S)
                       idx i64 (B,S)
BallQuery              xyz f32 (B,N,3),                    radius: float, nsample: int     idx i64 (B,S,nsample)
                       new_xyz f32 (B,S,3)
GroupPoints            features f32 (B,C,N),               -                               out f32 (B,C,S,K)
                       idx i64 (B,S,K)
ThreeNN                unknown f32 (B,n,3),                -                               dist f32 (B,n,3), idx i64 (B,n,3)
                       known f32 (B,m,3), m >= 3
ThreeInterpolate       features f32 (B,C,m),               -                               out f32 (B,C,n)
                       idx i64 (B,n,3), weight f32 (B,n,3)
TriangleDescriptor     query f32 (B,M,3),                  k: int (1 <= k <= N)            phi f32 (B,M,k(k-1)/2,3),
                       points f32 (B,N,3)                                                  knn_idx i64 (B,M,k)
=====================  ==================================  ==============================  ====================================

Semantics per node:

* FurthestPointSample: ``idx[b,0] = 0``; keep ``mind[n]`` = min over chosen c of
  d^2(x_n, x_c) (initially +inf); next index = argmax_n mind[n], the first (lowest
  n) maximum on ties. With duplicate points, once every remaining distance is 0
  the argmax is 0, so 0 repeats. (Unlike the CUDA PointNet2 kernel, points
  near the origin are NOT skipped.)
* GatherPoints: ``out[b,c,s] = features[b,c,idx[b,s]]``.
* BallQuery: ``r2 = f32(radius) * f32(radius)``; for each centre, scan n = 0..N-1
  and take the indices with ``d^2(new_xyz[b,s], xyz[b,n]) < r2`` (strict) until
  nsample are found; unfilled slots repeat the first hit; no hit -> all 0.
* GroupPoints: ``out[b,c,s,k] = features[b,c,idx[b,s,k]]``.
* ThreeNN: the 3 smallest d^2 (ascending, ties -> lower index); ``dist = sqrt(d^2)``.
* ThreeInterpolate: ``out[b,c,j] = (f0*w0 + f1*w1) + f2*w2`` with
  ``fk = features[b,c,idx[b,j,k]]``, ``wk = weight[b,j,k]``.
* TriangleDescriptor: knn_idx = the k smallest d^2(query_i, points_n)
  (ascending, ties -> lower index, a point equal to the query is kept).
  Triangles t over pairs (a, b), a < b, row-major: t = 0 is (0,1), then (0,2) ..
  (0,k-1), (1,2) ... With p = query_i, qa = points[knn_idx[a]], qb = points[knn_idx[b]]:
  ``ang(u, v) = acos(clip(dot(u,v) / (sqrt(u.u + 1e-12) * sqrt(v.v + 1e-12)), -1, 1))``,
  alpha = ang(qa-p, qb-p), beta = ang(p-qa, qb-qa), gamma = ang(p-qb, qa-qb);
  area = |(qa-p) x (qb-p)| / 2; w = softmax over t of area;
  ``phi[b,i,t,:] = w_t * (alpha, beta, gamma)``. k = 1 gives an empty phi (T = 0).
  The kNN compares float32 squared distances; the geometry (differences, dots,
  norms, acos, cross product, softmax) is evaluated in float64 from the float32
  inputs and phi is rounded to float32 at the end (acos near +-1 is
  ill-conditioned: float32 arithmetic is off by ~1e-4 rad for coincident points).
"""
from __future__ import annotations

import numpy as np
import torch
from onnx.reference.op_run import OpRun
from torch.onnx import symbolic_helper

from . import ops_reference as ref

DOMAIN = "ai.tricons"
OPSET = 17
DOMAIN_VERSION = 1
#: pass as ``custom_opsets=`` to ``torch.onnx.export``
CUSTOM_OPSETS = {DOMAIN: DOMAIN_VERSION}

#: torch op name -> ONNX node name
NODE_NAMES = {
    "tricons::furthest_point_sample": "FurthestPointSample",
    "tricons::gather_points": "GatherPoints",
    "tricons::ball_query": "BallQuery",
    "tricons::group_points": "GroupPoints",
    "tricons::three_nn": "ThreeNN",
    "tricons::three_interpolate": "ThreeInterpolate",
    "tricons::triangle_descriptor": "TriangleDescriptor",
}


# ---------------------------------------------------------------------------
# symbolics (TorchScript exporter)
# ---------------------------------------------------------------------------

def _sizes(v) -> list | None:
    """Known sizes of a graph value (None for dynamic dims), or None if the rank is unknown."""
    try:
        return symbolic_helper._get_tensor_sizes(v)
    except Exception:  # pragma: no cover - defensive
        return None


def _dim(sizes, i):
    return None if sizes is None or i >= len(sizes) else sizes[i]


def _set(out, like, dtype: torch.dtype, sizes: list) -> None:
    """Set the output's type (dtype and known dims) for ONNX shape inference / value_info."""
    try:
        out.setType(like.type().with_dtype(dtype).with_sizes(sizes))
    except Exception:  # pragma: no cover - type info is best effort
        pass


def _float_dtype(v) -> torch.dtype:
    st = symbolic_helper._try_get_scalar_type(v)
    return st.dtype() if st is not None else torch.float32


@symbolic_helper.parse_args("v", "i")
def _sym_fps(g, xyz, npoint):
    out = g.op(f"{DOMAIN}::FurthestPointSample", xyz, npoint_i=npoint)
    _set(out, xyz, torch.int64, [_dim(_sizes(xyz), 0), npoint])
    return out


@symbolic_helper.parse_args("v", "v")
def _sym_gather(g, features, idx):
    out = g.op(f"{DOMAIN}::GatherPoints", features, idx)
    f, i = _sizes(features), _sizes(idx)
    _set(out, features, _float_dtype(features), [_dim(f, 0), _dim(f, 1), _dim(i, 1)])
    return out


@symbolic_helper.parse_args("v", "v", "f", "i")
def _sym_ball_query(g, xyz, new_xyz, radius, nsample):
    out = g.op(f"{DOMAIN}::BallQuery", xyz, new_xyz, radius_f=radius, nsample_i=nsample)
    c = _sizes(new_xyz)
    _set(out, new_xyz, torch.int64, [_dim(c, 0), _dim(c, 1), nsample])
    return out


@symbolic_helper.parse_args("v", "v")
def _sym_group(g, features, idx):
    out = g.op(f"{DOMAIN}::GroupPoints", features, idx)
    f, i = _sizes(features), _sizes(idx)
    _set(out, features, _float_dtype(features), [_dim(f, 0), _dim(f, 1), _dim(i, 1), _dim(i, 2)])
    return out


@symbolic_helper.parse_args("v", "v")
def _sym_three_nn(g, unknown, known):
    dist, idx = g.op(f"{DOMAIN}::ThreeNN", unknown, known, outputs=2)
    u = _sizes(unknown)
    shape = [_dim(u, 0), _dim(u, 1), 3]
    _set(dist, unknown, _float_dtype(unknown), shape)
    _set(idx, unknown, torch.int64, shape)
    return dist, idx


@symbolic_helper.parse_args("v", "v", "v")
def _sym_three_interp(g, features, idx, weight):
    out = g.op(f"{DOMAIN}::ThreeInterpolate", features, idx, weight)
    f, i = _sizes(features), _sizes(idx)
    _set(out, features, _float_dtype(features), [_dim(f, 0), _dim(f, 1), _dim(i, 1)])
    return out


@symbolic_helper.parse_args("v", "v", "i")
def _sym_triangle(g, query, points, k):
    phi, idx = g.op(f"{DOMAIN}::TriangleDescriptor", query, points, k_i=k, outputs=2)
    q = _sizes(query)
    _set(phi, query, _float_dtype(query), [_dim(q, 0), _dim(q, 1), k * (k - 1) // 2, 3])
    _set(idx, query, torch.int64, [_dim(q, 0), _dim(q, 1), k])
    return phi, idx


_SYMBOLICS = {
    "tricons::furthest_point_sample": _sym_fps,
    "tricons::gather_points": _sym_gather,
    "tricons::ball_query": _sym_ball_query,
    "tricons::group_points": _sym_group,
    "tricons::three_nn": _sym_three_nn,
    "tricons::three_interpolate": _sym_three_interp,
    "tricons::triangle_descriptor": _sym_triangle,
}


def register_symbolics(opset_version: int = OPSET) -> None:
    """Register the TorchScript-exporter symbolics of all ``tricons::*`` ops.

    Idempotent. Afterwards export with ``torch.onnx.export(model, args, f,
    dynamo=False, opset_version=17, custom_opsets=CUSTOM_OPSETS, dynamic_axes=...)``.
    """
    from . import ops  # noqa: F401  (makes sure the torch ops are defined)

    for name, fn in _SYMBOLICS.items():
        torch.onnx.register_custom_op_symbolic(name, fn, opset_version)


# ---------------------------------------------------------------------------
# onnx.reference evaluators
# ---------------------------------------------------------------------------

class FurthestPointSample(OpRun):
    """ai.tricons::FurthestPointSample: xyz (B,N,3) -> idx int64 (B,npoint)."""

    op_domain = DOMAIN

    def _run(self, xyz, npoint=None):
        return (ref.furthest_point_sample(np.asarray(xyz), int(npoint)),)


class GatherPoints(OpRun):
    """ai.tricons::GatherPoints: features (B,C,N), idx (B,S) -> (B,C,S)."""

    op_domain = DOMAIN

    def _run(self, features, idx):
        return (ref.gather_points(features, idx.astype(np.int64)),)


class BallQuery(OpRun):
    """ai.tricons::BallQuery: xyz (B,N,3), new_xyz (B,S,3) -> idx int64 (B,S,nsample)."""

    op_domain = DOMAIN

    def _run(self, xyz, new_xyz, radius=None, nsample=None):
        return (ref.ball_query(xyz, new_xyz, float(radius), int(nsample)),)


class GroupPoints(OpRun):
    """ai.tricons::GroupPoints: features (B,C,N), idx (B,S,K) -> (B,C,S,K)."""

    op_domain = DOMAIN

    def _run(self, features, idx):
        return (ref.group_points(features, idx.astype(np.int64)),)


class ThreeNN(OpRun):
    """ai.tricons::ThreeNN: unknown (B,n,3), known (B,m,3) -> dist (B,n,3), idx int64 (B,n,3)."""

    op_domain = DOMAIN

    def _run(self, unknown, known):
        return ref.three_nn(unknown, known)


class ThreeInterpolate(OpRun):
    """ai.tricons::ThreeInterpolate: features (B,C,m), idx (B,n,3), weight (B,n,3) -> (B,C,n)."""

    op_domain = DOMAIN

    def _run(self, features, idx, weight):
        return (ref.three_interpolate(features, idx.astype(np.int64), weight),)


class TriangleDescriptor(OpRun):
    """ai.tricons::TriangleDescriptor: query (B,M,3), points (B,N,3) -> phi (B,M,k(k-1)/2,3), knn_idx (B,M,k)."""

    op_domain = DOMAIN

    def _run(self, query, points, k=None):
        return ref.triangle_descriptor(query, points, int(k))


def reference_ops() -> list[type[OpRun]]:
    """OpRun classes for all seven ``ai.tricons`` nodes, for ``ReferenceEvaluator(..., new_ops=...)``."""
    return [FurthestPointSample, GatherPoints, BallQuery, GroupPoints, ThreeNN, ThreeInterpolate,
            TriangleDescriptor]


# ---------------------------------------------------------------------------
# one entry point per node type (fixtures, tests)
# ---------------------------------------------------------------------------

#: node type -> (input names, output names, attribute names), in ONNX order
NODE_SIGNATURES = {
    "FurthestPointSample": (("xyz",), ("idx",), ("npoint",)),
    "GatherPoints": (("features", "idx"), ("out",), ()),
    "BallQuery": (("xyz", "new_xyz"), ("idx",), ("radius", "nsample")),
    "GroupPoints": (("features", "idx"), ("out",), ()),
    "ThreeNN": (("unknown", "known"), ("dist", "idx"), ()),
    "ThreeInterpolate": (("features", "idx", "weight"), ("out",), ()),
    "TriangleDescriptor": (("query", "points"), ("phi", "knn_idx"), ("k",)),
}


def run_node(op_type: str, inputs: dict, attrs: dict, impl: str = "torch") -> dict:
    """Evaluate one ``ai.tricons`` node on numpy inputs with the torch op (``impl="torch"``)
    or the numpy reference (``impl="reference"``); returns numpy outputs by name."""
    from . import ops

    in_names, out_names, attr_names = NODE_SIGNATURES[op_type]
    args = [inputs[n] for n in in_names]
    extra = [attrs[a] for a in attr_names]
    fn_name = {"FurthestPointSample": "furthest_point_sample", "GatherPoints": "gather_points",
               "BallQuery": "ball_query", "GroupPoints": "group_points", "ThreeNN": "three_nn",
               "ThreeInterpolate": "three_interpolate", "TriangleDescriptor": "triangle_descriptor"}[op_type]
    if impl == "torch":
        res = getattr(ops, fn_name)(*[torch.from_numpy(np.ascontiguousarray(a)) for a in args], *extra)
        res = tuple(r.numpy() for r in (res if isinstance(res, tuple) else (res,)))
    else:
        res = getattr(ref, fn_name)(*args, *extra)
        res = res if isinstance(res, tuple) else (res,)
    return dict(zip(out_names, res))
