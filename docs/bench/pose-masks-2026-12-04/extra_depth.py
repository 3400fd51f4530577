import json, sys, numpy as np
from pathlib import Path
from PIL import Image
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from tricons_pose.maskrcnn import decode_rle  # noqa: E402  (the project's run-length decoder)
rec, seg = Path(sys.argv[1]), Path(sys.argv[2])
meta = json.load(open(rec / "recording.json")) if (rec / "recording.json").exists() else None
def rle(r, h, w):
    return decode_rle(r, h * w).reshape(h, w)
dd = []; on = []
for line in open(seg / "segments.jsonl"):
    f = json.loads(line); h, w = f["height"], f["width"]
    gt = np.array(Image.open(rec / f"{f['frame']}_mask.png"))
    depth = np.array(Image.open(rec / f"{f['frame']}_depth.png")).astype(np.float64)
    preds = [rle(i["mask_rle"], h, w) for i in f["instances"]]
    for gid in np.unique(gt):
        if gid == 0: continue
        g = gt == gid
        if g.sum() < 50 or not preds: continue
        best = max(preds, key=lambda p: (p & g).sum() / (p | g).sum())
        if (best & g).sum() / (best | g).sum() < 0.3: continue
        med = np.median(depth[g & (depth > 0)])
        e = best & ~g & (depth > 0)
        dd.extend((depth[e] - med).tolist())
        gg = g & (depth > 0); on.extend(np.abs(depth[gg] - med).tolist())
dd = np.array(dd); on = np.array(on)
print("depth units: raw (mm if scale 0.001)")
print("extra pixels:", dd.size, "depth - instance median: percentiles 10/25/50/75/90:", np.percentile(dd, [10, 25, 50, 75, 90]).round(0))
for thr in (50, 100, 150, 200, 300):
    print(f"  |diff| > {thr}: extra {np.mean(np.abs(dd) > thr):.3f}  own pixels {np.mean(on > thr):.4f}")
