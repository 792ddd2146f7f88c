"""Measurement kinds: how :func:`~pkmcal.calibration.calibrate` tells an instrument from a
data file's columns or a data object's class, and which instruments calibrate a machine.

Every instrument of the registry (:mod:`pkmcal.instruments.registry`) is a kind: one with a
calibration flow of its own is dispatched by :func:`flow_kind`, one bringing only a model by
the generic path (:func:`instrument_kind`); kinds registered here (:func:`register_kind`) take
precedence.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from ..errors import InputError
from ..instruments.flow import source_of as _source_of
from ..paths import path_text
from .flows import (
    calibrate_flow,
    calibrate_instrument,
    check_instrument,
    joint_flow,
    joint_instrument,
)

__all__ = ["KINDS", "MeasurementKind", "all_kinds", "data_kinds", "flow_kind",
           "instrument_kind", "kind_of", "measurement_kind", "register_kind", "source_and_kind",
           "supported_kinds"]


@dataclass(frozen=True)
class MeasurementKind:
    """How :func:`calibrate` calibrates from one instrument's data (the calibration layer's
    part of an instrument of :mod:`pkmcal.instruments.registry`).

    What its files hold, how they are recognised, which machines it applies to: the
    instrument's (:attr:`columns`, :meth:`detect`, ...); how the calibration layer fits and
    reports it: this entry's handlers.

    Attributes
    ----------
    instrument : str
        The instrument's registry name (also the report's ``measurement``).
    calibrate : callable
        ``calibrate(machine, data, source, options, split, setups=None) -> Calibration``;
        ``data`` is a path or a data object, ``options`` the calibration's options (a mapping:
        option name -> value, ``noise`` and ``robust`` included), ``split`` None or
        ``(holdout, seed)``, ``setups`` the experiment's set-ups
        (:class:`~pkmcal.instruments.setups.Setups`; None: none).
    check_options : callable
        ``check_options(options, source)``: raise :class:`InputError` for options that do not
        apply.
    joint : callable or None
        ``joint(machine, data, source, noise, options, setups=None) -> JointPart``: the file's
        part of a fit of several files, ``setups`` the experiment's (None, or None returned:
        from the instrument problem of its own calibration, unless the instrument's
        ``joint_refusal`` says why it cannot combine).
    """

    instrument: str
    calibrate: Callable
    check_options: Callable
    joint: Callable | None = None

    @property
    def entry(self):
        """The instrument (:func:`~pkmcal.instruments.registry.instrument`)."""
        from ..instruments.registry import instrument

        return instrument(self.instrument)

    @property
    def name(self) -> str:
        """The kind's name: the instrument's."""
        return self.entry.name

    def __getattr__(self, attr):
        # what the data are (columns, detect, priority, readings_only, missing,
        # fixes_lengths, data_class, joint_refusal): the instrument's
        if attr.startswith("_") or attr in ("instrument", "calibrate", "check_options", "joint"):
            raise AttributeError(attr)
        return getattr(self.entry, attr)

    def why_not(self, machine) -> str | None:
        """Why ``machine`` cannot be calibrated from this kind (None: it can).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The instrument's reason (:meth:`~pkmcal.instruments.base.Instrument.applies`).
        """
        return self.entry.applies(machine)


#: the measurement kinds :func:`calibrate` knows, by name (:func:`register_kind`)
KINDS: dict[str, MeasurementKind] = {}


def register_kind(kind: MeasurementKind) -> MeasurementKind:
    """Make a measurement kind known to :func:`calibrate` (replacing one of the same name).

    Parameters
    ----------
    kind : MeasurementKind
        The kind.

    Returns
    -------
    MeasurementKind
        ``kind``.
    """
    KINDS[kind.name] = kind
    return kind


def all_kinds() -> list[MeasurementKind]:
    """Every instrument's calibration (its registered handlers, else its own flow, else the
    generic path), in the order data files are recognised."""
    from ..instruments.registry import INSTRUMENTS

    for name, inst in INSTRUMENTS.items():
        if name in KINDS:
            continue
        if inst.has_flow:
            KINDS[name] = flow_kind(inst)
        elif inst.fit_model is not None:
            KINDS[name] = instrument_kind(inst)
    return sorted(KINDS.values(), key=lambda k: k.priority)


def supported_kinds(machine) -> dict[str, str]:
    """The measurement kinds ``machine`` can be calibrated from, with the columns they need.

    Parameters
    ----------
    machine : Machine
        The machine.

    Returns
    -------
    dict
        Kind name -> what its data file holds.
    """
    return {k.name: k.columns for k in all_kinds() if k.why_not(machine) is None}


def measurement_kind(path, header: list[str], machine) -> str:
    """The measurement kind of a data file, from its columns, for ``machine``.

    Parameters
    ----------
    path : str or os.PathLike
        The data file (named in messages).
    header : list of str
        Its column names.
    machine : Machine
        The machine to calibrate.

    Returns
    -------
    str
        A key of :data:`KINDS`.

    Raises
    ------
    InputError
        When the columns match no kind, or ``machine`` cannot be calibrated from that kind.
    """
    supported = supported_kinds(machine)
    need = "; ".join(f"{k}: {v}" for k, v in supported.items()) or "none yet"
    matches = [k for k in all_kinds() if k.detect(header) and not k.readings_only]
    if len(matches) > 1:
        raise InputError(f"{path_text(path)}: "
                         f"columns of {len(matches)} kinds of measurement in one file ("
                         + "; ".join(f"{k.name}: {k.columns}" for k in matches)
                         + "): give each instrument's rows in a file of its own (several files "
                         "are fitted together: pkmcal calibrate MACHINE A.csv B.csv)")
    found = next((k for k in all_kinds() if k.detect(header)), None)
    if found is None:
        raise InputError(f"{path_text(path)}: cannot tell the measurement type from the columns "
                         f"({', '.join(header)}); a {machine.kind} is calibrated from {need}")
    if found.name not in supported:
        hints = [KINDS[k].missing for k in supported if KINDS[k].missing]
        if found.readings_only and found.instrument == machine.default_instrument:
            # the machine's own instrument lacks something in the machine file
            raise InputError(f"{_source_of(machine)}: {found.why_not(machine)}; {path_text(path)} "
                             "has "
                             f"joint readings alone ({found.name} data)")
        if found.readings_only and hints:
            columns, words = hints[0]
            raise InputError(f"{path_text(path)}: missing columns {columns}: a {machine.kind} is "
                             f"calibrated from {words} ({need}); columns found: "
                             f"{', '.join(header)}")
        raise InputError(f"{path_text(path)}: "
                         f"{found.name} measurements cannot calibrate a {machine.kind}: "
                         f"{found.why_not(machine)}; a {machine.kind} is calibrated from "
                         f"{need}")
    return found.name


def _names_of(kind: MeasurementKind) -> tuple:
    """The kind's names: its instrument's and the instrument's aliases."""
    return (kind.entry.name, *kind.entry.aliases)


