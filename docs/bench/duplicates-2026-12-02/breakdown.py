"""Where a segmenter's detections fall: each detection of `tricons segment`'s
segments.jsonl matched by mask IoU to the ground truth of its frame.
Usage: python breakdown.py RECORDING SEGMENTS_JSONL (numpy, Pillow)."""
import collections
import json
import sys

import numpy as np
from PIL import Image

W, H = 640, 480
NOCS = {"bottle", "bowl", "camera", "can", "laptop", "mug"}


def rle(runs):
    m = np.zeros(W * H, bool)
    p, fg = 0, False
    for r in runs:
        if fg:
            m[p:p + r] = True
        p += r
        fg = not fg
    return m


def kinds(rec, segs):
    """(kind, score) per detection; kind: first / second / wrong / partial / none."""
    for line in open(segs):
        fr = json.loads(line)
        gt = json.load(open(f"{rec}/{fr['frame']}_gt.json"))
        lab = np.array(Image.open(f"{rec}/{fr['frame']}_mask.png")).reshape(-1)
        gts = [(g["class"], lab == g["id"]) for g in gt["instances"]]
        used = set()
        for d in fr["instances"]:
            if d.get("class") not in NOCS:
                # a class the runtime never reports (a segmenter's "other"): not a detection
                yield "not_nocs", d["score"]
                continue
            m = rle(d["mask_rle"])
            best = (0.0, None)
            for j, (_, gm) in enumerate(gts):
                u = (m | gm).sum()
                iou = (m & gm).sum() / u if u else 0.0
                if iou > best[0]:
                    best = (iou, j)
            iou, j = best
            if iou < 0.1:
                k = "none"
            elif iou < 0.5:
                k = "partial"
            elif gts[j][0] != d["class"]:
                k = "wrong"
            elif j in used:
                k = "second"
            else:
                k = "first"
                used.add(j)
            yield k, d["score"]


rec, segs = sys.argv[1], sys.argv[2]
scores = collections.defaultdict(list)
for k, s in kinds(rec, segs):
    scores[k].append(s)
names = {"none": "no object (distractor/background)", "partial": "partial (IoU 0.1-0.5)",
         "wrong": "object, wrong class", "second": "object, right class, second",
         "first": "object, right class, first",
         "not_nocs": "of no NOCS class (not reported; not counted above)"}
print(f"{sum(len(v) for k, v in scores.items() if k != 'not_nocs')} detections")
for k, v in sorted(scores.items()):
    v = np.array(v)
    print(f"  {names[k]}: {len(v)}; scoring >= 0.5/0.6/0.7/0.8/0.9/0.95:",
          [int((v >= t).sum()) for t in (0.5, 0.6, 0.7, 0.8, 0.9, 0.95)])
