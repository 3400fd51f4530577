"""The standard-op forms of the custom operators (onnxruntime export) equal the torch ops."""

import numpy as np
import pytest
import torch

from tricons_pose import ops, ops_standard
from tricons_pose.config import ModelConfig
from tricons_pose.export import example_inputs, random_model


@pytest.fixture
def clouds():
    g = torch.Generator().manual_seed(3)
    return torch.rand(2, 200, 3, generator=g) * 0.2, torch.rand(2, 40, 3, generator=g) * 0.2


def test_point_ops_match(clouds):
    xyz, q = clouds
    assert torch.equal(ops_standard.furthest_point_sample(xyz, 32), ops.furthest_point_sample(xyz, 32))
    for r, ns in ((0.03, 8), (0.08, 16), (1e-4, 4)):  # the last: only the centre itself or nothing
        assert torch.equal(ops_standard.ball_query(xyz, q, r, ns), ops.ball_query(xyz, q, r, ns)), (r, ns)
    f = torch.randn(2, 5, 200)
    idx = torch.randint(0, 200, (2, 40))
    assert torch.equal(ops_standard.gather_points(f, idx), ops.gather_points(f, idx))
    gidx = torch.randint(0, 200, (2, 40, 6))
    assert torch.equal(ops_standard.group_points(f, gidx), ops.group_points(f, gidx))
    d_s, i_s = ops_standard.three_nn(q, xyz)
    d_c, i_c = ops.three_nn(q, xyz)
    assert torch.equal(i_s, i_c) and torch.allclose(d_s, d_c)
    w = torch.rand(2, 40, 3)
    assert torch.allclose(ops_standard.three_interpolate(f, i_c, w), ops.three_interpolate(f, i_c, w), atol=1e-6)
    phi_s, k_s = ops_standard.triangle_descriptor(q, xyz, 6)
    phi_c, k_c = ops.triangle_descriptor(q, xyz, 6)
    assert torch.equal(k_s, k_c) and torch.allclose(phi_s, phi_c, atol=1e-6)
    with ops_standard.standard_ops():  # float32 acos: near-degenerate triangles move by ~1e-4 rad at most
        phi_32, _ = ops_standard.triangle_descriptor(q, xyz, 6)
    assert torch.allclose(phi_32, phi_c, atol=1e-3)


def test_network_inside_standard_ops_equals_the_custom_op_network():
    cfg = ModelConfig.shipped()
    model = random_model(cfg, 0)
    x = example_inputs(cfg, 2, 1)
    with torch.no_grad():
        want = model(x)
        with ops_standard.standard_ops():
            got = model(x)
        again = model(x)  # the swap is undone
    for k in ("R", "t", "s"):
        np.testing.assert_allclose(got[k].numpy(), want[k].numpy(), atol=1e-5)
        assert torch.equal(again[k], want[k])
