import json, sys, collections
import numpy as np, onnxruntime as ort
from tricons_pose.bench import frame_batches
from tricons_pose.train import build_config
from tricons_pose.export import OUTPUT_NAMES
path, cfgname = sys.argv[1], sys.argv[2]
cfg = build_config(cfgname)
b = frame_batches("../tests/data/synthnocs-demo", cfg.n_points, cfg.crop_size, 0)[0]
b1 = {k: v[:1] for k, v in b.items()}
so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
so.enable_profiling = True; so.profile_file_prefix = "/tmp/prof/ort"
s = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
for _ in range(3): s.run(list(OUTPUT_NAMES), b1)
f = s.end_profiling()
ev = json.load(open(f))
runs = [e for e in ev if e.get("name") == "model_run"]
print("model_run ms:", [round(e["dur"]/1000, 1) for e in runs])
last_start = runs[-1]["ts"]
by = collections.Counter(); nodes = collections.Counter()
for e in ev:
    if e.get("cat") == "Node" and e["name"].endswith("_kernel_time") and e["ts"] >= last_start:
        op = e["args"].get("op_name"); by[op] += e["dur"]/1000; nodes[(op, e["name"][:-12])] += e["dur"]/1000
for op, ms in by.most_common(15): print(f"{op:30s} {ms:8.2f}")
print("slowest nodes")
for (op, n), ms in nodes.most_common(25): print(f"{ms:8.3f} {op:20s} {n}")
