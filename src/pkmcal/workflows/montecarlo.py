"""``pkmcal montecarlo`` as a library function: simulated calibrations while one setting
varies (issue 5, item 4).

Validates everything first (:class:`~pkmcal.errors.InputError`, nothing written), runs the
Monte Carlo of :mod:`pkmcal.analysis.montecarlo` (in this process, local worker processes or
a Dask cluster) advancing a progress, then writes ``runs.csv``, ``summary.csv``,
``summary.json`` and ``montecarlo.png`` into the output directory, all or none, and returns
the summary table as a :class:`~pkmcal.report.summary.Summary`: a warning per value with runs
that are not ok, an error and exit code 1 when a value has no ok run.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from ..calibration.run import versions
from ..errors import InputError
from ..instruments.flow import json_safe
from ..paths import path_text
from ..report.provenance import pinned_date, run_date
from ..report.summary import Summary
from ..units import format_number, format_quantity, parse_quantity
from .common import (
    check_outputs,
    commit_outputs,
    in_output_set,
    load_machine_setups_arg,
    no_progress,
)

__all__ = ["montecarlo", "parse_vary", "OUTPUT_FILES"]

#: files written into the output directory
OUTPUT_FILES = ("runs.csv", "summary.csv", "summary.json", "montecarlo.png")


def parse_vary(text: str) -> tuple[str, list]:
    """``"noise=0.1,1,10um"`` -> ``("noise", [1e-7, 1e-6, 1e-5])`` (SI).

    Each value may carry a unit suffix; values without one take the unit of the last value
    (``0.1,1,10um``); a list without any unit is SI. ``poses`` takes whole numbers.
    """
    from ..analysis.montecarlo import VARIABLES, parse_values, variable_name

    name, sep, rest = str(text).partition("=")
    if not sep or not name.strip():
        raise InputError(f"--vary {text}: expected VARIABLE=V1,V2,... (e.g. noise=0.1,1,10um; "
                         f"variables: {', '.join(VARIABLES)})")
    variable = variable_name(name)
    parts = [p.strip() for p in rest.split(",")]
    if not rest.strip() or any(not p for p in parts):
        raise InputError(f"--vary {variable}: expected comma-separated values after '=', got "
                         f"{rest!r}")
    quantity = VARIABLES[variable][0]
    if quantity == "count":
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            raise InputError(f"--vary {variable}: expected whole numbers, got {rest!r}") from None
        return variable, parse_values(variable, numbers)
    unit = re.match(r"^.*?([A-Za-z/]*)$", parts[-1]).group(1)
    what = f"--vary {variable}"
    values = [parse_quantity(p if re.search(r"[A-Za-z/]$", p) else p + unit, quantity, what)
              for p in parts]
    return variable, parse_values(variable, values)


def _length_option(text: str | None, what: str, allow: tuple[str, ...] = ()):
    """A length option (SI), or None when not given; ``allow`` words pass through."""
    if text is None:
        return None
    if text.strip().lower() in allow:
        return text.strip().lower()
    value = parse_quantity(text, "length", what)
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"{what}: must be >= 0, got {text}")
    return value


@in_output_set
def montecarlo(machine_spec: str, vary: str, output: Path, *, runs: int = 20,
               scenario: str | None = None, poses: int | None = None,
               noise: str | None = None, lc_error: str | None = None,
               tolerance: str | None = None, deviations: str | None = None,
               estimate_lc: bool = False, seed: int = 0, workers: int | None = None,
               scheduler: str | None = None, progress=no_progress) -> Summary:
    """``pkmcal montecarlo``: ``runs`` simulated calibrations at each value of the swept
    setting, their statuses and statistics written to ``output``.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    vary : str
        ``VARIABLE=V1,V2,...`` (:func:`parse_vary`): noise, lc-error, poses or tolerance.
    output : Path
        The output directory (created if missing): :data:`OUTPUT_FILES`.
    runs : int
        Simulated calibrations per value.
    scenario : str, optional
        The measurement scenario (default the machine type's own).
    poses : int, optional
        Measurements per calibration when not swept.
    noise, lc_error, tolerance : str, optional
        Lengths with units when not swept; ``noise`` may also be an instrument's word
        (``leica``).
    deviations : str, optional
        ``paper-table1``, ``random`` or ``none``: true machine = machine + deviations.
    estimate_lc : bool
        constraint-link: estimate Lc too.
    seed : int
        Run r at value i draws from ``SeedSequence(seed, spawn_key=(i, r))``: the same seed
        gives the same runs whatever ``workers`` or ``scheduler``.
    workers : int, optional
        Local worker processes (default all cores; 1 runs in this process).
    scheduler : str, optional
        A Dask scheduler's address to run on instead.
    progress : callable
        ``progress(description, total) -> advance(n=1, description=None)``, one task
        "calibrations" of ``len(values) * runs`` steps.

    Returns
    -------
    Summary
        The settings and the per-value statistics tables and the "wrote ..." line; a warning
        per value with runs not ok; exit code 1 (with an error) when a value has no ok run.

    Raises
    ------
    InputError
        A bad option, named; nothing is written.
    """
    from ..analysis.montecarlo import MonteCarloSettings, scenarios_varying
    from ..analysis.montecarlo import montecarlo as run_montecarlo

    check_outputs([output / name for name in OUTPUT_FILES], [], [output])
    if runs < 1:
        raise InputError(f"--runs: must be >= 1, got {runs}")
    if workers is not None and workers < 1:
        raise InputError(f"--workers: must be >= 1, got {workers}")
    if workers is not None and scheduler:
        raise InputError("--workers: does not apply with --scheduler (the Dask cluster has "
                         "its own workers)")
    variable, values = parse_vary(vary)
    from ..instruments.registry import INSTRUMENTS, instrument
    from ..planning import scenario_for

    machine, file_setups = load_machine_setups_arg(machine_spec)
    resolved = scenario_for(machine, scenario)      # the reason when it does not apply
    inst = instrument(resolved)
    words = tuple(w for i in INSTRUMENTS.values() for w in i.montecarlo_noise_words)
    noise_value = _length_option(noise, "--noise", allow=words)
    if noise_value in words:
        if noise_value not in inst.montecarlo_noise_words:
            users = [i.name for i in INSTRUMENTS.values()
                     if noise_value in i.montecarlo_noise_words]
            raise InputError(f"--noise {noise_value}: applies to the {' or '.join(users)} "
                             f"scenario, not {resolved}")
        noise_value = None
    # Lc estimated where the link length can be wrong
    if estimate_lc and "lc-error" not in inst.montecarlo_variables:
        raise InputError(f"--estimate-lc: applies to {scenarios_varying('lc-error')}, not "
                         f"{resolved}")
    settings = MonteCarloSettings(
        machine, resolved, poses=poses, noise=noise_value,
        lc_error=_length_option(lc_error, "--lc-error") or 0.0,
        deviations=deviations, tolerance=_length_option(tolerance, "--tolerance"),
        estimate_lc=estimate_lc, setups=file_setups)
    if lc_error is not None and "lc-error" not in \
            settings.resolved().instrument().montecarlo_variables:     # checks the settings
        raise InputError(f"--lc-error: applies to {scenarios_varying('lc-error')}, not "
                         f"{resolved} ({machine.kind})")

    advance = progress("calibrations", len(values) * runs)
    result = run_montecarlo(settings, variable, values, runs=runs, seed=seed, workers=workers,
                            scheduler=scheduler, progress=advance)
    files = _write_outputs(result, output, machine_spec)
    summary = Summary()
    _summary_tables(summary, result, files)
    _report_runs(summary, result)
    return summary


def _report_runs(summary: Summary, result) -> None:
    """A warning per value with runs that are not ok (counts per status, an example reason);
    an error and exit code 1 when some value has no ok run (its statistics are empty)."""
    from ..analysis.montecarlo import STATUS_COUNTS, STATUSES

    empty = []
    for i, p in enumerate(result.summary):
        bad = [row for row in result.rows if row["value_index"] == i and row["status"] != "ok"]
        if not bad:
            continue
        counts = ", ".join(f"{p[STATUS_COUNTS[k]]} {k}" for k in STATUSES[1:]
                           if p[STATUS_COUNTS[k]])
        summary.warn(f"{_value_text(result, p['value'])}: {len(bad)} of {p['runs']} runs not "
                     f"ok ({counts}), counted and left out of the statistics; e.g. run "
                     f"{bad[0]['run']}: {bad[0]['failure']}")
        if p["ok"] == 0:
            empty.append(_value_text(result, p["value"]))
    if empty:
        summary.error(f"no run ok (converged and accepted) at {'; '.join(empty)}: no "
                      "statistics; see the status and failure columns of runs.csv")


def _value_text(result, value) -> str:
    """``noise 1 um``: the swept variable at one value, in its display unit."""
    from ..analysis.montecarlo import VARIABLES

    _, unit, factor = VARIABLES[result.variable]
    if result.variable == "poses":
        return f"poses {int(value)}"
    return f"{result.variable} {format_number(value / factor)}" + (f" {unit}" if unit else "")


def _write_outputs(result, outdir: Path, machine_spec: str) -> list[Path]:
    """The four output files, staged and committed together; returns their paths."""
    from ..analysis.montecarlo import (
        ACCEPTANCE_MIN_RATIO,
        ACCEPTANCE_QUANTILE,
        EXACT_RESIDUAL_RATIO,
        STATISTICS,
        STATUS_COUNTS,
        VARIABLES,
        plot_montecarlo,
        runs_table,
        summary_table,
    )
    from ..io import atomic_write_text, write_table

    _, unit, factor = VARIABLES[result.variable]
    display = (lambda v: int(v)) if result.variable == "poses" else (lambda v: v / factor)
    wall = result.seconds
    seconds = [row["seconds"] for row in result.rows]
    report = {
        "pkmcal_report": 1,
        "command": "montecarlo",
        "date": run_date(),
        "machine_file": path_text(machine_spec),
        "settings": result.settings.describe(),
        "variable": result.variable,
        "unit": unit or None,
        "values": [display(v) for v in result.values],
        "runs_per_value": result.runs,
        "seed": result.seed,
        "seeding": "run r at value i draws from numpy SeedSequence(seed, spawn_key=(i, r)) = "
                   "SeedSequence(seed).spawn(n_values)[i].spawn(runs)[r]: the same seed gives "
                   "the same runs whatever the workers or scheduler",
        "executor": result.executor,
        "workers": result.workers,
        # durations vary from run to run: left out of a reproducible build's file (issue 37)
        "timing": ({"wall_seconds": None, "runs_per_second": None, "run_seconds_mean": None,
                    "run_seconds_max": None, "left_out": "SOURCE_DATE_EPOCH is set"}
                   if pinned_date() else
                   {"wall_seconds": wall,
                    "runs_per_second": len(result.rows) / wall if wall > 0 else None,
                    "run_seconds_mean": float(np.mean(seconds)),
                    "run_seconds_max": float(np.max(seconds))}),
        "metrics": {name: {"unit": u or None, "description": words}
                    for name, (u, _, words) in result.metrics.items()},
        "statuses": {
            "ok": "converged and accepted: the only runs in the statistics",
            "not converged": "the estimator did not converge",
            "rejected": "the estimator claimed convergence, but the residuals are more than "
                        "the noise explains (a wrong geometry) or the calibrated model fails "
                        "at the evaluation poses",
            "failed": "an exception (the failure column of runs.csv says which)",
            "converged": "count of runs the estimator said converged (ok + rejected)"},
        "acceptance": {
            "noisy data": f"chi2/dof of the whitened residuals above both chi2.ppf("
                          f"{ACCEPTANCE_QUANTILE}, dof)/dof and {ACCEPTANCE_MIN_RATIO:g} "
                          "rejects (a deliberate Lc error widens it by 1 + (Lc error / "
                          "noise)^2)",
            "exact data": f"residual RMS above {EXACT_RESIDUAL_RATIO:g} x the machine's "
                          "characteristic length (+ the Lc error) rejects"},
        "statistics": "over the ok runs of each value: mean, std (ddof 1), 95 % confidence "
                      "interval of the mean (Student t), median, mad_std (1.4826 x the median "
                      "absolute deviation), 5 % and 95 % quantiles; in the units of "
                      "'metrics'; null where undefined (no ok run; std, interval, spread and "
                      "quantiles of a single ok run)",
        "summary": [
            {"value": display(p["value"]), "runs": p["runs"],
             **{k: p[k] for k in STATUS_COUNTS.values()}, "converged": p["converged"],
             **{name: {k: p[name][k] / scale for k in STATISTICS}
                for name, (_, scale, _) in result.metrics.items()}}
            for p in result.summary],
        "versions": versions(*(("dask", "distributed")
                                 if result.executor.startswith("dask") else ())),
    }
    json_text = json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n"
    # outputs, at the very end, all together
    paths = [outdir / name for name in OUTPUT_FILES]
    write_table(paths[0], *runs_table(result))
    write_table(paths[1], *summary_table(result))
    atomic_write_text(paths[2], json_text)
    plot_montecarlo(result, paths[3])
    commit_outputs()
    return paths


def _summary_tables(summary: Summary, result, files) -> None:
    """The settings, the per-value statistics over the ok runs and the files written."""
    from ..analysis.montecarlo import VARIABLES

    _, unit, factor = VARIABLES[result.variable]
    s = result.settings
    head = summary.pairs(title="pkmcal montecarlo")
    d = s.describe()
    head.add_row("machine", f"{d['machine']} ({d['kind']}), scenario {d['scenario']}")
    fixed = [f"poses {d['poses']}" if result.variable != "poses" else None,
             (f"noise {_um(s.noise)}" if s.noise is not None else "noise default")
             if result.variable != "noise" else None,
             f"Lc error {_um(s.lc_error)}" if s.lc_error and result.variable != "lc-error"
             else None,
             f"deviations {d['deviations']}" + (f" +/-{s.tolerance * 1e3:.4g} mm"
                                                 if s.tolerance is not None else ""),
             "Lc estimated" if s.estimate_lc else None]
    head.add_row("fixed", ", ".join(f for f in fixed if f))
    wall = result.seconds
    head.add_row("runs", f"{result.runs} per value x {len(result.values)} values, seed "
                 f"{result.seed}; {result.executor}"
                 + (f", {result.workers} workers" if result.executor == "local processes"
                    else "")
                 + f"; {wall:.3g} s ({len(result.rows) / wall:.3g} runs/s)")
    metrics = [n for n in result.metrics if n.endswith("_mean")]
    col = f"{result.variable}" + (f" ({unit})" if unit else "")
    cols = [col, "ok", "not ok"]
    for name in metrics:
        u = result.metrics[name][0]
        words = name.removesuffix("_mean").replace("_", " ") + (f" ({u})" if u else "")
        cols += [f"{words} mean", "median", "5-95 %"]
    table = summary.table(*cols, title="error after calibration, over the ok runs",
                          justify={i: "right" for i in range(len(cols))})
    short = {"not_converged": "not conv.", "rejected": "rejected", "failed": "failed"}
    for p in result.summary:
        v = int(p["value"]) if result.variable == "poses" else p["value"] / factor
        bad = ", ".join(f"{p[k]} {w}" for k, w in short.items() if p[k])
        row = [format_number(v), f"{p['ok']}/{p['runs']}", bad or "-"]
        for name in metrics:
            scale = result.metrics[name][1]
            st = {k: p[name][k] / scale for k in p[name]}
            half = (st["ci95_high"] - st["ci95_low"]) / 2
            mean = (f"{format_number(st['mean'])} +/- {format_number(half, 2)}"
                    if math.isfinite(half) else _number(st["mean"], 4))
            spread = (f"{format_number(st['q05'], 3)}..{format_number(st['q95'], 3)}"
                      if math.isfinite(st["q05"]) else "-")
            row += [mean, _number(st["median"], 4), spread]
        table.add_row(*row)
    summary.line("mean +/- half-width of its 95 % confidence interval, median and 5-95 % of "
                 "the ok runs; runs not ok (not converged; rejected: residuals beyond the noise, "
                 "a wrong geometry; failed) are counted, never averaged")
    summary.line("wrote " + ", ".join(map(str, files)))


def _number(v: float, digits: int) -> str:
    """``v`` to ``digits`` significant digits, or ``-`` when undefined (no ok run)."""
    return format_number(v, digits) if math.isfinite(v) else "-"


def _um(v: float) -> str:
    """A length in m, for people (um below 1 mm, then mm)."""
    return format_quantity(v, "length")
