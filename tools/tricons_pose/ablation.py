"""The paper's ablation at the shipped sizes, trained the way the shipped model was (issue 16,
part 5; tools/MODEL.md, "The ablation")::

    # from tools/, on one core; resumable: run it again after an interruption
    taskset -c 0 .venv/bin/python -m tricons_pose.ablation advance --cycles 4 --compile --eval
    # a second worker (another core, or a machine sharing RUNS) takes the runs the first does not
    # hold; with the default frame cache each holds ~11 GB (train + train2): on a 24 GB machine
    # give both --frame-cache disk (~4 ms more per sample, the same samples)
    .venv/bin/python -m tricons_pose.ablation eval       # tools/eval_runtime.sh on every new cycle end
    .venv/bin/python -m tricons_pose.ablation table      # the paper's layout, mean (lo-hi) over seeds
    .venv/bin/python -m tricons_pose.ablation collect    # copy what a commit needs to models/checkpoints/ablation
    .venv/bin/python -m tricons_pose.ablation restore    # on a fresh checkout: the reverse

Four variants (AG-Pose baseline, w/o PIGA, w/o SCKD, full = the shipped configuration), two
training seeds each. Every run is a chain of cycles, each one 3000 steps of the schedule that
trained the shipped model's last four stages (tools/MODEL.md E7-E13): Adam from a fresh state,
triangular 5e-5..3e-4 over a half-cycle of 1500 steps, batch 16, a fifth of the samples on
perturbed masks, SynthNOCS train + train2 (8000 frames); cycle 1 starts from random weights,
cycle c > 1 from cycle c-1's last weights; the data order of cycle c of seed s is seed
100 s + c. ``advance`` goes round-robin by cycle (no run starts cycle c + 1 while one could
start cycle c), so a table at an equal budget exists after every round; workers share the round
through a lock file per cycle directory.

Layout: RUNS/<variant>-s<seed>/cycle<c>/ (a train.py run directory; ``model-step3000.pt`` marks a
finished cycle, ``eval-val/`` its evaluation).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from .report import ALL_METRICS, table

VARIANTS = (("baseline", "AG-Pose (Baseline)"), ("without_piga", "w/o PIGA"),
            ("without_sckd", "w/o SCKD"), ("shipped", "Full"))
SEEDS = (1, 2)
CYCLE_STEPS = 3000
END = f"model-step{CYCLE_STEPS}.pt"
TOOLS = Path(__file__).resolve().parents[1]
ROOT = TOOLS.parent
PAPER_METRICS = ("5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm", "IoU50", "IoU75")


def run_dir(runs: Path, variant: str, seed: int, cycle: int) -> Path:
    return runs / f"{variant}-s{seed}" / f"cycle{cycle}"


def train_command(runs: Path, data: list[str], cache: str, variant: str, seed: int, cycle: int,
                  frame_cache: str = "memory", compile: bool = False) -> list[str]:
    """The train.py command of one cycle (resuming it when its checkpoint exists); ``frame_cache``
    and ``compile`` are train.py's ``--frame-cache`` and ``--compile`` (the samples are the same
    either way; compiled kernels round differently)."""
    out = run_dir(runs, variant, seed, cycle)
    cmd = [sys.executable, "-m", "tricons_pose.train", "--data", *data, "--config", variant, "--out", str(out),
           "--epochs", "100", "--batch-size", "16", "--seed", str(100 * seed + cycle), "--workers", "1",
           "--threads", "1", "--cache-dir", cache, "--lr", "5e-5", "--max-lr", "3e-4", "--lr-mode", "triangular",
           "--cycle-steps", str(CYCLE_STEPS // 2), "--keep-cycle-ends", "--max-steps", str(CYCLE_STEPS),
           "--ckpt-every", "250", "--mask-perturb", "0.2", "--log-every", "100"]
    if frame_cache != "memory":
        cmd += ["--frame-cache", frame_cache]
    if compile:
        cmd.append("--compile")
    if (out / "checkpoint.pt").exists():
        cmd.append("--resume")
    elif cycle > 1:
        cmd += ["--init-from", str(run_dir(runs, variant, seed, cycle - 1) / END)]
    return cmd


def _holder(out: Path) -> int:
    """The pid in ``out``'s ``advance.lock`` when that process is alive, else 0."""
    try:
        pid = int((out / "advance.lock").read_text(encoding="utf-8").strip() or 0)
        if pid:
            os.kill(pid, 0)
    except PermissionError:  # alive, another user's
        return pid
    except (OSError, ValueError):  # no lock, unreadable, or its process is gone
        return 0
    return pid


