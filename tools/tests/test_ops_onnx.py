"""ONNX export of the tricons custom ops: graph content and reference-evaluator parity."""
from __future__ import annotations

import io
import warnings

import numpy as np
import onnx
import pytest
import torch
from onnx.reference import ReferenceEvaluator

from tricons_pose import ops
from tricons_pose.onnx_export_ops import CUSTOM_OPSETS, DOMAIN, register_symbolics, reference_ops

NPOINT, RADIUS, NSAMPLE, K = 8, 0.3, 4, 4


class AllOps(torch.nn.Module):
    """A tiny PointNet2-like block using every custom op once."""

    def forward(self, xyz, feat):
        idx = ops.furthest_point_sample(xyz, NPOINT)
        centres = ops.gather_points(xyz.transpose(1, 2).contiguous(), idx).transpose(1, 2).contiguous()
        nbr = ops.ball_query(xyz, centres, RADIUS, NSAMPLE)
        grouped = ops.group_points(feat, nbr)  # (B, C, S, nsample)
        pooled = grouped.amax(-1)  # (B, C, S)
        dist, nn_idx = ops.three_nn(xyz, centres)
        w = 1.0 / (dist + 1e-8)
        w = w / w.sum(-1, keepdim=True)
        up = ops.three_interpolate(pooled, nn_idx, w)  # (B, C, N)
        phi, knn = ops.triangle_descriptor(centres, xyz, K)
        return idx, nbr, up, dist, nn_idx, phi, knn


OUTPUTS = ["fps_idx", "ball_idx", "up", "dist", "nn_idx", "phi", "knn_idx"]


def _inputs(B, N, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(B, N, 3, generator=g), torch.randn(B, 5, N, generator=g)


@pytest.fixture(scope="module")
def exported():
    register_symbolics()
    model = AllOps().eval()
    buf = io.BytesIO()
    dyn = {"xyz": {0: "B", 1: "N"}, "feat": {0: "B", 2: "N"}}
    dyn.update({name: {0: "B"} for name in OUTPUTS})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter is deprecated
        torch.onnx.export(model, _inputs(2, 32, 0), buf, dynamo=False, opset_version=17,
                          custom_opsets=CUSTOM_OPSETS, input_names=["xyz", "feat"],
                          output_names=OUTPUTS, dynamic_axes=dyn)
    return model, onnx.load_from_string(buf.getvalue())


def test_graph_has_the_seven_nodes(exported):
    _, proto = exported
    onnx.checker.check_model(proto)
    imports = {o.domain: o.version for o in proto.opset_import}
    assert imports[DOMAIN] == 1 and imports[""] == 17
    custom = [n for n in proto.graph.node if n.domain == DOMAIN]
    attrs = {n.op_type: {a.name: onnx.helper.get_attribute_value(a) for a in n.attribute} for n in custom}
    assert sorted(attrs) == sorted(["FurthestPointSample", "GatherPoints", "BallQuery", "GroupPoints",
                                    "ThreeNN", "ThreeInterpolate", "TriangleDescriptor"])
    assert len(custom) == 7
    assert attrs["FurthestPointSample"] == {"npoint": NPOINT}
    assert attrs["BallQuery"]["nsample"] == NSAMPLE
    assert attrs["BallQuery"]["radius"] == pytest.approx(RADIUS, abs=1e-7)
    assert set(attrs["BallQuery"]) == {"radius", "nsample"}
    assert attrs["TriangleDescriptor"] == {"k": K}
    for name in ("GatherPoints", "GroupPoints", "ThreeNN", "ThreeInterpolate"):
        assert attrs[name] == {}
    by_type = {n.op_type: n for n in custom}
    assert len(by_type["ThreeNN"].output) == 2 and len(by_type["TriangleDescriptor"].output) == 2
    assert len(by_type["ThreeInterpolate"].input) == 3
    # no aten fallbacks / python ops left in the graph
    assert all(n.domain in ("", DOMAIN) for n in proto.graph.node)


def test_output_types_and_dynamic_batch(exported):
    _, proto = exported
    out = {o.name: o.type.tensor_type for o in proto.graph.output}
    i64, f32 = onnx.TensorProto.INT64, onnx.TensorProto.FLOAT
    expect = {"fps_idx": i64, "ball_idx": i64, "up": f32, "dist": f32, "nn_idx": i64, "phi": f32, "knn_idx": i64}
    for name, dt in expect.items():
        assert out[name].elem_type == dt, name
        assert out[name].shape.dim[0].dim_param == "B", name
    assert [d.dim_value for d in out["phi"].shape.dim[1:]] == [NPOINT, K * (K - 1) // 2, 3]
    assert [d.dim_value for d in out["knn_idx"].shape.dim[1:]] == [NPOINT, K]
    assert [d.dim_value for d in out["ball_idx"].shape.dim[1:]] == [NPOINT, NSAMPLE]


@pytest.mark.parametrize("B,N,seed", [(2, 32, 1), (3, 40, 2), (1, 17, 3)])
def test_reference_evaluator_matches_torch(exported, B, N, seed):
    model, proto = exported
    ev = ReferenceEvaluator(proto, new_ops=reference_ops())
    xyz, feat = _inputs(B, N, seed)
    got = ev.run(None, {"xyz": xyz.numpy(), "feat": feat.numpy()})
    with torch.no_grad():
        want = model(xyz, feat)
    for name, a, b in zip(OUTPUTS, got, want):
        b = b.numpy()
        assert a.shape == b.shape and a.dtype == b.dtype, name
        if b.dtype == np.int64:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, atol=1e-5, rtol=0, err_msg=name)


def test_onnxruntime_rejects_unknown_domain_cleanly(exported):
    # the custom nodes are for the Rust runtime (and the reference evaluator); onnxruntime has no
    # kernels for them. Guard that nothing silently produced a standard-op graph instead.
    ort = pytest.importorskip("onnxruntime")
    _, proto = exported
    with pytest.raises(Exception):
        ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
