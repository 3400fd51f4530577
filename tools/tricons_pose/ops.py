"""Custom operators of TriCons-Pose as ``torch.library`` ops (namespace ``tricons``).

The network needs the PointNet2 point operators (furthest point sampling, gather,
ball query, grouping, three-nearest-neighbour interpolation) and the PIGA triangle
descriptor. ONNX has none of them, so each one is a ``torch.library.custom_op``
that

* runs on CPU (and on CUDA tensors) with vectorised pure-torch code,
* has a ``register_fake`` rule (shapes only, symbolic sizes allowed), so it traces,
* has an autograd formula where the operator is differentiable, and
* exports to ONNX as one node in domain ``ai.tricons`` (see ``onnx_export_ops``).

Exact semantics (the Rust runtime implements the same nodes):

* Squared distances are computed per pair as ``(dx*dx + dy*dy) + dz*dz`` with
  ``d = a - b`` in the input dtype, with no fused multiply-add, so index results
  (FPS, ball query, kNN) are bit-reproducible against ``ops_reference`` and Rust.
* Ties in distance are broken towards the lower point index everywhere.
* Indices are int64, base 0.

Public API: :func:`furthest_point_sample`, :func:`gather_points`,
:func:`ball_query`, :func:`group_points`, :func:`three_nn`,
:func:`three_interpolate`, :func:`triangle_descriptor` (see ``tools/CONTRACT.md``).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "furthest_point_sample",
    "gather_points",
    "ball_query",
    "group_points",
    "three_nn",
    "three_interpolate",
    "triangle_descriptor",
    "TRIANGLE_NORM_EPS2",
    "triangle_descriptor_torch",
]

#: Epsilon added to squared side lengths before the square root in the triangle
#: descriptor's cosines: ``|u|_eps = sqrt(u.u + TRIANGLE_NORM_EPS2)`` (1e-6 m).
TRIANGLE_NORM_EPS2 = 1e-12

# Margin keeping the acos gradient finite (forward values use the exact clip to [-1, 1]).
_ACOS_GRAD_MARGIN = 1e-6


# ---------------------------------------------------------------------------
# helpers (pure torch, differentiable where it matters)
# ---------------------------------------------------------------------------

def _pairwise_sqdist(a: Tensor, b: Tensor) -> Tensor:
    """Squared distances (B, S, N) between a (B, S, 3) and b (B, N, 3); no autograd.

    Computed exactly as ``(dx*dx + dy*dy) + dz*dz`` with ``dx = a.x - b.x``
    (separate multiplies and adds, in place, no (B, S, N, 3) temporary).
    """
    # coordinate planes (B, 3, S) / (B, 3, N): contiguous rows broadcast faster than stride-3 views
    a = a.detach().transpose(1, 2).contiguous()
    b = b.detach().transpose(1, 2).contiguous()
    a0, a1, a2 = (t.unsqueeze(-1) for t in a.unbind(1))
    b0, b1, b2 = (t.unsqueeze(-2) for t in b.unbind(1))
    dx = a0 - b0
    d2 = dx.mul_(dx)
    dy = a1 - b1
    d2.add_(dy.mul_(dy))
    dz = torch.sub(a2, b2, out=dy)
    return d2.add_(dz.mul_(dz))


def _knn_sorted(query: Tensor, points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """k nearest points of each query: (sqdist, idx), ascending, ties -> lower index.

    Fast path: ``topk`` of k + 1; its first k are exact for a query whenever the
    (k+1)-th smallest distance is strictly above the k-th (no tie across the cut), and
    the k picks are then re-ordered by (distance, index). The queries where that fails
    (a tie across the cut, which duplicated sample points make common, or NaN) get a
    full stable sort of their row only.
    """
    d2 = _pairwise_sqdist(query, points)
    n = d2.shape[-1]
    if k >= n:
        vals, idx = torch.sort(d2, dim=-1, stable=True)
        return vals[..., :k].contiguous(), idx[..., :k].contiguous()
    vals, idx = torch.topk(d2, k + 1, dim=-1, largest=False, sorted=True)
    bad = ~(vals[..., k] > vals[..., k - 1])  # False for NaN too
    vals, idx = vals[..., :k], idx[..., :k]
    idx, perm = torch.sort(idx, dim=-1)
    vals = torch.gather(vals, -1, perm)
    vals, order = torch.sort(vals, dim=-1, stable=True)
    idx = torch.gather(idx, -1, order)
    if bool(bad.any()):
        v_bad, i_bad = torch.sort(d2[bad], dim=-1, stable=True)
        vals[bad] = v_bad[:, :k]
        idx[bad] = i_bad[:, :k]
    return vals, idx


def _gather_cols(features: Tensor, idx: Tensor) -> Tensor:
    """features (B, C, N), idx (B, ...) -> (B, C, ...) with out[b,c,...] = features[b,c,idx[b,...]]."""
    B, C, _ = features.shape
    flat = idx.reshape(B, 1, -1).expand(B, C, -1)
    return torch.gather(features, 2, flat).reshape((B, C) + tuple(idx.shape[1:]))


def _scatter_cols(grad: Tensor, idx: Tensor, n: int) -> Tensor:
    """Adjoint of :func:`_gather_cols`: scatter-add grad (B, C, ...) into (B, C, n)."""
    B, C = grad.shape[0], grad.shape[1]
    flat = idx.reshape(B, 1, -1).expand(B, C, -1)
    out = grad.new_zeros((B, C, n))
    return out.scatter_add_(2, flat, grad.reshape(B, C, -1))


def _check_xyz(name: str, t: Tensor) -> None:
    if t.dim() != 3 or t.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (B, N, 3), got {tuple(t.shape)}")


# ---------------------------------------------------------------------------
# furthest_point_sample
# ---------------------------------------------------------------------------

@torch.library.custom_op("tricons::furthest_point_sample", mutates_args=())
def _fps_op(xyz: Tensor, npoint: int) -> Tensor:
    _check_xyz("xyz", xyz)
    B, N, _ = xyz.shape
    if npoint < 0:
        raise ValueError("npoint must be >= 0")
    out = torch.zeros((B, npoint), dtype=torch.int64, device=xyz.device)
    if npoint == 0 or N == 0:
        return out
    # coordinate planes (B, 3, N) and preallocated buffers: the loop runs npoint times
    # over small tensors, so fewer and in-place operations are most of its cost
    planes = xyz.detach().transpose(1, 2).contiguous()
    x0, x1, x2 = planes.unbind(1)
    mind = torch.full((B, N), float("inf"), dtype=xyz.dtype, device=xyz.device)
    far = torch.zeros((B, 1), dtype=torch.int64, device=xyz.device)
    d = torch.empty_like(mind)
    t = torch.empty_like(mind)
    for i in range(npoint):
        out[:, i:i + 1] = far
        c = torch.gather(planes, 2, far.unsqueeze(1).expand(B, 3, 1))  # (B, 3, 1): the centre
        # (d0*d0 + d1*d1) + d2*d2 with d = point - centre
        torch.sub(x0, c[:, 0], out=d).mul_(d)
        d.add_(torch.sub(x1, c[:, 1], out=t).mul_(t))
        d.add_(torch.sub(x2, c[:, 2], out=t).mul_(t))
        torch.minimum(mind, d, out=mind)
        far = torch.argmax(mind, dim=1, keepdim=True)  # first maximum -> lowest index on ties
    return out


@_fps_op.register_fake
def _(xyz: Tensor, npoint: int) -> Tensor:
    return xyz.new_empty((xyz.shape[0], npoint), dtype=torch.int64)


def furthest_point_sample(xyz: Tensor, npoint: int) -> Tensor:
    """Furthest point sampling.

    Args:
        xyz: (B, N, 3) float points.
        npoint: number of samples S.

    Returns:
        (B, S) int64 indices. The first is 0; each next one is the point whose
        minimum squared distance to the already chosen ones is largest (ties ->
        lowest index). If all remaining distances are 0 (duplicates, or
        S > number of distinct points) index 0 is repeated by the tie rule.
        Not differentiable.
    """
    return _fps_op(xyz, int(npoint))


# ---------------------------------------------------------------------------
# gather_points
# ---------------------------------------------------------------------------

@torch.library.custom_op("tricons::gather_points", mutates_args=())
def _gather_op(features: Tensor, idx: Tensor) -> Tensor:
    return _gather_cols(features, idx)


@_gather_op.register_fake
def _(features: Tensor, idx: Tensor) -> Tensor:
    return features.new_empty((features.shape[0], features.shape[1], idx.shape[1]))


def _gather_setup(ctx, inputs, output):
    features, idx = inputs
    ctx.save_for_backward(idx)
    ctx.n = features.shape[2]


def _gather_backward(ctx, grad):
    (idx,) = ctx.saved_tensors
    return _scatter_cols(grad, idx, ctx.n), None


_gather_op.register_autograd(_gather_backward, setup_context=_gather_setup)


def gather_points(features: Tensor, idx: Tensor) -> Tensor:
    """Gather point features: out[b, c, s] = features[b, c, idx[b, s]].

    Args:
        features: (B, C, N) float.
        idx: (B, S) int64 in [0, N).

    Returns:
        (B, C, S). Differentiable w.r.t. ``features`` (scatter-add backward).
    """
    return _gather_op(features, idx)


# ---------------------------------------------------------------------------
# ball_query
# ---------------------------------------------------------------------------

@torch.library.custom_op("tricons::ball_query", mutates_args=())
def _ball_query_op(xyz: Tensor, new_xyz: Tensor, radius: float, nsample: int) -> Tensor:
    _check_xyz("xyz", xyz)
    _check_xyz("new_xyz", new_xyz)
    B, N, _ = xyz.shape
    S = new_xyz.shape[1]
    if nsample <= 0:
        return torch.zeros((B, S, max(nsample, 0)), dtype=torch.int64, device=xyz.device)
    r = torch.tensor(radius, dtype=xyz.dtype, device=xyz.device)
    r2 = r * r  # squared radius in the input dtype
    d2 = _pairwise_sqdist(new_xyz, xyz)  # (B, S, N)
    # hits up to and including each position; a row's j-th hit (1-based) is the first position
    # where the count reaches j, N when the row has fewer hits (exact: integer counts; the
    # narrowest integer type that holds N keeps the scan and the search cheap)
    top = max(N, nsample)
    count_dtype = torch.int16 if top < 2**15 else torch.int32 if top < 2**31 else torch.int64
    count = (d2 < r2).cumsum(-1, dtype=count_dtype)  # (B, S, N)
    del d2
    want = torch.arange(1, nsample + 1, dtype=count_dtype, device=xyz.device).expand(B, S, nsample)
    first = torch.searchsorted(count, want.contiguous())  # (B, S, nsample) int64, N: no such hit
    head = first[..., :1]
    head = torch.where(head == N, torch.zeros_like(head), head)  # no hit -> 0
    return torch.where(first == N, head.expand_as(first), first)


@_ball_query_op.register_fake
def _(xyz: Tensor, new_xyz: Tensor, radius: float, nsample: int) -> Tensor:
    return new_xyz.new_empty((new_xyz.shape[0], new_xyz.shape[1], nsample), dtype=torch.int64)


def ball_query(xyz: Tensor, new_xyz: Tensor, radius: float, nsample: int) -> Tensor:
    """Ball query around centres.

    Args:
        xyz: (B, N, 3) float points.
        new_xyz: (B, S, 3) float centres.
        radius: ball radius r (metres); a point is inside when d^2 < r*r, with
            r cast to the input dtype first and r*r computed in that dtype.
        nsample: K, number of indices per centre.

    Returns:
        (B, S, K) int64: the first K point indices in increasing index order
        that are inside the ball; remaining slots repeat the first hit; a centre
        with no hit gets all zeros. Not differentiable.
    """
    return _ball_query_op(xyz, new_xyz, float(radius), int(nsample))


# ---------------------------------------------------------------------------
# group_points
# ---------------------------------------------------------------------------

@torch.library.custom_op("tricons::group_points", mutates_args=())
def _group_op(features: Tensor, idx: Tensor) -> Tensor:
    return _gather_cols(features, idx)


@_group_op.register_fake
def _(features: Tensor, idx: Tensor) -> Tensor:
    return features.new_empty((features.shape[0], features.shape[1], idx.shape[1], idx.shape[2]))


_group_op.register_autograd(_gather_backward, setup_context=_gather_setup)


def group_points(features: Tensor, idx: Tensor) -> Tensor:
    """Group point features: out[b, c, s, k] = features[b, c, idx[b, s, k]].

    Args:
        features: (B, C, N) float.
        idx: (B, S, K) int64 in [0, N).

    Returns:
        (B, C, S, K). Differentiable w.r.t. ``features`` (scatter-add backward).
    """
    return _group_op(features, idx)


# ---------------------------------------------------------------------------
# three_nn
# ---------------------------------------------------------------------------

@torch.library.custom_op("tricons::three_nn", mutates_args=())
def _three_nn_op(unknown: Tensor, known: Tensor) -> tuple[Tensor, Tensor]:
    _check_xyz("unknown", unknown)
    _check_xyz("known", known)
    if known.shape[1] < 3:
        raise ValueError("three_nn needs at least 3 known points")
    d2, idx = _knn_sorted(unknown, known, 3)
    return torch.sqrt(d2), idx


@_three_nn_op.register_fake
def _(unknown: Tensor, known: Tensor) -> tuple[Tensor, Tensor]:
    shape = (unknown.shape[0], unknown.shape[1], 3)
    return unknown.new_empty(shape), unknown.new_empty(shape, dtype=torch.int64)


def three_nn(unknown: Tensor, known: Tensor) -> tuple[Tensor, Tensor]:
    """Three nearest known points of each unknown point.

    Args:
        unknown: (B, n, 3) float.
        known: (B, m, 3) float, m >= 3.

    Returns:
        dist (B, n, 3) Euclidean distances sqrt(d^2), ascending; idx (B, n, 3)
        int64 (ties -> lower index). Not differentiable.
    """
    return _three_nn_op(unknown, known)


# ---------------------------------------------------------------------------
# three_interpolate
# ---------------------------------------------------------------------------

def _three_interp(features: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    g = _gather_cols(features, idx)  # (B, C, n, 3)
    w = weight.unsqueeze(1)
    p = g * w
    return (p[..., 0] + p[..., 1]) + p[..., 2]


@torch.library.custom_op("tricons::three_interpolate", mutates_args=())
def _three_interp_op(features: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    return _three_interp(features, idx, weight)


@_three_interp_op.register_fake
def _(features: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    # the product promotes: bfloat16 features (autocast) with float32 weights give float32
    return features.new_empty((features.shape[0], features.shape[1], idx.shape[1]),
                              dtype=torch.promote_types(features.dtype, weight.dtype))


def _three_interp_setup(ctx, inputs, output):
    features, idx, weight = inputs
    ctx.save_for_backward(features, idx, weight)


def _three_interp_backward(ctx, grad):
    features, idx, weight = ctx.saved_tensors
    gf = gw = None
    if ctx.needs_input_grad[0]:
        g = grad.unsqueeze(-1) * weight.unsqueeze(1)  # (B, C, n, 3)
        gf = _scatter_cols(g, idx, features.shape[2])
    if ctx.needs_input_grad[2]:
        gw = (grad.unsqueeze(-1) * _gather_cols(features, idx)).sum(1)  # (B, n, 3)
    return gf, None, gw


_three_interp_op.register_autograd(_three_interp_backward, setup_context=_three_interp_setup)


def three_interpolate(features: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    """Weighted three-point interpolation.

    out[b, c, j] = sum_k features[b, c, idx[b, j, k]] * weight[b, j, k]
    (summed in order k = 0, 1, 2).

    Args:
        features: (B, C, m) float.
        idx: (B, n, 3) int64 in [0, m).
        weight: (B, n, 3) float (AG-Pose uses 1/(d + 1e-8) normalised to sum 1).

    Returns:
        (B, C, n). Differentiable w.r.t. ``features`` and ``weight``.
    """
    return _three_interp_op(features, idx, weight)


# ---------------------------------------------------------------------------
# triangle_descriptor
# ---------------------------------------------------------------------------

def _safe_acos(x: Tensor) -> Tensor:
    """acos(clip(x, -1, 1)) in value; gradient taken from a clip with a margin (finite)."""
    exact = torch.acos(torch.clamp(x, -1.0, 1.0))
    m = _ACOS_GRAD_MARGIN
    soft = torch.acos(torch.clamp(x, -1.0 + m, 1.0 - m))
    return soft + (exact - soft).detach()


def _eps_norm(u: Tensor) -> Tensor:
    return torch.sqrt((u[..., 0] * u[..., 0] + u[..., 1] * u[..., 1]) + u[..., 2] * u[..., 2]
                      + TRIANGLE_NORM_EPS2)


def _dot3(u: Tensor, v: Tensor) -> Tensor:
    return (u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]) + u[..., 2] * v[..., 2]


def _angle(u: Tensor, v: Tensor) -> Tensor:
    return _safe_acos(_dot3(u, v) / (_eps_norm(u) * _eps_norm(v)))


def _pair_indices(k: int, device) -> tuple[Tensor, Tensor]:
    """Row-major pairs (a, b), a < b, as constant index tensors (exportable, unlike triu_indices)."""
    pairs = [(a, b) for a in range(k) for b in range(a + 1, k)]
    ia = torch.tensor([a for a, _ in pairs], dtype=torch.int64, device=device)
    ib = torch.tensor([b for _, b in pairs], dtype=torch.int64, device=device)
    return ia, ib


def triangle_descriptor_torch(query: Tensor, points: Tensor, knn_idx: Tensor) -> Tensor:
    """Differentiable pure-torch triangle descriptor for given neighbour indices.

    Args:
        query: (B, M, 3) float.
        points: (B, N, 3) float.
        knn_idx: (B, M, K) int64 neighbour indices (any order; pairs follow it).

    Returns:
        phi (B, M, K(K-1)/2, 3), see :func:`triangle_descriptor`.
    """
    B, M, K = knn_idx.shape
    out_dtype = query.dtype
    # geometry in float64: acos near +-1 is ill-conditioned (coincident / collinear
    # points are common), float32 arithmetic would cost ~1e-4 rad there.
    query = query.to(torch.float64)
    points = points.to(torch.float64)
    ia, ib = _pair_indices(K, query.device)
    nb = torch.gather(points, 1, knn_idx.reshape(B, M * K, 1).expand(B, M * K, 3)).reshape(B, M, K, 3)
    qa = nb[:, :, ia]  # (B, M, T, 3)
    qb = nb[:, :, ib]
    p = query.unsqueeze(2)
    u = qa - p
    v = qb - p
    alpha = _angle(u, v)
    beta = _angle(p - qa, qb - qa)
    gamma = _angle(p - qb, qa - qb)
    cx = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    cy = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    cz = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    c2 = (cx * cx + cy * cy) + cz * cz
    area = 0.5 * torch.sqrt(c2)
    area_soft = 0.5 * torch.sqrt(c2 + TRIANGLE_NORM_EPS2 * TRIANGLE_NORM_EPS2)  # finite gradient
    area = area_soft + (area - area_soft).detach()
    w = torch.softmax(area, dim=-1)
    return (w.unsqueeze(-1) * torch.stack([alpha, beta, gamma], dim=-1)).to(out_dtype)


@torch.library.custom_op("tricons::triangle_descriptor", mutates_args=())
def _tri_op(query: Tensor, points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    _check_xyz("query", query)
    _check_xyz("points", points)
    if k < 1 or k > points.shape[1]:
        raise ValueError(f"k must be in [1, N={points.shape[1]}], got {k}")
    _, idx = _knn_sorted(query, points, k)
    with torch.no_grad():
        phi = triangle_descriptor_torch(query, points, idx)
    return phi, idx


@_tri_op.register_fake
def _(query: Tensor, points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    B, M = query.shape[0], query.shape[1]
    T = k * (k - 1) // 2
    return query.new_empty((B, M, T, 3)), query.new_empty((B, M, k), dtype=torch.int64)


def _tri_setup(ctx, inputs, output):
    query, points, _k = inputs
    ctx.save_for_backward(query, points, output[1])


def _tri_backward(ctx, grad_phi, _grad_idx):
    query, points, idx = ctx.saved_tensors
    with torch.enable_grad():
        q = query.detach().requires_grad_(True)
        p = points.detach().requires_grad_(True)
        phi = triangle_descriptor_torch(q, p, idx)
        gq, gp = torch.autograd.grad(phi, (q, p), grad_phi, allow_unused=True)
    if gq is None:
        gq = torch.zeros_like(query)
    if gp is None:
        gp = torch.zeros_like(points)
    return gq, gp, None


_tri_op.register_autograd(_tri_backward, setup_context=_tri_setup)


def triangle_descriptor(query: Tensor, points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """PIGA triangle descriptor.

    For each query p_i: its k nearest points q (squared Euclidean, ascending,
    ties -> lower index; a point coinciding with p_i is kept); all pairs a < b
    of the k neighbours in row-major order ((0,1), (0,2), ..., (k-2,k-1));
    the inner angles alpha (at p_i), beta (at q_a), gamma (at q_b), each
    ``acos(clip(dot(u, v) / (|u|_e |v|_e), -1, 1))`` with
    ``|u|_e = sqrt(u.u + TRIANGLE_NORM_EPS2)``; area A = |(q_a-p_i) x (q_b-p_i)| / 2;
    w = softmax of A over the k(k-1)/2 triangles; phi = w * [alpha, beta, gamma].
    The kNN uses squared distances in the input dtype; the geometry (angles,
    areas, softmax) is evaluated in float64 and phi cast back to the input dtype.

    Args:
        query: (B, M, 3) float32 or float64.
        points: (B, N, 3) same dtype, N >= k.
        k: neighbours per query.

    Returns:
        phi (B, M, k(k-1)/2, 3) and knn_idx (B, M, k) int64. phi is
        differentiable w.r.t. ``query`` and ``points`` (finite also for
        coincident points).
    """
    return _tri_op(query, points, int(k))
