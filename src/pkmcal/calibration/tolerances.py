"""What the data measured and what the build tolerances held (SPEC 9, issue 35): the report's
``tolerances`` section, the warning for a value the data pull beyond three tolerances, and the
machine's own words for what its firmware cannot hold (:meth:`Machine.build_error_words`).
"""

from __future__ import annotations

import numpy as np

#: a value this many tolerances from its nominal is named (the data pull it there)
PULLED = 3.0


def tolerance_section(result, units: dict, factors: tuple[float, float]) -> dict | None:
    """The report's ``tolerances`` section of a fit with a prior (None without one).

    Parameters
    ----------
    result : CalibrationResult
        The fit (:meth:`~pkmcal.estimation.estimator.CalibrationResult.prior_summary`).
    units : dict
        The file's units (``length``, ``angle``).
    factors : tuple of float
        SI factors of those units (length, angle).

    Returns
    -------
    dict or None
        ``rows``: per prior row its name, machine-file key, change from nominal, tolerance,
        posterior std (file units), the data's share of the information and the label;
        ``measured`` / ``prior_held`` counts; ``pulled``: the rows beyond :data:`PULLED`
        tolerances.
    """
    rows = result.prior_summary()
    if not rows:
        return None
    fl, fa = factors

    def unit(row):
        return (fa, units["angle"]) if row.kind == "angle" else (fl, units["length"])

    out = []
    for row in rows:
        f, u = unit(row)
        out.append({"name": row.name, "key": row.key, "unit": u,
                    "change": (row.value - row.mean) / f, "prior_std": row.prior_std / f,
                    "posterior_std": row.posterior_std / f if np.isfinite(row.posterior_std)
                    else None,
                    "data_share": row.data_share, "label": row.label,
                    "sigmas_off": row.sigmas})
    return {"of": "build tolerances as a prior (SPEC 9): each row's change from its nominal, "
                  "its tolerance (prior std) and its std after the fit; 'measured' where the "
                  "data carry at least half of the information, 'prior-held' where the "
                  "tolerance does, 'unidentifiable' where no measurement changes it",
            "entries": out,
            "measured": sum(r.label == "measured" for r in rows),
            "prior_held": sum(r.label == "prior-held" for r in rows),
            "pulled": [r.name for r in rows if r.sigmas > PULLED]}


def pulled_warnings(result, source, units: dict, factors: tuple[float, float]) -> list[str]:
    """One warning naming the values the data pull beyond :data:`PULLED` tolerances."""
    rows = [r for r in result.prior_summary() if r.sigmas > PULLED]
    if not rows:
        return []
    fl, fa = factors
    words = []
    for r in rows:
        f, u = (fa, units["angle"]) if r.kind == "angle" else (fl, units["length"])
        words.append(f"{r.name} {(r.value - r.mean) / f:+.4g} {u} ({r.sigmas:.1f} times its "
                     f"tolerance {r.prior_std / f:.3g} {u}, {r.key})")
    return [f"{source}: the data pull {len(rows)} value(s) beyond {PULLED:g} times their "
            f"build tolerance: {'; '.join(words)}; a real build error that large, or a "
            "symptom of something the model lacks (check the data, or widen the tolerance "
            "in the machine file)"]


def tolerance_report(result, calibrated, report: dict, source: str, units,
                     warnings: list) -> None:
    """With build tolerances (SPEC 9): the report's ``tolerances`` section (what the data
    measured, what the prior held), the warning for values the data pull beyond
    :data:`PULLED` tolerances, and the machine's actions for what its firmware cannot hold
    (:meth:`~pkmcal.machines.Machine.build_error_words`); nothing without a prior."""
    from ..units import ANGLE, LENGTH

    units = units or {"length": "mm", "angle": "deg"}
    factors = (LENGTH[units["length"]], ANGLE[units["angle"]])
    section = tolerance_section(result, units, factors)
    if section is None:
        return
    actions = calibrated.build_error_words(result.prior_summary())
    section["actions"] = actions
    report["tolerances"] = section
    warnings.extend(pulled_warnings(result, source, units, factors))
    warnings.extend(actions)
