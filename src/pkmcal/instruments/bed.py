"""A printer's bed in its probe heights (SPEC 8): the printer's frame is its bed.

A machine whose frame is its bed (``machine.frame_is_bed``: a printer, z = 0 the probed bed,
z up its normal) holds the bed's height at 0 in every calibration from probe heights: its
endstops carry the height. The bed's tilt against the towers is an unknown only where the data
tell it from the parameter set (:func:`bed_choice`); otherwise the bed is square to the
towers, as the firmwares model it, and the calibration says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..estimation.rank import RTOL, numerical_rank
from ..machines.base import Machine
from .data import InstrumentData
from .models import ProbeModel
from .problem import instrument_problem

#: equations beyond the unknowns that the data must leave for a printer's bed tilt to be
#: estimated beside the parameter set (the capacity rule of the noise levels)
TILT_REDUNDANCY = 10
#: what ``--bed-tilt`` takes
BED_TILT_CHOICES = ("auto", "estimate", "square")


@dataclass
class BedChoice:
    """How the bed enters a calibration from probe heights.

    Attributes
    ----------
    fixed : tuple of str
        The bed's parameters held (``bed.z`` on a printer, whose frame is its bed; the tilts
        when the bed is taken square to the towers).
    tilt : str
        ``"estimated"`` or ``"square"``.
    words : str
        The assumption in words, for the report and the console.
    """

    fixed: tuple
    tilt: str
    words: str

    def model(self) -> ProbeModel:
        """The probe's model with these parameters held."""
        return ProbeModel(fixed=self.fixed)


def bed_choice(machine: Machine, data: InstrumentData, noise=None, choice: str = "auto",
               extra_equations: int = 0, extra_unknowns: int = 0,
               rtol: float = RTOL, others=()) -> BedChoice:
    """The bed's unknowns for probe heights on ``machine`` (SPEC 8: a printer's frame is its
    bed).

    A machine whose frame is its bed (``machine.frame_is_bed``: a printer, z = 0 the probed
    bed) holds the bed's height at 0: the endstops carry it. Its tilt against the towers is
    estimated (``choice="auto"``) when the data determine it beside the parameter set: they
    leave at least :data:`TILT_REDUNDANCY` equations beyond the unknowns with it, the heights
    tell it from the free parameters (it adds two to the rank of the heights' Jacobian at the
    start geometry), and they fix it well: its standard deviation at the assumed noise moves
    the bed at the edge of the probed disk by no more than that noise. Otherwise the bed is
    square to the towers, as the firmwares model it (a delta's endstops carry almost all of a
    tilt: the heights fix it only as well as the endstops' differences). Other machines
    estimate the bed's height and tilt.

    Parameters
    ----------
    machine : Machine
        Start geometry with the parameter set's fixed flags.
    data : InstrumentData
        The probe heights.
    noise : object, optional
        Their noise model (whitening).
    choice : {"auto", "estimate", "square"}, optional
        ``--bed-tilt``: decide from the data, estimate the tilt, or hold it at 0.
    extra_equations, extra_unknowns : int, optional
        Equations and unknowns of the other files of a joint fit.
    others : sequence of tuple, optional
        ``(data, model, noise)`` of the other files of a joint fit: the rank and the tilt's
        standard deviation are those of the joint problem (a ballbar fixes the arms that
        heights alone leave loose, and with them the tilt).
    rtol : float, optional
        Rank tolerance.

    Returns
    -------
    BedChoice
        What is held and why, in words.
    """
    if choice not in BED_TILT_CHOICES:
        raise InputError(f"--bed-tilt {choice}: auto, estimate or square")
    if not getattr(machine, "frame_is_bed", False):
        return BedChoice((), "estimated", "the bed plane's height and tilt estimated")
    if choice == "estimate":
        return BedChoice(("bed.z",), "estimated",
                         "z = 0 is the probed bed (the printer's frame); its tilt against the "
                         "towers estimated (--bed-tilt estimate)")
    square = ("z = 0 is the probed bed (the printer's frame), square to the towers as the "
              "firmware models it")
    if choice == "square":
        return BedChoice(("bed.z", "bed.tilt_x", "bed.tilt_y"), "square",
                         square + " (--bed-tilt square)")
    n_free = int(np.sum(machine.parameters.free))
    redundancy = len(data) + extra_equations - (n_free + 2 + extra_unknowns)
    if redundancy < TILT_REDUNDANCY:
        return BedChoice(("bed.z", "bed.tilt_x", "bed.tilt_y"), "square",
                         f"{square}: with its tilt the data would leave {max(redundancy, 0)} "
                         f"equation(s) beyond the unknowns (fewer than {TILT_REDUNDANCY}); "
                         "--bed-tilt estimate to fit it anyway")

    ranks, tilt_std, reach = [], np.inf, 0.0
    started = [(d, _started(machine, d, m, nz), nz) for d, m, nz in others]
    for fixed in (("bed.z",), ("bed.z", "bed.tilt_x", "bed.tilt_y")):
        model = _started(machine, data, ProbeModel(fixed=fixed), noise)
        problem = instrument_problem(machine, data, model, noise)
        reach = float(np.max(np.hypot(problem._P0[:, 0], problem._P0[:, 1])))
        if started:
            from .joint import JointProblem

            problem = JointProblem(machine, [(data, model, noise)] + started,
                                   [f"part{i}" for i in range(len(started) + 1)])
        _, J, _ = problem.evaluate(problem.initial_state())
        free = problem.parameters.free
        Jf = (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))
        Jf = Jf[np.all(np.isfinite(Jf), axis=1)]
        s = np.linalg.svd(Jf, compute_uv=False)
        ranks.append(numerical_rank(s, rtol))
        if len(ranks) == 1:
            # the tilt's standard deviation at the assumed noise (whitened Jacobian)
            cov = np.linalg.pinv(Jf.T @ Jf, hermitian=True)
            names = [n for n, f in zip(problem.parameters.names, free, strict=True) if f]
            idx = [i for i, n in enumerate(names) if n.endswith(("bed.tilt_x", "bed.tilt_y"))]
            tilt_std = float(np.sqrt(np.max(np.diag(cov)[idx])))
    if ranks[0] - ranks[1] < 2:
        return BedChoice(("bed.z", "bed.tilt_x", "bed.tilt_y"), "square",
                         f"{square}: the heights cannot tell its tilt from the free parameters "
                         "(a common lean of the towers); --bed-tilt estimate to fit it anyway")
    sigma = float(np.min(getattr(noise, "sigma", np.inf)))
    if not tilt_std * reach <= sigma:
        # the parameter set holds almost all of a tilt (a delta's endstops do): the heights
        # fix it only to more than their noise at the edge of the probed disk, and the
        # firmware's own parameters carry what is seen of it
        return BedChoice(("bed.z", "bed.tilt_x", "bed.tilt_y"), "square",
                         f"{square}: the heights fix its tilt only to {tilt_std * 1e3:.2g} "
                         f"mm/m, {tilt_std * reach * 1e6:.3g} um at the edge of the probed "
                         f"disk, more than their noise: the parameter set carries what they "
                         "see of it; --bed-tilt estimate to fit it anyway")
    return BedChoice(("bed.z",), "estimated",
                     f"z = 0 is the probed bed (the printer's frame); its tilt against the "
                     f"towers estimated ({redundancy} equations beyond the unknowns)")


def _started(machine: Machine, data, model, noise):
    """``model`` with its closed-form start values on ``machine``'s poses of ``data``."""
    problem = instrument_problem(machine, data, model, noise)
    return model.start(problem._P0, problem._R0, data.values, data.group, data.source)