def data_kinds(data, machine) -> list:
    """The measurement kinds of the data (paths by their columns, objects by their class)."""
    from ..io import read_table

    out = []
    for item in (list(data) if isinstance(data, (list, tuple)) else [data]):
        if isinstance(item, (str, Path)):
            header, _ = read_table(Path(item))
            out.append(KINDS[measurement_kind(Path(item), header, machine)])
        else:
            kind = next((k for k in all_kinds() if k.data_class == type(item).__name__
                         and getattr(item, "kind", k.instrument) in _names_of(k)), None)
            if kind is None:
                source = getattr(item, "source", None) or "the data"
                raise InputError(f"{path_text(source)}: "
                                 f"{type(item).__name__} is no calibration data")
            out.append(kind)
    return out


def source_and_kind(machine, item, i: int):
    """The name and :class:`MeasurementKind` of data item ``i`` of several: a file's kind by
    its columns (:func:`measurement_kind`), a data object's by its class and instrument
    (named ``data{i+1}`` unless it has a source).

    Raises
    ------
    InputError
        When an object is no calibration data (or a file's columns fit no kind).
    """
    from ..io import read_table

    if isinstance(item, (str, Path)):
        source = Path(item)
        header, _ = read_table(source)
        return source, KINDS[measurement_kind(source, header, machine)]
    source = getattr(item, "source", None) or f"data{i + 1}"
    kind = next((k for k in all_kinds() if k.data_class == type(item).__name__
                 and getattr(item, "kind", k.instrument) in _names_of(k)), None)
    if kind is None:
        raise InputError(f"{path_text(source)}: {type(item).__name__} is no calibration data")
    return source, kind


