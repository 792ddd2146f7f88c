"""Several instruments on one machine in one fit: the joint problem and what each file adds.

Every file is an :class:`~pkmcal.instruments.problem.InstrumentProblem` (its readings, its
instrument's model and noise) on the same machine. The joint problem's global unknowns are
the machine's parameters, once, followed by every file's nuisance parameters, each named with
its file's label in front (``pts.csv:tracker.x``, ``bar.csv:setup1.pivot.x``): two files of one
kind (two tracker stations, two ballbar sessions) keep their own frames and mountings. The
residuals are the files' whitened residuals, every component its own row (``(M, 1)`` with
``M`` the number of measured components of all files): no padding, so the chi-square, the
degrees of freedom and the covariance are exactly those of the stacked least-squares problem,
and a component whose forward kinematics fail is NaN as in a single file's problem.

Only problems without per-measurement unknowns combine this way (the instrument layer's
kinds: points, distances, and any other :class:`~pkmcal.instruments.NuisanceModel`); full
poses and the constraint link estimate a pose per measurement and are refused by the command
line.

What each file adds (:meth:`JointProblem.contributions`): at the joint estimate, the number
of identifiable machine-parameter directions from each file alone (with its own nuisance
unknowns) and from all together, the machine directions that only the combination fixes, and
per machine parameter its Cramér-Rao standard deviation under the assumed noise from each file
alone and jointly ("not fixed" when the file leaves it undetermined).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..errors import InputError
from ..estimation.rank import RTOL, numerical_rank
from ..estimation.sections import Section
from ..identifiability import NullGroup, name_null_space, name_weak_directions
from ..machines.base import Machine
from ..parameters import ParameterSet, Prior
from ..paths import path_text
from .problem import (
    InstrumentProblem,
    InstrumentState,
    frame_motion_groups,
    instrument_problem,
)

#: a machine parameter whose unit vector has a null-space component above this (scaled) is
#: not determined by the data
ESTIMABLE_TOL = 1e-6
#: a session's reading offsets' prior standard deviation, m: "A typical endstop switch has an
#: accuracy of around 100 microns" (Klipper's docs/Endstop_Phase.md); the data pull them
#: further where they see it
SESSION_SIGMA = 100e-6


def file_labels(sources) -> list[str]:
    """Short labels of data files for parameter names: the file name, numbered on a clash.

    Parameters
    ----------
    sources : sequence of str or os.PathLike
        The files (or names of in-memory data).

    Returns
    -------
    list of str
        ``["pts.csv", "bar.csv"]``; two files of one name become ``a.csv`` and ``a.csv#2``.
    """
    names = [Path(str(s)).name or str(s) for s in sources]
    out, seen = [], {}
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return out


@dataclass
class JointState:
    """Estimator state of a joint problem.

    Attributes
    ----------
    u : ndarray
        Machine parameters.
    parts : list of InstrumentState
        Each file's state (its ``u`` is ``u``; nuisance values and the poses last solved).
    dq : ndarray, shape (n_sessions, n_joints), optional
        Each session's reading offsets beyond the reference session's (None: no sessions).
    """

    u: np.ndarray
    parts: list = field(default_factory=list)
    dq: np.ndarray | None = None


class JointProblem:
    """Block problem (no local unknowns) of several instrument problems on one machine.

    Parameters
    ----------
    machine : Machine
        Start geometry; its fixed flags are used (every part's machine must be this one's
        parameters: the parts are rebuilt on it).
    parts : sequence
        :class:`~pkmcal.instruments.InstrumentProblem` objects, or ``(data, model, noise)``
        tuples (an :class:`~pkmcal.instruments.InstrumentData`, a
        :class:`~pkmcal.instruments.NuisanceModel` with its start values and a noise model).
    labels : sequence of str, optional
        One label per part, put in front of its nuisance names (``label:name``); default
        :func:`file_labels` of the data's sources.
    sessions : sequence, optional
        One entry per part: the name of the session it was measured in, None for the
        reference session (default: every part in it). Each other session has its own
        reading offsets, one per joint, shared by its parts (a printer's endstops trigger
        anew at each session's homing): unknowns ``session NAME:dq1`` .. after every part's
        nuisance, each with a prior of :data:`SESSION_SIGMA`.

    Raises
    ------
    InputError
        When a part has per-measurement unknowns, no parts are given or the labels do not
        match the parts.
    """

    local_dof = 0

    def __init__(self, machine: Machine, parts, labels=None, sessions=None):
        built = []
        for part in parts:
            if isinstance(part, InstrumentProblem):
                problem = part
            elif isinstance(part, tuple) and len(part) == 3:
                problem = instrument_problem(machine, *part)
            else:
                raise InputError(f"joint fit: {type(part).__name__} is not an instrument "
                                 "problem; combine points, distances and other instrument "
                                 "models without per-measurement unknowns")
            if getattr(problem, "local_dof", 0):
                raise InputError(f"{path_text(problem.data.source)}: "
                                 "per-measurement unknowns; only "
                                 "instrument problems without them combine")
            if problem.machine is not machine or not problem.fit_machine:
                problem = instrument_problem(machine, problem.data, problem.model, problem.noise)
            built.append(problem)
        if not built:
            raise InputError("joint fit: no data")
        self.machine, self.parts = machine, built
        self.labels = (file_labels([p.data.source for p in built]) if labels is None
                       else [str(v) for v in labels])
        if len(self.labels) != len(built) or len(set(self.labels)) != len(built):
            raise InputError("joint fit: one distinct label per file is needed")
        self.n_machine = len(machine.parameters)
        params = machine.parameters
        self.offsets = []
        nuisance = []
        for label, problem in zip(self.labels, built, strict=True):
            mp = problem.model.parameters
            self.offsets.append(len(params))
            prefixed = ParameterSet([f"{label}:{n}" for n in mp.names], mp.kinds, mp.values,
                                    mp.fixed)
            nuisance.append(prefixed)
            params = params.concat(prefixed)
        self.parameters = params
        # a session's own reading offsets, shared by its parts
        sessions = [None] * len(built) if sessions is None else list(sessions)
        if len(sessions) != len(built):
            raise InputError("joint fit: one session (or None) per file is needed")
        self.session_names = [s for s in dict.fromkeys(sessions) if s is not None]
        self.session_of = [None if s is None else self.session_names.index(s)
                           for s in sessions]
        self.dq_offset = len(params)
        nj = machine.n_joints
        if self.session_names:
            names = [f"session {name}:dq{j + 1}" for name in self.session_names
                     for j in range(nj)]
            dq = ParameterSet(names, ["length"] * len(names), np.zeros(len(names)))
            # an endstop triggers within its repeatability of where it did: a prior, or the
            # offsets take up what the heights barely see (the arms) session by session
            dq = dq.with_prior(Prior.about(dq, [(n, {n: 1.0}, SESSION_SIGMA, "session offset")
                                                for n in names]))
            nuisance.append(dq)
            params = params.concat(dq)
            for problem, s in zip(built, self.session_of, strict=True):
                problem.reading_offsets = s is not None
        self.parameters = params
        extra = nuisance[0]
        for ps in nuisance[1:]:
            extra = extra.concat(ps)
        self.scales = machine.scales_with(extra)
        self.cost_floor = 0.0
        #: number of whitened residual components of each part
        self.sizes = [len(p.data) * p.model.size for p in built]

    # -- columns --------------------------------------------------------------------------
    def columns(self, i: int) -> np.ndarray:
        """Joint columns of part ``i``'s parameters (machine's, then its nuisance).

        Parameters
        ----------
        i : int
            The part.

        Returns
        -------
        ndarray of int
            Indices into :attr:`parameters`.
        """
        n = len(self.parts[i].model.parameters)
        cols = [np.arange(self.n_machine), self.offsets[i] + np.arange(n)]
        s = self.session_of[i] if self.session_names else None
        if s is not None:
            nj = self.machine.n_joints
            cols.append(self.dq_offset + s * nj + np.arange(nj))
        return np.concatenate(cols)

    # -- state ----------------------------------------------------------------------------
    def initial_state(self) -> JointState:
        """Start state: the machine's parameters and every part's start.

        Returns
        -------
        JointState
            The state.
        """
        return JointState(self.machine.u.copy(), [p.initial_state() for p in self.parts],
                          np.zeros((len(self.session_names), self.machine.n_joints)))

    def part_state(self, state: JointState, i: int) -> InstrumentState:
        """Part ``i``'s state (the joint machine parameters and its nuisance).

        Parameters
        ----------
        state : JointState
            A joint state.
        i : int
            The part.

        Returns
        -------
        InstrumentState
            The part's state, sharing the joint ``u``.
        """
        sub = state.parts[i]
        sub.u = state.u
        s = self.session_of[i] if self.session_names else None
        sub.dq = None if s is None or state.dq is None else state.dq[s]
        return sub

    def global_values(self, state) -> np.ndarray:
        """Machine parameters followed by every part's nuisance values.

        Parameters
        ----------
        state : JointState
            An estimator state.

        Returns
        -------
        ndarray, shape (n,)
            Values, internal units.
        """
        dq = [] if state.dq is None else [np.ravel(state.dq)]
        return np.concatenate([state.u] + [s.nuisance.values for s in state.parts] + dq)

    def retract(self, state, du, dl):
        """The state after a global step.

        Parameters
        ----------
        state : JointState
            Current state.
        du : ndarray, shape (n,)
            Global step.
        dl : None
            Unused (no local unknowns).

        Returns
        -------
        JointState
            The new state (poses kept as the next forward kinematics' start).
        """
        n = self.n_machine
        u = state.u + du[:n]
        parts = []
        for i, (problem, sub) in enumerate(zip(self.parts, state.parts, strict=True)):
            step = du[self.offsets[i]:self.offsets[i] + len(problem.model.parameters)]
            parts.append(InstrumentState(u, problem.model.retract(sub.nuisance, step),
                                         sub.P, sub.R))
        dq = state.dq
        if self.session_names:
            nj = self.machine.n_joints
            dq = state.dq + du[self.dq_offset:self.dq_offset + dq.size].reshape(-1, nj)
        return JointState(u, parts, dq)

    def evaluate(self, state, jacobian=True):
        """Whitened residuals of every part, one component per row (see the module docstring).

        Parameters
        ----------
        state : JointState
            The state.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (M, 1)
            The parts' whitened residual components in order; NaN where a forward kinematics
            failed.
        J_g : ndarray, shape (M, 1, n) or None
            Derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        rs, Js = [], []
        n = len(self.parameters)
        for i, problem in enumerate(self.parts):
            r, J, _ = problem.evaluate(self.part_state(state, i), jacobian)
            rs.append(r.reshape(-1, 1))
            if jacobian:
                Jf = np.zeros((r.size, 1, n))
                Jf[:, 0, self.columns(i)] = J.reshape(r.size, -1)
                Js.append(Jf)
        r = np.concatenate(rs, 0)
        return r, (np.concatenate(Js, 0) if jacobian else None), None

    def noise_groups(self):
        """Every file's noise groups, named for the file (``label:key``): each file's levels
        are estimated on their own. None when a part has no groups.

        Returns
        -------
        NoiseGroups or None
            See :class:`~pkmcal.estimation.variance.NoiseGroups`.
        """
        from ..estimation.variance import concat_groups

        parts, offset = [], 0
        for label, problem in zip(self.labels, self.parts, strict=True):
            groups = problem.noise_groups()
            if groups is None:
                return None
            parts.append(groups.prefixed(label, offset))
            offset += len(groups.id_names)
        return concat_groups(parts)

    def split(self, residuals) -> list[np.ndarray]:
        """Joint residual rows back to each part's ``(K_i, size_i)``.

        Parameters
        ----------
        residuals : array_like, shape (M, 1) or (M,)
            Joint residuals (:meth:`evaluate`, a result's ``residuals``).

        Returns
        -------
        list of ndarray
            One array per part.
        """
        flat = np.asarray(residuals, float).reshape(-1)
        out, start = [], 0
        for problem, size in zip(self.parts, self.sizes, strict=True):
            out.append(flat[start:start + size].reshape(len(problem.data), problem.model.size))
            start += size
        return out

    # -- words ----------------------------------------------------------------------------
    def words(self) -> dict:
        """Nuisance heads (``label:head``) -> what they are, in words, naming the file.

        Returns
        -------
        dict
            E.g. ``{"pts.csv:tracker": "the tracker frame of pts.csv"}``.
        """
        out = {}
        for label, problem in zip(self.labels, self.parts, strict=True):
            model_words = problem.model.words
            for name in problem.model.parameters.names:
                head = name.rsplit(".", 1)[0]
                key = next((k for k in model_words if k in head.split(".")
                            or head.startswith(k)), None)
                what = model_words[key] if key is not None else head
                out.setdefault(f"{label}:{head}", f"{what} of {label}")
        for name in self.session_names:
            out[f"session {name}"] = (f"the reading offsets of session {name} (its endstops' "
                                      "triggers)")
        return out

    def null_space(self, state, rtol: float = RTOL) -> np.ndarray:
        """The joint problem's numerical null space (scaled coordinates, fixed = 0).

        Parameters
        ----------
        state : JointState
            The state to linearise at.
        rtol : float, optional
            Relative singular-value tolerance.

        Returns
        -------
        ndarray, shape (n, k)
            Orthonormal unidentifiable directions.
        """
        from .problem import problem_null_space

        return problem_null_space(self, state, rtol)

    def null_groups(self, state, scales, null_space=None) -> list[NullGroup]:
        """The machine's frame motions the files together cannot see, with what absorbs them.

        Parameters
        ----------
        state : JointState
            The state to linearise at.
        scales : ndarray, shape (n,)
            Column scales.
        null_space : ndarray, shape (n, k), optional
            The null space when known; default computed.

        Returns
        -------
        list of NullGroup
            One group per frame motion, absorbers named with their file.
        """
        N = self.null_space(state) if null_space is None else np.asarray(null_space, float)
        return frame_motion_groups(self.machine, state.u, self.parameters, self.n_machine,
                                   scales, N, self.words())

    # -- what each file adds --------------------------------------------------------------
    def contributions(self, state, rtol: float = RTOL) -> JointContributions:
        """Identifiability of the machine's parameters from each file alone and together.

        Parameters
        ----------
        state : JointState
            The state to linearise at (the joint estimate).
        rtol : float, optional
            Relative singular-value tolerance (the one rank rule).

        Returns
        -------
        JointContributions
            Ranks, directions fixed only jointly, per-parameter standard deviations.
        """
        _, J, _ = self.evaluate(state)
        J = J[:, 0, :]
        ok = np.isfinite(J).all(axis=1)
        J = np.where(ok[:, None], J, 0.0) * self.scales
        free = self.parameters.free
        nm = self.n_machine
        mfree = free[:nm]
        starts = np.cumsum([0] + self.sizes)
        rows = [slice(starts[i], starts[i + 1]) for i in range(len(self.parts))]
        cols = [self.columns(i) for i in range(len(self.parts))]

        def analyse(row_sel, col_sel):
            col_sel = np.asarray([c for c in col_sel if free[c]], int)
            A = J[row_sel][:, col_sel]
            machine_cols = col_sel < nm
            _, s, Vt = np.linalg.svd(A, full_matrices=True)
            rank = numerical_rank(s, rtol)
            nuis = A[:, ~machine_cols]
            rank_v = numerical_rank(np.linalg.svd(nuis, compute_uv=False), rtol) \
                if nuis.shape[1] else 0
            N = Vt[rank:].T                                   # null space (scaled, free cols)
            Nm = np.zeros((nm, N.shape[1]))
            Nm[col_sel[machine_cols]] = N[machine_cols]
            # machine directions that cannot be told apart: the machine parts of the null space
            U, sv, _ = np.linalg.svd(Nm, full_matrices=False)
            Um = U[:, sv > 1e-6] if sv.size else np.zeros((nm, 0))
            info_cov = np.zeros((nm, nm))
            if rank:
                cov = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
                m_idx = np.flatnonzero(machine_cols)
                info_cov[np.ix_(col_sel[machine_cols], col_sel[machine_cols])] = \
                    cov[np.ix_(m_idx, m_idx)]
            sc = self.scales[:nm]
            std = np.sqrt(np.clip(np.diag(info_cov), 0, None)) * sc
            estimable = np.linalg.norm(Um, axis=1) < ESTIMABLE_TOL
            std = np.where(estimable & mfree, std, np.nan)
            return {"identifiable": rank - rank_v, "unidentifiable": Um, "std": std}

        alone = [analyse(rows[i], cols[i]) for i in range(len(self.parts))]
        joint = analyse(slice(None), np.arange(len(self.parameters)))
        names = self.parameters.names[:nm]
        mparams = ParameterSet(names, self.parameters.kinds[:nm], state.u,
                               self.parameters.fixed[:nm])
        added = []
        for i in range(len(self.parts)):
            others = [j for j in range(len(self.parts)) if j != i]
            if not others:
                added.append([])
                continue
            without = analyse(np.concatenate([np.arange(starts[j], starts[j + 1])
                                              for j in others]),
                              np.unique(np.concatenate([cols[j] for j in others])))
            Uw, Uj = without["unidentifiable"], joint["unidentifiable"]
            rest = Uw - Uj @ (Uj.T @ Uw)          # fixed once file i joins the others
            U, sv, _ = np.linalg.svd(rest, full_matrices=False) if rest.size else (None, [], None)
            dirs = [] if rest.size == 0 else [U[:, k] for k in range(len(sv)) if sv[k] > 1e-3]
            added.append([mparams.describe_direction(d) for d in dirs])
        return JointContributions(
            labels=list(self.labels), parameters=list(names), fixed=mparams.fixed.copy(),
            n_free=int(mfree.sum()), alone_identifiable=[a["identifiable"] for a in alone],
            joint_identifiable=int(joint["identifiable"]),
            alone_std=np.array([a["std"] for a in alone]), joint_std=joint["std"],
            added=added, kinds=list(self.parameters.kinds[:nm]))


@dataclass
class JointContributions:
    """What each file of a joint fit adds (:meth:`JointProblem.contributions`).

    Attributes
    ----------
    labels : list of str
        The files.
    parameters : list of str
        The machine's parameter names.
    fixed : ndarray of bool
        Held parameters.
    n_free : int
        Free machine parameters.
    alone_identifiable : list of int
        Identifiable machine-parameter directions from each file alone (its own nuisance
        unknowns estimated with them).
    joint_identifiable : int
        The same from all files together.
    alone_std : ndarray, shape (files, n_machine)
        Cramér-Rao standard deviation of each machine parameter from each file alone under
        the assumed noise, SI units; NaN where the file does not determine it (or fixed).
    joint_std : ndarray, shape (n_machine,)
        The same from all files together.
    added : list of list of str
        Per file: the machine directions (in words) that the other files leave undetermined
        and that are fixed once this file joins them.
    kinds : list of str
        Parameter kinds (``length``, ``angle``, ``ratio``).
    """

    labels: list
    parameters: list
    fixed: np.ndarray
    n_free: int
    alone_identifiable: list
    joint_identifiable: int
    alone_std: np.ndarray
    joint_std: np.ndarray
    added: list
    kinds: list

    def as_dict(self, length_factor: float = 1e-3, angle_factor: float = np.pi / 180,
                units: tuple = ("mm", "deg")) -> dict:
        """The report's section, standard deviations in the file's units.

        Parameters
        ----------
        length_factor : float, optional
            Metres per file length unit.
        angle_factor : float, optional
            Radians per file angle unit.
        units : tuple of str, optional
            The units' names ``(length, angle)``.

        Returns
        -------
        dict
            ``files`` (per file: identifiable alone and what it adds), ``joint_identifiable``,
            ``free_parameters`` and ``parameters`` (per parameter: std alone per file and
            joint, None where not determined).
        """
        def conv(v, kind):
            f = length_factor if kind == "length" else angle_factor if kind == "angle" else 1.0
            return None if not np.isfinite(v) else float(v / f)

        files = [{"file": label, "identifiable_alone": int(n), "fixes_with_the_others": a}
                 for label, n, a in zip(self.labels, self.alone_identifiable, self.added,
                                        strict=True)]
        params = []
        for j, (name, kind) in enumerate(zip(self.parameters, self.kinds, strict=True)):
            if self.fixed[j]:
                continue
            unit = units[0] if kind == "length" else units[1] if kind == "angle" else "1"
            params.append({"name": name, "unit": unit,
                           "alone": {label: conv(self.alone_std[i, j], kind)
                                     for i, label in enumerate(self.labels)},
                           "joint": conv(self.joint_std[j], kind)})
        return {"free_parameters": self.n_free, "joint_identifiable": self.joint_identifiable,
                "files": files, "parameters": params,
                "std_of": "Cramér-Rao standard deviation under the assumed noise, at the joint "
                          "estimate; null: the file(s) do not determine the parameter"}

    def lines(self, units: tuple = ("mm", "deg"), length_factor: float = 1e-3,
              angle_factor: float = np.pi / 180, limit: int = 12) -> list[str]:
        """What each file adds, in words (one line each).

        Parameters
        ----------
        units : tuple of str, optional
            ``(length, angle)`` unit names.
        length_factor : float, optional
            Metres per length unit.
        angle_factor : float, optional
            Radians per angle unit.
        limit : int, optional
            Parameters listed at most (those whose std the combination improves most).

        Returns
        -------
        list of str
            E.g. ``"arm.l1: std not fixed from probe.csv alone, 0.8 um from bar.csv alone,
            0.6 um jointly"``.
        """
        out = [f"{self.joint_identifiable} of {self.n_free} machine-parameter directions "
               "identifiable jointly; alone: "
               + ", ".join(f"{n} from {label}" for label, n
                           in zip(self.labels, self.alone_identifiable, strict=True))]
        for label, added in zip(self.labels, self.added, strict=True):
            if added:
                out.append(f"{label} fixes what the other file(s) leave free: "
                           + "; ".join(added))

        def text(v, kind):
            if not np.isfinite(v):
                return "not fixed"
            if kind == "length":
                return f"{v * 1e6:.3g} um" if v < 1e-3 else f"{v * 1e3:.3g} mm"
            if kind == "angle":
                return f"{v * 1e6:.3g} urad" if v < 1e-3 else f"{np.degrees(v):.3g} deg"
            return f"{v:.3g}"

        best = np.nanmin(np.where(np.isfinite(self.alone_std), self.alone_std, np.inf), axis=0)
        with np.errstate(all="ignore"):
            gain = np.where(np.isfinite(self.joint_std),
                            np.where(np.isfinite(best), best / self.joint_std, np.inf), 0.0)
        order = [j for j in np.argsort(-gain) if not self.fixed[j] and gain[j] > 0][:limit]
        for j in order:
            kind = self.kinds[j]
            alone = ", ".join(f"{text(self.alone_std[i, j], kind)} from {label} alone"
                              for i, label in enumerate(self.labels))
            out.append(f"{self.parameters[j]}: std {alone}; "
                       f"{text(self.joint_std[j], kind)} jointly")
        return out


@dataclass
class JointSection(Section):
    """What a fit of several files adds to its result (``result.sections["joint"]``): each
    file's instrument model at the estimate and at the start, each file's fit with the
    machine held, and what each file contributes. The report's ``files`` and
    ``contributions`` are the calibration layer's (it knows the files' kinds)."""

    instrument: ClassVar[str] = "joint"
    title: ClassVar[str] = "files fitted together"

    models: list
    start_models: list
    before: list
    contributions: object


def fit_joint(machine: Machine, parts, labels=None, rtol: float = RTOL, estimate_noise=True,
              robust: bool = False, sessions=None, **options):
    """Fit one geometry to several instruments' data: starts, each instrument alone, then all.

    Each part's nuisance unknowns start from its model's closed form on the start geometry
    (:meth:`NuisanceModel.start`) and are fitted alone with the machine held (the "before
    calibration" baseline of each file). The file that fixes most machine directions alone
    then calibrates a start geometry, on which the other files' instruments are started
    again (fitted alone); finally the machine's parameters and every file's unknowns are
    fitted together from there.

    Parameters
    ----------
    machine : Machine
        Start geometry (its fixed flags are kept); not modified.
    parts : sequence of tuple
        ``(data, model, noise)`` per file: an :class:`~pkmcal.instruments.InstrumentData`, a
        :class:`~pkmcal.instruments.NuisanceModel` (its start values are computed) and a noise
        model (``whitening``; None: unit weights).
    labels : sequence of str, optional
        One label per file (default :func:`file_labels` of the sources).
    rtol : float, optional
        Rank tolerance.
    estimate_noise : bool or collection of str, optional
        Estimate each file's noise levels from its residuals (its noise model the prior;
        :func:`~pkmcal.estimation.variance.fit`); False holds them; or the group keys to
        hold (``"label:key"``).
    robust : bool, optional
        Leave out the rows the outlier test names.
    sessions : sequence, optional
        Per file the session it was measured in (None: the reference session); each other
        session has its own reading offsets (:class:`JointProblem`).
    **options
        Passed to :func:`~pkmcal.estimation.estimator.levenberg_marquardt` (``max_std``
        defaults to :data:`~pkmcal.estimation.rank.MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``noise``, ``outliers``; ``problem`` (the :class:`JointProblem`),
        ``machine`` (calibrated), ``unidentifiable``; its :class:`JointSection`: ``models``
        (each file's model at the estimate),
        ``start_models``, ``before`` (each file's fit with the machine held),
        ``contributions``
        (:class:`JointContributions`).

    Raises
    ------
    InputError
        When the start geometry cannot reproduce some readings or a file cannot register its
        instrument.
    """
    from ..estimation.estimator import MAX_STD, levenberg_marquardt
    from ..estimation.variance import fit

    options = {"max_std": MAX_STD, **options}
    parts = list(parts)
    labels = file_labels([d.source for d, _, _ in parts]) if labels is None else list(labels)

    def started_on(geometry, data, model, noise):
        """The model started on ``geometry`` and fitted alone (machine held)."""
        check = instrument_problem(geometry, data, model, noise)   # raises, naming the rows
        start = model.start(check._P0, check._R0, data.values, data.group, data.source)
        alone = instrument_problem(geometry, data, start, noise, fit_machine=False)
        first = levenberg_marquardt(alone, rtol=rtol, **options)
        first.problem = alone
        return start.with_start(first.state.nuisance), first

    started, before = [], []
    for data, model, noise in parts:
        start, first = started_on(machine, data, model, noise)
        started.append(start)
        before.append(first)
    u0 = machine.u
    if len(parts) > 1:
        # the file that fixes most machine directions alone calibrates the start geometry;
        # the others' instruments start on it (a ballbar circle's pivot, registered on the
        # nominal model, can sit in the mirror image of the true one)
        counts = []
        for (data, _, noise), start, first in zip(parts, started, before, strict=True):
            single = JointProblem(machine, [(data, start, noise)], ["lead"])
            state = single.initial_state()
            counts.append(single.contributions(state, rtol).joint_identifiable)
        lead = int(np.argmax(counts))
        data, _, noise = parts[lead]
        first = levenberg_marquardt(JointProblem(machine, [(data, started[lead], noise)],
                                                 ["lead"]), rtol=rtol, **options)
        if first.success and np.all(np.isfinite(first.x)):
            u0 = first.state.u
            geometry = machine.with_parameters(u0)
            started[lead] = started[lead].with_start(first.state.parts[0].nuisance)
            for i, (data, model, noise) in enumerate(parts):
                if i != lead:
                    started[i] = started_on(geometry, data, model, noise)[0]
    problem = JointProblem(machine, [(d, m, nz) for (d, _, nz), m
                                     in zip(parts, started, strict=True)], labels, sessions)
    state = problem.initial_state()
    state.u = np.array(u0, float)
    for sub in state.parts:
        sub.u = state.u
    result = fit(problem, estimate_noise, robust=robust, rtol=rtol, state=state, **options)
    state = result.state
    groups = problem.null_groups(state, result.scales, result.null_space)
    result.problem, result.machine = problem, machine.with_parameters(state.u)
    result.unidentifiable = (name_null_space(result.null_space, problem.parameters, groups)
                             + name_weak_directions(result, problem.parameters))
    result.add_section(JointSection(
        models=[m.with_start(s.nuisance) for m, s in zip(started, state.parts, strict=True)],
        start_models=started, before=before, contributions=problem.contributions(state, rtol)))
    return result
