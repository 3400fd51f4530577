#!/usr/bin/env python3
"""Golden fixtures for `tricons::metrics`, produced by the NOCS reference code.

The NOCS authors' evaluation (`compute_degree_cm_mAP` in `utils.py` of
https://github.com/hughw19/NOCS_CVPR2019) is *not* copied here: the functions
are read at run time from a checkout the user points to (`--nocs-utils`),
picked out of the module with `ast` and executed in a namespace holding numpy
(the module itself imports tensorflow, cv2, skimage, ... at the top, none of
which the evaluation needs). Plotting calls are sent to a no-op stand-in and
the pickles it writes go to a temporary directory.

For each case this script builds deterministic (seeded) frames of ground truth
and predictions, writes them in the tricons JSON format (GT `{id, class, R, t,
s, handle_visible}`, predictions `{class, score, R, t, s}`), converts them to
the reference's input (`gt_RTs` = [|s| R, t], `gt_scales` = s/|s|, ...), runs
the reference with use_matches_for_pose=True / iou_pose_thres=0.1 (the
protocol of NOCS, DPDN, AG-Pose tables) and stores its AP values in percent.

    python tools/golden/make_nocs_metric_fixtures.py \
        --nocs-utils PATH/NOCS_CVPR2019/utils.py --out tests/fixtures/nocs_reference

`--verify` re-runs the reference on the inputs of fixtures already in `--out`
and compares with their stored values (nothing is written). `--agpose-utils
PATH/AG-Pose/utils/evaluation_utils.py` additionally runs AG-Pose's copy
(`compute_independent_mAP`) and records that it gives the same numbers.
"""

import argparse
import ast
import contextlib
import io
import json
import math
import os
import pickle
import subprocess
import sys
import tempfile

import numpy as np

SYNSET_NAMES = ["BG", "bottle", "bowl", "camera", "can", "laptop", "mug"]
CLASSES = SYNSET_NAMES[1:]
SYMMETRIC = {"bottle", "bowl", "can"}

# What is asked of the reference, and where each tricons metric is read.
DEGREE_THRESHOLDS = [5, 10, 15]  # 15 and 10 cm only because the reference's
SHIFT_THRESHOLDS = [2, 5, 10]  # final print statements look them up.
IOU_THRESHOLDS = [0.10, 0.25, 0.50, 0.75]
IOU_POSE_THRES = 0.10
IOU_METRICS = {"IoU25": 0.25, "IoU50": 0.50, "IoU75": 0.75}
POSE_METRICS = {"5deg2cm": (5, 2), "5deg5cm": (5, 5), "10deg2cm": (10, 2), "10deg5cm": (10, 5)}
METRICS = list(IOU_METRICS) + list(POSE_METRICS)

# Pairs whose IoU or pose error lies this close to a threshold are redrawn:
# tricons documents that it differs from the reference only at exact ties
# (float32 IoUs, float32 recalls) and at arccos NaN.
IOU_MARGIN = 1e-5
POSE_MARGIN = 1e-4

NOCS_FUNCTIONS = [
    "get_3d_bbox",
    "transform_coordinates_3d",
    "trim_zeros",
    "compute_3d_iou_new",
    "compute_3d_matches",
    "compute_ap_from_matches_scores",
    "compute_RT_degree_cm_symmetry",
    "compute_RT_overlaps",
    "compute_match_from_degree_cm",
    "compute_degree_cm_mAP",
]
AGPOSE_FUNCTIONS = NOCS_FUNCTIONS[:-1] + ["compute_independent_mAP"]

SIZES = {  # typical tight box sizes in metres (x, y, z)
    "bottle": (0.08, 0.22, 0.08),
    "bowl": (0.16, 0.07, 0.16),
    "camera": (0.12, 0.09, 0.10),
    "can": (0.07, 0.12, 0.07),
    "laptop": (0.32, 0.22, 0.26),
    "mug": (0.13, 0.10, 0.09),
}


# --------------------------------------------------------------------------
# Loading the reference