def claim(out: Path) -> bool:
    """Take ``out`` for this process (``advance.lock`` holding its pid, created exclusively);
    False while a live process holds it. A lock left by a dead process is taken over."""
    lock = out / "advance.lock"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            if _holder(out):
                return False
            lock.unlink(missing_ok=True)
            continue
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        return True
    return False


def held(out: Path) -> bool:
    """Whether a live process other than this one is training ``out``."""
    return _holder(out) not in (0, os.getpid())


def next_cycle(runs: Path, cycles: int):
    """The first (variant, seed, cycle) in round-robin order that is neither finished nor held
    by another ``advance``, and whose previous cycle has finished; "wait" when only held runs
    (or cycles after them) are left; None when every run has ``cycles`` cycles."""
    waiting = False
    for cycle in range(1, cycles + 1):
        for seed in SEEDS:
            for variant, _ in VARIANTS:
                out = run_dir(runs, variant, seed, cycle)
                if (out / END).exists():
                    continue
                if held(out):
                    waiting = True
                    continue
                if cycle > 1 and not (run_dir(runs, variant, seed, cycle - 1) / END).exists():
                    if held(run_dir(runs, variant, seed, cycle - 1)):
                        waiting = True
                        continue
                    raise SystemExit(f"{out}: cycle {cycle - 1} of this run has not finished")
                return variant, seed, cycle
    return "wait" if waiting else None


def advance(args) -> int:
    """Train the next cycle until every run has ``--cycles``; several ``advance`` processes
    (one per core) share the work: each takes a run no other one holds (``advance.lock``)."""
    runs = Path(args.runs).resolve()
    while True:
        nxt = next_cycle(runs, args.cycles)
        if nxt is None:
            return 0
        if nxt == "wait":
            time.sleep(args.poll_s)
            continue
        variant, seed, cycle = nxt
        out = run_dir(runs, variant, seed, cycle)
        out.mkdir(parents=True, exist_ok=True)
        if not claim(out):
            continue
        try:
            cmd = train_command(runs, args.data, args.cache_dir, variant, seed, cycle, args.frame_cache,
                                args.compile)
            print(f"[ablation] {variant} seed {seed} cycle {cycle}: {' '.join(cmd[1:])}", flush=True)
            with open(out / "stdout.log", "a", encoding="utf-8") as log:
                rc = subprocess.call(cmd, cwd=TOOLS, stdout=log, stderr=subprocess.STDOUT)
        finally:
            (out / "advance.lock").unlink(missing_ok=True)
        if rc != 0:
            raise SystemExit(f"{out}: train.py exited with {rc} (see {out / 'stdout.log'})")
        if args.eval:
            # on this worker's core, between cycles: every finished cycle gets its evaluation
            # even when no one is there to run `eval`; a failed evaluation stops no training
            try:
                evaluate(args)
            except SystemExit as e:
                print(f"[ablation] evaluation failed, training goes on: {e}", flush=True)


def finished(runs: Path):
    """(variant, seed, cycle, dir) of every finished cycle."""
    for variant, _ in VARIANTS:
        for seed in SEEDS:
            cycle = 1
            while (run_dir(runs, variant, seed, cycle) / END).exists():
                yield variant, seed, cycle, run_dir(runs, variant, seed, cycle)
                cycle += 1


