import json, sys, glob
import numpy as np
pred = [json.loads(l) for l in open(sys.argv[1])]
rec = sys.argv[2]
rows = []
for fr in pred:
    gt = json.load(open(f"{rec}/{fr['frame']}_gt.json"))["instances"]
    for p, g in zip(fr["instances"], gt):
        if p["class"] != g["class"] or g["class"] not in ("camera", "laptop", "mug"): continue
        Rg, Rp = np.array(g["R"]), np.array(p["R"])
        E = Rg.T @ Rp  # error in object frame
        ang = np.degrees(np.arccos(np.clip((np.trace(E) - 1) / 2, -1, 1)))
        w = np.array([E[2,1]-E[1,2], E[0,2]-E[2,0], E[1,0]-E[0,1]]) / 2  # sin(a) * axis
        # also camera-frame axis
        Ec = Rp @ Rg.T
        wc = np.array([Ec[2,1]-Ec[1,2], Ec[0,2]-Ec[2,0], Ec[1,0]-Ec[0,1]]) / 2
        rows.append((g["class"], ang, np.degrees(np.arcsin(np.clip(w, -1, 1))), np.degrees(np.arcsin(np.clip(wc, -1, 1))), g.get("handle_visible")))
for c in ("camera", "laptop", "mug"):
    r = [x for x in rows if x[0] == c and (c != "mug" or x[4])]
    a = np.array([x[1] for x in r]); w = np.array([x[2] for x in r]); wc = np.array([x[3] for x in r])
    print(c, len(r), "median", np.median(a).round(2))
    print("  object-frame axis comp (deg): mean", w.mean(0).round(2), "rms", np.sqrt((w**2).mean(0)).round(2), "median abs", np.median(abs(w),0).round(2))
    print("  camera-frame axis comp (deg): mean", wc.mean(0).round(2), "rms", np.sqrt((wc**2).mean(0)).round(2), "median abs", np.median(abs(wc),0).round(2))
print("signed y (object frame): median, frac<0, p25, p75")
for c in ("camera", "laptop", "mug"):
    r = [x for x in rows if x[0] == c and (c != "mug" or x[4])]
    y = np.array([x[2][1] for x in r])
    print(" ", c, np.median(y).round(2), (y < 0).mean().round(2), np.percentile(y, 25).round(2), np.percentile(y, 75).round(2))
