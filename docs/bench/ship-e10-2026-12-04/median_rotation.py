"""Median rotation error per class of one predictions file against a recording's ground truth
(`tricons inspect REC --predictions`): each annotated object paired with the nearest prediction of
its class within 10 cm; bottle, bowl and can by the angle of their symmetry axes, every other
class (mugs included, whether or not the handle shows) by the full rotation. Throwaway, for the
record. Usage: python median_rotation.py GT.jsonl PRED.jsonl"""
import json, os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from nocs_errors import rerr, terr  # noqa: E402
from collections import defaultdict
def load(p):
    return {json.loads(l)["frame"]: json.loads(l)["instances"] for l in open(p)}
gt, pr = load(sys.argv[1]), load(sys.argv[2])
errs = defaultdict(list)
for f, gis in gt.items():
    for g in gis:
        c = [p for p in pr.get(f, []) if p["class"] == g["class"]]
        if not c: continue
        p = min(c, key=lambda p: terr(g, p))
        if terr(g, p) < 10: errs[g["class"]].append(rerr(g, p, g["class"]))
print(" ".join(f"{k} {np.median(v):.1f}" for k, v in sorted(errs.items())))