def evaluate(args) -> int:
    runs = Path(args.runs).resolve()
    for variant, seed, cycle, d in finished(runs):
        out = d / f"eval-{args.split}"
        if (out / "gt-seed2.eval.json").exists():
            continue
        # --no-check: the onnx reference evaluator cannot run the relative-coordinate
        # variants' GatherElements (numpy.choose takes at most 64 arrays); the runtime can
        print(f"[ablation] eval {variant} seed {seed} cycle {cycle} on {args.split}", flush=True)
        rc = subprocess.call(["tools/eval_runtime.sh", str(d / END), str(out), f"data/synthnocs-{args.split}"],
                             cwd=ROOT, env={**os.environ, "MASKS": "gt", "SEEDS": "0 1 2", "EXPORT_ARGS": "--no-check",
                                  # the card protocol the ablation started with (no rotation blend)
                                  "ROTATION_KEYPOINT_BLEND": "none", "MIN_SCORE": "none"})
        if rc != 0:
            raise SystemExit(f"{out}: tools/eval_runtime.sh exited with {rc}")
    return 0


def run_mean(eval_dir: Path) -> dict | None:
    """The mean over the sampling seeds of one run's reports, as a report ({"mean": ...})."""
    reps = [json.loads(p.read_text(encoding="utf-8")) for p in sorted(eval_dir.glob("gt-seed*.eval.json"))]
    if not reps:
        return None
    return {"mean": {m: sum(r["mean"][m] for r in reps) / len(reps) for m in ALL_METRICS}}


def ablation_table(runs: Path, cycle: int, split: str, metrics=PAPER_METRICS) -> str | None:
    """The paper's layout at one cycle: each cell the mean over the training seeds (each seed
    the mean of its sampling seeds) and, in brackets, the lowest and highest seed; None unless
    every run has an evaluation of that cycle."""
    rows = []
    for variant, name in VARIANTS:
        per_seed = [run_mean(run_dir(runs, variant, s, cycle) / f"eval-{split}") for s in SEEDS]
        if any(r is None for r in per_seed):
            return None
        rows.append((name, per_seed))
    return table(rows, metrics, bold_best=True)


def convergence(runs: Path, cycle: int, split: str, metrics=PAPER_METRICS) -> list[tuple[str, str, float, float]] | None:
    """The stopping rule (tools/MODEL.md, "The ablation"): a round converged when it moved no
    variant's mean by more than that variant's spread between training seeds. Per variant and
    metric: (name, metric, move of the mean from cycle - 1 to ``cycle``, spread at ``cycle``);
    None unless every run has evaluations of both cycles."""
    if cycle < 2:
        return None
    out = []
    for variant, name in VARIANTS:
        seeds_of = {}  # cycle -> one report per training seed
        for c in (cycle - 1, cycle):
            seeds_of[c] = [run_mean(run_dir(runs, variant, s, c) / f"eval-{split}") for s in SEEDS]
            if any(r is None for r in seeds_of[c]):
                return None
        for m in metrics:
            b = [r["mean"][m] for r in seeds_of[cycle - 1]]
            a = [r["mean"][m] for r in seeds_of[cycle]]
            out.append((name, m, sum(a) / len(a) - sum(b) / len(b), max(a) - min(a)))
    return out


def converged(moves: list[tuple[str, str, float, float]]) -> bool:
    """Whether no mean moved by more than its seeds' spread."""
    return all(abs(move) <= spread for _, _, move, spread in moves)


def show(args) -> int:
    runs = Path(args.runs).resolve()
    shown = False
    for cycle in range(1, 100):
        t = ablation_table(runs, cycle, args.split)
        if t is None:
            if cycle > 1 and not any(run_dir(runs, v, s, cycle).exists() for v, _ in VARIANTS for s in SEEDS):
                break
            continue
        print(f"\nSynthNOCS-{args.split}, after {cycle} cycle(s) ({cycle * CYCLE_STEPS} steps):\n\n{t}")
        moves = convergence(runs, cycle, args.split)
        if moves is not None:
            worst = max(moves, key=lambda x: abs(x[2]) - x[3])
            print(f"\nround {cycle} against {cycle - 1}: "
                  + ("converged (no mean moved by more than its seeds' spread)" if converged(moves) else
                     f"not converged: {sum(abs(mv) > sp for _, _, mv, sp in moves)} of {len(moves)} means moved by "
                     f"more than their seeds' spread (most: {worst[0]} {worst[1]} {worst[2]:+.1f}, "
                     f"spread {worst[3]:.1f})"))
        shown = True
    if not shown:
        print("no cycle has an evaluation of every run yet", file=sys.stderr)
    return 0


