"""tricons and ROS 2, checked against independent implementations: bags written by the Python
``mcap`` + ``mcap-ros2-support`` writer replay exactly like the recording they came from; MCAP
files tricons writes read back in the Python ``mcap`` reader; and Eclipse Cyclone DDS (Python
binding) receives what ``tricons serve --ros2`` publishes, field for field as its JSON Lines.

All DDS traffic stays on loopback: Cyclone is configured for ``lo`` with multicast off and
127.0.0.1 as its only peer; tricons publishes on loopback only by default.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, find_tricons
from tricons_pose.rosbag import write_bag

DEMO = REPO / "tests" / "data" / "synthnocs-demo"
FRAME_ID = "camera_color_optical_frame"


def tricons(*args, check: bool = True, timeout: float = 900) -> subprocess.CompletedProcess:
    p = subprocess.run(
        [str(find_tricons()), *map(str, args)], cwd=REPO, capture_output=True, text=True, timeout=timeout
    )
    if check and p.returncode != 0:
        raise AssertionError(f"tricons {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return p


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def quat_to_matrix(q) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def assert_detections_equal_line(msg, line: dict) -> None:
    """A decoded Detection3DArray carries exactly what the JSON line says."""
    stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    assert abs(stamp - line["timestamp_s"]) < 1e-6
    assert msg.header.frame_id == FRAME_ID
    assert len(msg.detections) == len(line["instances"])
    for k, (det, inst) in enumerate(zip(msg.detections, line["instances"])):
        assert det.id == str(k)
        assert det.header.frame_id == FRAME_ID
        assert len(det.results) == 1
        hyp = det.results[0]
        assert hyp.hypothesis.class_id == inst["class"]
        assert hyp.hypothesis.score == inst["score"]
        p = hyp.pose.pose
        assert [p.position.x, p.position.y, p.position.z] == inst["t"]
        np.testing.assert_allclose(quat_to_matrix(p.orientation), np.array(inst["R"]), atol=1e-9)
        assert list(hyp.pose.covariance) == [0.0] * 36
        c = det.bbox.center
        assert (c.position.x, c.position.y, c.position.z) == (p.position.x, p.position.y, p.position.z)
        assert (c.orientation.x, c.orientation.w) == (p.orientation.x, p.orientation.w)
        assert [det.bbox.size.x, det.bbox.size.y, det.bbox.size.z] == inst["s"]


@pytest.fixture(scope="module")
def demo_replay(tmp_path_factory):
    """The demo recording replayed (shipped models), with its MCAP output."""
    d = tmp_path_factory.mktemp("demo-replay")
    tricons("replay", "--recording", DEMO, "--out", d / "demo.jsonl", "--mcap", d / "demo.mcap", "--threads", "1")
    return d


@pytest.mark.parametrize(
    "color,depth,compression", [("rgb8", "16UC1", "zstd"), ("bgr8", "32FC1", "lz4")], ids=["rgb8-mm-zstd", "bgr8-m-lz4"]
)
def test_a_python_written_bag_replays_exactly_like_its_recording(demo_replay, tmp_path, color, depth, compression):
    bag = write_bag(DEMO, tmp_path / "demo.mcap", color=color, depth=depth, compression=compression)
    tricons("replay", "--recording", bag, "--out", tmp_path / "bag.jsonl", "--threads", "1")
    from_rec = read_jsonl(demo_replay / "demo.jsonl")
    from_bag = read_jsonl(tmp_path / "bag.jsonl")
    assert [f["frame"] for f in from_bag] == [f"{i:06d}" for i in range(len(from_rec))]
    assert sum(len(f["instances"]) for f in from_rec) > 0
    for a, b in zip(from_rec, from_bag):
        assert abs(a["timestamp_s"] - b["timestamp_s"]) < 1e-9
        assert a["instances"] == b["instances"]
    # the metrics: the bag's predictions matched to the recording's ground truth by time
    tricons("eval", "--gt", DEMO, "--pred", tmp_path / "bag.jsonl", "--match", "timestamp", "--json", tmp_path / "e.json")
    ours = json.loads((tmp_path / "e.json").read_text())
    theirs = json.loads((demo_replay / "demo.eval.json").read_text())
    ours.pop("predictions", None), theirs.pop("predictions", None)
    assert ours == theirs


def test_tricons_mcap_reads_back_in_the_python_reader(demo_replay):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    lines = read_jsonl(demo_replay / "demo.jsonl")
    with open(demo_replay / "demo.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert topics == {
            "/tricons/detections": "vision_msgs/msg/Detection3DArray",
            "/tricons/markers": "visualization_msgs/msg/MarkerArray",
            "/tricons/overlay": "sensor_msgs/msg/Image",
        }
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        assert all(summary.schemas[c.schema_id].encoding == "ros2msg" for c in summary.channels.values())
        counts = summary.statistics.channel_message_counts
        assert sorted(counts.values()) == [len(lines)] * 3
        got: dict[str, list] = {t: [] for t in topics}
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            got[channel.topic].append((message.log_time, decoded))
    for (log_time, det), line in zip(got["/tricons/detections"], lines):
        assert log_time == round(line["timestamp_s"] * 1e9)
        assert_detections_equal_line(det, line)
    for (_, markers), line in zip(got["/tricons/markers"], lines):
        n = len(line["instances"])
        assert len(markers.markers) == 1 + 2 * n
        assert markers.markers[0].action == 3  # DELETEALL
        assert [m.type for m in markers.markers[1:]] == [5, 9] * n  # LINE_LIST, TEXT_VIEW_FACING
        assert [len(m.points) for m in markers.markers[1::2]] == [24] * n
        assert [m.text for m in markers.markers[2::2]] == [f"{i['class']} {i['score']:.2f}" for i in line["instances"]]
    for _, img in got["/tricons/overlay"]:
        assert (img.width, img.height, img.encoding, img.step) == (640, 480, "rgb8", 1920)
        assert len(img.data) == 640 * 480 * 3


def test_bags_without_the_topics_or_truncated_are_clear_errors(tmp_path):
    bag = write_bag(DEMO, tmp_path / "other.mcap", topics=("/a/color", "/a/depth", "/a/info"), frames=[0, 1])
    p = tricons("replay", "--recording", bag, "--out", tmp_path / "x.jsonl", check=False)
    assert p.returncode != 0 and "panicked" not in p.stderr
    assert "no messages on /camera/camera/color/image_raw" in p.stderr, p.stderr
    assert "--color-topic" in p.stderr and "/a/color (sensor_msgs/msg/Image, 2 messages)" in p.stderr, p.stderr
    # the same bag read from its own topics works
    tricons(
        "replay", "--recording", bag, "--out", tmp_path / "y.jsonl", "--masks", "model", "--color-topic", "/a/color",
        "--depth-topic", "/a/depth", "--camera-info-topic", "/a/info", "--threads", "1",
    )
    assert len(read_jsonl(tmp_path / "y.jsonl")) == 2
    # cut inside a chunk: an error naming the file, nothing written
    whole = write_bag(DEMO, tmp_path / "whole.mcap", compression="none", frames=[0, 1]).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) // 2])
    out = tmp_path / "cut.jsonl"
    p = tricons("replay", "--recording", cut, "--out", out, check=False)
    assert p.returncode != 0 and "panicked" not in p.stderr
    assert "cut.mcap" in p.stderr and "truncated" in p.stderr, p.stderr
    assert not out.exists()


CYCLONE_LOOPBACK = """<CycloneDDS xmlns="https://cdds.io/config"><Domain Id="any">
  <General>
    <Interfaces><NetworkInterface name="lo" address="127.0.0.1" multicast="false"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
