"""How loose are the shipped Mask R-CNN's masks against ground truth? For each GT instance,
the best-IoU predicted mask: IoU, fraction of predicted pixels off the instance, fraction of
GT pixels missed, and the equivalent dilation radius (extra pixels / GT perimeter)."""
import json, sys, numpy as np
from pathlib import Path
from PIL import Image
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from tricons_pose.maskrcnn import decode_rle  # noqa: E402  (the project's run-length decoder)
rec, seg = Path(sys.argv[1]), Path(sys.argv[2])
def rle(r, h, w):
    return decode_rle(r, h * w).reshape(h, w)
rows = []
for line in open(seg / "segments.jsonl"):
    f = json.loads(line)
    h, w = f["height"], f["width"]
    gt = np.array(Image.open(rec / f"{f['frame']}_mask.png"))
    preds = [rle(i["mask_rle"], h, w) for i in f["instances"]]
    for gid in np.unique(gt):
        if gid == 0: continue
        g = gt == gid
        if g.sum() < 50: continue
        best = max(preds, key=lambda p: (p & g).sum() / (p | g).sum(), default=None)
        if best is None: continue
        iou = (best & g).sum() / (best | g).sum()
        if iou < 0.3: continue
        perim = g.sum() - (g[1:-1, 1:-1] & g[:-2, 1:-1] & g[2:, 1:-1] & g[1:-1, :-2] & g[1:-1, 2:]).sum()
        extra = (best & ~g).sum(); miss = (g & ~best).sum()
        rows.append((iou, extra / best.sum(), miss / g.sum(), extra / max(perim, 1), miss / max(perim, 1)))
a = np.array(rows)
print(f"{len(a)} matched instances")
for k, name in enumerate(["IoU", "off-instance frac of pred", "missed frac of GT", "extra px / perimeter (dilation px)", "missed px / perimeter (erosion px)"]):
    print(f"{name:40s} p10 {np.percentile(a[:,k],10):.3f} median {np.median(a[:,k]):.3f} p90 {np.percentile(a[:,k],90):.3f} mean {a[:,k].mean():.3f}")
