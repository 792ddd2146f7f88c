"""One geometry from several data files (:func:`calibrate_joint`): each file's part (its
instrument's), one maximum-likelihood fit of every file's instrument unknowns, and the report
of each file's residuals before and after, the sessions and what each file adds."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..instruments.flow import JointPart, variance_json
from ..instruments.flow import convergence_json as _convergence_json
from ..instruments.flow import identifiability_json as _identifiability_json
from ..instruments.flow import identifiability_metadata as _identifiability_metadata
from ..instruments.flow import parameter_table as _parameter_table
from ..instruments.flow import public_parameters as _public
from ..instruments.flow import require_converged as _require_converged
from ..instruments.flow import source_of as _source_of
from ..instruments.flow import split_rows as _split_rows
from ..instruments.flow import um as _um
from ..instruments.flow import validation_section as _validation
from ..instruments.setups import Setups
from ..paths import file_identity, path_text
from .acceptance import calibration_report_head as _report_head
from .acceptance import finish as _finish
from .kinds import MeasurementKind, all_kinds, source_and_kind
from .noise_args import noise_of
from .options import refuse_in_joint
from .provenance import file_units
from .result import Calibration

__all__ = ["calibrate_joint", "joint_part", "session_report"]


def _combining() -> str:
    """The kinds whose files combine in one fit, in words."""
    return ", ".join(sorted(k.name for k in all_kinds() if not k.joint_refusal))


def joint_part(machine, data, source, kind: MeasurementKind, noise,
               options=None, setups=None) -> JointPart:
    """The joint fit's view of one file (its kind's ``joint`` preparation, else the kind's
    own calibration's instrument problem; the experiment's ``setups`` given to both); refused
    for instruments with a ``joint_refusal`` (full poses and the constraint link: a pose per
    measurement)."""
    from ..instruments import InstrumentProblem

    if kind.joint_refusal:
        raise InputError(f"{path_text(source)}: "
                         f"{kind.name} data cannot be combined with other files in "
                         f"one fit ({kind.joint_refusal}); the kinds that combine: "
                         f"{_combining()}; calibrate from {path_text(source)} on its own")
    part = kind.joint(machine, data, source, noise, {**(options or {}), "noise": noise},
                      setups=setups) if kind.joint is not None else None
    if part is not None:
        return part
    kind.check_options({"noise": noise}, source)
    alone = kind.calibrate(machine, data, source, {"noise": noise}, None, setups=setups)
    problem = alone.result.problem
    if not isinstance(problem, InstrumentProblem) or getattr(problem, "local_dof", 0):
        raise InputError(f"{path_text(source)}: "
                         f"{kind.name} data cannot be combined with other files in "
                         f"one fit (no instrument model of the shared layer); the kinds that "
                         f"combine: {', '.join(sorted(k.name for k in all_kinds() if k.joint))}")
    text = alone.report.get("noise")
    return JointPart(problem.data, problem.model, problem.noise,
                     str(text) if text is not None else f"{kind.name} default", kind.name)


def _part_rms(problem, state, data) -> tuple[float | None, np.ndarray]:
    """RMS (um) of the per-row residual norm (3-D for points) and the residuals (m)."""
    predicted = problem.predict(state, data.q, data.group)
    r = data.values - predicted
    norm = np.linalg.norm(r, axis=1)
    ok = np.isfinite(norm)
    return (_um(math.sqrt(float(np.mean(norm[ok] ** 2)))) if ok.any() else None), r


def session_report(summary, problem, state, result, fl: float, unit: str) -> dict:
    """The report's ``sessions``: how many, which files repeated another's points, which meshes
    were used or left out and why, and each session's own reading offsets (the drift of its
    endstops against the reference session) with their standard deviations."""
    out = dict(summary or {})
    offsets = {}
    nj = problem.machine.n_joints
    for k, name in enumerate(problem.session_names):
        cols = problem.dq_offset + k * nj + np.arange(nj)
        offsets[name] = {"offsets": [float(v) / fl for v in np.ravel(state.dq[k])],
                         "std": [float(result.std[c]) / fl for c in cols], "unit": unit}
    out["offsets"] = offsets
    out["offsets_are"] = ("each session's reading offsets against the reference session "
                          "(the newest): where its endstops triggered; a session's heights "
                          "also have their own height offset, its probe z_offset")
    return out


def calibrate_joint(machine, data: list, *, noise=None, split=None,
                    options=None, setups=None) -> Calibration:
    """One geometry from several data files of instrument-layer kinds (``calibrate`` with a
    list).

    Every file's kind comes from its columns; each keeps its own instrument unknowns (named
    ``FILE:name``) and noise; one maximum-likelihood fit estimates everything
    (:func:`~pkmcal.instruments.joint.fit_joint`). The report has each file's residuals
    before (the machine file's model, the file's instrument fitted alone) and after, the
    joint identifiability in words and what each file adds
    (:class:`~pkmcal.instruments.joint.JointContributions`); the calibrated file carries the
    instruments' sections (the first tracker file's frame and targets, every ballbar file's
    mountings in order).

    Parameters
    ----------
    machine : Machine
        The machine's nominal model (its fixed flags are kept).
    data : list
        Data files (or data objects of the instrument layer), at least one.
    noise : dict or None, optional
        File (as given, its file name, or its index) -> noise (text or model); files not
        named use their kind's default.
    split : tuple, optional
        ``(holdout, seed)``: the rows held out of every file.
    options : mapping, optional
        The other options (name -> value; ``robust``, and the instruments' own): refused
        unless a file's instrument declares them for its part of a fit of several files.
    setups : Setups or mapping, optional
        The experiment's set-ups (None: none); the calibrated file's are these with the fitted
        ones in their place.

    Returns
    -------
    Calibration
        Kind ``"joint"``.

    Raises
    ------
    InputError
        Bad data or options, or a file of a kind that does not combine.
    CalibrationNotConverged
        When the estimator did not converge.
    """
    from ..instruments import IsotropicNoise
    from ..instruments.joint import file_labels, fit_joint
    from ..instruments.registry import INSTRUMENTS
    from ..units import LENGTH

    options = dict(options or {})
    if isinstance(noise, str) or (noise is not None and not isinstance(noise, dict)):
        raise InputError("--noise: with several data files give FILE=VALUE per file (e.g. "
                         "--noise bar.csv=2um)")
    sources, kinds = [], []
    for i, item in enumerate(data):
        source, kind = source_and_kind(machine, item, i)
        kinds.append(kind)
        sources.append(source)
    refuse_in_joint(options, [k.entry for k in kinds])
    seen: dict = {}
    for s in sources:       # one file by two names (hard or symbolic links, ./x and x)
        key = file_identity(s) if isinstance(s, (str, Path)) else ("data", str(s))
        if key in seen:
            first = seen[key]
            how = ("given twice" if str(first) == str(s) else
                   f"given twice: {path_text(first)} and {path_text(s)} are the same file")
            raise InputError(f"{path_text(s)}: the same data file is {how}; give each "
                             "file once")
        seen[key] = s
    labels = file_labels(sources)
    # several sessions (a printer's configs): a source's relative weights hold within one of
    # its runs (Klipper weighs one DELTA_CALIBRATE's heights against its distances), not
    # across runs nobody weighed together; there each file's level is its own variance
    # component, estimated from its residuals where its redundancy allows (a file whose
    # data do not fit the others' machine is down-weighted and named in the noise report)
    pooled = len({getattr(d, "session", None) for d in data}) > 1
    parts, held, hold = [], [], []
    for i, (item, source, kind) in enumerate(zip(data, sources, kinds, strict=True)):
        given = noise_of(noise, sources, i)
        if given is not None:       # the user's level for this file is held
            hold.append(f"{labels[i]}:*")
        part = joint_part(machine, item, source, kind, given, options, setups)
        weights = getattr(part.data, "weights", None)
        if given is None and weights is not None:    # the data's own source's weights
            if pooled:
                part.noise_text += (" (its source's weight as the level assumed; one of "
                                    "several sessions: its level estimated from its own "
                                    "residuals)")
            else:
                part.noise_text += f" ({weights[1]})"
                hold.append(f"{labels[i]}:*")
                part.tied = True
        part.data, h = _split_rows(part.data, split, source)
        parts.append(part)
        held.append(h)
    for i, part in enumerate(parts):
        if part.with_others is not None:
            others = [p for j, p in enumerate(parts) if j != i]
            part.model, part.frame = part.with_others(
                sum(len(p.data) * p.model.size for p in others),
                sum(int(np.sum(p.model.parameters.free)) for p in others), None,
                part.data, [(p.data, p.model, p.noise) for p in others])
    names = ", ".join(map(str, sources))
    sessions = [getattr(p.data, "session", None) for p in parts]
    sessions = sessions if any(s is not None for s in sessions) else None
    try:
        result = fit_joint(machine, [(p.data, p.model, p.noise) for p in parts], labels,
                           estimate_noise=hold,
                           robust=bool(options.get("robust")),
                           sessions=sessions)
        if all(p.tied for p in parts) and result.dof > 0 \
                and np.isfinite(result.residual_variance):
            # every file weighed as its source weighs them (Klipper's DELTA_CALIBRATE): the
            # relative weights held, their common level from the residuals - the same fit,
            # with the outlier test and the covariance at the data's level
            scale = math.sqrt(result.residual_variance)
            for p in parts:
                p.noise = IsotropicNoise(p.noise.sigma * scale)
                p.noise_text = (f"{p.noise.sigma * 1e6:.4g} um (std; the relative weights "
                                f"as the data's source gives them, x{scale:.3g} from the "
                                "residuals)")
            result = fit_joint(machine, [(p.data, p.model, p.noise) for p in parts], labels,
                               estimate_noise=hold,
                               robust=bool(options.get("robust")),
                               sessions=sessions)
            # the residuals set the noise's level: their test against it cannot fail
            result.untested = (
                "the noise level was set from these residuals (the data's source gives only "
                "relative weights), so they cannot be tested against it")
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        message = str(exc) if isinstance(exc, InputError) else \
            f"{names}: joint calibration failed: {exc}"
        if split is not None:
            message = f"--holdout: {message}"
        raise InputError(message) from None
    _require_converged(result, names, "check that the files measure the same machine")
    problem = result.problem
    state = result.state
    units = file_units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    for label, start in zip(labels, result.sections["joint"].start_models, strict=True):
        nominal_of.update({f"{label}:{n}": v for n, v in zip(
            start.parameters.names, start.parameters.values, strict=True)})
    nominal_of.update({n: 0.0 for n in problem.parameters.names if n.startswith("session ")})
    params = _parameter_table(result, nominal_of, units)

    # what the files' instruments set on the calibrated machine file (the first file of each
    # instrument its frame, every ballbar file its setups), shared among the files
    files, sections, taken = [], [], {"given": Setups(setups), "setups": {}}
    for i, (part, label, source) in enumerate(zip(parts, labels, sources, strict=True)):
        sub = problem.part_state(state, i)
        before = result.sections["joint"].before[i]
        bproblem = before.problem
        rms_after, r_after = _part_rms(problem.parts[i], sub, part.data)
        rms_before, _ = _part_rms(bproblem, before.state, part.data)
        model = problem.parts[i].model
        entry = {"file": path_text(source), "label": label, "measurement": part.kind,
                 "measurements": len(part.data), "noise": part.noise_text,
                 "residuals": {"of": ("3-D distance of the points" if model.size == 3 else
                                      "measured - predicted"),
                               "rms_um": rms_after, "before_rms_um": rms_before,
                               "before": "machine file's model, this file's instrument "
                                         "fitted alone",
                               "chi_square": float(np.nansum(problem.split(
                                   result.residuals)[i] ** 2)),
                               "count": int(np.sum(np.isfinite(r_after).all(axis=1)))}}
        found, words = model.joint_section(sub.nuisance, machine, calibrated, str(source), fl,
                                           units, part.frame, taken)
        entry.update(found)
        if words:
            sections.append(words)
        if held[i] is not None:
            entry["validation"] = _validation(
                split, held[i], f"{part.kind} of the held-out rows of {path_text(source)}, "
                                "measured - "
                "predicted with the identified instrument; before: the machine file's model "
                "with the instrument fitted alone", "um",
                _part_rms(bproblem, before.state, held[i])[0],
                _part_rms(problem.parts[i], sub, held[i])[0], rms_after)
        files.append(entry)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable or [])
    contributions = result.sections["joint"].contributions
    from ..units import ANGLE

    fa = ANGLE[units["angle"]]
    r = np.asarray(result.residuals, float)
    report = {
        **_report_head(machine, names, "joint", "joint", units),
        "data_files": [path_text(s) for s in sources],
        "measurements": int(sum(len(p.data) for p in parts)),
        "files": files,
        "parameter_names": "each file's instrument unknowns are named FILE:name (e.g. "
                           f"{labels[0]}:{parts[0].model.parameters.names[0]})",
        "instrument_sections": sections,
        **({"bed_frame": next(p.frame for p in parts if p.frame)}
           if any(p.frame for p in parts) else {}),
        "convergence": _convergence_json(result),
        "residuals": {
            "of": "every file's whitened residuals (measured - predicted, / assumed noise)",
            "count": int(np.isfinite(r).sum()),
            **variance_json(result),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "contributions": {**contributions.as_dict(fl, fa, (units["length"], units["angle"])),
                          "summary": contributions.lines()},
        "parameters": _public(params),
    }
    summary = next((getattr(p.data, "sessions", None) for p in parts
                    if getattr(p.data, "sessions", None)), None)
    if summary is not None or problem.session_names:
        report["sessions"] = session_report(summary, problem, state, result, fl,
                                            units["length"])
    if any(h is not None for h in held):
        report["validation"] = {
            "summary": "; ".join(f"{f['file']}: {f['validation']['summary']}" for f in files
                                 if "validation" in f),
            "holdout": split[0], "seed": split[1]}
    metadata = {
        "method": "joint",
        "date": report["date"],
        "data": [path_text(s) for s in sources],
        "machine": _source_of(machine),
        "measurements": report["measurements"],
        "rms_residual_um": {f["label"]: f["residuals"]["rms_um"] for f in files},
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
    }
    fitted = {name: INSTRUMENTS[name].Setup(*args) for name, args in taken["setups"].items()}
    calibration = _finish("joint", machine, calibrated, result, report, metadata, params, units,
                          Setups(setups).merged(fitted))
    levels = report.get("noise_model")
    if result.untested and isinstance(levels, dict):
        # the levels held in the last fit are the data's weights scaled by the residuals
        for g in levels["groups"]:
            if g["status"] == "held":
                g["status"] = "estimated"
        levels["estimated"] = True
    inputs = [Path(s) for s, item in zip(sources, data, strict=True)
              if isinstance(item, (str, Path))]
    machine_file = getattr(machine, "source", None)
    if machine_file and machine_file != "default" and Path(machine_file).is_file():
        inputs.append(Path(machine_file))
    calibration.inputs = inputs
    return calibration
