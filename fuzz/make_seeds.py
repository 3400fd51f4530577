"""Writes the hand-made seeds of fuzz/seeds/ (the shipped files listed in
fuzz/seeds.txt are the rest of the seed corpus). Run from the repository root with
tools/.venv/bin/python fuzz/make_seeds.py; deterministic."""
import pathlib

import onnx
from onnx import TensorProto, helper

root = pathlib.Path("fuzz/seeds")


def put(target, name, data):
    d = root / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data)


# NOCS meta: instance id, class id (0 distractor, 1..6 bottle..mug), model name.
put("nocs_meta", "two_instances.txt", b"1 1 bottle_blue_google_norm\n2 6 mug_brown_starbucks_norm\n")
put("nocs_meta", "distractor.txt", b"1 0 distractor\n2 4 can_arizona_tea_norm\n")

# V4L2 buffers: [format (0 YUYV, 1 MJPG, 2 RGB3, 3 Z16), width-1, height-1, row padding] + payload.
put("v4l2_decode", "yuyv_4x2.bin", bytes([0, 3, 1, 0]) + bytes(range(16)))
put("v4l2_decode", "rgb3_2x2_pad2.bin", bytes([2, 1, 1, 2]) + bytes(range(16)))
put("v4l2_decode", "z16_3x2.bin", bytes([3, 2, 1, 0]) + bytes(range(12)))
for jpg in ["mjpg_422_48x32.jpg", "mjpg_422_48x32_nodht.jpg"]:
    put("v4l2_decode", jpg + ".bin", bytes([1, 47, 31, 0]) + pathlib.Path("tests/fixtures/capture", jpg).read_bytes())

# HTTP request heads.
for name, head in {
    "health.txt": b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    "stream_query.txt": b"GET /stream?x=1 HTTP/1.0\n\n",
    "post.txt": b"POST /metrics HTTP/1.1\r\nContent-Length: 3\r\n\r\nabc",
    "partial.txt": b"GET /lat",
}.items():
    put("http_request", name, head)


def graph(name, node, inputs, outputs):
    g = helper.make_graph([node], name, inputs, outputs)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17), helper.make_opsetid("ai.tricons", 1)])
    m.ir_version = 8
    return m.SerializeToString()


f = lambda n, shape: helper.make_tensor_value_info(n, TensorProto.FLOAT, shape)
i64 = lambda n, shape: helper.make_tensor_value_info(n, TensorProto.INT64, shape)
put("onnx_graph", "fps.onnx", graph(
    "fps", helper.make_node("FurthestPointSample", ["xyz"], ["idx"], domain="ai.tricons", npoint=8),
    [f("xyz", [1, 32, 3])], [i64("idx", [1, 8])]))
put("onnx_graph", "ball_query.onnx", graph(
    "bq", helper.make_node("BallQuery", ["xyz", "new_xyz"], ["idx"], domain="ai.tricons", radius=0.2, nsample=4),
    [f("xyz", [1, 32, 3]), f("new_xyz", [1, 8, 3])], [i64("idx", [1, 8, 4])]))
put("onnx_graph", "reduce_max.onnx", graph(
    "rm", helper.make_node("ReduceMaxAxis", ["x"], ["y"], domain="ai.tricons", axis=3),
    [f("x", [1, 4, 8, 5])], [f("y", [1, 4, 8])]))
put("onnx_graph", "upsample.onnx", graph(
    "up", helper.make_node("BilinearUpsample2x", ["x"], ["y"], domain="ai.tricons"),
    [f("x", [1, 2, 3, 3])], [f("y", [1, 2, 6, 6])]))
put("onnx_graph", "relu.onnx", graph("relu", helper.make_node("Relu", ["x"], ["y"]), [f("x", [2, 3])], [f("y", [2, 3])]))
