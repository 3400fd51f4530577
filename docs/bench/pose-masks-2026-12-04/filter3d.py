"""Class-aware 3D outlier rule, offline: pixels of the predicted mask farther than
k * max|s|(class) from the mask's median 3D point. Shares removed: off-instance pixels
(pred & ~gt) and the instance's own (pred & gt)."""
import json, sys, numpy as np
from collections import defaultdict
from pathlib import Path
from PIL import Image
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from tricons_pose.maskrcnn import decode_rle  # noqa: E402  (the project's run-length decoder)
rec, seg = Path(sys.argv[1]), Path(sys.argv[2])
man = json.load(open(rec / "manifest.json")); K = man["intrinsics"]; sc = man["depth_scale_m"]
def rle(r, h, w):
    return decode_rle(r, h * w).reshape(h, w)
h, w = K["height"], K["width"]
vv, uu = np.mgrid[0:h, 0:w]
rows = []
for line in open(seg / "segments.jsonl"):
    f = json.loads(line)
    gt = np.array(Image.open(rec / f"{f['frame']}_mask.png"))
    ann = json.load(open(rec / f"{f['frame']}_gt.json"))["instances"]
    z = np.array(Image.open(rec / f"{f['frame']}_depth.png")).astype(np.float64) * sc
    P = np.stack([(uu - K["cx"]) * z / K["fx"], (vv - K["cy"]) * z / K["fy"], z], -1)
    preds = [rle(i["mask_rle"], h, w) for i in f["instances"]]
    for a in ann:
        g = gt == a["id"]
        if g.sum() < 50 or not preds: continue
        best = max(preds, key=lambda p: (p & g).sum() / (p | g).sum())
        if (best & g).sum() / (best | g).sum() < 0.3: continue
        v = best & (z > 0)
        med = np.median(P[v], axis=0)
        d = np.linalg.norm(P - med, axis=-1)
        gmed = np.median(P[g & (z > 0)], axis=0); dg = np.linalg.norm(P - gmed, axis=-1)
        rows.append((a["class"], np.linalg.norm(a["s"]), d[v & ~g], d[v & g], dg[g & (z > 0)]))
smax = defaultdict(float)
for c, s, *_ in rows: smax[c] = max(smax[c], s)
print("max |s| per class (val GT):", {c: round(v, 3) for c, v in smax.items()})
for k in (0.5, 0.75, 1.0):
    out = defaultdict(lambda: np.zeros(5))
    for c, s, de, do, dg in rows:
        r = k * smax[c]
        out[c] += [np.sum(de > r), de.size, np.sum(do > r), do.size, np.sum(dg > r)]
    print(f"k={k}: " + "  ".join(f"{c}: off {o[0]/max(o[1],1):.2f} own {o[2]/max(o[3],1):.4f} gtmask-own {o[4]/max(o[3],1):.4f}" for c, o in sorted(out.items())))
