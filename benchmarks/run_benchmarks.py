"""Run the pkmcal benchmarks (issue 2 targets) and store the figures in results.json.

Usage (from the repository root)::

    .venv/bin/python benchmarks/run_benchmarks.py            # full: ~80-100 s on 2 cores
    .venv/bin/python benchmarks/run_benchmarks.py --quick    # fewer repeats, 50 MC runs
    .venv/bin/python benchmarks/run_benchmarks.py -o other.json

Exit code 1 when a figure misses its target. ``pkmcal bench`` runs the same suite
(:func:`pkmcal.bench.run_all`) and prints the table without writing a file.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np
import scipy

from pkmcal.bench import run_all

HERE = Path(__file__).resolve().parent


def environment() -> dict:
    from importlib.metadata import version

    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "pkmcal": version("pkmcal"),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "system": platform.system(),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="fewer repeats, 50 instead of 200 Monte Carlo runs in (d) and "
                             "(g), and a 50-run single-process baseline in (h)")
    parser.add_argument("-o", "--output", type=Path, default=HERE / "results.json",
                        help="JSON file to write (default: benchmarks/results.json)")
    args = parser.parse_args(argv)
    results = run_all(quick=args.quick)
    width = max(len(r["name"]) for r in results)
    for r in results:
        flag = "ok " if r["ok"] else "NO "
        print(f"{flag} {r['name']:<{width}}  {r['value']:>10.4g} {r['unit']:<6} "
              f"target {r['target']:<10}  {r['detail']}")
    payload = {"quick": args.quick, "environment": environment(), "results": results}
    tmp = args.output.with_suffix(args.output.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2) + "\n")
    tmp.replace(args.output)
    print(f"wrote {args.output}")
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
