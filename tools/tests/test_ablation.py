"""Tests of tricons_pose.ablation: the cycle chain's commands, the table, collect/restore."""
import argparse
import gzip
import json
from pathlib import Path

from tricons_pose import ablation as A


def _report(path, value):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"mean": {m: value for m in A.ALL_METRICS}}))


def test_cycles_chain_weights_and_resume_in_place(tmp_path):
    runs = tmp_path / "runs"
    first = A.train_command(runs, ["d"], "c", "baseline", 2, 1)
    assert "--init-from" not in first and "--resume" not in first
    assert first[first.index("--seed") + 1] == "201" and first[first.index("--config") + 1] == "baseline"
    assert first[first.index("--lr-mode") + 1] == "triangular"
    second = A.train_command(runs, ["d"], "c", "baseline", 2, 2)
    assert second[second.index("--init-from") + 1] == str(runs / "baseline-s2" / "cycle1" / A.END)
    (runs / "baseline-s2" / "cycle2").mkdir(parents=True)
    (runs / "baseline-s2" / "cycle2" / "checkpoint.pt").write_bytes(b"x")
    again = A.train_command(runs, ["d"], "c", "baseline", 2, 2)
    assert "--resume" in again and "--init-from" not in again
    assert "--frame-cache" not in again
    disk = A.train_command(runs, ["d"], "c", "baseline", 2, 2, "disk")
    assert disk[disk.index("--frame-cache") + 1] == "disk"
    assert "--compile" not in disk and "--compile" in A.train_command(runs, ["d"], "c", "baseline", 2, 2, compile=True)


def test_table_is_the_mean_over_training_seeds_of_each_seeds_sampling_mean(tmp_path):
    runs = tmp_path / "runs"
    for k, (variant, _) in enumerate(A.VARIANTS):
        for seed in A.SEEDS:
            for s in range(3):
                # seed 1: 10k + 0/1/2 (mean 10k + 1); seed 2: 10k + 3/4/5 (mean 10k + 4)
                _report(A.run_dir(runs, variant, seed, 1) / "eval-val" / f"gt-seed{s}.eval.json",
                        10 * k + 3 * (seed - 1) + s)
    t = A.ablation_table(runs, 1, "val")
    lines = t.splitlines()
    assert lines[0].startswith("| Method | 5°2cm")
    assert lines[2] == "| AG-Pose (Baseline) | " + " | ".join(["2.5 (1.0-4.0)"] * 6) + " |"
    assert lines[5].startswith("| Full | **32.5 (31.0-34.0)**")
    assert A.ablation_table(runs, 2, "val") is None  # cycle 2 not evaluated


def test_convergence_compares_each_means_move_with_its_seeds_spread(tmp_path, capsys):
    runs = tmp_path / "runs"

    def write(cycle, value_of):
        for variant, _ in A.VARIANTS:
            for seed in A.SEEDS:
                for s in range(3):
                    _report(A.run_dir(runs, variant, seed, cycle) / "eval-val" / f"gt-seed{s}.eval.json",
                            value_of(variant, seed))

    write(1, lambda v, seed: 10.0 + seed)  # seeds 11 and 12: mean 11.5
    assert A.convergence(runs, 1, "val") is None and A.convergence(runs, 2, "val") is None
    write(2, lambda v, seed: 20.0 + 3 * seed)  # 23 and 26: mean 24.5, moved 13 > spread 3
    moves = A.convergence(runs, 2, "val")
    assert len(moves) == len(A.VARIANTS) * len(A.PAPER_METRICS)
    assert all(abs(mv - 13.0) < 1e-9 and abs(sp - 3.0) < 1e-9 for _, _, mv, sp in moves)
    assert not A.converged(moves)
    # one variant still moving is enough to say no; every mean within its spread says yes
    write(3, lambda v, seed: (30.0 if v == "shipped" else 24.5) + (seed - 1.5) * 3)
    assert not A.converged(A.convergence(runs, 3, "val"))
    write(4, lambda v, seed: (31.0 if v == "shipped" else 23.0) + (seed - 1.5) * 3)
    assert A.converged(A.convergence(runs, 4, "val"))
    A.main(["table", "--runs", str(runs)])
    out = capsys.readouterr().out
    assert "round 2 against 1: not converged: 24 of 24" in out and "round 4 against 3: converged" in out


