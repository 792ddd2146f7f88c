"""``pkmcal montecarlo`` as whole processes: one worker against two (issue 37, item 4).

Times ``pkmcal montecarlo default --vary noise=2um --runs N --workers W`` as the user runs it
(a new process: start-up, worker pool, runs, files), ``--repeat`` times each, alternating
one and two workers, and prints per run the wall time, the CPU time of the command and its
workers (user + system, from the kernel's accounting of waited-for children) and the load
average: on a machine shared with other work the wall times are what is left to us, the CPU
times what the command itself spent. The figure of the issue is the ratio of the median wall
times (target >= 1.7 for 200 runs on 2 cores, and 1000 runs <= 30 s), meaningful only on a
quiet machine (load average well below the number of cores).

Usage (from the repository root)::

    .venv/bin/python benchmarks/montecarlo_workers.py                  # 200 runs, 3 times
    .venv/bin/python benchmarks/montecarlo_workers.py --runs 1000 --repeat 1 --workers 2
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PKMCAL = Path(sys.executable).parent / "pkmcal"


def one(runs: int, workers: int) -> dict:
    """One whole ``pkmcal montecarlo`` process: wall, CPU of it and its workers, load."""
    out = Path(tempfile.mkdtemp(prefix="pkmcal-mc-"))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([str(PKMCAL), "montecarlo", "default", "--vary", "noise=2um",
                           "--runs", str(runs), "--workers", str(workers), "-o",
                           str(out / "mc"), "-q"], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(out, ignore_errors=True)
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"runs": runs, "workers": workers, "wall_s": wall, "cpu_s": cpu,
            "load": os.getloadavg()[0]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    rows = []
    for _ in range(args.repeat):
        for w in args.workers:
            row = one(args.runs, w)
            rows.append(row)
            print(f"runs {row['runs']:5d}  workers {w}  wall {row['wall_s']:7.2f} s  "
                  f"cpu {row['cpu_s']:7.2f} s  load {row['load']:.2f}", flush=True)
    med = {w: statistics.median(r["wall_s"] for r in rows if r["workers"] == w)
           for w in args.workers}
    cpu = {w: statistics.median(r["cpu_s"] for r in rows if r["workers"] == w)
           for w in args.workers}
    print(f"cores {os.cpu_count()}; median wall " + ", ".join(
        f"{w} worker(s) {s:.2f} s" for w, s in med.items()) + "; median cpu " + ", ".join(
        f"{w}: {s:.2f} s" for w, s in cpu.items()))
    if 1 in med:
        for w in args.workers:
            if w != 1:
                print(f"speed-up of {w} workers over 1 (median wall): {med[1] / med[w]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
