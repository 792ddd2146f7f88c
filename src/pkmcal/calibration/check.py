"""A calibrated (or imported) machine scored on data it was not fitted to (issue 35).

``pkmcal check CALIBRATED DATA...``: how far off is the machine on today's data? The machine's
parameters are held; each data file's instrument keeps its own unknowns and one free offset
(a probe's trigger height, a saved mesh's reference: :meth:`NuisanceModel.with_free_offset`),
as the next-session test scores a session (SPEC 9). Reported per file: the residuals (RMS,
largest), their size against the data's assumed noise and the verdict of a chi-square test;
then, where the data come in sessions (a printer's saved configs), each session's own reading
offsets fitted on top (its endstops' drift since the calibration) with their standard
deviations, and the residuals that remain. It is how a user compares the values in force
with pkmcal's on a session neither was fitted to: check the imported ``printer.yaml`` and the
calibrated file on the same ``printer.cfg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..paths import path_text

#: the share of the chi-square distribution a machine that explains the data stays below
CHECK_LEVEL = 0.99


@dataclass
class CheckResult:
    """The outcome of :func:`check`.

    Attributes
    ----------
    report : dict
        ``files`` (per file: rows, noise, RMS, max, noise ratio, verdict), ``verdict``,
        ``sessions`` (drift), ``machine``, ``data``.
    lines : list of str
        The summary in words.
    """

    report: dict
    lines: list = field(default_factory=list)


def _fixed(machine):
    """A copy of ``machine`` with every parameter held."""
    from ..parameters import ParameterSet

    mp = machine.parameters
    new = machine.with_parameters(mp.values)
    new.parameters = ParameterSet(mp.names, mp.kinds, mp.values, np.ones(len(mp), bool))
    for key in ("name", "source", "home"):
        if hasattr(machine, key):
            try:
                setattr(new, key, getattr(machine, key))
            except AttributeError:
                pass
    return new


def _parts(machine, data, noise, setups=None):
    """Each data object's joint part (its instrument model with a free offset) and session;
    a part whose frame is fitted with the others (a printer's bed) takes it as calibrated,
    from the set-ups ``setups``."""
    from ..instruments.probe import bed_plane
    from .firmware_data import expand_firmware_data
    from .joint import joint_part
    from .kinds import source_and_kind
    from .noise_args import noise_of

    given = list(data) if isinstance(data, (list, tuple)) else [data]
    if not given:
        raise InputError("no data file given")
    expanded = expand_firmware_data(given, machine)
    items = list(expanded) if isinstance(expanded, (list, tuple)) else [expanded]
    parts, sources, sessions = [], [], []
    for i, item in enumerate(items):
        source, kind = source_and_kind(machine, item, i)
        level = noise_of(noise, [getattr(item, "origin", source)], 0) if noise else None
        part = joint_part(machine, item, source, kind, level)
        if part.with_others is not None:
            # the frame as calibrated: a printer's bed as its calibration left it
            part.model, part.frame = part.with_others(0, 0, "square")
            bed = bed_plane(setups)
            if bed is not None and len(part.model.parameters) == len(bed):
                part.model.parameters = part.model.parameters.with_values(
                    np.asarray(bed, float))
        part.model = part.model.with_free_offset()
        origin = getattr(item, "origin", None)
        # a firmware's saved state is a session of its own: its endstops triggered anew
        sessions.append(Path(str(origin)).name if origin is not None else None)
        parts.append(part)
        sources.append(source)
    return parts, sources, sessions


def _fit(machine, parts, labels, sessions):
    """The parts' instruments (and the sessions' reading offsets) fitted on the held machine."""
    from ..estimation.estimator import levenberg_marquardt
    from ..instruments.joint import JointProblem
    from ..instruments.problem import instrument_problem

    started = []
    for p in parts:
        check = instrument_problem(machine, p.data, p.model, p.noise)   # raises, naming rows
        started.append(p.model.start(check._P0, check._R0, p.data.values, p.data.group,
                                     p.data.source))
    problem = JointProblem(machine, [(p.data, m, p.noise) for p, m in
                                     zip(parts, started, strict=True)], labels, sessions)
    result = levenberg_marquardt(problem, absolute_sigma=True)
    return problem, result


def check(machine, data, *, noise=None, setups=None) -> CheckResult:
    """Score a calibrated or imported machine on data it was not fitted to.

    Parameters
    ----------
    machine : Machine
        The machine (its parameters are held).
    data : path, data object or list of them
        What :func:`~pkmcal.calibration.run.calibrate` takes: CSV files of any instrument,
        a Klipper ``printer.cfg`` and its backups (their saved points and bed meshes: each
        config a session), a pasted probe report.
    noise : dict, optional
        File -> noise (text or model), as ``calibrate``'s ``--noise FILE=VALUE``; default each
        instrument's (held: the verdict is against it).
    setups : Setups, optional
        The machine file's set-ups (:func:`~pkmcal.io.load_machine_file`): a printer's bed as
        its calibration left it is the frame its probe heights are scored in.

    Returns
    -------
    CheckResult
        The report and its summary lines.

    Raises
    ------
    InputError
        Bad data (naming file, row, column), or data the machine cannot reproduce.
    """
    from scipy.stats import chi2

    from ..instruments.joint import file_labels

    if isinstance(noise, str) or (noise is not None and not isinstance(noise, dict)):
        raise InputError("--noise: give FILE=VALUE per file (e.g. --noise probe.csv=20um)")
    held = _fixed(machine)
    parts, sources, sessions = _parts(machine, data, noise, setups)
    labels = file_labels(sources)
    problem, result = _fit(held, parts, labels, None)
    if not np.all(np.isfinite(result.x)):
        raise InputError(f"{', '.join(map(path_text, sources))}: the machine cannot reproduce "
                         "these data (no pose of its model fits some readings)")
    state = result.state
    files, lines = [], []
    whitened = problem.split(result.residuals)
    total, n_total, k_total = 0.0, 0, 0
    for i, (part, label) in enumerate(zip(parts, labels, strict=True)):
        sub = problem.part_state(state, i)
        predicted = problem.parts[i].predict(sub, part.data.q, part.data.group)
        r = np.linalg.norm(part.data.values - predicted, axis=1)
        ok = np.isfinite(r)
        w = whitened[i][np.all(np.isfinite(whitened[i]), axis=1)]
        k = int(np.sum(problem.parts[i].model.parameters.free))
        n = int(w.size)
        dof = max(n - k, 1)
        c2 = float(np.sum(w * w))
        ratio = math.sqrt(c2 / dof)
        limit = math.sqrt(chi2.ppf(CHECK_LEVEL, dof) / dof)
        total, n_total, k_total = total + c2, n_total + n, k_total + k
        rms = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else math.nan
        worst = int(np.argmax(np.where(ok, r, -1.0))) if ok.any() else 0
        explained = ratio <= limit
        entry = {"file": path_text(part.data.source), "label": label,
                 "measurement": part.kind, "rows": int(ok.sum()), "noise": part.noise_text,
                 "rms_um": rms * 1e6, "max_um": float(r[worst]) * 1e6,
                 "max_row": int(part.data.rows[worst]),
                 "noise_ratio": ratio, "noise_ratio_limit": limit,
                 "explained": bool(explained),
                 "offsets": {n_: float(v) for n_, v, f in zip(
                     problem.parts[i].model.parameters.names, sub.nuisance.values,
                     problem.parts[i].model.parameters.free, strict=True) if f}}
        files.append(entry)
        lines.append(f"{label}: {entry['rows']} rows, RMS {rms * 1e6:.4g} um, max "
                     f"{entry['max_um']:.4g} um (row {entry['max_row']}); {ratio:.3g}x the "
                     f"assumed noise ({part.noise_text}): "
                     + ("explained" if explained else
                        f"NOT explained (at most {limit:.3g}x expected)"))
    dof = max(n_total - k_total, 1)
    ratio = math.sqrt(total / dof)
    limit = math.sqrt(chi2.ppf(CHECK_LEVEL, dof) / dof)
    verdict = {"noise_ratio": ratio, "noise_ratio_limit": limit, "explained": ratio <= limit,
               "text": (f"the machine explains these data: residuals {ratio:.3g}x their assumed "
                        f"noise (at most {limit:.3g}x expected at {CHECK_LEVEL:.0%})"
                        if ratio <= limit else
                        f"the machine does not explain these data: residuals {ratio:.3g}x "
                        f"their assumed noise (at most {limit:.3g}x expected at "
                        f"{CHECK_LEVEL:.0%}): it changed since, or its model misses what "
                        "they see")}
    report = {"machine": path_text(getattr(machine, "source", "") or "the machine"),
              "data": [path_text(s) for s in sources], "files": files, "verdict": verdict,
              "offsets_are": "one free offset per data set (a probe's trigger height, a saved "
                             "mesh's reference) and each instrument's own unknowns; the "
                             "machine's parameters held"}
    lines.append(verdict["text"])
    named = [s for s in dict.fromkeys(sessions) if s is not None]
    nj = machine.n_joints
    if named and nj == len(getattr(machine, "pose_space", ())):
        sproblem, sresult = _fit(held, parts, labels, sessions)
        drift = {}
        for k, name in enumerate(sproblem.session_names):
            cols = sproblem.dq_offset + k * nj + np.arange(nj)
            dq = np.ravel(sresult.state.dq[k])
            std = np.asarray(sresult.std, float)[cols]
            after = {}
            for j in [j for j, s in enumerate(sessions) if s == name]:
                r = np.linalg.norm(parts[j].data.values - sproblem.parts[j].predict(
                    sproblem.part_state(sresult.state, j), parts[j].data.q,
                    parts[j].data.group), axis=1)
                r = r[np.isfinite(r)]
                after[labels[j]] = float(np.sqrt(np.mean(r * r))) * 1e6 if len(r) else None
            drift[name] = {"reading_offsets_mm": [float(v) * 1e3 for v in dq],
                           "std_mm": [float(v) * 1e3 for v in std],
                           "rms_after_um": after}
            lines.append(f"session {name}: reading offsets (its endstops' drift since the "
                         "calibration) " + ", ".join(
                             f"q{j + 1} {v * 1e3:+.4f} +- {s * 1e3:.4f} mm"
                             for j, (v, s) in enumerate(zip(dq, std, strict=True)))
                         + "; RMS with them taken out: " + ", ".join(
                             f"{k} {v:.4g} um" for k, v in after.items() if v is not None))
        report["sessions"] = {"drift": drift,
                              "words": "each session's reading offsets (its endstops' drift) "
                                       "fitted on top of the free offsets; the machine's "
                                       "parameters held"}
    return CheckResult(report, lines)
