"""Offline replay of the runtime's duplicate rule on `segment --keep-duplicates` output,
with the choice of whether non-NOCS ("other") detections may suppress NOCS ones; then the
breakdown counts. Usage: suppress.py REC SEGMENTS_JSONL {all,nocs}"""
import json, sys, collections
import numpy as np
from PIL import Image
W, H = 640, 480
NOCS = {"bottle", "bowl", "camera", "can", "laptop", "mug"}

def rle(runs):
    m = np.zeros(W * H, bool); p, fg = 0, False
    for r in runs:
        if fg: m[p:p + r] = True
        p += r; fg = not fg
    return m

rec, segs, mode = sys.argv[1:4]
thr = float(sys.argv[4]) if len(sys.argv) > 4 else 0.0
counts = collections.Counter()
missed = collections.Counter()
for line in open(segs):
    fr = json.loads(line)
    dets = sorted((d for d in fr["instances"] if d["score"] >= thr), key=lambda d: -d["score"])
    kept = []
    for d in dets:
        m = rle(d["mask_rle"]); px = m.sum()
        dup = False
        for k, km in kept:
            if mode == "nocs" and k.get("class") not in NOCS:
                continue
            inter = (m & km).sum(); union = px + km.sum() - inter
            if (union and inter / union > 0.3) or (px and inter / px > 0.5):
                dup = True; break
        if not dup:
            kept.append((d, m))
    gt = json.load(open(f"{rec}/{fr['frame']}_gt.json"))
    lab = np.array(Image.open(f"{rec}/{fr['frame']}_mask.png")).reshape(-1)
    gts = [(g["class"], lab == g["id"]) for g in gt["instances"]]
    used = set()
    for d, m in kept:
        if d.get("class") not in NOCS:
            counts["other"] += 1; continue
        ious = [((m & gm).sum() / max(1, (m | gm).sum())) for _, gm in gts]
        j = int(np.argmax(ious)) if ious else None
        iou = ious[j] if ious else 0
        if iou < 0.1: k = "none"
        elif iou < 0.5: k = "partial"
        elif gts[j][0] != d["class"]: k = "wrong"
        elif j in used: k = "second"
        else: k = "first"; used.add(j)
        counts[k] += 1
    for j, (c, gm) in enumerate(gts):
        if j in used:
            continue
        by_other = any(d.get("class") not in NOCS and (m & gm).sum() / max(1, (m | gm).sum()) >= 0.5 for d, m in kept)
        missed[(c, "other" if by_other else "-")] += 1
print(mode, thr, dict(sorted(counts.items())))
print("  missed (class, covered by other):", dict(sorted(missed.items())))
