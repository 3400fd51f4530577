# How many objects does the "other" class take from the pose pipeline, and how many distractors?
# Simulates the runtime's greedy suppression (card: IoU > 0.3 or inside > 0.5) on the raw
# detections of `tricons segment --keep-duplicates --min-score 0.2`, with a margin rule variant.
import json, sys, numpy as np
from PIL import Image
rec, seg = sys.argv[1], sys.argv[2]
W, H = 640, 480
def decode(rle, n):
    m = np.zeros(n, bool); pos = 0; val = False
    for r in rle:
        if val: m[pos:pos + r] = True
        pos += r; val = not val
    return m
frames = [json.loads(l) for l in open(seg)]
data = []
for f in frames:
    gt = json.load(open(f"{rec}/{f['frame']}_gt.json"))
    mk = np.array(Image.open(f"{rec}/{f['frame']}_mask.png")).reshape(-1)
    objs = [(g['class'], mk == g['id']) for g in gt['instances']]
    dets = [(d['class'], d['score'], decode(d['mask_rle'], W * H)) for d in f['instances']]
    data.append((objs, dets))
def iou(a, b):
    i = np.count_nonzero(a & b); u = np.count_nonzero(a | b); return i / u if u else 0.0
def inside(a, b):
    n = np.count_nonzero(a); return np.count_nonzero(a & b) / n if n else 0.0
def run(thr_nocs, thr_other, margin):
    rec_hit = n_obj = fp = wrong = 0
    lost_to_other = 0
    for objs, dets in data:
        cand = [d for d in dets if d[1] >= (thr_other if d[0] == 'other' else thr_nocs)]
        cand.sort(key=lambda d: -d[1])
        kept = []
        for c in cand:
            dup = False
            for k in kept:
                if iou(c[2], k[2]) > 0.3 or inside(c[2], k[2]) > 0.5:
                    if k[0] == 'other' and c[0] != 'other' and margin is not None and k[1] - c[1] <= margin:
                        continue
                    dup = True; break
            if not dup: kept.append(c)
        out = [k for k in kept if k[0] != 'other']
        for cls, m in objs:
            n_obj += 1
            if any(k[0] == cls and iou(k[2], m) >= 0.5 for k in out): rec_hit += 1
        for k in out:
            best = max([(iou(k[2], m), cls) for cls, m in objs] or [(0, None)])
            if best[0] < 0.5: fp += 1
            elif best[1] != k[0]: wrong += 1
    return n_obj, rec_hit, fp, wrong
for thr_nocs in (0.7, 0.5):
    for margin in (None, 0.1, 0.2, 0.3, 1.0):
        n, hit, fp, wrong = run(thr_nocs, 0.7, margin)
        print(f"NOCS threshold {thr_nocs} margin {margin}: recall {hit}/{n} = {100*hit/n:.1f} %, detections on no object {fp}, on an object of another class {wrong}")
# per class: objects found at the card's rule; of the missed, how many have any detection of
# their class (any score >= 0.2) with mask IoU >= 0.5, and its best score
from collections import Counter
found, total, near = Counter(), Counter(), Counter()
best_scores = {}
for objs, dets in data:
    cand = sorted([d for d in dets if d[1] >= 0.7], key=lambda d: -d[1])
    kept = []
    for c in cand:
        if not any(iou(c[2], k[2]) > 0.3 or inside(c[2], k[2]) > 0.5 for k in kept): kept.append(c)
    out = [k for k in kept if k[0] != 'other']
    for cls, m in objs:
        total[cls] += 1
        if any(k[0] == cls and iou(k[2], m) >= 0.5 for k in out): found[cls] += 1; continue
        s = [d[1] for d in dets if d[0] == cls and iou(d[2], m) >= 0.5]
        o = [d[1] for d in dets if d[0] == 'other' and iou(d[2], m) >= 0.5]
        if s: near[cls] += 1
        best_scores.setdefault(cls, []).append((round(max(s), 2) if s else None, round(max(o), 2) if o else None, int(m.sum())))
for cls in sorted(total):
    print(f"{cls}: found {found[cls]}/{total[cls]}; missed with a own-class detection below 0.7: {near[cls]}; missed (own best, other best, pixels): {sorted(best_scores.get(cls, []), key=lambda x: x[2])[:12]}")
# missed objects without any detection of their own class: how many does a confident "other" cover?
flat = [x for v in best_scores.values() for x in v]
none_own = [x for x in flat if x[0] is None]
print(f"missed {len(flat)}: with an own-class detection that did not survive {len(flat) - len(none_own)}; "
      f"with none {len(none_own)}, of which an 'other' detection >= 0.7 covers {sum(1 for x in none_own if x[1] and x[1] >= 0.7)}")
