"""Golden fixtures for the segmentation operators, produced by onnxruntime.

Writes tests/fixtures/segment/{roi_align,nms}.json: small random inputs and
onnxruntime's outputs for single-node ONNX graphs (RoiAlign at opset 10 and 16,
both coordinate modes, sampling ratio 0 and 2, avg and max; NonMaxSuppression
with and without a score threshold, both box formats). Run from tools/:

    python golden/make_segment_fixtures.py
"""

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper

OUT = Path(__file__).resolve().parents[2] / "tests" / "fixtures" / "segment"


def run_node(node, inputs: dict, opset: int, out_type):
    graph = helper.make_graph(
        [node],
        "g",
        [helper.make_tensor_value_info(k, TensorProto.INT64 if v.dtype == np.int64 else TensorProto.FLOAT, v.shape)
         for k, v in inputs.items()],
        [helper.make_tensor_value_info(node.output[0], out_type, None)],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 8
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, inputs)[0]


def roi_align_cases(rng):
    cases = []
    x = rng.standard_normal((2, 3, 11, 14)).astype(np.float32)
    rois = np.array(
        [
            [1.0, 2.0, 20.0, 15.0],
            [0.0, 0.0, 27.9, 21.9],  # whole map at scale 0.5
            [-4.0, -3.0, 6.0, 5.0],  # partly outside
            [10.3, 7.7, 10.9, 8.1],  # smaller than a pixel
            [25.0, 19.0, 40.0, 30.0],  # mostly outside
        ],
        np.float32,
    )
    batch = np.array([0, 1, 0, 1, 0], np.int64)
    for opset, ctm in [(10, None), (16, "half_pixel"), (16, "output_half_pixel")]:
        for sr in (0, 2):
            for mode in ("avg", "max"):
                attrs = dict(output_height=3, output_width=4, sampling_ratio=sr, spatial_scale=0.5, mode=mode)
                if ctm is not None:
                    attrs["coordinate_transformation_mode"] = ctm
                node = helper.make_node("RoiAlign", ["X", "rois", "batch_indices"], ["Y"], **attrs)
                y = run_node(node, {"X": x, "rois": rois, "batch_indices": batch}, opset, TensorProto.FLOAT)
                cases.append({"opset": opset, "attrs": attrs, "y": y.reshape(-1).tolist(), "y_shape": list(y.shape)})
    return {"x": x.reshape(-1).tolist(), "x_shape": list(x.shape), "rois": rois.reshape(-1).tolist(),
            "batch_indices": batch.tolist(), "cases": cases}


def nms_cases(rng):
    cases = []
    for k, (n, center, thr, score_thr, max_out) in enumerate(
        [(60, 0, 0.5, None, 0), (200, 0, 0.3, 0.2, 0), (80, 1, 0.6, None, 10), (150, 0, 0.7, 0.5, 0)]
    ):
        xy = rng.uniform(0, 100, (n, 2)).astype(np.float32)
        wh = rng.uniform(2, 30, (n, 2)).astype(np.float32)
        if center:
            boxes = np.concatenate([xy, wh], 1)
        else:
            boxes = np.concatenate([xy[:, ::-1], xy[:, ::-1] + wh[:, ::-1]], 1)  # y1 x1 y2 x2
            flip = rng.random(n) < 0.2  # some corners given in the other order
            boxes[flip] = boxes[flip][:, [2, 3, 0, 1]]
        scores = rng.random((1, 2, n)).astype(np.float32)
        scores[0, 0, 5] = scores[0, 0, 6]  # a tie
        inputs = {"boxes": boxes[None].astype(np.float32), "scores": scores,
                  "max_out": np.array([max_out], np.int64), "iou": np.array([thr], np.float32)}
        names = ["boxes", "scores", "max_out", "iou"]
        if score_thr is not None:
            inputs["score_thr"] = np.array([score_thr], np.float32)
            names.append("score_thr")
        node = helper.make_node("NonMaxSuppression", names, ["sel"], center_point_box=center)
        sel = run_node(node, inputs, 11, TensorProto.INT64)
        cases.append({"center_point_box": center, "iou_threshold": thr, "score_threshold": score_thr,
                      "max_output": max_out, "n": n, "boxes": boxes.reshape(-1).tolist(),
                      "scores": scores.reshape(-1).tolist(), "selected": sel.reshape(-1).tolist()})
    return cases


def main():
    rng = np.random.default_rng(20261122)
    OUT.mkdir(parents=True, exist_ok=True)
    meta = {"producer": f"onnxruntime {ort.__version__}, onnx {onnx.__version__}"}
    (OUT / "roi_align.json").write_text(json.dumps({**meta, **roi_align_cases(rng)}) + "\n")
    (OUT / "nms.json").write_text(json.dumps({**meta, "cases": nms_cases(rng)}) + "\n")
    print(f"wrote {OUT}/roi_align.json, nms.json")


if __name__ == "__main__":
    main()
