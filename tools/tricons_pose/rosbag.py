"""Write a tricons recording as a ROS 2 bag (MCAP), with the Python ``mcap`` and
``mcap-ros2-support`` packages: an encoder independent of tricons' own (Rust) one.

The bag has what a RealSense camera driver publishes: ``sensor_msgs/Image`` colour (rgb8 or
bgr8) or ``sensor_msgs/CompressedImage`` (jpeg), depth aligned to colour (``16UC1`` millimetres
or ``32FC1`` metres) and the colour ``sensor_msgs/CameraInfo``, on the RealSense wrapper's
default topics, each stamped with the frame's recording time::

    python -m tricons_pose.rosbag --recording ../tests/data/synthnocs-demo --out demo.mcap
    tricons replay --recording demo.mcap

The message definitions below are written out here (not read from the Rust sources), so a bag
from this module checks tricons' reader against an independent description of the messages.
"""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path

import numpy as np
from PIL import Image as PilImage

COLOR_TOPIC = "/camera/camera/color/image_raw"
COMPRESSED_TOPIC = "/camera/camera/color/image_raw/compressed"
DEPTH_TOPIC = "/camera/camera/aligned_depth_to_color/image_raw"
INFO_TOPIC = "/camera/camera/color/camera_info"
FRAME_ID = "camera_color_optical_frame"

_SEP = "=" * 80
_HEADER = f"""{_SEP}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_SEP}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
IMAGE_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    "uint32 step\nuint8[] data\n" + _HEADER
)
COMPRESSED_DEF = "std_msgs/Header header\nstring format\nuint8[] data\n" + _HEADER
CAMERA_INFO_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
    "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n"
    f"{_SEP}\nMSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\n"
    "uint32 width\nbool do_rectify\n" + _HEADER
)


def _stamp(t_s: float) -> dict:
    ns = int(round(t_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def write_bag(
    recording: Path,
    out: Path,
    *,
    color: str = "rgb8",
    depth: str = "16UC1",
    compression: str = "zstd",
    frames: list[int] | None = None,
    topics: tuple[str, str, str] | None = None,
) -> Path:
    """Writes ``recording`` (a tricons recording directory) as a ROS 2 bag at ``out``.

    ``color``: ``rgb8``, ``bgr8`` or ``jpeg``; ``depth``: ``16UC1`` or ``32FC1``;
    ``compression``: ``zstd``, ``lz4`` or ``none``; ``frames``: indices to include (all);
    ``topics``: (colour, depth, camera info) instead of the RealSense defaults.
    """
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer

    manifest = json.loads((recording / "manifest.json").read_text())
    k = manifest["intrinsics"]
    scale_m = manifest["depth_scale_m"]
    entries = manifest["frames"]
    if frames is not None:
        entries = [entries[i] for i in frames]
    color_topic, depth_topic, info_topic = topics or (
        COMPRESSED_TOPIC if color == "jpeg" else COLOR_TOPIC,
        DEPTH_TOPIC,
        INFO_TOPIC,
    )
    kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    with open(out, "wb") as f:
        w = Writer(f, compression=kind)
        image_schema = w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        compressed_schema = w.register_msgdef("sensor_msgs/msg/CompressedImage", COMPRESSED_DEF)
        info_schema = w.register_msgdef("sensor_msgs/msg/CameraInfo", CAMERA_INFO_DEF)
        for e in entries:
            t_ns = int(round(e["timestamp_s"] * 1e9))
            header = {"stamp": _stamp(e["timestamp_s"]), "frame_id": FRAME_ID}
            rgb = np.asarray(PilImage.open(recording / e["color"]).convert("RGB"))
            h, wd = rgb.shape[:2]
            w.write_message(
                info_topic,
                info_schema,
                {
                    "header": header,
                    "height": h,
                    "width": wd,
                    "distortion_model": "plumb_bob",
                    "d": [0.0] * 5,
                    "k": [k["fx"], 0.0, k["cx"], 0.0, k["fy"], k["cy"], 0.0, 0.0, 1.0],
                    "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    "p": [k["fx"], 0.0, k["cx"], 0.0, 0.0, k["fy"], k["cy"], 0.0, 0.0, 0.0, 1.0, 0.0],
                    "binning_x": 0,
                    "binning_y": 0,
                    "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
                },
                log_time=t_ns,
                publish_time=t_ns,
            )
            if color == "jpeg":
                buf = io.BytesIO()
                PilImage.fromarray(rgb).save(buf, format="JPEG", quality=95)
                msg = {"header": header, "format": "jpeg", "data": buf.getvalue()}
                w.write_message(color_topic, compressed_schema, msg, log_time=t_ns, publish_time=t_ns)
            else:
                pixels = rgb[:, :, ::-1] if color == "bgr8" else rgb
                msg = {
                    "header": header,
                    "height": h,
                    "width": wd,
                    "encoding": color,
                    "is_bigendian": 0,
                    "step": 3 * wd,
                    "data": np.ascontiguousarray(pixels).tobytes(),
                }
                w.write_message(color_topic, image_schema, msg, log_time=t_ns, publish_time=t_ns)
            raw = np.asarray(PilImage.open(recording / e["depth"])).astype(np.uint16)
            if depth == "32FC1":
                data = (raw.astype(np.float64) * scale_m).astype("<f4")
                data[raw == 0] = np.nan
                step = 4 * wd
            else:
                if abs(scale_m - 1e-3) > 1e-12:
                    raise ValueError(f"16UC1 depth is millimetres; the recording's unit is {scale_m} m")
                data = raw.astype("<u2")
                step = 2 * wd
            msg = {
                "header": header,
                "height": h,
                "width": wd,
                "encoding": depth,
                "is_bigendian": 0,
                "step": step,
                "data": data.tobytes(),
            }
            w.write_message(depth_topic, image_schema, msg, log_time=t_ns, publish_time=t_ns)
        w.finish()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--recording", type=Path, required=True, help="tricons recording directory")
    p.add_argument("--out", type=Path, required=True, help="bag to write (.mcap)")
    p.add_argument("--color", choices=["rgb8", "bgr8", "jpeg"], default="rgb8")
    p.add_argument("--depth", choices=["16UC1", "32FC1"], default="16UC1")
    p.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd")
    a = p.parse_args()
    write_bag(a.recording, a.out, color=a.color, depth=a.depth, compression=a.compression)
    print(a.out)


if __name__ == "__main__":
    main()