</Domain></CycloneDDS>"""


def test_cyclone_dds_receives_what_serve_publishes(tmp_path):
    """`tricons serve --ros2` replays the demo in a loop; a Cyclone DDS reader in this process
    takes Detection3DArray and MarkerArray samples, and each equals the JSON line of its frame."""
    pytest.importorskip("cyclonedds")
    # RustDDS sends no multicast only because Linux's `lo` has no MULTICAST flag: where it has
    # one, discovery would go by multicast (on lo) and this test would send more than unicast
    lo_flags = Path("/sys/class/net/lo/flags")
    if lo_flags.exists() and int(lo_flags.read_text(), 16) & 0x1000:
        pytest.skip("the loopback interface has the MULTICAST flag: RustDDS would multicast on it")
    os.environ["CYCLONEDDS_URI"] = CYCLONE_LOOPBACK
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from ros2_types import Detection3DArray, MarkerArray

    domain = 20 + os.getpid() % 80  # apart from other DDS users of the machine
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile, Policy.History.KeepLast(100))
    dp = DomainParticipant(domain)
    det_reader = DataReader(dp, Topic(dp, "rt/tricons/detections", Detection3DArray, qos=qos), qos=qos)
    marker_reader = DataReader(dp, Topic(dp, "rt/tricons/markers", MarkerArray, qos=qos), qos=qos)
    out = tmp_path / "serve.jsonl"
    serve = subprocess.Popen(
        [str(find_tricons()), "serve", "--recording", str(DEMO), "--loop", "0", "--masks", "gt", "--no-listen",
         "--out", str(out), "--ros2", "--ros2-domain", str(domain), "--stats-interval", "0", "--threads", "1",
         "--mcap", str(tmp_path / "serve.mcap")],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    detections, markers = [], []
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and (len(detections) < 6 or len(markers) < 6):
            if serve.poll() is not None:
                break
            detections += det_reader.take(N=100)
            markers += marker_reader.take(N=100)
            time.sleep(0.05)
    finally:
        serve.send_signal(signal.SIGTERM)
        _, stderr = serve.communicate(timeout=60)
    assert serve.returncode == 0, stderr[-3000:]
    assert len(detections) >= 6 and len(markers) >= 6, f"{len(detections)} detections, {len(markers)} markers\n{stderr[-3000:]}"
    lines = {round(l["timestamp_s"] * 1e9): l for l in read_jsonl(out)}
    for msg in detections:
        line = lines[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec]
        assert_detections_equal_line(msg, line)
    assert any(len(m.detections) > 0 for m in detections)
    for msg in markers:
        stamp = msg.markers[0].header.stamp
        line = lines[stamp.sec * 1_000_000_000 + stamp.nanosec]
        assert len(msg.markers) == 1 + 2 * len(line["instances"])
        assert [m.text for m in msg.markers[2::2]] == [f"{i['class']} {i['score']:.2f}" for i in line["instances"]]
    # the MCAP written beside: completed at SIGTERM, one of each message per JSON line
    from mcap.reader import make_reader

    with open(tmp_path / "serve.mcap", "rb") as f:
        counts = make_reader(f).get_summary().statistics.channel_message_counts
    assert sorted(counts.values()) == [len(lines)] * 3
    assert not (tmp_path / "serve.mcap.part").exists()


def test_a_jpeg_bag_replays(tmp_path):
    """CompressedImage colour (lossy): every frame decodes and is estimated."""
    bag = write_bag(DEMO, tmp_path / "jpeg.mcap", color="jpeg")
    tricons("replay", "--recording", bag, "--out", tmp_path / "jpeg.jsonl", "--threads", "1")
    frames = read_jsonl(tmp_path / "jpeg.jsonl")
    assert len(frames) == 4 and sum(len(f["instances"]) for f in frames) > 0
