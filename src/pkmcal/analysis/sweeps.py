"""Accuracy after calibration as a function of a study variable (seed 000 Figs. 5 and 6)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..calibration import calibrate_constraint_link
from ..machines.base import Machine
from ..measurements import simulate_constraint_link
from .accuracy import pose_accuracy, workspace_poses


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
                          rng=0, progress: Callable[[], None] | None = None) -> list[SweepPoint]:
    """Calibrate (maximum likelihood) on simulated constraint-link data while one setting
    varies, and measure the gauge-aligned pose accuracy over the workspace cube.

    ``variable``: ``'noise'`` (encoder noise std, m) or ``'link_length_error'`` (error of the
    assumed ``Lc``, m). ``progress`` is called after every calibration.
    """
    if variable not in ("noise", "link_length_error"):
        raise ValueError(f"variable must be 'noise' or 'link_length_error', got {variable!r}")
    rng = np.random.default_rng(rng)
    P, R = workspace_poses(true.home[0], n=300, rng=rng)
    out = []
    for value in values:
        pos, ori = [], []
        for _ in range(seeds):
            noise = value if variable == "noise" else noise_m
            lc_err = value if variable == "link_length_error" else 0.0
            data = simulate_constraint_link(true, n_poses, noise_m=noise,
                                            link_length_error=lc_err, rng=rng)
            res = calibrate_constraint_link(nominal, data, sigma_m=max(noise, 1e-7),
                                            estimate_link_length=estimate_link_length)
            acc = pose_accuracy(true, res.extras["machine"], P, R)
            pos.append(acc.position_mean)
            ori.append(acc.orientation_mean)
            if progress:
                progress()
        out.append(SweepPoint(float(value), float(np.mean(pos)), float(np.std(pos)),
                              float(np.mean(ori)), float(np.std(ori)), seeds))
    return out