def kind_of(machine, data):
    """The name and :class:`MeasurementKind` of one data item to calibrate ``machine`` from: a
    file's kind by its columns (:func:`measurement_kind`), a data object's by its class and
    instrument, refused when the machine cannot be calibrated from it.

    Returns
    -------
    tuple
        ``(source, kind)``.

    Raises
    ------
    InputError
        When the data are no calibration data, or not of this machine.
    """
    from ..io import read_table

    if isinstance(data, (str, Path)):
        source = Path(data)
        header, _ = read_table(source)
        return source, KINDS[measurement_kind(source, header, machine)]
    source = getattr(data, "source", None) or "the data"
    kind = next((k for k in all_kinds() if k.data_class == type(data).__name__
                 and getattr(data, "kind", k.instrument) in _names_of(k)), None)
    if kind is None:
        raise InputError(f"{path_text(source)}: "
                         f"{type(data).__name__} is no calibration data (known: "
                         f"{', '.join(k.data_class for k in all_kinds())})")
    supported = supported_kinds(machine)
    if kind.name not in supported:
        need = "; ".join(f"{k}: {v}" for k, v in supported.items()) or "none yet"
        raise InputError(f"{path_text(source)}: {kind.name} measurements cannot calibrate a "
                         f"{machine.kind}: {kind.why_not(machine)}; a {machine.kind} is "
                         f"calibrated from {need}")
    return source, kind


def flow_kind(inst) -> MeasurementKind:
    """The calibration of an instrument with a flow of its own: its
    :meth:`~pkmcal.instruments.base.Instrument.calibrate`, its option check and its joint part
    (:meth:`~pkmcal.instruments.base.Instrument.joint_part`, else the generic one).

    Parameters
    ----------
    inst : Instrument
        A registry entry with a flow of its own
        (:attr:`~pkmcal.instruments.base.Instrument.has_flow`).

    Returns
    -------
    MeasurementKind
        Its calibration, option check and joint part.
    """
    return MeasurementKind(inst.name, partial(calibrate_flow, inst=inst),
                           partial(check_instrument, inst=inst),
                           partial(joint_flow, inst=inst))


# -- any instrument of the shared layer: a model without unknowns of the machine's frame ----


def instrument_kind(inst) -> MeasurementKind:
    """The calibration of an instrument that registers no handler of its own: the generic
    path of the shared layer (:func:`calibrate_instrument`).

    Parameters
    ----------
    inst : Instrument
        A registry entry with a :meth:`~pkmcal.instruments.base.Instrument.fit_model` (its
        :meth:`~pkmcal.instruments.base.Instrument.calibration_model` is fitted).

    Returns
    -------
    MeasurementKind
        Its calibration, option check and joint part.
    """
    return MeasurementKind(inst.name, partial(calibrate_instrument, inst=inst),
                           partial(check_instrument, inst=inst),
                           partial(joint_instrument, inst=inst))


# every instrument without handlers of its own calibrates by the generic path
all_kinds()
