"""Deviations of a simulated true machine from its nominal geometry."""

from __future__ import annotations

import numpy as np

#: half-widths of the uniform random deviations per machine type: (length m, angle rad)
RANDOM_DEVIATION = {"hexaslide": (2e-3, 0.02), "delta": (1e-3, np.deg2rad(0.5))}


def random_deviations(machine, rng) -> np.ndarray:
    """Uniform random errors of every parameter (:data:`RANDOM_DEVIATION` for the machine
    type; lengths and angles, other kinds +/-1e-3)."""
    params = machine.parameters
    length, angle = RANDOM_DEVIATION.get(getattr(machine, "kind", ""), (2e-3, 0.02))
    kinds = np.array(params.kinds)
    size = np.where(kinds == "length", length, np.where(kinds == "angle", angle, 1e-3))
    return np.random.default_rng(rng).uniform(-1.0, 1.0, len(params)) * size
