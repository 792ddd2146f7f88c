"""Accuracy after calibration as a function of a study variable (seed 000 Figs. 5 and 6),
through the Monte-Carlo engine (:mod:`pkmcal.analysis.montecarlo`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..machines.base import Machine
from .montecarlo import MonteCarloSettings, montecarlo

#: the study variables of this module and the engine's names for them
_VARIABLES = {"noise": "noise", "link_length_error": "lc-error"}


@dataclass
class SweepPoint:
    """Calibrated accuracy at one value of the study variable (mean over seeds)."""

    value: float
    position_mean: float
    position_std: float
    orientation_mean: float
    orientation_std: float
    runs: int


def constraint_link_sweep(nominal: Machine, true: Machine, variable: str,
                          values: Sequence[float], n_poses: int = 150, seeds: int = 3,
                          noise_m: float = 0.0, estimate_link_length: bool = False,
                          rng=0, progress: Callable[[], None] | None = None,
                          workers: int | None = 1) -> list[SweepPoint]:
    """Calibrate (maximum likelihood) on simulated constraint-link data while one setting
    varies, and measure the gauge-aligned pose accuracy over the workspace cube.

    ``variable``: ``'noise'`` (encoder noise std, m) or ``'link_length_error'`` (error of the
    assumed ``Lc``, m). ``seeds`` runs per value; ``rng`` the seed of the Monte Carlo (an
    integer, or a Generator that draws one); ``workers`` as in
    :func:`~pkmcal.analysis.montecarlo.montecarlo`. ``progress`` is called after every
    calibration. Standard deviations are over the runs (``ddof=1``).
    """
    if variable not in _VARIABLES:
        raise ValueError(f"variable must be 'noise' or 'link_length_error', got {variable!r}")
    seed = int(rng.integers(2**63)) if isinstance(rng, np.random.Generator) else int(rng)
    settings = MonteCarloSettings(nominal, "constraint-link", poses=n_poses, noise=noise_m,
                                  deviations=true.u - nominal.u,
                                  estimate_lc=estimate_link_length)
    tick = None if progress is None else (lambda n: [progress() for _ in range(n)])
    result = montecarlo(settings, _VARIABLES[variable], values, runs=seeds, seed=seed,
                        workers=workers, progress=tick)
    def spread(std):                                    # one run: no spread
        return std if np.isfinite(std) else 0.0

    out = []
    for p in result.summary:
        pos, ori = p["position_mean"], p["orientation_mean"]
        out.append(SweepPoint(float(p["value"]), pos["mean"], spread(pos["std"]), ori["mean"],
                              spread(ori["std"]), p["runs"]))
    return out
