"""Where does the full pipeline lose against GT masks? Per GT instance: the GT-mask prediction
and the nearest same-class model-mask prediction (by centre, < 10 cm); the share within
10°5cm / 5°2cm of each on the same instances, plus instances with no same-class prediction."""
import json, os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from nocs_errors import rerr, terr  # noqa: E402
from collections import defaultdict
def load(p):
    return {json.loads(l)["frame"]: json.loads(l)["instances"] for l in open(p)}
gt, pg, pm = load(sys.argv[1]), load(sys.argv[2]), load(sys.argv[3])
def nearest(g, preds):
    c = [p for p in preds if p["class"] == g["class"]]
    if not c: return None
    p = min(c, key=lambda p: terr(g, p))
    return p if terr(g, p) < 10 else None
st = defaultdict(lambda: defaultdict(int))
for f, gis in gt.items():
    for g in gis:
        k = g["class"]; s = st[k]; s["n"] += 1
        a, b = nearest(g, pg.get(f, [])), nearest(g, pm.get(f, []))
        if b is None: s["missed"] += 1
        if a is None or b is None: continue
        s["both"] += 1
        for name, p in (("gt", a), ("model", b)):
            r, t = rerr(g, p, k), terr(g, p)
            s[f"{name}_10_5"] += (r <= 10) & (t <= 5); s[f"{name}_5_2"] += (r <= 5) & (t <= 2)
            s[f"{name}_t"] += t
n_fp = sum(1 for f, ps in pm.items() for p in ps if not any(g["class"] == p["class"] and terr(g, p) < 10 for g in gt[f]))
print(f"{'class':8s} {'n':>4s} {'missed':>6s} {'both':>4s} | 10°5cm gt-mask model-mask | 5°2cm gt-mask model-mask | mean t err cm gt / model")
for k in sorted(st):
    s = st[k]; b = max(s["both"], 1)
    print(f"{k:8s} {s['n']:4d} {s['missed']:6d} {s['both']:4d} | {100*s['gt_10_5']/b:6.1f} {100*s['model_10_5']/b:6.1f} | {100*s['gt_5_2']/b:6.1f} {100*s['model_5_2']/b:6.1f} | {s['gt_t']/b:.2f} / {s['model_t']/b:.2f}")
print("model-mask predictions matching no GT of their class within 10 cm:", n_fp, "of", sum(len(v) for v in pm.values()))