KEEP = ("config.json", "stdout.log", END, "checkpoint.pt")


def collect(args) -> int:
    """Copy to DEST what resuming and reporting need: per cycle its config, stdout, log
    (gzip), weights at the end, evaluation; the Adam checkpoint only of unfinished cycles."""
    runs, dest = Path(args.runs).resolve(), Path(args.dest).resolve()
    for d in sorted(runs.glob("*-s*/cycle*")):
        target = dest / d.relative_to(runs)
        target.mkdir(parents=True, exist_ok=True)
        done = (d / END).exists()
        for name in KEEP:
            if (d / name).exists() and not (name == "checkpoint.pt" and done):
                shutil.copy2(d / name, target / name)
        if done and (target / "checkpoint.pt").exists():
            (target / "checkpoint.pt").unlink()
        if (d / "log.jsonl").exists():
            with open(d / "log.jsonl", "rb") as src, gzip.open(target / "log.jsonl.gz", "wb") as dst:
                shutil.copyfileobj(src, dst)
        for ev in d.glob("eval-*"):
            for f in list(ev.glob("*.eval.json")) + list(ev.glob("*.txt")) + list(ev.glob("summary.md")):
                (target / ev.name).mkdir(exist_ok=True)
                shutil.copy2(f, target / ev.name / f.name)
    print(f"collected into {dest}")
    return 0


def restore(args) -> int:
    """The reverse of collect, for a fresh checkout (never overwrites a newer run directory)."""
    runs, src = Path(args.runs).resolve(), Path(args.dest).resolve()
    for d in sorted(src.glob("*-s*/cycle*")):
        target = runs / d.relative_to(src)
        if (target / "log.jsonl").exists():
            continue
        shutil.copytree(d, target, dirs_exist_ok=True)
        if (target / "log.jsonl.gz").exists():
            with gzip.open(target / "log.jsonl.gz", "rb") as s, open(target / "log.jsonl", "wb") as t:
                shutil.copyfileobj(s, t)
    print(f"restored into {runs}")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tricons_pose.ablation", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("advance", "eval", "table", "collect", "restore"))
    p.add_argument("--runs", default=str(ROOT / "data/runs/ablation"), help="run directories")
    p.add_argument("--dest", default=str(ROOT / "models/checkpoints/ablation"), help="collect/restore: committed copy")
    p.add_argument("--cycles", type=int, default=1, help="advance: every run up to this many cycles")
    p.add_argument("--frame-cache", choices=("memory", "disk"), default="memory",
                   help="advance: train.py's --frame-cache; disk lets two workers share the OS page cache "
                        "instead of holding ~11 GB each")
    p.add_argument("--compile", action="store_true",
                   help="advance: train.py's --compile (inductor kernels: ~1.2x per step after a few minutes of "
                        "compilation per cycle)")
    p.add_argument("--eval", action="store_true",
                   help="advance: after each cycle, run `eval` (on --split) for every finished cycle that lacks one")
    p.add_argument("--poll-s", type=float, default=60.0,
                   help="advance: while only runs held by another advance are left, look again after this long")
    p.add_argument("--data", nargs="+", default=["../data/synthnocs-train", "../data/synthnocs-train2"],
                   help="advance: training recordings (relative to tools/)")
    p.add_argument("--cache-dir", default="../data/cache-train", help="advance: preprocessing cache")
    p.add_argument("--split", default="val", help="eval/table: data/synthnocs-SPLIT")
    args = p.parse_args(argv)
    return {"advance": advance, "eval": evaluate, "table": show, "collect": collect, "restore": restore}[args.command](args)


if __name__ == "__main__":
    raise SystemExit(main())
