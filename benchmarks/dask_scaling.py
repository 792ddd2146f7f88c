"""The Dask path of ``pkmcal montecarlo`` against its local processes (issue 26, item 2).

``pkmcal bench`` (h) times 1000 Hexa Slide calibrations on local worker processes; this
script runs the same runs (same settings, seed and values) through a Dask scheduler with as
many single-threaded worker processes as the machine has cores (``LocalCluster``, started
before the clock), after the local processes and the first ``--baseline`` runs in this
process (Dask's client leaves threads behind), in one run: the figures are the two
speed-ups over one process, and the rows must be identical whichever path ran them.

Usage (from the repository root; needs ``pip install 'pkmcal[distributed]'``)::

    .venv/bin/python benchmarks/dask_scaling.py                 # 1000 runs, 100 baseline
    .venv/bin/python benchmarks/dask_scaling.py --runs 200 --json dask.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys

# one BLAS thread per process, before numpy is imported (threads cost ~10x on small SVDs)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
# the workers' statistical profiler samples the computing thread every 10 ms: ~7 % of these
# Python-heavy runs (start your own workers with the same variable)
os.environ.setdefault("DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED", "False")

from pkmcal.analysis.montecarlo import MonteCarloSettings, montecarlo
from pkmcal.machines import default_hexaslide


def _rows(result):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in result.rows]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--baseline", type=int, default=100)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    from distributed import LocalCluster

    settings = MonteCarloSettings(default_hexaslide(), "constraint-link", poses=150,
                                  noise=2e-6, deviations="paper-table1")
    # local processes and one process first: Dask's client leaves threads in this process
    local = montecarlo(settings, "noise", [2e-6], args.runs, seed=8, workers=args.workers)
    one = montecarlo(settings, "noise", [2e-6], args.baseline, seed=8, workers=1)
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        dask = montecarlo(settings, "noise", [2e-6], args.runs, seed=8,
                          scheduler=cluster.scheduler_address)
    single = one.seconds / args.baseline * args.runs
    out = {"runs": args.runs, "workers": args.workers, "dask_seconds": dask.seconds,
           "local_seconds": local.seconds, "single_seconds": single,
           "dask_speedup": single / dask.seconds, "local_speedup": single / local.seconds,
           "identical": _rows(dask) == _rows(local)
           and _rows(one) == _rows(local)[:args.baseline]}
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0 if out["identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
