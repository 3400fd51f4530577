"""Blend head and keypoint rotations per class: R = proj((1-w) R_head + w R_kpt)."""
import json, sys
import numpy as np
head, kpt, out = sys.argv[1:4]
w = json.loads(sys.argv[4])  # {"camera": 0.5, ...}; missing: 0
def proj(m):
    u, _, vt = np.linalg.svd(m); d = np.sign(np.linalg.det(u @ vt)); return u @ np.diag([1, 1, d]) @ vt
with open(out, "w") as f:
    for a, b in zip(open(head), open(kpt)):
        a, b = json.loads(a), json.loads(b)
        assert a["frame"] == b["frame"] and len(a["instances"]) == len(b["instances"])
        for x, y in zip(a["instances"], b["instances"]):
            assert x["class"] == y["class"] and x["t"] == y["t"]
            k = w.get(x["class"], 0.0)
            x["R"] = proj((1 - k) * np.array(x["R"]) + k * np.array(y["R"])).tolist()
        f.write(json.dumps(a) + "\n")
