"""Simulation helpers: deviations of a true machine, rejection sampling of poses."""

from __future__ import annotations

import numpy as np

from ..paths import path_text

#: half-width of random deviations of ratio parameters (gains), relative to their value
RATIO_DEVIATION = 1e-3



def deviations(machine, which: str, rng) -> np.ndarray:
    """Parameter errors of a simulated true machine: ``none``, ``paper-table1`` (seed 000
    Table 1, Hexa Slide only) or ``random`` (:func:`random_deviations`)."""
    from ..errors import InputError

    params = machine.parameters
    if which == "none":
        return np.zeros(len(params))
    if which == "paper-table1":
        du = machine.paper_deviations()
        if du is None:
            raise InputError(f"--deviations paper-table1 applies to hexaslide machines (seed "
                             f"000 Table 1), not {machine.kind}; use random or none")
        return du
    if which != "random":
        raise InputError(f"--deviations: unknown kind {which!r}; use random, paper-table1 or "
                         "none")
    return random_deviations(machine, rng)


def random_deviations(machine, rng) -> np.ndarray:
    """Uniform random errors of every parameter of a machine.

    Lengths and angles are drawn within the machine's ``RANDOM_DEVIATION`` (2 mm / 0.02 rad
    unless its type says otherwise), ratios (a leg's gain, in whatever reading unit) within
    :data:`RATIO_DEVIATION` of their own value.

    Parameters
    ----------
    machine : Machine
        The machine whose parameters get errors.
    rng : int, numpy.random.Generator or None
        Random generator or seed.

    Returns
    -------
    ndarray, shape (n_params,)
        Deviations in internal units (m, rad, ratio), to add to ``machine.u``.
    """
    params = machine.parameters
    length, angle = machine.RANDOM_DEVIATION
    kinds = np.array(params.kinds)
    ratio = RATIO_DEVIATION * np.abs(params.values)
    size = np.where(kinds == "length", length, np.where(kinds == "angle", angle, ratio))
    return np.random.default_rng(rng).uniform(-1.0, 1.0, len(params)) * size


def draw_accepted(draw, n: int, rng, failure: str, rounds: int = 50, machine=None):
    """``n`` poses from ``draw(m, rng) -> (P (m,3), R (m,3,3), ok (m,))``, drawing batches
    (about twice what is still missing) until enough are accepted.

    With ``machine``, poses whose joint values break its ``joint_limits`` (machine file) are
    not accepted either (:meth:`~pkmcal.machines.base.Machine.within_limits`).

    Raises :class:`~pkmcal.errors.InputError` with ``failure`` (formatted with ``have`` and
    ``n``) when ``rounds`` batches do not give ``n``; when the limits rejected poses, the
    message names the limits, how many poses broke them and the joint values at home.
    """
    from ..errors import InputError

    limited = machine is not None and getattr(machine, "joint_limits", None) is not None
    outside = drawn = 0
    P_out, R_out = [], []
    have = 0
    for _ in range(rounds):
        m = 2 * (n - have) + 16
        if limited and drawn and have:
            # tight limits accept few poses: draw in proportion to the rate seen so far
            m = min(int(m * drawn / have), 100 * m, 200_000)
        P, R, ok = draw(m, rng)
        drawn += m
        if limited and ok.any():
            inside = machine.within_limits(machine.ik(P[ok], R[ok]))
            outside += int((~inside).sum())
            ok = ok.copy()
            ok[ok] = inside
        P_out.append(P[ok])
        R_out.append(R[ok])
        have += int(ok.sum())
        if have >= n:
            return np.concatenate(P_out)[:n], np.concatenate(R_out)[:n]
    if outside:
        source = getattr(machine, "source", None) or "the machine file"
        unit, f = machine.joint_unit()
        with np.errstate(all="ignore"):
            home = np.asarray(machine.ik(*machine.home), float).reshape(-1) / f
        raise InputError(
            f"{path_text(source)}: " + ("no pose" if have == 0 else f"only {have} of {n} poses")
            + f" within the joint limits ({machine.joint_limits_text()}) could be drawn: "
            f"{outside} drawn pose(s) the machine reaches need joint values outside them; "
            f"widen joint_limits or check them against the joint values at home ("
            + ", ".join(f"q{j + 1} = {v:.6g}" for j, v in enumerate(home)) + f" {unit})")
    raise InputError(failure.format(have=have, n=n))