def test_collect_keeps_the_adam_state_only_of_unfinished_cycles_and_restore_reverses_it(tmp_path):
    runs, dest = tmp_path / "runs", tmp_path / "dest"
    done, going = A.run_dir(runs, "shipped", 1, 1), A.run_dir(runs, "shipped", 1, 2)
    for d in (done, going):
        d.mkdir(parents=True)
        (d / "checkpoint.pt").write_bytes(b"adam")
        (d / "config.json").write_text("{}")
        (d / "log.jsonl").write_text('{"step": 1}\n')
    (done / A.END).write_bytes(b"weights")
    _report(done / "eval-val" / "gt-seed0.eval.json", 1.0)

    class Args:
        pass
    args = Args()
    args.runs, args.dest = str(runs), str(dest)
    A.collect(args)
    c_done, c_going = dest / "shipped-s1" / "cycle1", dest / "shipped-s1" / "cycle2"
    assert (c_done / A.END).exists() and not (c_done / "checkpoint.pt").exists()
    assert (c_going / "checkpoint.pt").read_bytes() == b"adam" and not (c_going / A.END).exists()
    assert gzip.open(c_done / "log.jsonl.gz").read() == b'{"step": 1}\n'
    assert (c_done / "eval-val" / "gt-seed0.eval.json").exists()
    args.runs = str(tmp_path / "fresh")
    A.restore(args)
    back = A.run_dir(tmp_path / "fresh", "shipped", 1, 2)
    assert (back / "checkpoint.pt").read_bytes() == b"adam" and (back / "log.jsonl").read_text() == '{"step": 1}\n'


def _finish(runs, variant, seed, cycle):
    d = A.run_dir(runs, variant, seed, cycle)
    d.mkdir(parents=True, exist_ok=True)
    (d / A.END).write_bytes(b"weights")


def test_workers_share_a_round_through_locks_and_take_over_a_dead_ones(tmp_path):
    import os
    import subprocess
    import sys

    runs = tmp_path / "runs"
    first = (A.VARIANTS[0][0], A.SEEDS[0], 1)
    assert A.next_cycle(runs, 1) == first
    # another live process (pytest's parent) holds the first run: the next one is taken
    d = A.run_dir(runs, *first)
    d.mkdir(parents=True)
    (d / "advance.lock").write_text(str(os.getppid()))
    assert A.held(d) and not A.claim(d)
    assert A.next_cycle(runs, 1) == (A.VARIANTS[1][0], A.SEEDS[0], 1)
    # every other run of cycle 1 finished: cycle 2 of those starts, not of the held run
    for seed in A.SEEDS:
        for variant, _ in A.VARIANTS:
            if (variant, seed, 1) != first:
                _finish(runs, variant, seed, 1)
    assert A.next_cycle(runs, 1) == "wait"
    assert A.next_cycle(runs, 2) == (A.VARIANTS[1][0], A.SEEDS[0], 2)
    # the holder died: its lock is stale, the run is claimable again and claimed by this pid
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (d / "advance.lock").write_text(str(dead.pid))
    assert not A.held(d) and A.next_cycle(runs, 1) == first
    assert A.claim(d) and (d / "advance.lock").read_text() == str(os.getpid())
    assert not A.held(d)  # this process's own lock
    _finish(runs, *first)
    assert A.next_cycle(runs, 1) is None


def test_advance_evaluates_each_finished_cycle_when_asked_and_keeps_training_when_that_fails(tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    trained, evaluated = [], []

    def fake_train(cmd, cwd, stdout, stderr):
        out = Path(cmd[cmd.index("--out") + 1])
        trained.append(out)
        (out / A.END).write_bytes(b"w")
        return 0

    def fake_eval(args):
        evaluated.append(len(trained))
        if len(trained) == 2:
            raise SystemExit("eval_runtime.sh exited with 1")
        return 0

    monkeypatch.setattr(A.subprocess, "call", fake_train)
    monkeypatch.setattr(A, "evaluate", fake_eval)
    args = argparse.Namespace(runs=str(runs), cycles=1, data=["d"], cache_dir="c", frame_cache="memory",
                              compile=False, poll_s=0.0, eval=True, split="val")
    assert A.advance(args) == 0
    n = len(A.VARIANTS) * len(A.SEEDS)
    assert len(trained) == n and evaluated == list(range(1, n + 1))  # after every cycle, past the failure
    args.eval, trained[:], evaluated[:] = False, [], []
    args.cycles = 2
    A.advance(args)
    assert len(trained) == n and evaluated == []
