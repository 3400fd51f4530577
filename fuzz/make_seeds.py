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

# A decoder tail of the form pose::early_gather rewrites: x2 Resize, skip Concat, 1x1 Conv,
# Relu, 1x1 head, then the pixel gather at `choose` as image_encoder.gather_pixel_features
# exports it (sizes constant here).
c = lambda n, v, t=TensorProto.INT64: helper.make_tensor(n, t, [len(v)], v)
tail_nodes = [
    helper.make_node("Resize", ["low", "", "scales"], ["up"], mode="linear", coordinate_transformation_mode="half_pixel"),
    helper.make_node("Concat", ["up", "skip"], ["cat"], axis=1),
    helper.make_node("Conv", ["cat", "w1"], ["c1"], kernel_shape=[1, 1]),
    helper.make_node("Relu", ["c1"], ["r1"]),
    helper.make_node("Conv", ["r1", "w2", "b2"], ["feat"], kernel_shape=[1, 1]),
    helper.make_node("Reshape", ["feat", "s_bc_hw"], ["flat"]),
    helper.make_node("Transpose", ["flat"], ["rows_t"], perm=[0, 2, 1]),
    helper.make_node("Reshape", ["rows_t", "s_rows"], ["table"]),
    helper.make_node("Add", ["choose", "offsets"], ["at"]),
    helper.make_node("Reshape", ["at", "s_flat"], ["at_flat"]),
    helper.make_node("Gather", ["table", "at_flat"], ["picked"], axis=0),
]
tail = helper.make_graph(tail_nodes, "pixel_tail", [f("low", [1, 2, 2, 2]), f("skip", [1, 1, 4, 4]),
                                                    i64("choose", [1, 5])], [f("picked", [5, 2])], [
    c("scales", [1.0, 1.0, 2.0, 2.0], TensorProto.FLOAT),
    helper.make_tensor("w1", TensorProto.FLOAT, [3, 3, 1, 1], [0.5, -1.0, 0.25, 1.0, 0.0, -0.5, 0.125, 2.0, 1.0]),
    helper.make_tensor("w2", TensorProto.FLOAT, [2, 3, 1, 1], [1.0, 0.5, -0.25, -1.0, 0.75, 0.5]),
    c("b2", [0.1, -0.2], TensorProto.FLOAT),
    c("s_bc_hw", [1, 2, 16]), c("s_rows", [-1, 2]), helper.make_tensor("offsets", TensorProto.INT64, [1, 1], [0]),
    c("s_flat", [-1]),
])
tail_model = helper.make_model(tail, opset_imports=[helper.make_opsetid("", 17)])
tail_model.ir_version = 8
put("onnx_graph", "pixel_tail.onnx", tail_model.SerializeToString())

# A resampled map of the form pose::early_gather gathers at its source grid (the paper
# configuration's image encoder): MatMul(MatMul(rows, low), cols) from 3x3 to 6x6 (two
# taps per row and column, one dense row), then the same pixel gather.
resample_nodes = [
    helper.make_node("MatMul", ["rows", "low"], ["tall"]),
    helper.make_node("MatMul", ["tall", "cols"], ["feat"]),
] + tail_nodes[5:]
rows = [0.75, 0.25, 0, 0.25, 0.75, 0, 0, 0.75, 0.25, 0, 0.25, 0.75, 0.2, 0.3, 0.5, 0, 0, 1.0]
cols = [1.0, 0.75, 0.25, 0, 0, 0, 0, 0.25, 0.75, 0.75, 0.25, 0, 0, 0, 0, 0.25, 0.75, 1.0]
resample = helper.make_graph(resample_nodes, "resample_tail", [f("low", [1, 2, 3, 3]), i64("choose", [1, 5])],
                             [f("picked", [5, 2])], [
    helper.make_tensor("rows", TensorProto.FLOAT, [6, 3], rows),
    helper.make_tensor("cols", TensorProto.FLOAT, [3, 6], cols),
    c("s_bc_hw", [1, 2, 36]), c("s_rows", [-1, 2]), helper.make_tensor("offsets", TensorProto.INT64, [1, 1], [0]),
    c("s_flat", [-1]),
])
resample_model = helper.make_model(resample, opset_imports=[helper.make_opsetid("", 17)])
resample_model.ir_version = 8
put("onnx_graph", "resample_tail.onnx", resample_model.SerializeToString())

# ROS 2 bags (MCAP): tiny 4x3 frames on the topics the ros2_bag harness reads, written by
# the Python mcap-ros2-support writer (uncompressed, zstd, lz4; raw and jpeg colour).
import io
import struct
import sys

sys.path.insert(0, "tools")
from mcap.writer import CompressionType  # noqa: E402
from mcap_ros2.writer import Writer  # noqa: E402
from PIL import Image as PilImage  # noqa: E402
from tricons_pose.rosbag import CAMERA_INFO_DEF, COMPRESSED_DEF, IMAGE_DEF  # noqa: E402


def bag(color, depth, compression):
    out = io.BytesIO()
    w = Writer(out, compression=compression)
    img = w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
    jpg = w.register_msgdef("sensor_msgs/msg/CompressedImage", COMPRESSED_DEF)
    info = w.register_msgdef("sensor_msgs/msg/CameraInfo", CAMERA_INFO_DEF)
    for i in range(2):
        header = {"stamp": {"sec": 5, "nanosec": i * 100_000_000}, "frame_id": "cam"}
        k = [4.0, 0.0, 1.5, 0.0, 4.0, 1.0, 0.0, 0.0, 1.0]
        w.write_message("/i", info, {"header": header, "height": 3, "width": 4, "k": k}, log_time=i)
        pixels = bytes((7 * j + i) % 256 for j in range(36))
        if color == "jpeg":
            buf = io.BytesIO()
            PilImage.frombytes("RGB", (4, 3), pixels).save(buf, format="JPEG")
            w.write_message("/c", jpg, {"header": header, "format": "jpeg", "data": buf.getvalue()}, log_time=i)
        else:
            msg = {"header": header, "height": 3, "width": 4, "encoding": color, "step": 12, "data": pixels}
            w.write_message("/c", img, msg, log_time=i)
        if depth == "32FC1":
            data = b"".join(struct.pack("<f", 0.5 + 0.01 * j) for j in range(12))
            step = 16
        else:
            data = b"".join((500 + j).to_bytes(2, "little") for j in range(12))
            step = 8
        msg = {"header": header, "height": 3, "width": 4, "encoding": depth, "step": step, "data": data}
        w.write_message("/d", img, msg, log_time=i)
    w.finish()
    return out.getvalue()


put("ros2_bag", "rgb8_16uc1_none.mcap", bag("rgb8", "16UC1", CompressionType.NONE))
put("ros2_bag", "bgr8_32fc1_zstd.mcap", bag("bgr8", "32FC1", CompressionType.ZSTD))
put("ros2_bag", "jpeg_16uc1_lz4.mcap", bag("jpeg", "16UC1", CompressionType.LZ4))
