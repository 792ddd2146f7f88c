"""``pkmcal demo`` and ``pkmcal bench`` as library functions: the main job on the embedded
defaults (:mod:`pkmcal.demo`) and the benchmarks against their targets (:mod:`pkmcal.bench`),
each as a :class:`~pkmcal.report.summary.Summary`."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..instruments.flow import json_safe
from ..paths import path_text
from ..report.summary import Summary
from .common import check_outputs, commit_outputs, no_progress

__all__ = ["demo", "bench"]


def _optional_module(name: str, what: str):
    """The module ``name``, which an installation may leave out: its absence is an
    :class:`InputError` with exit code 1 (the command cannot run here)."""
    import importlib

    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            raise InputError(f"{what} is not available in this installation (module {name} "
                             "is missing)", 1) from None
        raise


def demo(outdir: Path, progress=no_progress) -> Summary:
    """``pkmcal demo``: simulate, calibrate and compare on the embedded Hexa Slide, Delta and
    cubic 6-UPU (:func:`pkmcal.demo.run_demo`), the files written into ``outdir``.

    Parameters
    ----------
    outdir : Path
        The demo's directory (created if missing; its files written all or none).
    progress : callable
        ``progress(description, total) -> advance(n=1, description=None)`` (the Monte Carlo
        stages).

    Returns
    -------
    Summary
        The settings lines (seeds, noise, poses, deviations of every case), the table
        ``pkmcal demo: calibration (embedded Hexa Slide and Delta)`` (quantity, before,
        after), the notes and the files written.

    Raises
    ------
    InputError
        ``outdir`` cannot be written (exit 2); :mod:`pkmcal.demo` missing from this
        installation (exit 1).
    """
    module = _optional_module("pkmcal.demo", "the demo")
    check_outputs([], [], [outdir])
    result = module.run_demo(outdir, progress=progress)
    commit_outputs()
    summary = Summary()
    for i, line in enumerate(getattr(result, "settings", []) or []):
        summary.line(f"{'settings: ' if i == 0 else '          '}{line}")
    table = summary.table("quantity", "before calibration", "after calibration",
                          title="pkmcal demo: calibration (embedded Hexa Slide and Delta)")
    for row in result.rows:
        table.add_row(*map(str, row))
    for note in getattr(result, "notes", []) or []:
        summary.line(f"note: {note}")
    files = list(getattr(result, "files", []) or [])
    if files:
        summary.line("files:")
        for f in files:
            summary.line(f"  {path_text(f)}")
    return summary


def bench(json_output: bool = False, progress=no_progress) -> Summary:
    """``pkmcal bench``: every benchmark of :func:`pkmcal.bench.run_all` against its target.

    Parameters
    ----------
    json_output : bool
        The results as a JSON list (raw text) instead of a table.
    progress : callable
        ``progress(description, total) -> advance(n=1, description=None)``: one task
        ``bench``, advanced as each benchmark starts.

    Returns
    -------
    Summary
        The table ``pkmcal bench`` (benchmark, value, unit, target, ok) or the JSON; exit
        code 1 when a benchmark misses its target.

    Raises
    ------
    InputError
        :mod:`pkmcal.bench` missing from this installation (exit 1).
    """
    module = _optional_module("pkmcal.bench", "the benchmark suite")
    bar = {}

    def step(done: int, total: int, description: str | None):
        if not bar:
            bar["advance"], bar["done"] = progress("bench", total), 0
        bar["advance"](done - bar["done"], f"bench: {description}" if description else None)
        bar["done"] = done

    results = list(module.run_all(progress=step))
    summary = Summary(exit_code=0 if all(bool(r.get("ok")) for r in results) else 1)
    if json_output:
        summary.raw(json.dumps(json_safe(results), indent=2) + "\n")
        return summary
    table = summary.table("benchmark", "value", "unit", "target", "ok", title="pkmcal bench",
                          justify={1: "right"})
    for r in results:
        value = r.get("value")
        shown = f"{value:.4g}" if isinstance(value, (int, float)) else str(value)
        table.add_row(str(r.get("name")), shown, str(r.get("unit", "")),
                      str(r.get("target", "")), ("yes", "green") if r.get("ok") else ("NO", "red"))
    return summary
