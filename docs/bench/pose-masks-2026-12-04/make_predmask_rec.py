"""Copy of a recording whose instance masks are the segmenter's (each GT instance gets its
best-IoU predicted mask, IoU >= 0.3, else it is dropped), optionally filtered by the 3D rule
(pixels farther than k * max|s|(class) from the mask's median 3D point removed)."""
import json, sys, os, shutil, sys, numpy as np
from pathlib import Path
from PIL import Image
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from tricons_pose.maskrcnn import decode_rle  # noqa: E402  (the project's run-length decoder)
rec, seg, out, k = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), float(sys.argv[4])
ero = int(sys.argv[5]) if len(sys.argv) > 5 else 0
def erode(m, r):
    for _ in range(r):
        e = m.copy(); e[1:] &= m[:-1]; e[:-1] &= m[1:]; e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]
        e2 = e.copy(); e2[1:, 1:] &= m[:-1, :-1]; e2[:-1, :-1] &= m[1:, 1:]; e2[1:, :-1] &= m[:-1, 1:]; e2[:-1, 1:] &= m[1:, :-1]; m = e2
    return m
SMAX = {'mug': 0.261, 'bowl': 0.322, 'camera': 0.277, 'laptop': 0.719, 'bottle': 0.363, 'can': 0.32}
out.mkdir(parents=True, exist_ok=True)
man = json.load(open(rec / "manifest.json")); K = man["intrinsics"]; sc = man["depth_scale_m"]
shutil.copy(rec / "manifest.json", out / "manifest.json")
h, w = K["height"], K["width"]; vv, uu = np.mgrid[0:h, 0:w]
def rle(r):
    return decode_rle(r, h * w).reshape(h, w)
removed = kept = 0
for line in open(seg / "segments.jsonl"):
    f = json.loads(line); fr = f["frame"]
    for suf in ("color.png", "depth.png", "coord.png"):
        if not (out / f"{fr}_{suf}").exists(): os.symlink((rec / f"{fr}_{suf}").resolve(), out / f"{fr}_{suf}")
    gt = np.array(Image.open(rec / f"{fr}_mask.png"))
    ann = json.load(open(rec / f"{fr}_gt.json"))
    z = np.array(Image.open(rec / f"{fr}_depth.png")).astype(np.float64) * sc
    P = np.stack([(uu - K["cx"]) * z / K["fx"], (vv - K["cy"]) * z / K["fy"], z], -1)
    preds = [rle(i["mask_rle"]) for i in f["instances"]]
    new = np.zeros_like(gt); keep = []
    for a in ann["instances"]:
        g = gt == a["id"]
        if not preds or g.sum() == 0: continue
        best = max(preds, key=lambda p: (p & g).sum() / (p | g).sum())
        if (best & g).sum() / (best | g).sum() < 0.3: continue
        m = (g if k < 0 else erode(best, ero)) & (new == 0)
        if k > 0:
            v = m & (z > 0)
            if v.sum():
                med = np.median(P[v], axis=0)
                far = v & (np.linalg.norm(P - med, axis=-1) > k * SMAX[a["class"]])
                removed += far.sum(); m = m & ~far
        kept += m.sum()
        if m.sum() == 0: continue
        new[m] = a["id"]; keep.append(a)
    ann["instances"] = keep
    Image.fromarray(new).save(out / f"{fr}_mask.png")
    json.dump(ann, open(out / f"{fr}_gt.json", "w"))
print("removed", removed, "kept", kept)
