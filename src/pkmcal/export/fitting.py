"""The best values a controller can hold for a calibrated machine, and what they leave.

:func:`fit_controller` finds the values that minimise the position error over a workspace:
the controller commands joints for each target, the calibrated machine (the best model of
the real one) goes where those joints put it, and the distance to the target is the error the
controller leaves. Values are fitted, not copied: a controller with fewer parameters than the
calibrated model gets its least-squares best, and the remaining error is reported
(:class:`ExportResult`). The formats themselves: :mod:`pkmcal.export.base`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..instruments.setups import Setups
from ..machines.base import Machine
from .base import ControllerFormat, ControllerParameters


@dataclass
class ExportResult:
    """The controller's best values for a calibrated machine, and the error they leave.

    Attributes
    ----------
    format : str
        The format's name.
    params : ControllerParameters
        The fitted values.
    text : str
        The file the controller reads.
    remaining_rms, remaining_max : float
        Position error the fitted values leave over the workspace (RMS, max), m.
    before_rms, before_max : float or None
        The same for the values the controller had before (``nominal``), m.
    workspace : str
        The workspace in words.
    points : int
        Number of workspace poses.
    height_rms, height_max : float or None
        A printer's nozzle height error above the bed over the workspace's points on the bed
        (RMS, max), m; None without such points.
    before_height_rms, before_height_max : float or None
        The same for ``nominal``'s values.
    notes : list of str
        What the user must know to use the file (:meth:`ControllerFormat.export_notes`).
    """

    format: str
    params: ControllerParameters
    text: str
    remaining_rms: float
    remaining_max: float
    before_rms: float | None
    before_max: float | None
    workspace: str
    points: int
    height_rms: float | None = None
    height_max: float | None = None
    before_height_rms: float | None = None
    before_height_max: float | None = None
    notes: list = field(default_factory=list)
    #: the workspace poses the controller cannot command, left out (empty: none), in words
    left_out: str = ""

    def as_dict(self) -> dict:
        """The result for a report (lengths in um).

        Returns
        -------
        dict
            Format, values (SI) and errors.
        """
        um = (lambda v: None if v is None else float(v) * 1e6)  # noqa: E731
        return {"format": self.format, "values": self.params.as_dict(),
                "fixed": [n for n, f in zip(self.params.names, self.params.fixed,
                                            strict=True) if f],
                "workspace": self.workspace, "points": self.points,
                "remaining_rms_um": um(self.remaining_rms),
                "remaining_max_um": um(self.remaining_max),
                "before_rms_um": um(self.before_rms), "before_max_um": um(self.before_max),
                "height_rms_um": um(self.height_rms), "height_max_um": um(self.height_max),
                "before_height_rms_um": um(self.before_height_rms),
                "before_height_max_um": um(self.before_height_max),
                "notes": list(self.notes),
                **({"left_out": self.left_out} if self.left_out else {})}


def position_errors(fmt: ControllerFormat, params: ControllerParameters, machine: Machine,
                    P, R=None) -> np.ndarray:
    """Where the machine goes when the controller commands targets, minus the targets.

    Parameters
    ----------
    fmt : ControllerFormat
        The controller.
    params : ControllerParameters
        Its values.
    machine : Machine
        The machine that moves (the calibrated model).
    P : ndarray, shape (K, 3)
        Targets, m.
    R : ndarray, shape (K, 3, 3), optional
        Target orientations.

    Returns
    -------
    ndarray, shape (K, 3)
        Position errors, m; NaN where the controller or the machine fails.
    """
    P = np.asarray(P, float)
    R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else np.asarray(R, float)
    with np.errstate(all="ignore"):
        q = fmt.ik(params, P, R)
        ok = np.all(np.isfinite(q), axis=-1)
        out = np.full(P.shape, np.nan)
        if ok.any():
            fk = machine.fk(q[ok], start=(P[ok], R[ok]))
            out[ok] = np.where(fk.converged[:, None], fk.P - P[ok], np.nan)
    return out


#: weight of the position error against a printer's nozzle height on its bed in the export's
#: fit (:func:`fit_controller` with ``surface``)
POSITION_WEIGHT = 0.1


def fit_controller(fmt: ControllerFormat, machine: Machine, P, R=None,
                   start: ControllerParameters | None = None,
                   surface=None, setups=None) -> ControllerParameters:
    """The controller's values that minimise the position error over workspace poses.

    Least squares (scipy's trust-region reflective with a finite-difference Jacobian, the
    controller's kinematics being a black box here) from :meth:`ControllerFormat.initial` of
    the machine, over the free parameters; lengths scaled by the machine's characteristic
    length.

    Parameters
    ----------
    fmt : ControllerFormat
        The controller.
    machine : Machine
        The calibrated machine.
    P : ndarray, shape (K, 3)
        Workspace positions, m.
    R : ndarray, shape (K, 3, 3), optional
        Workspace orientations.
    start : ControllerParameters, optional
        Start values; default ``fmt.initial(machine)`` placed for the workspace
        (:meth:`ControllerFormat.placed`).
    surface : array_like of bool, shape (K,), optional
        Workspace poses on a printer's bed: the fit is first of all the nozzle's height above
        the bed there (what a printer's probe heights fix, and its first layer), the position
        error everywhere weighing :data:`POSITION_WEIGHT` beside it. A controller whose
        values cannot hold a tilt of the bed against the towers otherwise takes height errors
        for sideways ones.
    setups : Setups, optional
        The experiment's set-ups: a printer's bed (:class:`~pkmcal.instruments.probe.BedSetup`),
        the frame the controller commands in.

    Returns
    -------
    ControllerParameters
        The fitted values.

    Raises
    ------
    InputError
        When the controller cannot reach the workspace with its start values.
    """
    from scipy.optimize import least_squares

    params = fmt.placed(fmt.initial(machine, setups), machine, P) if start is None else start
    free = ~params.fixed
    L = machine.characteristic_length()
    scale = np.array([L if k == "length" else 1.0 for k in params.kinds])[free]

    on = None if surface is None else np.asarray(surface, bool)
    if on is not None and not on.any():
        on = None

    def residual(x):
        v = params.values.copy()
        v[free] = x * scale
        e = position_errors(fmt, params.with_values(v), machine, P, R) / L
        if on is not None:
            e = np.concatenate([e[on, 2], POSITION_WEIGHT * e.ravel()])
        return np.nan_to_num(e.ravel(), nan=1.0)      # a target lost weighs a lot

    e0 = position_errors(fmt, params, machine, P, R)
    if not np.any(np.all(np.isfinite(e0), axis=-1)):
        raise InputError(f"{fmt.name}: none of the {len(P)} workspace poses can be commanded "
                         "with the controller's values read off the machine; give a smaller "
                         "workspace (--workspace)")
    if not np.all(np.isfinite(e0)):
        # the model holds more than the controller: poses its values cannot command are left
        # out of the fit (export() says how many and where), never a refusal
        keep = np.all(np.isfinite(e0), axis=-1)
        P = np.asarray(P, float)[keep]
        R = None if R is None else np.asarray(R, float)[keep]
        on = None if on is None else on[keep]
        if on is not None and not on.any():
            on = None
    if not free.any() or fmt.exact:
        return params
    fit = least_squares(residual, params.values[free] / scale, method="trf", xtol=1e-15,
                        ftol=1e-15, gtol=1e-15, max_nfev=200 * (int(free.sum()) + 1))
    v = params.values.copy()
    v[free] = fit.x * scale
    return params.with_values(v)


def export(fmt: ControllerFormat, machine: Machine, P, R=None, nominal: Machine | None = None,
           workspace: str = "", surface=None, existing: str | None = None,
           source: str = "", setups=None, nominal_setups=None) -> ExportResult:
    """The controller file for a calibrated machine: fitted values and the error they leave.

    The error is that of the values as the file holds them (:meth:`ControllerFormat.written`:
    rounded as written, or as the controller's own save rounds them onto ``existing``), so
    that it is what the controller then does.

    Parameters
    ----------
    fmt : ControllerFormat
        The controller.
    machine : Machine
        The calibrated machine.
    P : ndarray, shape (K, 3)
        Workspace positions, m.
    R : ndarray, shape (K, 3, 3), optional
        Workspace orientations.
    nominal : Machine, optional
        The machine the controller's current values come from (its machine file before
        calibration): their error on the calibrated machine is reported too.
    workspace : str, optional
        The workspace in words.
    surface : array_like of bool, shape (K,), optional
        Poses on a printer's bed: their z error is reported as the nozzle's height error.
    existing : str, optional
        The controller's current file: the values are saved into it
        (:meth:`ControllerFormat.update`) and the result's text is the updated file.
    source : str, optional
        The file's name (for messages; its includes are read beside it).
    setups : Setups, optional
        The experiment's set-ups: a printer's bed (:class:`~pkmcal.instruments.probe.BedSetup`),
        the frame the controller commands in.
    nominal_setups : Setups, optional
        The set-ups of ``nominal``'s machine file.

    Returns
    -------
    ExportResult
        The result: the values as written, their errors, the file's text.

    Raises
    ------
    InputError
        When the format does not apply to the machine, or the workspace cannot be commanded.
    """
    why = fmt.applies(machine)
    if why is not None:
        raise InputError(f"--to {fmt.name}: {why}")
    P, R, surface, left_out = commandable(fmt, machine, P, R, surface, setups)
    text, params = fmt.written(fit_controller(fmt, machine, P, R, surface=surface,
                                              setups=setups), machine, existing, source,
                               setups)
    E = position_errors(fmt, params, machine, P, R)
    e = np.linalg.norm(E, axis=-1)
    on = None if surface is None else np.asarray(surface, bool)
    if on is not None and not on.any():
        on = None

    def heights(errors):
        if on is None:
            return None, None
        z = np.abs(errors[on, 2])
        return float(np.sqrt(np.nanmean(z**2))), float(np.nanmax(z))

    before, before_h = (None, None), (None, None)
    if nominal is not None:
        E0 = position_errors(fmt, fmt.placed(fmt.initial(nominal, nominal_setups), nominal, P),
                             machine, P, R)
        e0 = np.linalg.norm(E0, axis=-1)
        before = (float(np.sqrt(np.nanmean(e0**2))), float(np.nanmax(e0)))
        before_h = heights(E0)
    return ExportResult(fmt.name, params, text,
                        float(np.sqrt(np.nanmean(e**2))), float(np.nanmax(e)), *before,
                        workspace, len(P), *heights(E), *before_h,
                        fmt.export_notes(params, machine, P), left_out=left_out)


def commandable(fmt: ControllerFormat, machine: Machine, P, R=None, surface=None,
                setups=None):
    """The workspace poses the controller can command with the values read off the machine
    (the model may hold more than the controller: a leaning tower moves the reachable
    volume), and the others in words.

    Parameters
    ----------
    fmt : ControllerFormat
        The controller.
    machine : Machine
        The calibrated machine.
    P, R, surface, setups
        As :func:`export`.

    Returns
    -------
    P, R, surface
        The commandable poses.
    left_out : str
        Empty, or ``"150 of 491 workspace poses ... left out"`` with where they are.

    Raises
    ------
    InputError
        When none can be commanded.
    """
    P = np.asarray(P, float)
    e0 = position_errors(fmt, fmt.initial(machine, setups), machine, P, R)
    keep = np.all(np.isfinite(e0), axis=-1)
    if keep.all():
        return P, R, surface, ""
    if not keep.any():
        raise InputError(f"{fmt.name}: none of the {len(P)} workspace poses can be commanded "
                         "with the controller's values read off the machine; give a smaller "
                         "workspace (--workspace)")
    out = P[~keep]
    rho = np.hypot(out[:, 0], out[:, 1])
    words = (f"{int((~keep).sum())} of {len(P)} workspace poses cannot be commanded with the "
             f"controller's values (the model holds more than the controller): left out of "
             f"the fit and of the errors; they lie {rho.min() * 1e3:.4g}-{rho.max() * 1e3:.4g}"
             f" mm from the axis, at heights {out[:, 2].min() * 1e3:.4g}-"
             f"{out[:, 2].max() * 1e3:.4g} mm")
    return (P[keep], None if R is None else np.asarray(R, float)[keep],
            None if surface is None else np.asarray(surface, bool)[keep], words)



def export_workspace(machine: Machine, workspace=None, n: int = 500, rng=0):
    """The workspace an export is fitted and evaluated over.

    Parameters
    ----------
    machine : Machine
        The calibrated machine.
    workspace : Workspace or ndarray, optional
        A :class:`~pkmcal.analysis.accuracy.Workspace` (e.g. of
        :func:`~pkmcal.analysis.accuracy.box_workspace`), or positions (K, 3), m (at the home
        orientation); default the machine's: :func:`~pkmcal.analysis.accuracy.default_workspace`
        (the SPEC 5 0.1 m cube around home, orientations within +/-10 deg where the platform
        rotates).
    n : int, optional
        Number of poses of the default workspace.
    rng : int or numpy.random.Generator, optional
        Seed of the default workspace's poses.

    Returns
    -------
    Workspace
        Poses ``P`` (K, 3), ``R`` (K, 3, 3) and the description.
    """
    from ..machines.reach import Workspace, default_workspace

    if workspace is None:
        return default_workspace(machine, n, rng)
    if isinstance(workspace, Workspace):
        return workspace
    P = np.asarray(workspace, float).reshape(-1, 3)
    R = np.broadcast_to(np.asarray(machine.home[1], float), (len(P), 3, 3))
    return Workspace(P, R, f"{len(P)} given positions", (P.min(axis=0), P.max(axis=0)))


def carry_like(machine: Machine, like: Machine | None) -> Machine:
    """What ``pkmcal import --like`` takes from the machine file it names, onto an imported
    machine: its name, home, file units, joint limits and effector offsets (a Delta's
    ``smr_offset``, a platform's tracker targets) -- every field a controller's file does
    not hold. The formats' :meth:`~ControllerFormat.to_machine` take what their kinematics
    need of it (the home, a platform radius); this carries the rest, the same for every
    format.

    Parameters
    ----------
    machine : Machine
        The imported machine.
    like : Machine or None
        The ``--like`` machine (of the same type); None: nothing is carried.

    Returns
    -------
    Machine
        ``machine``, changed in place.
    """
    if like is None:
        return machine
    if getattr(like, "name", ""):
        machine.name = like.name
    units = getattr(like, "file_units", None)
    if units:
        machine.file_units = dict(units)
    limits = getattr(like, "joint_limits", None)
    if limits is not None and getattr(like, "n_joints", None) == machine.n_joints:
        machine.joint_limits = (np.array(limits[0], float), np.array(limits[1], float))
    if "smr_offset" in vars(like) or "smr_offset" in vars(machine):
        machine.smr_offset = float(getattr(like, "smr_offset", 0.0) or 0.0)
    return machine


def carry_like_setups(machine: Machine, setups) -> Setups:
    """The set-ups an imported machine takes from the ``--like`` machine file's (``setups``):
    the tracker's, where it holds the targets' places on the platform and the imported
    machine does not fix them (the places with the tracker section that holds them).

    Parameters
    ----------
    machine : Machine
        The imported machine.
    setups : Setups or mapping or None
        The ``--like`` file's set-ups; None: nothing is carried.

    Returns
    -------
    Setups
        What the imported machine file carries.
    """
    tracker = (setups or {}).get("tracker")
    if tracker is None or tracker.targets is None or machine.tracker_target() is not None:
        return Setups()
    return Setups({"tracker": tracker})
