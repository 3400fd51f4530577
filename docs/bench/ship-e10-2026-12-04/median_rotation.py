"""Median rotation error per class of one predictions file against a recording's ground truth
(`tricons inspect REC --predictions`): each annotated object paired with the nearest prediction of
its class within 10 cm; bottle, bowl and can by the angle of their symmetry axes, every other
class (mugs included, whether or not the handle shows) by the full rotation. Throwaway, for the
record. Usage: python median_rotation.py GT.jsonl PRED.jsonl"""
import json, sys, numpy as np
from collections import defaultdict
SYM = {"bottle", "bowl", "can"}
def load(p): return {json.loads(l)["frame"]: json.loads(l)["instances"] for l in open(p)}
gt, pr = load(sys.argv[1]), load(sys.argv[2])
def rerr(a, b, cls):
    Ra, Rb = np.array(a["R"]), np.array(b["R"])
    if cls in SYM:
        ya, yb = Ra[:, 1], Rb[:, 1]
        return np.degrees(np.arccos(np.clip(ya @ yb / np.linalg.norm(ya) / np.linalg.norm(yb), -1, 1)))
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))
def terr(a, b): return np.linalg.norm(np.array(a["t"]) - np.array(b["t"])) * 100
errs = defaultdict(list)
for f, gis in gt.items():
    for g in gis:
        c = [p for p in pr.get(f, []) if p["class"] == g["class"]]
        if not c: continue
        p = min(c, key=lambda p: terr(g, p))
        if terr(g, p) < 10: errs[g["class"]].append(rerr(g, p, g["class"]))
print(" ".join(f"{k} {np.median(v):.1f}" for k, v in sorted(errs.items())))
