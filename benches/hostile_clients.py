#!/usr/bin/env python3
"""Issue 17's service check under hostile HTTP clients (a benchmark, not a test).

Starts `tricons serve` on a recording (loopback only), then:
  1. baseline: for PHASE seconds, /health latency (fresh connection per request) and the
     frames published, with no other client;
  2. hostile: opens IDLE connections that never send a byte and SLOW /stream clients that
     send their request and never read (a 4 KiB receive buffer), then measures the same
     for PHASE seconds;
  3. sends SIGTERM and measures the time to exit, the exit status, whether --stats-out was
     written, and whether every line of --out is a whole JSON line and their count equals
     the frames the final stats say were published.
Prints a JSON report (also to --report). Standard library only; every loop is bounded in
count and time; all traffic goes to 127.0.0.1.

    python3 benches/hostile_clients.py --bin target/release/tricons --idle 200 --slow 40
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get(port: int, path: str, timeout_s: float = 5.0) -> tuple[int, bytes, float]:
    """One HTTP/1.1 GET on a fresh connection: (status, body, seconds to the whole answer)."""
    t0 = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while len(data) < 1 << 20:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    dt = time.perf_counter() - t0
    head, _, body = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1]) if head.startswith(b"HTTP/") else -1
    return status, body, dt


def health(port: int) -> dict:
    status, body, _ = get(port, "/health")
    return json.loads(body) if status == 200 else {}


def phase(port: int, seconds: float, probes: int) -> dict:
    """/health latencies (ms) and frames published during `seconds`."""
    start = health(port).get("frames_published", 0)
    lat_ms, codes = [], []
    t_end = time.monotonic() + seconds
    gap = seconds / probes
    for _ in range(probes):
        status, _, dt = get(port, "/health")
        codes.append(status)
        lat_ms.append(dt * 1000.0)
        time.sleep(max(0.0, min(gap, t_end - time.monotonic())))
    end = health(port).get("frames_published", 0)
    return {
        "health_ms_median": round(statistics.median(lat_ms), 3),
        "health_ms_max": round(max(lat_ms), 3),
        "health_status": sorted(set(codes)),
        "published": end - start,
        "frames_per_s": round((end - start) / seconds, 3),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--bin", default=str(REPO / "target/release/tricons"))
    p.add_argument("--recording", default=str(REPO / "tests/data/synthnocs-demo"))
    p.add_argument("--masks", default="gt", choices=("gt", "model"))
    p.add_argument("--idle", type=int, default=200)
    p.add_argument("--slow", type=int, default=40)
    p.add_argument("--phase", type=float, default=10.0, help="seconds per phase")
    p.add_argument("--probes", type=int, default=40, help="/health requests per phase")
    p.add_argument("--report", help="also write the report here")
    args = p.parse_args()

    work = Path(tempfile.mkdtemp(prefix="tricons-hostile-"))
    out, stats_out = work / "out.jsonl", work / "stats.json"
    port = free_port()
    cmd = [args.bin, "serve", "--recording", args.recording, "--masks", args.masks, "--rate", "recorded",
           "--loop", "0", "--listen", f"127.0.0.1:{port}", "--out", str(out), "--stats-out", str(stats_out),
           "--stats-interval", "0"]
    proc = subprocess.Popen(cmd, stderr=open(work / "serve.log", "wb"))
    report: dict = {"command": " ".join(cmd), "idle": args.idle, "slow": args.slow}
    socks: list[socket.socket] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # wait for the first published frame
            try:
                if health(port).get("frames_published", 0) > 0:
                    break
            except OSError:
                pass
            time.sleep(0.2)
        else:
            raise SystemExit("serve published nothing within 120 s")
        report["baseline"] = phase(port, args.phase, args.probes)

        for _ in range(args.idle):
            socks.append(socket.create_connection(("127.0.0.1", port), timeout=5))
        for _ in range(args.slow):
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.settimeout(5)
            s.connect(("127.0.0.1", port))
            s.sendall(b"GET /stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            socks.append(s)
        time.sleep(1.0)
        report["hostile"] = phase(port, args.phase, args.probes)
        report["hostile"]["final_counters"] = {
            k: v for k, v in health(port).items() if k.startswith("http_") or k.startswith("stream_")
        }

        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
            report["killed_after_30_s"] = True
        report["sigterm_exit_s"] = round(time.monotonic() - t0, 3)
        report["exit_status"] = rc
    finally:
        for s in socks:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()

    report["stats_out_written"] = stats_out.exists()
    final = json.loads(stats_out.read_text()) if stats_out.exists() else {}
    raw = out.read_bytes() if out.exists() else b""
    lines = raw.split(b"\n")
    whole = lines[:-1] if raw.endswith(b"\n") else lines
    parsed = 0
    for line in whole:
        try:
            json.loads(line)
            parsed += 1
        except ValueError:
            pass
    report["out_lines"] = len(whole)
    report["out_lines_whole_json"] = parsed
    report["out_ends_with_newline"] = raw.endswith(b"\n") or not raw
    report["final_published"] = final.get("frames_published")
    report["every_published_result_written"] = final.get("frames_published") == parsed == len(whole)
    text = json.dumps(report, indent=2)
    print(text)
    if args.report:
        Path(args.report).write_text(text + "\n")
    ok = (report.get("exit_status") == 0 and report["sigterm_exit_s"] <= 5.0 and report["stats_out_written"]
          and report["every_published_result_written"] and report["hostile"]["health_status"] == [200])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
