"""Combine K replays (GT masks: same instances in the same order) into one: rotation by the
chordal mean (SVD projection of the sum), t, s and score by the mean."""
import json, sys
import numpy as np

out, ins = sys.argv[1], sys.argv[2:]
files = [[json.loads(l) for l in open(p)] for p in ins]
with open(out, "w") as f:
    for frames in zip(*files):
        base = frames[0]
        assert all(fr["frame"] == base["frame"] and len(fr["instances"]) == len(base["instances"]) for fr in frames)
        insts = []
        for j, inst in enumerate(base["instances"]):
            group = [fr["instances"][j] for fr in frames]
            assert all(g["class"] == inst["class"] for g in group)
            m = sum(np.array(g["R"]) for g in group)
            u, _, vt = np.linalg.svd(m)
            d = np.sign(np.linalg.det(u @ vt))
            r = u @ np.diag([1, 1, d]) @ vt
            new = dict(inst)
            new["R"] = r.tolist()
            new["t"] = np.mean([g["t"] for g in group], axis=0).tolist()
            new["s"] = np.mean([g["s"] for g in group], axis=0).tolist()
            new["score"] = float(np.mean([g["score"] for g in group]))
            insts.append(new)
        f.write(json.dumps({**base, "instances": insts}) + "\n")
