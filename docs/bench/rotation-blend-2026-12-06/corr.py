import json, sys
import numpy as np
pred = [json.loads(l) for l in open(sys.argv[1])]
rec = sys.argv[2]
for cls in ("camera", "laptop", "mug"):
    ys, feats = [], []
    for fr in pred:
        gt = json.load(open(f"{rec}/{fr['frame']}_gt.json"))["instances"]
        for p, g in zip(fr["instances"], gt):
            if g["class"] != cls or (cls == "mug" and not g.get("handle_visible")): continue
            Rg, Rp = np.array(g["R"]), np.array(p["R"])
            E = Rg.T @ Rp
            ys.append(np.degrees(np.arcsin(np.clip((E[0,2]-E[2,0])/2, -1, 1))))
            t = np.array(g["t"])
            # azimuth of the camera seen from the object, in object frame
            v = Rg.T @ (-t); az = np.degrees(np.arctan2(v[0], v[2])); el = np.degrees(np.arcsin(v[1]/np.linalg.norm(v)))
            feats.append((t[0]/t[2], t[1]/t[2], t[2], az, el, np.degrees(np.arctan2(Rg[0,1], Rg[1,1]))))
    ys = np.array(ys); F = np.array(feats)
    names = ["x/z", "y/z", "z", "azimuth", "elevation", "roll of up axis"]
    print(cls, len(ys), "corr:", {n: round(float(np.corrcoef(ys, F[:, i])[0, 1]), 2) for i, n in enumerate(names)})
    # bins of azimuth
    for lo in range(-180, 180, 60):
        sel = (F[:, 3] >= lo) & (F[:, 3] < lo + 60)
        if sel.sum(): print(f"   az {lo:4d}..{lo+60:4d}: n {sel.sum():3d} median y-err {np.median(ys[sel]):6.2f}")
