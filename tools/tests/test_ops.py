"""Tests of the tricons custom operators against brute-force numpy references."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tricons_pose import ops, ops_reference as ref

SIZES = [(1, 7, 3), (2, 33, 8), (3, 64, 16)]  # (B, N, S)


def _rand(*shape, seed=0, dtype=torch.float32, scale=1.0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=g, dtype=torch.float64) * scale).to(dtype)


def _random_rotation(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


# ----------------------------------------------------------------- FPS

@pytest.mark.parametrize("B,N,S", SIZES)
def test_fps_matches_reference(B, N, S):
    x = _rand(B, N, 3, seed=N)
    got = ops.furthest_point_sample(x, S)
    assert got.dtype == torch.int64 and got.shape == (B, S)
    np.testing.assert_array_equal(got.numpy(), ref.furthest_point_sample(x.numpy(), S))


def test_fps_distinct_start_zero_deterministic():
    x = _rand(2, 50, 3, seed=3)
    a = ops.furthest_point_sample(x, 20)
    b = ops.furthest_point_sample(x, 20)
    assert torch.equal(a, b)
    assert (a[:, 0] == 0).all()
    for row in a:
        assert len(set(row.tolist())) == 20


def test_fps_duplicate_points():
    base = _rand(1, 5, 3, seed=4)
    x = torch.cat([base, base, base[:, :2]], dim=1)  # 12 points, 5 distinct
    got = ops.furthest_point_sample(x, 9)
    np.testing.assert_array_equal(got.numpy(), ref.furthest_point_sample(x.numpy(), 9))
    first5 = got[0, :5].tolist()
    assert len({tuple(x[0, i].tolist()) for i in first5}) == 5  # all distinct locations first
    assert all(i < 5 for i in first5)  # duplicates never beat their lower-index copy
    assert got[0, 5:].tolist() == [0, 0, 0, 0]  # all remaining distances 0 -> index 0


def test_fps_ties_lowest_index():
    # square corners: after 0, points 1 and 3 are equally far (d^2 = 1), 2 is farthest
    x = torch.tensor([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]], dtype=torch.float32)
    assert ops.furthest_point_sample(x, 4).tolist() == [[0, 2, 1, 3]]


# ----------------------------------------------------------------- gather / group

@pytest.mark.parametrize("B,N,S", SIZES)
def test_gather_and_group_match_reference(B, N, S):
    f = _rand(B, 5, N, seed=1) - 0.5
    g = torch.Generator().manual_seed(2)
    idx = torch.randint(0, N, (B, S), generator=g)
    idx3 = torch.randint(0, N, (B, S, 4), generator=g)
    np.testing.assert_array_equal(ops.gather_points(f, idx).numpy(), ref.gather_points(f.numpy(), idx.numpy()))
    np.testing.assert_array_equal(ops.group_points(f, idx3).numpy(), ref.group_points(f.numpy(), idx3.numpy()))


def test_gather_group_backward_scatter_add():
    f = _rand(1, 2, 4, seed=5).requires_grad_(True)
    idx = torch.tensor([[3, 3, 0]])
    ops.gather_points(f, idx).sum().backward()
    assert f.grad.tolist() == [[[1.0, 0.0, 0.0, 2.0]] * 2]
    f.grad = None
    ops.group_points(f, torch.tensor([[[1, 1], [1, 2]]])).sum().backward()
    assert f.grad.tolist() == [[[0.0, 3.0, 1.0, 0.0]] * 2]


def test_gradcheck_gather_group_interpolate():
    f = _rand(2, 3, 6, seed=6, dtype=torch.float64).requires_grad_(True)
    idx = torch.tensor([[0, 5, 5, 2], [1, 1, 3, 4]])
    idx3 = torch.tensor([[[0, 5, 5], [2, 2, 1]], [[4, 3, 1], [0, 0, 0]]])
    w = _rand(2, 2, 3, seed=7, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: ops.gather_points(t, idx), (f,))
    assert torch.autograd.gradcheck(lambda t: ops.group_points(t, idx3), (f,))
    assert torch.autograd.gradcheck(lambda t, u: ops.three_interpolate(t, idx3, u), (f, w))


# ----------------------------------------------------------------- ball query

@pytest.mark.parametrize("B,N,S", SIZES)
@pytest.mark.parametrize("radius,nsample", [(0.2, 4), (0.35, 8), (0.05, 3)])
def test_ball_query_matches_reference(B, N, S, radius, nsample):
    x = _rand(B, N, 3, seed=N + 1)
    c = _rand(B, S, 3, seed=S + 2)
    got = ops.ball_query(x, c, radius, nsample)
    assert got.dtype == torch.int64 and got.shape == (B, S, nsample)
    np.testing.assert_array_equal(got.numpy(), ref.ball_query(x.numpy(), c.numpy(), radius, nsample))


def test_ball_query_edge_cases():
    x = torch.tensor([[[0, 0, 0], [5, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0]]], dtype=torch.float32)
    c = torch.tensor([[[0.25, 0, 0], [9, 9, 9], [0.0, 0, 0]]], dtype=torch.float32)
    got = ops.ball_query(x, c, 0.11, 4).tolist()[0]
    assert got[0] == [3, 4, 3, 3]  # fewer hits than nsample: pad with the first hit
    assert got[1] == [0, 0, 0, 0]  # no hit: zeros
    assert got[2] == [0, 2, 0, 0]
    # more hits than nsample: the first ones in index order; nsample > N works
    assert ops.ball_query(x, c, 100.0, 2).tolist()[0][0] == [0, 1]
    assert ops.ball_query(x, c, 100.0, 7).tolist()[0][0] == [0, 1, 2, 3, 4, 0, 0]
    np.testing.assert_array_equal(ops.ball_query(x, c, 100.0, 7).numpy(), ref.ball_query(x.numpy(), c.numpy(), 100.0, 7))
    # strict inequality: a point exactly on the sphere (d^2 == r^2) is outside
    x2 = torch.tensor([[[0.5, 0, 0], [0.25, 0, 0]]], dtype=torch.float32)
    c2 = torch.zeros(1, 1, 3)
    assert ops.ball_query(x2, c2, 0.5, 2).tolist() == [[[1, 1]]]


def test_ball_query_wide_counts():
    """Past the 16-bit hit counts: N >= 2**15 points (and nsample past N) count in a wider type."""
    n = 2**15 + 7
    x = torch.zeros(1, n, 3)
    x[0, :, 0] = torch.linspace(0.0, 1.0, n)
    c = torch.tensor([[[1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [3.0, 0.0, 0.0]]])
    got = ops.ball_query(x, c, 1e-4, 5)
    np.testing.assert_array_equal(got.numpy(), ref.ball_query(x.numpy(), c.numpy(), 1e-4, 5))
    assert n - 1 in got[0, 0].tolist() and got[0, 2].tolist() == [0] * 5
    few = torch.tensor([[[0.0, 0, 0], [0.1, 0, 0]]])
    many = ops.ball_query(few, few[:, :1], 1.0, 2**15 + 2)  # nsample alone past 16 bits
    assert many.shape == (1, 1, 2**15 + 2) and many[0, 0, :3].tolist() == [0, 1, 0]


# ----------------------------------------------------------------- three_nn / interpolate

@pytest.mark.parametrize("B,N,S", SIZES)
def test_three_nn_matches_reference(B, N, S):
    known = _rand(B, N, 3, seed=N + 3)
    unknown = _rand(B, S + 5, 3, seed=S + 4)
    d, i = ops.three_nn(unknown, known)
    rd, ri = ref.three_nn(unknown.numpy(), known.numpy())
    np.testing.assert_array_equal(i.numpy(), ri)
    np.testing.assert_allclose(d.numpy(), rd, atol=1e-6, rtol=0)
    assert (d[..., 1:] >= d[..., :-1]).all()


def test_three_nn_ties_lower_index():
    # on a grid with duplicates: equal distances must come out in index order
    known = torch.tensor([[[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, 0, 0], [0, -1, 0], [1, 0, 0]]], dtype=torch.float32)
    unknown = torch.tensor([[[0, 0, 0], [1, 0, 0]]], dtype=torch.float32)
    d, i = ops.three_nn(unknown, known)
    assert i.tolist() == [[[3, 0, 1], [0, 5, 3]]]
    assert d.tolist() == [[[0.0, 1.0, 1.0], [0.0, 0.0, 1.0]]]
    np.testing.assert_array_equal(i.numpy(), ref.three_nn(unknown.numpy(), known.numpy())[1])


def test_three_nn_with_duplicated_points_matches_reference():
    # sampling with replacement duplicates points: some queries tie across the cut
    # (their rows take the full sort), the others not (topk); both against the reference
    base = _rand(3, 40, 3, seed=21)
    known = torch.cat([base, base[:, :25]], dim=1)
    unknown = torch.cat([known[:, ::3], _rand(3, 30, 3, seed=22)], dim=1)
    d, i = ops.three_nn(unknown, known)
    rd, ri = ref.three_nn(unknown.numpy(), known.numpy())
    np.testing.assert_array_equal(i.numpy(), ri)
    np.testing.assert_allclose(d.numpy(), rd, atol=1e-6, rtol=0)


@pytest.mark.parametrize("k", [1, 3, 8])
def test_knn_fast_path_equals_a_full_stable_sort(k):
    """The topk fast path with its tie and NaN fallback gives what a full stable sort gives."""
    base = _rand(2, 30, 3, seed=31)
    points = torch.cat([base, base[:, :12], base[:, 5:9]], dim=1)  # duplicates: ties across cuts
    points[1, 7] = float("nan")  # a NaN distance in every row of batch 1
    query = torch.cat([points[:, ::4], _rand(2, 20, 3, seed=32)], dim=1)
    vals, idx = ops._knn_sorted(query, points, k)
    full_vals, full_idx = torch.sort(ops._pairwise_sqdist(query, points), dim=-1, stable=True)
    assert torch.equal(idx, full_idx[..., :k])
    assert torch.equal(vals.nan_to_num(-1.0), full_vals[..., :k].nan_to_num(-1.0))


@pytest.mark.parametrize("B,N,S", SIZES)
def test_three_interpolate_matches_reference(B, N, S):
    f = _rand(B, 6, N, seed=8) - 0.5
    known = _rand(B, N, 3, seed=9)
    unknown = _rand(B, S, 3, seed=10)
    d, i = ops.three_nn(unknown, known)
    w = 1.0 / (d + 1e-8)
    w = w / w.sum(-1, keepdim=True)
    np.testing.assert_allclose(ops.three_interpolate(f, i, w).numpy(),
                               ref.three_interpolate(f.numpy(), i.numpy(), w.numpy()), atol=1e-6, rtol=0)


# ----------------------------------------------------------------- triangle descriptor

@pytest.mark.parametrize("dtype,atol", [(torch.float64, 1e-9), (torch.float32, 1e-5)])
@pytest.mark.parametrize("B,M,N,k", [(1, 3, 5, 2), (2, 6, 20, 4), (2, 5, 16, 6)])
def test_triangle_descriptor_matches_reference(dtype, atol, B, M, N, k):
    q = _rand(B, M, 3, seed=11 + M, dtype=dtype)
    p = _rand(B, N, 3, seed=12 + N, dtype=dtype)
    phi, idx = ops.triangle_descriptor(q, p, k)
    assert phi.dtype == dtype and phi.shape == (B, M, k * (k - 1) // 2, 3)
    assert idx.dtype == torch.int64 and idx.shape == (B, M, k)
    rphi, ridx = ref.triangle_descriptor(q.numpy(), p.numpy(), k)
    np.testing.assert_array_equal(idx.numpy(), ridx)
    np.testing.assert_allclose(phi.numpy(), rphi, atol=atol, rtol=0)


def test_triangle_descriptor_properties():
    q = _rand(2, 7, 3, seed=13, dtype=torch.float64)
    p = _rand(2, 30, 3, seed=14, dtype=torch.float64)
    k = 5
    phi, idx = ops.triangle_descriptor(q, p, k)
    assert phi.shape == (2, 7, 10, 3)
    # recover weights and angles: w = sum(phi)/pi since angles sum to pi
    w = phi.sum(-1) / math.pi
    torch.testing.assert_close(w.sum(-1), torch.ones(2, 7, dtype=torch.float64), atol=1e-9, rtol=0)
    # angle sums via the pure-torch path with unit weights
    nb = torch.stack([p[b][idx[b]] for b in range(2)])
    ia, ib = torch.triu_indices(k, k, 1)
    assert ia.tolist()[:4] == [0, 0, 0, 0] and ib.tolist()[:4] == [1, 2, 3, 4]  # row-major pairs
    alpha = ops._angle(nb[:, :, ia] - q[:, :, None], nb[:, :, ib] - q[:, :, None])
    beta = ops._angle(q[:, :, None] - nb[:, :, ia], nb[:, :, ib] - nb[:, :, ia])
    gamma = ops._angle(q[:, :, None] - nb[:, :, ib], nb[:, :, ia] - nb[:, :, ib])
    torch.testing.assert_close(alpha + beta + gamma, torch.full_like(alpha, math.pi), atol=1e-9, rtol=0)
    torch.testing.assert_close(phi / w.unsqueeze(-1), torch.stack([alpha, beta, gamma], -1), atol=1e-9, rtol=0)
    # kNN ascending
    d = (nb - q[:, :, None]).norm(dim=-1)
    assert (d[..., 1:] >= d[..., :-1]).all()


def test_triangle_descriptor_knn_ties_and_self():
    p = torch.tensor([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, 0, 2]]], dtype=torch.float32)
    q = torch.tensor([[[0, 0, 0]]], dtype=torch.float32)
    phi, idx = ops.triangle_descriptor(q, p, 3)
    assert idx.tolist() == [[[0, 1, 2]]]  # the coincident point is kept; ties in index order
    assert torch.isfinite(phi).all()
    np.testing.assert_allclose(phi.numpy(), ref.triangle_descriptor(q.numpy(), p.numpy(), 3)[0], atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triangle_descriptor_rigid_invariance(seed):
    q = _rand(2, 6, 3, seed=20 + seed, dtype=torch.float64) * 0.2
    p = _rand(2, 40, 3, seed=30 + seed, dtype=torch.float64) * 0.2
    R = _random_rotation(seed)
    t = torch.tensor([0.3, -1.2, 2.5], dtype=torch.float64)
    phi, idx = ops.triangle_descriptor(q, p, 6)
    phi2, idx2 = ops.triangle_descriptor(q @ R.T + t, p @ R.T + t, 6)
    assert torch.equal(idx, idx2)
    torch.testing.assert_close(phi2, phi, atol=1e-5, rtol=0)
    # float32 input: same neighbours, descriptor close
    phi3, idx3 = ops.triangle_descriptor((q @ R.T + t).float(), (p @ R.T + t).float(), 6)
    assert torch.equal(idx, idx3)
    torch.testing.assert_close(phi3.double(), phi, atol=1e-3, rtol=0)


def test_triangle_descriptor_gradcheck():
    q = _rand(1, 2, 3, seed=40, dtype=torch.float64).requires_grad_(True)
    p = _rand(1, 6, 3, seed=41, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, b: ops.triangle_descriptor(a, b, 4)[0], (q, p))


def _angle_sums(q, p, idx):
    k = idx.shape[-1]
    nb = torch.stack([p[b][idx[b]] for b in range(p.shape[0])]).double()
    q = q.double()
    ia, ib = torch.triu_indices(k, k, 1)
    qa, qb, c = nb[:, :, ia], nb[:, :, ib], q[:, :, None]
    return ops._angle(qa - c, qb - c) + ops._angle(c - qa, qb - qa) + ops._angle(c - qb, qa - qb)


def test_triangle_descriptor_degenerate_finite_gradient():
    # query coinciding with points, duplicate points, collinear points
    p = torch.tensor([[[0, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]], dtype=torch.float32, requires_grad=True)
    q = torch.tensor([[[0, 0, 0], [1, 0, 0]]], dtype=torch.float32, requires_grad=True)
    phi, idx = ops.triangle_descriptor(q, p, 4)
    assert torch.isfinite(phi).all()
    (phi * torch.randn_like(phi)).sum().backward()
    assert torch.isfinite(q.grad).all() and torch.isfinite(p.grad).all()
    np.testing.assert_allclose(phi.detach().numpy(),
                               ref.triangle_descriptor(q.detach().numpy(), p.detach().numpy(), 4)[0], atol=1e-6, rtol=0)
    # one zero side (or collinear): angles still sum to pi (up to the norm epsilon);
    # three coincident points: all cosines 0 -> 3 pi / 2
    sums = _angle_sums(q.detach(), p.detach(), idx)
    all_same = torch.tensor([[[True, False, False, False, False, False], [False] * 6]])
    torch.testing.assert_close(sums, torch.where(all_same, 1.5 * math.pi, math.pi).double(), atol=5e-6, rtol=0)  # eps: acos(1-1e-12) ~ 1.4e-6


def test_triangle_descriptor_float32_query_on_points():
    # queries taken from the point set (zero distance to the first neighbour): float32 must
    # still match the float64-geometry reference tightly
    p = _rand(2, 24, 3, seed=42) * 0.1
    q = p[:, ::3].contiguous()
    phi, idx = ops.triangle_descriptor(q, p, 5)
    assert (idx[..., 0] == torch.arange(0, 24, 3)).all()
    rphi, ridx = ref.triangle_descriptor(q.numpy(), p.numpy(), 5)
    np.testing.assert_array_equal(idx.numpy(), ridx)
    np.testing.assert_allclose(phi.numpy(), rphi, atol=1e-6, rtol=0)


# ----------------------------------------------------------------- fake tensors / compile

def test_fake_shapes():
    from torch._subclasses.fake_tensor import FakeTensorMode
    with FakeTensorMode():
        x = torch.empty(2, 40, 3)
        c = torch.empty(2, 9, 3)
        f = torch.empty(2, 5, 40)
        assert ops.furthest_point_sample(x, 9).shape == (2, 9)
        assert ops.ball_query(x, c, 0.1, 4).shape == (2, 9, 4)
        assert ops.gather_points(f, torch.empty(2, 9, dtype=torch.int64)).shape == (2, 5, 9)
        assert ops.group_points(f, torch.empty(2, 9, 4, dtype=torch.int64)).shape == (2, 5, 9, 4)
        d, i = ops.three_nn(c, x)
        assert d.shape == (2, 9, 3) and i.dtype == torch.int64
        assert ops.three_interpolate(f, i, d).shape == (2, 5, 9)
        phi, idx = ops.triangle_descriptor(c, x, 5)
        assert phi.shape == (2, 9, 10, 3) and idx.shape == (2, 9, 5)


def test_opcheck():
    x = _rand(2, 12, 3, seed=50)
    f = _rand(2, 4, 12, seed=51).requires_grad_(True)
    idx = torch.tensor([[0, 3, 11], [2, 2, 5]])
    idx3 = ops.ball_query(x, x[:, :3], 0.5, 4)
    d, i = ops.three_nn(x[:, :5], x)
    q = x[:, :4].clone().requires_grad_(True)
    p = x.clone().requires_grad_(True)
    cases = [
        (ops._fps_op, (x, 5)),
        (ops._gather_op, (f, idx)),
        (ops._ball_query_op, (x, x[:, :3], 0.5, 4)),
        (ops._group_op, (f, idx3)),
        (ops._three_nn_op, (x[:, :5], x)),
        (ops._three_interp_op, (f, i, d.clone().requires_grad_(True))),
        # mixed precision, as under bf16 autocast: bfloat16 features, float32 weights
        (ops._three_interp_op, (f.detach().bfloat16().requires_grad_(True), i, d.clone().requires_grad_(True))),
        (ops._tri_op, (q, p, 4)),
    ]
    for op, args in cases:
        torch.library.opcheck(op, args, test_utils=("test_schema", "test_faketensor", "test_autograd_registration"))


# ----------------------------------------------------------------- many exact ties (integer grid)

def _grid(B, N, seed, levels=3):
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, levels, (B, N, 3), generator=g).float() * 0.25


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_tie_heavy_inputs_match_reference(seed):
    x = _grid(2, 30, seed)
    c = _grid(2, 9, seed + 100)
    np.testing.assert_array_equal(ops.furthest_point_sample(x, 12).numpy(), ref.furthest_point_sample(x.numpy(), 12))
    np.testing.assert_array_equal(ops.ball_query(x, c, 0.3, 5).numpy(), ref.ball_query(x.numpy(), c.numpy(), 0.3, 5))
    d, i = ops.three_nn(c, x)
    rd, ri = ref.three_nn(c.numpy(), x.numpy())
    np.testing.assert_array_equal(i.numpy(), ri)
    np.testing.assert_allclose(d.numpy(), rd, atol=1e-6, rtol=0)
    for k in (3, 6):
        phi, idx = ops.triangle_descriptor(c, x, k)
        rphi, ridx = ref.triangle_descriptor(c.numpy(), x.numpy(), k)
        np.testing.assert_array_equal(idx.numpy(), ridx)
        np.testing.assert_allclose(phi.numpy(), rphi, atol=1e-6, rtol=0)


def test_knn_ties_inside_the_cut_fast_path():
    # ties among the k picked but not across the k-th distance: the topk fast path must
    # still order them by index
    known = torch.tensor([[[2, 0, 0], [0, 0, 1], [0, 0, 0], [0, 1, 0], [5, 5, 5], [1, 0, 0]]], dtype=torch.float32)
    unknown = torch.zeros(1, 1, 3)
    d2, idx = ops._knn_sorted(unknown, known, 4)
    assert idx.tolist() == [[[2, 1, 3, 5]]]
    assert d2.tolist() == [[[0.0, 1.0, 1.0, 1.0]]]
    _, idx3 = ops.three_nn(unknown, known)
    assert idx3.tolist() == [[[2, 1, 3]]]  # tie across the cut: fallback path


def test_small_edge_sizes():
    p = _rand(2, 5, 3, seed=60)
    q = _rand(2, 3, 3, seed=61).requires_grad_(True)
    phi, idx = ops.triangle_descriptor(q, p, 1)  # k = 1: no triangles
    assert phi.shape == (2, 3, 0, 3) and idx.shape == (2, 3, 1)
    phi.sum().backward()
    assert (q.grad == 0).all()
    phi5, idx5 = ops.triangle_descriptor(q.detach(), p, 5)  # k = N
    np.testing.assert_array_equal(idx5.numpy(), ref.triangle_descriptor(q.detach().numpy(), p.numpy(), 5)[1])
    with pytest.raises(Exception):
        ops.triangle_descriptor(q.detach(), p, 6)
    # npoint > N: distinct points first, then index 0 repeats
    np.testing.assert_array_equal(ops.furthest_point_sample(p, 7).numpy(), ref.furthest_point_sample(p.numpy(), 7))
    assert ops.furthest_point_sample(p, 7)[:, 5:].tolist() == [[0, 0], [0, 0]]