class _NoPlot:
    """Stands in for matplotlib.pyplot, figures and axes: every call is a no-op."""

    def __getattr__(self, _name):
        return self

    def __call__(self, *args, **kwargs):
        return self


def _identity(x, *args, **kwargs):
    return x


def load_functions(path, names):
    """Extracts the named top-level functions of the module at `path` and
    executes them in a namespace with numpy, math, os, pickle and a no-op
    plotting stand-in. Returns that namespace."""
    with open(path, encoding="utf-8") as f:
        source = f.read()
    tree = ast.parse(source, filename=path)
    found = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    missing = [n for n in names if n not in found]
    if missing:
        raise SystemExit(f"{path}: functions not found: {', '.join(missing)}")
    module = ast.Module(body=[found[n] for n in names], type_ignores=[])
    namespace = {
        "np": np,
        "math": math,
        "os": os,
        "cPickle": pickle,
        "plt": _NoPlot(),
        "tqdm": _identity,
        "__name__": "nocs_reference",
    }
    exec(compile(module, path, "exec"), namespace)
    return namespace


def git_commit(path):
    """The commit of the checkout holding `path`, or None."""
    try:
        out = subprocess.run(
            ["git", "-C", os.path.dirname(os.path.abspath(path)), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


# --------------------------------------------------------------------------
# Conversion tricons format -> reference input


def to_rt(inst):
    """[|s| R, t; 0 0 0 1] and s/|s|, the reference's pose and scale."""
    s = np.array(inst["s"], dtype=np.float64)
    norm = np.linalg.norm(s)
    rt = np.eye(4)
    rt[:3, :3] = np.array(inst["R"], dtype=np.float64) * norm
    rt[:3, 3] = inst["t"]
    return rt, s / norm


def to_reference_frame(frame):
    """One tricons frame (gt, pred lists) as the reference's result dict."""
    gts, preds = frame["gt"], frame["pred"]
    gt_rts = [to_rt(g) for g in gts]
    pred_rts = [to_rt(p) for p in preds]
    return {
        "gt_class_ids": np.array([SYNSET_NAMES.index(g["class"]) for g in gts], dtype=np.int32),
        "gt_RTs": np.array([r for r, _ in gt_rts]).reshape(-1, 4, 4),
        "gt_scales": np.array([s for _, s in gt_rts]).reshape(-1, 3),
        "gt_handle_visibility": np.array([1 if g["handle_visible"] else 0 for g in gts], dtype=np.int32),
        "pred_class_ids": np.array([SYNSET_NAMES.index(p["class"]) for p in preds], dtype=np.int32),
        # 2D boxes only have to be non-zero (trim_zeros); they affect nothing else.
        "pred_bboxes": np.array([[10.0, 20.0, 110.0, 120.0] for _ in preds]).reshape(-1, 4),
        "pred_scores": np.array([p["score"] for p in preds], dtype=np.float64),
        "pred_RTs": np.array([r for r, _ in pred_rts]).reshape(-1, 4, 4),
        "pred_scales": np.array([s for _, s in pred_rts]).reshape(-1, 3),
    }


def run_reference(ns, frames, agpose=False):
    """Runs the reference on tricons-format frames; returns {class: {metric:
    fraction or nan}} and {metric: the reference's mean row}."""
    return run_reference_results(ns, [to_reference_frame(f) for f in frames], agpose)


def run_reference_results(ns, results, agpose=False):
    """Runs the reference on its own per-image result dicts (``gt_*`` and ``pred_*``
    arrays, as its evaluation unpickles them); returns as :func:`run_reference`."""
    with tempfile.TemporaryDirectory() as log_dir, contextlib.redirect_stdout(io.StringIO()):
        with np.errstate(invalid="ignore", divide="ignore"):
            if agpose:
                iou_aps, pose_aps = ns["compute_independent_mAP"](
                    results,
                    SYNSET_NAMES,
                    degree_thresholds=DEGREE_THRESHOLDS,
                    shift_thresholds=SHIFT_THRESHOLDS,
                    iou_3d_thresholds=IOU_THRESHOLDS,
                    iou_pose_thres=IOU_POSE_THRES,
                    use_matches_for_pose=True,
                )
            else:
                iou_aps, pose_aps = ns["compute_degree_cm_mAP"](
                    results,
                    SYNSET_NAMES,
                    log_dir,
                    degree_thresholds=DEGREE_THRESHOLDS,
                    shift_thresholds=SHIFT_THRESHOLDS,
                    iou_3d_thresholds=IOU_THRESHOLDS,
                    iou_pose_thres=IOU_POSE_THRES,
                    use_matches_for_pose=True,
                )
    # Index as the reference's own prints do: lists extended with 360 / 100.
    iou_list = list(IOU_THRESHOLDS)
    degree_list = list(DEGREE_THRESHOLDS) + [360]
    shift_list = list(SHIFT_THRESHOLDS) + [100]

    def row(r):
        out = {}
        for name, thr in IOU_METRICS.items():
            out[name] = float(iou_aps[r, iou_list.index(thr)])
        for name, (deg, cm) in POSE_METRICS.items():
            out[name] = float(pose_aps[r, degree_list.index(deg), shift_list.index(cm)])
        return out

    per_class = {c: row(SYNSET_NAMES.index(c)) for c in CLASSES}
    return per_class, row(-1)


# --------------------------------------------------------------------------
# Random scenes


def rot_axis_angle(axis, angle):
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def rot_y(angle):
    return rot_axis_angle([0, 1, 0], angle)


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def small_rotation(rng, sigma_deg, min_deg=0.05):
    """A rotation about a random axis by |N(0, sigma)| degrees, at least min_deg
    (never exactly the identity: keeps the reference's arccos away from NaN)."""
    angle = max(abs(rng.normal(0.0, sigma_deg)), min_deg)
    return rot_axis_angle(rng.normal(size=3), math.radians(angle))


def tabletop_rotation(rng):
    """Object upright on a table seen by a camera tilted down 30-70 degrees."""
    tilt = rot_axis_angle([1, 0, 0], math.radians(rng.uniform(30, 70)))
    return tilt @ rot_y(rng.uniform(0, 2 * math.pi)) @ small_rotation(rng, 2.0)


def orthonormalise(r):
    u, _, vt = np.linalg.svd(r)
    out = u @ vt
    if np.linalg.det(out) < 0:
        u[:, -1] *= -1
        out = u @ vt
    return out


def as_list(a, digits):
    return [round(float(v), digits) for v in np.asarray(a).ravel()]


def rounded_rotation(r):
    """Rotation rows rounded to 12 decimals (orthonormal to ~1e-12)."""
    r = orthonormalise(r)
    return [as_list(row, 12) for row in r]


def make_gt(rng, iid, cls, p):
    size = np.array(SIZES[cls]) * rng.uniform(0.8, 1.25, size=3)
    if p["upright"] and rng.uniform() < 0.8:
        r = tabletop_rotation(rng)
    else:
        r = random_rotation(rng)
    spread = p["spread"]
    t = np.array([rng.uniform(-spread, spread), rng.uniform(-0.7 * spread, 0.7 * spread), rng.uniform(*p["depth"])])
    if cls == "mug":
        handle = bool(rng.uniform() < p["p_handle_visible"])
    else:
        handle = True
    return {
        "id": iid,
        "class": cls,
        "R": rounded_rotation(r),
        "t": as_list(t, 9),
        "s": as_list(size, 9),
        "handle_visible": handle,
    }


def perturb(rng, g, p, cls=None, scale=1.0):
    """A prediction of GT `g`: rotation, translation and size noise; symmetric
    objects (and some mugs) optionally turned about their y axis by a large angle."""
    r = np.array(g["R"])
    c = cls or g["class"]
    if g["class"] in SYMMETRIC or g["class"] == "mug":
        if rng.uniform() < p["p_big_y_turn"]:
            r = r @ rot_y(math.radians(rng.uniform(20, 340)))
    r = r @ small_rotation(rng, p["rot_sigma_deg"] * scale)
    t = np.array(g["t"]) + rng.normal(0.0, p["trans_sigma_cm"] * scale / 100.0, size=3)
    s = np.array(g["s"]) * (1 + rng.uniform(-p["size_frac"], p["size_frac"], size=3) * scale)
    return {"class": c, "score": 0.0, "R": rounded_rotation(r), "t": as_list(t, 9), "s": as_list(s, 9)}


def random_prediction(rng, cls, p):
    size = np.array(SIZES[cls]) * rng.uniform(0.7, 1.3, size=3)
    spread = p["spread"]
    t = np.array([rng.uniform(-spread, spread), rng.uniform(-0.7 * spread, 0.7 * spread), rng.uniform(*p["depth"])])
    return {
        "class": cls,
        "score": 0.0,
        "R": rounded_rotation(random_rotation(rng)),
        "t": as_list(t, 9),
        "s": as_list(size, 9),
    }


def make_frame(rng, p):
    n = int(rng.integers(p["objects"][0], p["objects"][1] + 1))
    pool = p["classes"]
    gts = [make_gt(rng, i + 1, pool[int(rng.integers(len(pool)))], p) for i in range(n)]
    preds = []
    for g in gts:
        if rng.uniform() < p["p_miss"]:
            continue
        pr = perturb(rng, g, p)
        pr["score"] = rng.uniform(*p["tp_score"])
        preds.append(pr)
        if rng.uniform() < p["p_duplicate"]:
            d = perturb(rng, g, p, scale=1.5)
            d["score"] = rng.uniform(0.05, 1.0)
            preds.append(d)
        if rng.uniform() < p["p_wrong_class"]:
            other = [c for c in CLASSES if c != g["class"]]
            w = perturb(rng, g, p, cls=other[int(rng.integers(len(other)))])
            w["score"] = rng.uniform(0.05, 1.0)
            preds.append(w)
    for _ in range(int(rng.integers(p["false_positives"][0], p["false_positives"][1] + 1))):
        fp_pool = p.get("fp_classes", CLASSES)
        f = random_prediction(rng, fp_pool[int(rng.integers(len(fp_pool)))], p)
        f["score"] = rng.uniform(*p["fp_score"])
        preds.append(f)
    order = rng.permutation(len(preds))
    preds = [preds[i] for i in order]
    for pr in preds:
        pr["score"] = round(float(pr["score"]), 9)
    return {"gt": gts, "pred": preds}


DEFAULTS = {
    "frames": 4,
    "objects": (2, 6),
    "classes": CLASSES,
    "upright": True,
    "spread": 0.30,
    "depth": (0.5, 1.2),
    "p_handle_visible": 0.5,
    "rot_sigma_deg": 4.0,
    "trans_sigma_cm": 1.5,
    "size_frac": 0.10,
    "p_big_y_turn": 0.3,
    "p_miss": 0.15,
    "p_duplicate": 0.15,
    "p_wrong_class": 0.1,
    "false_positives": (0, 2),
    "tp_score": (0.3, 1.0),
    "fp_score": (0.0, 1.0),
}

CASES = [
    (
        "noisy_all_classes",
        101,
        "GT scenes over all six classes, predictions = GT with realistic noise",
        {"frames": 5, "objects": (3, 7)},
    ),
    ("noisy_many_frames", 102, "8 frames of 1-8 objects, realistic noise", {"frames": 8, "objects": (1, 8)}),
    (
        "low_noise",
        103,
        "small errors (1 deg, 0.5 cm, 3 % size): high APs, few misses",
        {"rot_sigma_deg": 1.0, "trans_sigma_cm": 0.5, "size_frac": 0.03, "p_miss": 0.05, "false_positives": (0, 1)},
    ),
    (
        "heavy_noise",
        104,
        "large errors (8 deg, 3 cm, 25 % size): many pose and IoU75 failures",
        {"rot_sigma_deg": 8.0, "trans_sigma_cm": 3.0, "size_frac": 0.25},
    ),
    (
        "false_positives_high_scores",
        105,
        "many random false positives (some of classes absent there) scored above the true positives",
        {"false_positives": (2, 5), "tp_score": (0.1, 0.7), "fp_score": (0.4, 1.0), "p_wrong_class": 0.3},
    ),
    (
        "duplicates",
        106,
        "many duplicate predictions of the same object with independent noise and scores",
        {"p_duplicate": 0.8, "false_positives": (0, 1)},
    ),
    (
        "missed_ground_truth",
        107,
        "half the GT missed, some classes with GT and no prediction at all",
        {"p_miss": 0.5, "frames": 5},
    ),
    (
        "mugs_handle_visibility",
        108,
        "mugs only, handle visible or hidden, predictions often turned about y by large angles",
        {"classes": ["mug"], "objects": (2, 5), "p_big_y_turn": 0.6, "fp_classes": ["mug"], "frames": 5},
    ),
    (
        "symmetric_y_turns",
        109,
        "bottles, bowls, cans with predictions turned about their y axis by 20-340 deg",
        {"classes": ["bottle", "bowl", "can"], "p_big_y_turn": 1.0, "objects": (2, 6), "frames": 5},
    ),
    (
        "classes_without_gt",
        110,
        "no laptop/camera GT; laptop predictions exist (reference NaN), camera neither (reference 0)",
        {
            "classes": ["bottle", "bowl", "can", "mug"],
            "fp_classes": ["laptop", "bottle", "mug"],
            "false_positives": (1, 3),
            "p_wrong_class": 0.0,
        },
    ),
    (
        "crowded_same_class",
        111,
        "objects packed close (often the same class) so predictions compete for GT",
        {"spread": 0.06, "objects": (4, 8), "classes": ["can", "mug", "camera"], "p_duplicate": 0.3},
    ),
    (
        "random_orientations",
        112,
        "arbitrary GT orientations (not upright), realistic noise",
        {"upright": False},
    ),
    (
        "near_and_far",
        113,
        "depths from 0.3 m to 2.5 m (the published IoU depends on position)",
        {"depth": (0.3, 2.5), "spread": 0.5},
    ),
    (
        "gate_band",
        114,
        "large translation errors (4-8 cm): many pairs pass the IoU 0.1 gate but fail pose thresholds",
        {"trans_sigma_cm": 5.0, "rot_sigma_deg": 6.0},
    ),
    (
        "single_frame",
        115,
        "one frame, three objects, one false positive",
        {"frames": 1, "objects": (3, 3), "p_miss": 0.0, "false_positives": (1, 1)},
    ),
]


# --------------------------------------------------------------------------
# Margin checks (with the reference's own functions)


def close_calls(ns, frames):
    """Pairs of one class whose reference IoU or pose error is within the
    margins of a threshold, or NaN; and duplicate scores within a class."""
    problems = []
    scores = {c: [] for c in CLASSES}
    for fi, frame in enumerate(frames):
        for pi, p in enumerate(frame["pred"]):
            scores[p["class"]].append(p["score"])
            prt, ps = to_rt(p)
            for gi, g in enumerate(frame["gt"]):
                if g["class"] != p["class"]:
                    continue
                grt, gs = to_rt(g)
                hv = 1 if (g["handle_visible"] or g["class"] != "mug") else 0
                with contextlib.redirect_stdout(io.StringIO()), np.errstate(invalid="ignore", divide="ignore"):
                    iou = ns["compute_3d_iou_new"](prt, grt, ps, gs, hv, p["class"], g["class"])
                    class_id = SYNSET_NAMES.index(g["class"])
                    deg, cm = ns["compute_RT_degree_cm_symmetry"](prt, grt, class_id, hv, SYNSET_NAMES)
                if not np.isfinite(iou) or any(abs(iou - t) < IOU_MARGIN for t in IOU_THRESHOLDS):
                    problems.append((fi, pi, f"IoU {iou}"))
                if not (np.isfinite(deg) and np.isfinite(cm)):
                    problems.append((fi, pi, f"pose error {deg} {cm}"))
                elif any(abs(deg - d) < POSE_MARGIN for d in DEGREE_THRESHOLDS) or any(
                    abs(cm - c) < POSE_MARGIN for c in SHIFT_THRESHOLDS
                ):
                    problems.append((fi, pi, f"pose error {deg} deg {cm} cm"))
    for c, s in scores.items():
        if len(set(s)) != len(s):
            problems.append((-1, -1, f"duplicate scores in class {c}"))
    return problems


# --------------------------------------------------------------------------
# Fixtures


def percent(v):
    return None if not np.isfinite(v) else float(v) * 100.0


def build_case(ns, name, seed, description, overrides):
    p = dict(DEFAULTS)
    p.update(overrides)
    for attempt in range(100):
        rng = np.random.default_rng([seed, attempt])
        frames = [make_frame(rng, p) for _ in range(p["frames"])]
        problems = close_calls(ns, frames)
        if not problems:
            return frames, attempt
    raise SystemExit(f"case {name}: could not avoid threshold ties: {problems[:3]}")


def expected_block(ns, frames):
    per_class, mean_row = run_reference(ns, frames)
    num_gt = {c: sum(1 for f in frames for g in f["gt"] if g["class"] == c) for c in CLASSES}
    num_pred = {c: sum(1 for f in frames for q in f["pred"] if q["class"] == c) for c in CLASSES}
    with_gt = [c for c in CLASSES if num_gt[c] > 0]
    classes = {}
    for c in CLASSES:
        classes[c] = {
            "num_gt": num_gt[c],
            "num_pred": num_pred[c],
            "ap": {m: percent(per_class[c][m]) for m in METRICS},
        }
    mean_with_gt = {m: float(np.mean([per_class[c][m] for c in with_gt])) * 100.0 if with_gt else None for m in METRICS}
    return {
        "metrics": METRICS,
        "classes": classes,
        "mean_reference_row": {m: percent(mean_row[m]) for m in METRICS},
        "mean_over_classes_with_gt": mean_with_gt,
        "classes_with_gt": with_gt,
    }, per_class


def dump_fixture(fx):
    """Compact JSON, one instance per line, so diffs stay readable."""
    lines = ["{"]
    head = {k: v for k, v in fx.items() if k not in ("frames", "expected")}
    for k, v in head.items():
        lines.append(f"  {json.dumps(k)}: {json.dumps(v)},")
    lines.append('  "expected": ' + json.dumps(fx["expected"], indent=None) + ",")
    lines.append('  "frames": [')
    for fi, f in enumerate(fx["frames"]):
        lines.append('    {"gt": [')
        lines.append(",\n".join("      " + json.dumps(g, separators=(",", ":")) for g in f["gt"]))
        lines.append('    ], "pred": [')
        lines.append(",\n".join("      " + json.dumps(q, separators=(",", ":")) for q in f["pred"]))
        lines.append("    ]}" + ("," if fi + 1 < len(fx["frames"]) else ""))
    lines.append("  ]")
    lines.append("}")
    return "\n".join(line for line in lines if line.strip() != "") + "\n"


def compare(a, b):
    """Largest |a - b| over two {class: {metric: percent or None}} tables; NaN/None must agree."""
    worst = 0.0
    for c in CLASSES:
        for m in METRICS:
            x, y = a[c][m], b[c][m]
            if (x is None) != (y is None):
                return math.inf
            if x is not None:
                worst = max(worst, abs(x - y))
    return worst


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nocs-utils", required=True, help="path to utils.py of a NOCS_CVPR2019 checkout")
    ap.add_argument("--nocs-commit", help="commit of that checkout (default: asked of git)")
    ap.add_argument("--agpose-utils", help="optional: AG-Pose utils/evaluation_utils.py, run as a cross-check")
    ap.add_argument("--agpose-commit", help="commit of the AG-Pose checkout (default: asked of git)")
    ap.add_argument("--out", default="tests/fixtures/nocs_reference", help="fixture directory")
    ap.add_argument("--verify", action="store_true", help="re-run the reference on existing fixtures; write nothing")
    args = ap.parse_args()

    ns = load_functions(args.nocs_utils, NOCS_FUNCTIONS)
    ag = load_functions(args.agpose_utils, AGPOSE_FUNCTIONS) if args.agpose_utils else None
    nocs_commit = args.nocs_commit or git_commit(args.nocs_utils)
    ag_commit = (args.agpose_commit or git_commit(args.agpose_utils)) if ag else None

    if args.verify:
        worst = 0.0
        names = sorted(n for n in os.listdir(args.out) if n.endswith(".json"))
        for n in names:
            with open(os.path.join(args.out, n), encoding="utf-8") as f:
                fx = json.load(f)
            per_class, _ = run_reference(ns, fx["frames"])
            got = {c: {m: percent(per_class[c][m]) for m in METRICS} for c in CLASSES}
            stored = {c: fx["expected"]["classes"][c]["ap"] for c in CLASSES}
            d = compare(got, stored)
            worst = max(worst, d)
            print(f"{n}: max |reference now - stored| = {d:.3g} percent")
        print(f"{len(names)} fixtures, max difference {worst:.3g} percent")
        return 0 if worst < 1e-9 else 1

    os.makedirs(args.out, exist_ok=True)
    total = 0
    for name, seed, description, overrides in CASES:
        frames, attempt = build_case(ns, name, seed, description, overrides)
        expected, per_class = expected_block(ns, frames)
        notes = [
            "AP in percent; null where the reference returns NaN. A class without GT gets NaN for the IoU "
            "metrics when it has predictions (0/0 recall), 0 without predictions, and 0 for the pose metrics "
            "(nothing passes the IoU gate); tricons reports null for all of them.",
            "The reference's mean row averages all six classes, NaN and no-GT zeros included; tricons "
            "leaves classes without GT out, so compare its mean with mean_over_classes_with_gt.",
            "Reference inputs: RT = [|s| R, t], scales = s/|s|, handle visibility 1/0, dummy non-zero 2D boxes.",
            f"Every same-class pair is at least {IOU_MARGIN} from each IoU threshold and {POSE_MARGIN} "
            "from each degree/cm threshold; scores are distinct within a class.",
        ]
        cross = None
        if ag:
            ag_class, _ = run_reference(ag, frames, agpose=True)
            a = {c: {m: percent(ag_class[c][m]) for m in METRICS} for c in CLASSES}
            b = {c: {m: percent(per_class[c][m]) for m in METRICS} for c in CLASSES}
            diff = compare(a, b)
            cross = {
                "repo": "Leeiieeo/AG-Pose",
                "commit": ag_commit,
                "file": "utils/evaluation_utils.py",
                "function": "compute_independent_mAP",
                "max_abs_diff_percent": diff,
            }
            if diff > 1e-9:
                print(f"warning: {name}: AG-Pose differs from NOCS by {diff} percent", file=sys.stderr)
        fx = {
            "schema": "tricons-nocs-reference/1",
            "case": name,
            "description": description,
            "seed": seed,
            "attempt": attempt,
            "generator": "tools/golden/make_nocs_metric_fixtures.py",
            "reference": {
                "repo": "hughw19/NOCS_CVPR2019",
                "commit": nocs_commit,
                "file": "utils.py",
                "function": "compute_degree_cm_mAP",
                "arguments": {
                    "degree_thresholds": DEGREE_THRESHOLDS,
                    "shift_thresholds": SHIFT_THRESHOLDS,
                    "iou_3d_thresholds": IOU_THRESHOLDS,
                    "iou_pose_thres": IOU_POSE_THRES,
                    "use_matches_for_pose": True,
                },
                "numpy": np.__version__,
                "python": sys.version.split()[0],
            },
            "cross_check": cross,
            "notes": notes,
            "expected": expected,
            "frames": frames,
        }
        if cross is None:
            del fx["cross_check"]
        text = dump_fixture(fx)
        json.loads(text)  # well-formed
        path = os.path.join(args.out, f"{name}.json")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        total += len(text)
        n_gt = sum(len(f["gt"]) for f in frames)
        n_pred = sum(len(f["pred"]) for f in frames)
        print(f"{path}: {len(frames)} frames, {n_gt} GT, {n_pred} predictions, attempt {attempt}, {len(text)} bytes")
    print(f"{len(CASES)} cases, {total} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
