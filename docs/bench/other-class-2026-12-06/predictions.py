"""Where a replay's predictions land (as docs/results.md "Score floor and containment"): a
prediction is matched when its 2D box has IoU > 0.5 with a ground-truth object of its class
(box from the ground-truth label image), wrong class with one of another class, part at IoU
0.1-0.5, nothing otherwise. Usage: predictions.py REC PRED_JSONL"""
import json, sys, collections
import numpy as np
from PIL import Image
rec, pred = sys.argv[1:3]
c = collections.Counter(); n_obj = 0
def iou(a, b):
    x0, y0, x1, y1 = max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])
    i = max(0, x1 - x0) * max(0, y1 - y0)
    u = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - i
    return i / u if u > 0 else 0
for line in open(pred):
    f = json.loads(line)
    gt = json.load(open(f"{rec}/{f['frame']}_gt.json"))
    lab = np.array(Image.open(f"{rec}/{f['frame']}_mask.png"))
    boxes = []
    for g in gt["instances"]:
        ys, xs = np.nonzero(lab == g["id"])
        if len(xs):
            boxes.append((g["class"], [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]))
    n_obj += len(gt["instances"])
    for p in f["instances"]:
        best = max(((iou(p["box2d"], b), cl) for cl, b in boxes), default=(0, None))
        same = max((iou(p["box2d"], b) for cl, b in boxes if cl == p["class"]), default=0)
        if same > 0.5: k = "matched"
        elif best[0] > 0.5: k = "wrong class"
        elif best[0] >= 0.1: k = "part"
        else: k = "nothing"
        c[k] += 1
tot = sum(c.values())
print(f"{pred}: {tot} predictions for {n_obj} objects ({tot / n_obj:.2f} per object):", dict(sorted(c.items())))
