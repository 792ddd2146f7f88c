"""Machine files (YAML, SPEC 6): load, validate, save.

A machine file states its format version, machine type and units, then the machine's own
section (its geometry, in the file's units) and its home pose::

    pkmcal: 1
    machine: hexaslide
    name: any text
    units: {length: mm, angle: deg}
    constraint_link: {length: 300.0}
    home: [0.0, 0.0, 300.0, 0.0, 0.0, 0.0]      # x, y, z, psi, theta, phi (file units)
    chains:                                    # hexaslide: exactly 6
      - {a0: [451.05, -164.17, -400.0], alpha: 160.0, beta: 70.0, b: [84.85, -84.85, 0.0], l: 450.0}
    calibration: {...}                         # optional metadata written by `pkmcal calibrate`

Each machine type states its section in its own module (``FILE_FORMAT``, a
:class:`~pkmcal.machines.file_format.MachineFormat`, documented there): the Hexa Slide
(:mod:`pkmcal.machines.hexaslide`), the Delta robot (:mod:`pkmcal.machines.delta`), the
six-leg platform (:mod:`pkmcal.machines.stewart`, with its reading units and gains), the
linear Delta printer (:mod:`pkmcal.machines.linear_delta`) and the 3-RPR planar robot
(:mod:`pkmcal.machines.planar_3rpr`). A file's ``home`` lists the pose coordinates the
platform moves along (:attr:`~pkmcal.machines.Machine.pose_space`): ``[x, y, z]`` for a
platform that only translates, ``[x, y, phi]`` for a planar one.

Every machine file may carry what an instrument's calibration fitted (issue 13), in the
file's length unit; all optional::

    tracker:                                   # points (laser tracker): base_from_tracker
      {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0],
       targets: [[10.0, -5.0, -15.0]]}          # not on a Delta (its target is smr_offset)
    ballbar:                                   # distances: one mounting per setup 1..K
      - {pivot: [0.0, 0.0, 200.0], ball: [0.0, 0.0, 0.0]}   # pivot base frame, ball platform
    measurement_frames:                        # poses (a platform that moves in space)
      mocap_from_base: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0]}
      platform_from_marker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0]}
    bed: {height: 0.5, tilt_x: -0.0004, tilt_y: 0.0}   # probe heights: the bed plane

read as the instruments' set-ups (:mod:`pkmcal.instruments.setups`), returned beside the
machine by :func:`load_machine_file` / :func:`parse_machine_file` and written by
:func:`machine_to_text` / :func:`save_machine` (``setups=``): each instrument with a section
declares its set-up type, its section's place in the file and how the section reads and
writes it (:attr:`~pkmcal.instruments.base.Instrument.Setup`,
:meth:`~pkmcal.instruments.base.Instrument.read_setup`,
:meth:`~pkmcal.instruments.base.Instrument.setup_section`); this module names none of them.
They are :class:`~pkmcal.instruments.tracker.TrackerSetup` (``base_from_tracker = (R, t)``,
``targets`` (K, 3) platform-frame places, m, None without ``targets``: the platform origin,
or the Delta's reflector), :class:`~pkmcal.instruments.distance.BallbarSetup` (``mountings``,
``(pivot, ball)`` pairs, m), :class:`~pkmcal.instruments.probe.BedSetup` (``height`` m,
``tilt_x``, ``tilt_y``, ``surface``) and :class:`~pkmcal.instruments.pose.MeasurementFrames`
(a mocap point is ``mocap_from_base`` of a base point, a platform point
``platform_from_marker`` of a marker point). ``pkmcal fk --frame instrument`` predicts the
instrument's measurements from them, ``pkmcal compensate --frame instrument`` takes targets
in the instrument's frame. The machine holds none of them: the loader returns them beside it,
the writer writes those it is given.

Every machine file may state the joints' travel (issue 12 item 7)::

    joint_limits: {min: 0.0, max: 400.0}         # one pair for every joint, or
    joint_limits: {min: [-40, -40, -40], max: [80, 80, 80]}   # one value per joint

in the file's unit of the joint values: slider travel in the length unit (Hexa Slide), arm
angles in the angle unit (Delta), leg readings in the reading unit (Stewart). It is kept on the
machine as ``machine.joint_limits = (lo, hi)`` (arrays in internal units; None without the
key), checked by ``ik``, ``compensate``, ``select-poses`` and ``simulate``, and written back
(a calibrated file keeps it). Lengths may be in ``mm``, ``m`` or ``in`` (``inch`` is read as
``in``).

Loading dispatches on ``machine:`` through :data:`MACHINE_FORMATS` (one entry per machine
type: a pydantic schema, a builder and a dumper), built from the modules listed in
:mod:`pkmcal.machines.registry`: a new machine type is its module and one line there. This
module adds what every machine file has (``pkmcal``, ``machine``, ``name``, ``units``, the
instrument sections, ``joint_limits``, ``calibration``) where the machine's schema does not
state it, reads and writes the instrument sections and ``home``, and checks that the numbers
are plausible (each format says which are lengths, dimensions, angles or gains). Every
problem is an :class:`~pkmcal.errors.InputError` whose message reads
``FILE: key.path: what is wrong (line N)``, e.g.
``machine.yaml: chains[3].alpha: not a number: 'abc' (line 12)``; list indices are 0-based.

Values are converted to internal units (m, rad) on loading; the file's units are kept on the
machine as ``machine.file_units`` so outputs use them. Saving writes every float with ``repr``
(shortest round-trip form), so ``load_machine(save_machine(m))`` reproduces the parameters to
a few ulp, and writes atomically (:func:`~pkmcal.io.atomic.atomic_write_text`).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import datetime as _dt
import functools
import json
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ValidationError, create_model

from ..errors import InputError
from ..instruments.registry import INSTRUMENTS
from ..instruments.setups import Setups
from ..kinematics import euler_from_matrix
from ..limits import (
    MAX_ANGLE,
    MAX_LENGTH,
    MAX_LENGTH_RATIO,
    MAX_MACHINE_FILE_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    MIN_GAIN,
)
from ..machines.base import Machine
from ..machines.file_format import MachineFormat, Units, factors
from ..machines.file_format import show as _show
from ..machines.registry import machine_formats as registered_machine_formats
from ..paths import path_text
from .atomic import atomic_write_text, read_input_text

FORMAT_VERSION = 1
LENGTH_UNITS = ("mm", "m", "in")
#: other names of the length units (``inch`` is read as ``in``)
LENGTH_ALIASES = {"inch": "in"}
ANGLE_UNITS = ("deg", "rad")
DEFAULT_UNITS = {"length": "mm", "angle": "deg"}

# --------------------------------------------------------------------------------------------
# YAML reading: floats such as 1e-3 (YAML 1.1 wants 1.0e-3), duplicate keys, line numbers
# --------------------------------------------------------------------------------------------


class _DuplicateKey(yaml.MarkedYAMLError):
    pass


class _Refused(yaml.MarkedYAMLError):
    """A file refused while it is composed (too deep, too many values): ``problem`` says why,
    ``context`` holds the key path."""


def _path_text(path) -> str:
    """``chains[3].alpha`` of a composer path (shortened when deep)."""
    parts = list(path)
    text = _key_path(parts[:6])
    if len(parts) > 6:
        text += "..."
    return text


class _Loader(yaml.SafeLoader):
    """Safe loader that reads ``1e-3`` as a float, refuses duplicate keys and bounds the
    document before it is constructed: nesting depth (:data:`~pkmcal.limits.MAX_YAML_DEPTH`)
    and values with aliases expanded (:data:`~pkmcal.limits.MAX_YAML_NODES`); an alias to
    the collection that holds it is refused. Aliased nodes are shared in the composed graph,
    so the expanded size is counted with one size per node, never by walking the expansion.
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._path: list = []
        self._depth = 0
        self._expanded = 0
        self._sizes: dict[int, int] = {}

    def _refuse(self, what: str, mark):
        raise _Refused(_path_text(self._path), None, what, mark)

    def _count(self, n: int, mark) -> None:
        self._expanded += n
        if self._expanded > MAX_YAML_NODES:
            self._refuse(f"more than {MAX_YAML_NODES} values with the aliases (*name) "
                         "expanded; a machine file has a few hundred: write the values out "
                         "instead of nesting anchors (&name) and aliases", mark)

    def compose_node(self, parent, index):
        if isinstance(parent, yaml.MappingNode):
            part = index.value if isinstance(index, yaml.ScalarNode) else None
            pushed = index is not None
        else:
            part, pushed = index, parent is not None
        if pushed:
            self._path.append(part if part is not None else "?")
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            node = super().compose_node(parent, index)
            size = self._sizes.get(id(node))
            if size is None:
                self._refuse("the alias refers to a collection that contains it (a recursive "
                             "alias)", mark)
            self._count(size, mark)
            if pushed:
                self._path.pop()
            return node
        mark = self.peek_event().start_mark
        if self._depth >= MAX_YAML_DEPTH:
            self._refuse(f"nested more than {MAX_YAML_DEPTH} levels deep; a machine file "
                         "needs a few", mark)
        self._count(1, mark)
        self._depth += 1
        node = super().compose_node(parent, index)
        self._depth -= 1
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        else:
            children = []
        self._sizes[id(node)] = 1 + sum(self._sizes[id(c)] for c in children)
        if pushed:
            self._path.pop()
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    hash(key)
                except TypeError:
                    continue  # the base class reports unhashable keys
                if key in seen:
                    raise _DuplicateKey(None, None, f"duplicate key {key!r}",
                                        key_node.start_mark)
                seen[key] = True
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def _line_map(node, path=(), out=None) -> dict[tuple, int]:
    """1-based line of every key path in a composed YAML node tree."""
    out = {} if out is None else out
    out[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            _line_map(value_node, path + (key,), out)
            out[path + (key,)] = key_node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _line_map(item, path + (i,), out)
    return out


def _parse_yaml(text: str, source: str):
    """``(document, line_map)``; YAML syntax errors become :class:`InputError` with a line.

    A text parsed again (the same file loaded again in one process: a library's loop, the
    commands of a session) is not scanned again: the document of one of the last texts
    parsed is returned as a deep copy, so nothing a caller changes is seen by the next one
    (a file that fails is parsed, and refused, every time)."""
    data, lines = _parsed_yaml(text, source)
    return copy.deepcopy(data), dict(lines)


@functools.lru_cache(maxsize=16)
def _parsed_yaml(text: str, source: str):
    """:func:`_parse_yaml`'s parse (its result shared: only ever copied)."""
    try:
        loader = _Loader(text)
    except yaml.YAMLError as exc:       # e.g. a control character: the reader refuses it
        reason = " ".join(str(exc).split())
        raise InputError(f"{path_text(source)}: not a YAML text file: {reason}") from None
    try:
        node = loader.get_single_node()
        if node is None:
            raise InputError(f"{path_text(source)}: "
                             "the file is empty (expected a machine description "
                             "starting with 'pkmcal: 1')")
        data = loader.construct_document(node)
    except _Refused as exc:
        line = exc.problem_mark.line + 1
        raise InputError(f"{path_text(source)}: "
                         f"{exc.context}: {exc.problem} (line {line})") from None
    except RecursionError:       # not reached within MAX_YAML_DEPTH; never a traceback
        raise InputError(f"{path_text(source)}: nested too deeply to be a machine file") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        what = exc.problem or exc.context or "invalid YAML"
        raise InputError(f"{path_text(source)}: {where}YAML syntax error: {what}") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path_text(source)}: "
                         f"YAML syntax error: {' '.join(str(exc).split())}") from None
    finally:
        loader.dispose()
    return data, _line_map(node)


# --------------------------------------------------------------------------------------------
# Machine formats: each machine module's section, with what every machine file has
# --------------------------------------------------------------------------------------------


def _file_units(units: dict) -> dict:
    """Units with the aliases replaced (``inch`` -> ``in``), as kept on the machine."""
    units = dict(units)
    units["length"] = LENGTH_ALIASES.get(units.get("length"), units.get("length"))
    return units


def _fmt(x: float) -> str:
    """Shortest round-trip text of a float that YAML 1.1 also reads as a float."""
    x = float(x)
    if x == 0.0:
        return "0.0"
    s = repr(x)
    if "e" in s and "." not in s:
        mant, exp = s.split("e")
        s = f"{mant}.0e{exp}"
    return s


def _setup_instruments() -> list:
    """The instruments with a set-up (:attr:`~pkmcal.instruments.base.Instrument.Setup`), in
    the order of their sections in a machine file."""
    return sorted((inst for inst in INSTRUMENTS.values() if inst.Setup is not None),
                  key=lambda inst: inst.section_order)


def _read_setups(machine: Machine, doc, fl: float) -> Setups:
    """The set-ups of a validated file: each instrument's, read from its section (those the
    file has; keys a machine type's schema does not have are absent)."""
    return Setups({inst.name: inst.read_setup(section, fl, machine)
                   for inst in _setup_instruments()
                   if (section := getattr(doc, inst.section, None)) is not None})


def bed_frame(machine: Machine, setups: Setups) -> tuple[Machine, Setups]:
    """``machine`` and its set-ups expressed in its bed's frame when its frame is its bed (a
    printer, SPEC 8): a ``bed`` at a height ``h`` above z = 0 (a simulated true printer's, an
    older file's) is the same printer with its base frame ``h`` lower - the endstops carry
    the height, the bed is at z = 0 with its tilt kept - and so it is read and written: a
    printer's file never says its bed is anywhere but z = 0 (issue 37). Every base-frame value
    moves with it (``home``, each set-up: :meth:`Setups.shifted
    <pkmcal.instruments.setups.Setups.shifted>`); no reading changes.

    Parameters
    ----------
    machine : Machine
        The machine.
    setups : Setups
        Its set-ups (the bed's says where the frame is: :meth:`Setups.frame_shift
        <pkmcal.instruments.setups.Setups.frame_shift>`).

    Returns
    -------
    tuple
        ``(machine, setups)`` themselves when there is nothing to move, else moved copies.
    """
    t = setups.frame_shift(machine)
    if t is None:
        return machine, setups
    out = machine.with_parameters(machine.transform_base(machine.u, np.eye(3), t=t))
    if machine._home is not None:
        out.home = (machine._home[0] + t, machine._home[1])
    return out, setups.shifted(t)


def _setup_sections(machine: Machine, setups: Setups, fl: float) -> dict:
    """The instrument sections of ``setups`` in the file's length unit, in file order (the
    inverse of :func:`_read_setups`)."""
    out: dict[str, Any] = {}
    for inst in _setup_instruments():
        setup = setups.get(inst.name)
        if setup is not None:
            section = inst.setup_section(setup, fl, machine)
            if section is not None:
                out[inst.section] = section
    return out


@functools.cache
def _instrument_kinds() -> dict:
    """Quantities of the instrument sections (every machine type; a key a type lacks never
    matches): each instrument's ``file_quantities``, looked up when a number is not the
    machine's own."""
    return {path: kind for inst in INSTRUMENTS.values()
            for path, kind in inst.file_quantities.items()}

#: what every machine file may have, in file order, where a machine's schema does not state
#: it itself (``machine`` is always the format's own type): the head, the instrument sections
#: every machine may have (each instrument's ``section_schema``, in the order of their
#: sections), then ``joint_limits`` (checked by :func:`_joint_limits`, per-joint messages)
#: and ``calibration``
_COMMON_FIELDS: dict[str, tuple | None] = dict(
    pkmcal=(Literal[1], ...), machine=None,                 # machine: the format's own type
    name=(str | None, None), units=(Units, ...),
    **{inst.section: (inst.section_schema | None, None) for inst in _setup_instruments()
       if inst.section_schema is not None},
    joint_limits=(Any, None), calibration=(dict[str, Any] | None, None))


def _with_common_sections(fmt: MachineFormat) -> MachineFormat:
    """A machine module's format (:mod:`pkmcal.machines.registry`) with what every machine
    file has: ``machine`` (the format's type), and the fields of :data:`_COMMON_FIELDS` its
    schema does not state (``pkmcal``, ``name``, ``units``, the instrument sections
    ``tracker``, ``ballbar``, ``bed``: :func:`_read_setups`, ``joint_limits`` and
    ``calibration``), added after its own. The module states its own keys (and ``home``)."""
    own = fmt.schema.model_fields
    fields = {key: (Literal[fmt.kind], ...) if key == "machine" else field
              for key, field in _COMMON_FIELDS.items() if key == "machine" or key not in own}
    schema = create_model(fmt.schema.__name__, __base__=fmt.schema,
                          __module__=fmt.schema.__module__, **fields)

    return dataclasses.replace(fmt, schema=schema, kinds=fmt.kinds)


#: machine type (``machine:`` in files) -> format: every machine module's
#: (:mod:`pkmcal.machines.registry`), with what every machine file has
MACHINE_FORMATS: dict[str, MachineFormat] = {
    kind: _with_common_sections(fmt) for kind, fmt in registered_machine_formats().items()}


def _kind_of(path: tuple, kinds: dict) -> str | None:
    for pattern, kind in kinds.items():
        if len(pattern) == len(path) and all(p == "*" or p == k
                                             for p, k in zip(pattern, path, strict=True)):
            return kind
    # ``home`` is x, y, z [, psi, theta, phi] unless the format says otherwise
    if len(path) == 2 and path[0] == "home" and isinstance(path[1], int):
        return "length" if path[1] < 3 else "angle"
    return None


def _numbers(value, path=()):
    """``(path, number)`` of every number in a file's mapping (calibration metadata aside)."""
    if isinstance(value, dict):
        for key, item in value.items():
            if not (path == () and key == "calibration"):
                yield from _numbers(item, path + (key,))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _numbers(item, path + (i,))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, value


def _line_of(lines: dict, key: tuple) -> int | None:
    """Line of the deepest prefix of ``key`` that is in the file."""
    for k in range(len(key), -1, -1):
        if key[:k] in lines:
            return lines[key[:k]]
    return None


#: smallest dimension of a machine (a number of kind ``"dimension"``: a link, an arm, a radius,
#: the constraint link) relative to the machine's size: one this small is a typo, and it divides
MIN_LENGTH_RATIO = 1e-6


def _check_magnitudes(data: dict, doc, fmt: MachineFormat, source: str, lines: dict) -> None:
    """Refuse finite but absurd numbers before anything is computed with them.

    A length is at most :data:`~pkmcal.limits.MAX_LENGTH_RATIO` times the machine's own size
    (``fmt.size``, a median, so one absurd value does not set the scale) and never more than
    :data:`~pkmcal.limits.MAX_LENGTH`; an angle at most :data:`~pkmcal.limits.MAX_ANGLE`; a
    Stewart gain (length per reading unit) between :data:`~pkmcal.limits.MIN_GAIN` and the
    largest length. Beyond these, squares and products overflow or lose every digit.
    """
    units = doc.units.model_dump()
    fl, fa = factors(units)
    lu, au = units["length"], units["angle"]
    with np.errstate(all="ignore"):
        size, what = fmt.size(doc) if fmt.size is not None else (float("nan"), "")
    relative = size > 0 and np.isfinite(size) and size <= MAX_LENGTH
    limit = min(MAX_LENGTH, MAX_LENGTH_RATIO * size) if relative else MAX_LENGTH
    why = (f"more than {MAX_LENGTH_RATIO:g} times the machine's size ({size / fl:.6g} {lu}, "
           f"{what})") if relative else f"more than {MAX_LENGTH / 1000:g} km"
    for path, value in _numbers(data):
        kind = _kind_of(path, fmt.kinds or {})
        if kind is None:                     # an instrument section's number, or none
            kind = _kind_of(path, _instrument_kinds())
        problem = None
        if kind in ("length", "dimension") and not abs(value) * fl <= limit:
            problem = f"{value:.6g} {lu} is not a plausible length: {why}"
        elif (kind == "dimension" and relative
              and 0 < value * fl < MIN_LENGTH_RATIO * size):
            problem = (f"{value:.6g} {lu} is not a plausible length: less than "
                       f"{MIN_LENGTH_RATIO:g} of the machine's size ({size / fl:.6g} {lu}, "
                       f"{what})")
        elif kind == "angle" and not abs(value) * fa <= MAX_ANGLE:
            problem = (f"{value:.6g} {au} is not a plausible angle: more than "
                       f"{MAX_ANGLE / (2 * np.pi):g} turns")
        elif kind == "gain" and not MIN_GAIN <= abs(value) * fl <= limit:
            problem = (f"{value:.6g} {lu} per reading unit is not a plausible gain: the leg "
                       f"length per reading unit must be between {MIN_GAIN:g} m and "
                       + (f"{MAX_LENGTH_RATIO:g} times the machine's size ({size / fl:.6g} "
                          f"{lu})" if relative else f"{MAX_LENGTH / 1000:g} km"))
        if problem is not None:
            line = _line_of(lines, path)
            raise MachineFileError(f"{path_text(source)}: {_key_path(path)}: {problem}"
                                   + (f" (line {line})" if line else ""), path, problem,
                                   "magnitude")


# --------------------------------------------------------------------------------------------
# Validation errors in words
# --------------------------------------------------------------------------------------------


class MachineFileError(InputError):
    """A machine file's value that is wrong, with the key path and the problem kept apart
    (the message is ``FILE: key.path: what (line N)``): a reader of another format that
    writes a machine file (``pkmcal import``) names its own file's key instead.

    Attributes
    ----------
    key : tuple
        The key path (``("position_endstop", 0)``).
    what : str
        The problem in words, without the file, key and line.
    stage : str
        ``"schema"``, ``"magnitude"``, ``"geometry"`` or ``"joint_limits"``.
    """

    def __init__(self, message: str, key: tuple = (), what: str = "", stage: str = ""):
        super().__init__(message)
        self.key = tuple(key)
        self.what = what or message
        self.stage = stage


def key_path_text(loc) -> str:
    """A key path as messages write it: ``legs[2].dtheta`` (list indices 0-based).

    Parameters
    ----------
    loc : sequence of str or int
        The key path.

    Returns
    -------
    str
        The path in words (``(top level)`` for an empty one).
    """
    return _key_path(loc)


def _key_path(loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _unwrap(annotation):
    """The model class or list item type inside Optional/Annotated/list annotations."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(annotation) if a is not type(None)]
            annotation = args[0]
        else:
            return annotation


def _model_at(model: type[BaseModel], loc) -> type[BaseModel] | None:
    """The pydantic model that describes the mapping at key path ``loc``."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            if typing.get_origin(current) is not list:
                return None
            current = _unwrap(typing.get_args(current)[0])
        else:
            if not (isinstance(current, type) and issubclass(current, BaseModel)):
                return None
            field = current.model_fields.get(part)
            if field is None:
                return None
            current = _unwrap(field.annotation)
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


_HINTS = {
    "units": "every machine file states its units, e.g. units: {length: mm, angle: deg}",
    "pkmcal": "the file format version; write pkmcal: 1",
}


#: list keys of the instrument sections and what they hold, for messages (each instrument's
#: ``section_lists``)
_LIST_SECTIONS = {key: words for inst in INSTRUMENTS.values()
                  for key, words in inst.section_lists.items()}


def _not_a_number(value) -> str:
    """``not a number: 'abc'``; a number written as text (in quotes) says so."""
    if isinstance(value, str):
        with contextlib.suppress(ValueError):
            float(value)
            return f"not a number: the text {_show(value)} (write it without quotes)"
    return f"not a number: {_show(value)}"


def _describe(err: dict, fmt: MachineFormat) -> str:
    schema, counts = fmt.schema, fmt.counts
    kind, loc, value = err["type"], err["loc"], err.get("input")
    ctx = err.get("ctx") or {}
    last = loc[-1] if loc else None
    if kind == "missing":
        hints = {**_HINTS, **(fmt.hints or {})} if len(loc) == 1 else {}
        hint = hints.get(last) if isinstance(last, str) else None
        return "missing key" + (f" ({hint})" if hint else "")
    if kind == "extra_forbidden":
        model = _model_at(schema, loc[:-1])
        allowed = f" (allowed here: {', '.join(model.model_fields)})" if model else ""
        return "unknown key" + allowed
    if kind in ("float_type", "float_parsing", "int_type"):
        return _not_a_number(value)
    if kind == "finite_number":
        return f"must be a finite number, got {_show(value)}"
    if kind == "greater_than":
        return f"must be > {ctx.get('gt')}, got {_show(value)}"
    if kind == "greater_than_equal":
        return f"must be >= {ctx.get('ge')}, got {_show(value)}"
    if kind == "literal_error":
        if loc and loc[0] == "units" and isinstance(last, str):
            return (f"unknown {last} unit {_show(value)} (accepted: "
                    f"{', '.join(LENGTH_UNITS if last == 'length' else ANGLE_UNITS)})")
        return f"got {_show(value)}, expected {ctx.get('expected')}"
    if kind in ("too_short", "too_long"):
        n = ctx.get("min_length") if kind == "too_short" else ctx.get("max_length")
        actual = ctx.get("actual_length")
        if isinstance(last, str) and last in counts:
            return f"expected exactly {counts[last]} {last}, got {actual}"
        if last == "home":
            return f"expected {fmt.home_text.count(',') + 1} numbers {fmt.home_text}, got " \
                   f"{actual}"
        if last == "rotation":
            return f"expected a 3x3 matrix (3 rows of 3 numbers), got {actual} rows"
        if last in _LIST_SECTIONS:
            return f"expected at least one entry: {_LIST_SECTIONS[last]}"
        return f"expected {n} numbers, got {actual}"
    if kind == "list_type":
        if last == "home":
            return f"expected a list {fmt.home_text}, got {_show(value)}"
        if isinstance(last, str) and last in counts:
            return f"expected a list of {counts[last]} entries, got {_show(value)}"
        if last in _LIST_SECTIONS:
            return f"expected {_LIST_SECTIONS[last]}, got {_show(value)}"
        return f"expected a list [x, y, z], got {_show(value)}"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"expected a mapping (key: value), got {_show(value)}"
    if kind == "string_type":
        return f"expected text, got {_show(value)}"
    return err.get("msg", kind)


def _validation_message(exc: ValidationError, source: str, lines: dict,
                        fmt: MachineFormat) -> str:
    parts = []
    errors = exc.errors()
    for err in errors[:3]:
        loc = tuple(err["loc"])
        line = None
        for k in range(len(loc), -1, -1):  # deepest key that exists in the file
            if loc[:k] in lines:
                line = lines[loc[:k]]
                break
        where = f" (line {line})" if line else ""
        parts.append(f"{_key_path(loc)}: {_describe(err, fmt)}{where}")
    more = f"; and {len(errors) - 3} more problem(s)" if len(errors) > 3 else ""
    return f"{path_text(source)}: " + "; ".join(parts) + more


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def parse_machine(text: str, source: str = "<machine>") -> Machine:
    """Machine from the text of a machine file (its set-ups: :func:`parse_machine_file`).

    Parameters
    ----------
    text : str
        YAML text of a machine file (SPEC 6).
    source : str, optional
        Names the text in messages.

    Returns
    -------
    Machine
        In internal units (m, rad), with ``file_units``, ``source`` and ``calibration_info``.

    Raises
    ------
    InputError
        As :func:`parse_machine_file`.
    """
    return parse_machine_file(text, source)[0]


def parse_machine_file(text: str, source: str = "<machine>") -> tuple[Machine, Setups]:
    """Machine and instrument set-ups from the text of a machine file.

    Parameters
    ----------
    text : str
        YAML text of a machine file (SPEC 6).
    source : str, optional
        Names the text in messages.

    Returns
    -------
    machine : Machine
        In internal units (m, rad), with ``file_units``, ``source`` and ``calibration_info``.
    setups : Setups
        The instruments' set-ups of its sections (``tracker``, ``ballbar``, ``bed``,
        ``measurement_frames``: :mod:`pkmcal.instruments.setups`), internal units; a printer
        and its set-ups in its bed's frame (:func:`bed_frame`).

    Raises
    ------
    InputError
        For invalid YAML, a missing or unsupported ``pkmcal`` version, an unknown machine
        type, or a schema error (``FILE: key.path: what is wrong (line N)``); a problem of
        a value (schema, magnitude, geometry, joint limits) is a :class:`MachineFileError`
        that keeps the key path and the problem apart.
    """
    data, lines = _parse_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(f"{path_text(source)}: "
                         "expected a mapping of keys (pkmcal: 1, machine: ..., "
                         f"units: ...), got {type(data).__name__}")
    if "pkmcal" not in data:
        raise InputError(f"{path_text(source)}: pkmcal: missing key ({_HINTS['pkmcal']})")
    version = data["pkmcal"]
    line = lines.get(("pkmcal",), "?")
    if type(version) is not int:
        # the version as text ("1" in quotes), 1.0 or true: not the number the format has
        quoted = isinstance(version, str) and version.strip() == str(FORMAT_VERSION)
        got = (f"the text {_show(version)}" if isinstance(version, str) else _show(version))
        raise InputError(f"{source}: pkmcal: the file format version must be the number "
                         f"{FORMAT_VERSION}, not {got} (line {line}); write pkmcal: "
                         f"{FORMAT_VERSION}" + (" without quotes" if quoted else ""))
    if version != FORMAT_VERSION:
        raise InputError(f"{source}: pkmcal: unsupported file format version {version} "
                         f"(line {line}); this pkmcal reads version {FORMAT_VERSION}")
    known = ", ".join(MACHINE_FORMATS)
    if "machine" not in data:
        raise InputError(f"{path_text(source)}: "
                         f"machine: missing key (the machine type, one of: {known})")
    kind = data["machine"]
    if not isinstance(kind, str) or kind not in MACHINE_FORMATS:
        raise InputError(f"{path_text(source)}: machine: unknown machine type {_show(kind)} (line "
                         f"{lines.get(('machine',), '?')}); known types: {known}")
    fmt = MACHINE_FORMATS[kind]
    try:
        doc = fmt.schema.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise MachineFileError(_validation_message(exc, source, lines, fmt), first["loc"],
                               _describe(first, fmt), "schema") from None
    _check_magnitudes(data, doc, fmt, source, lines)
    with np.errstate(all="ignore"):         # no numpy warning ever reaches the user
        machine = fmt.build(doc, source)
        setups = _read_setups(machine, doc, factors(doc.units.model_dump())[0])
        machine, setups = bed_frame(machine, setups)
        machine.file_units = _file_units(doc.units.model_dump())
        problems = machine.geometry_problems(home_given=doc.home is not None)
    if problems:
        key, what = problems[0]
        line = _line_of(lines, key)
        raise MachineFileError(f"{path_text(source)}: {_key_path(key)}: {what}"
                               + (f" (line {line})" if line else ""), key, what, "geometry")
    machine.joint_limits = _joint_limits(data.get("joint_limits"), machine, source, lines)
    machine.source = source
    machine.calibration_info = doc.calibration
    return machine, setups


def _joint_limits(value, machine: Machine, source: str, lines: dict):
    """``joint_limits: {min: ..., max: ...}`` of a file as ``(lo, hi)`` arrays (n_joints,) in
    internal units, or None without the key.

    Each side is one number (every joint) or a list of one number per joint, in the file's
    unit of the joint values (:meth:`~pkmcal.machines.base.Machine.joint_unit`); ``min`` must
    be below ``max`` for every joint. Problems are :class:`InputError` with the key path.
    """
    if value is None:
        return None
    n = machine.n_joints
    unit, factor = machine.joint_unit()
    form = (f"joint_limits: {{min: LOW, max: HIGH}} with one number for every joint or a list "
            f"of {n} (q1..q{n}, in {unit})")

    def fail(path: tuple, what: str):
        line = _line_of(lines, path)
        raise MachineFileError(f"{path_text(source)}: {_key_path(path)}: {what}"
                               + (f" (line {line})" if line else ""), path, what,
                               "joint_limits")

    if not isinstance(value, dict):
        fail(("joint_limits",), f"expected a mapping, got {_show(value)}; write {form}")
    for key in value:
        if key not in ("min", "max"):
            fail(("joint_limits", key), "unknown key (allowed here: min, max)")
    sides = []
    for key in ("min", "max"):
        if key not in value:
            fail(("joint_limits",), f"missing key {key}; write {form}")
        v = value[key]
        items = v if isinstance(v, list) else [v]
        if isinstance(v, list) and len(v) != n:
            fail(("joint_limits", key), f"expected one number or a list of {n} (one per joint "
                                        f"q1..q{n}), got {len(v)}")
        for i, x in enumerate(items):
            path = ("joint_limits", key) + ((i,) if isinstance(v, list) else ())
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                fail(path, _not_a_number(x))
            if not np.isfinite(x):
                fail(path, f"must be a finite number, got {_show(x)}")
        sides.append(np.broadcast_to(np.asarray(items, float), (n,)) * factor)
    lo, hi = sides
    for j in range(n):
        if not lo[j] < hi[j]:
            listed = isinstance(value["min"], list)
            fail(("joint_limits", "min") + ((j,) if listed else ()),
                 f"q{j + 1}: min {lo[j] / factor:.6g} {unit} must be below max "
                 f"{hi[j] / factor:.6g} {unit}")
    return lo.copy(), hi.copy()


def _limits_text(machine: Machine, units: dict) -> str | None:
    """The ``joint_limits`` line of a machine file, or None when the machine has none."""
    limits = getattr(machine, "joint_limits", None)
    if limits is None:
        return None
    _, factor = machine.joint_unit(units)
    sides = {}
    for key, v in zip(("min", "max"), limits, strict=True):
        # 12 digits: a limit is not a measurement, and 30 deg stays 30.0 (not 29.999999999999996)
        v = [float(f"{float(x) / factor:.12g}") for x in np.asarray(v, float)]
        sides[key] = v[0] if all(x == v[0] for x in v) else v
    return f"joint_limits: {_flow(sides)}"


def load_machine(path) -> Machine:
    """Load a machine file (SPEC 6) into a machine in internal units (m, rad).

    Parameters
    ----------
    path : str or os.PathLike
        The machine file.

    Returns
    -------
    Machine
        Carrying ``file_units`` (``{"length": "mm", "angle": "deg"}``), ``source`` (the path)
        and ``calibration_info`` (the file's ``calibration:`` mapping or None).

    Raises
    ------
    InputError
        Naming the file, key path and line; also for a missing or non-text file.
    """
    return load_machine_file(path)[0]


def load_machine_file(path) -> tuple[Machine, Setups]:
    """Load a machine file (SPEC 6): the machine and the instruments' set-ups it carries.

    Parameters
    ----------
    path : str or os.PathLike
        The machine file.

    Returns
    -------
    machine : Machine
        As :func:`load_machine`.
    setups : Setups
        The set-ups of its instrument sections (:func:`parse_machine_file`).

    Raises
    ------
    InputError
        Naming the file, key path and line; also for a missing or non-text file.
    """
    path = Path(path)
    text = read_input_text(path, "machine file", MAX_MACHINE_FILE_BYTES)
    return parse_machine_file(text, str(path))


def _plain(value):
    """Metadata made of YAML/JSON-safe Python values (numpy, paths and dates converted)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, (_dt.datetime, _dt.date)):
        return value.isoformat()
    if value is None or isinstance(value, str):
        return value
    return str(value)


_PLAIN = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_YAML_WORDS = {"true", "false", "yes", "no", "on", "off", "null", "y", "n"}


def _flow(value) -> str:
    """One-line YAML of scalars, lists and mappings (numbers at full precision)."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return _fmt(value)
    if value is None:
        return "null"
    text = str(value)
    if _PLAIN.match(text) and text.lower() not in _YAML_WORDS:
        return text
    return json.dumps(text, ensure_ascii=False)


def machine_to_text(machine: Machine, units: dict | None = None,
                    calibration: dict | None = None, setups: Setups | None = None) -> str:
    """Text of the machine file of ``machine`` (see :func:`save_machine`).

    Parameters
    ----------
    machine : Machine
        A Hexa Slide, Delta or Stewart machine.
    units : dict, optional
        ``{"length": "mm"|"m", "angle": "deg"|"rad"}``; default ``machine.file_units`` or
        mm/deg.
    calibration : dict, optional
        Metadata written as the ``calibration:`` section.
    setups : Setups, optional
        The instruments' set-ups, written as their sections
        (:mod:`pkmcal.instruments.setups`); None: none.

    Returns
    -------
    str
        The YAML text, floats at full precision.

    Raises
    ------
    InputError
        For an unknown machine type, invalid units, or metadata that is not a mapping.
    """
    kind = getattr(machine, "kind", "")
    if kind not in MACHINE_FORMATS:
        raise InputError(f"cannot save machine type {kind!r}; known: {', '.join(MACHINE_FORMATS)}")
    units = _file_units(units or getattr(machine, "file_units", None) or DEFAULT_UNITS)
    if set(units) != {"length", "angle"} or units["length"] not in LENGTH_UNITS \
            or units["angle"] not in ANGLE_UNITS:
        raise InputError(f"units must be {{length: mm|m|in, angle: deg|rad}}, got {units}")
    fl, fa = factors(units)
    setups = Setups(setups)
    framed, setups = bed_frame(machine, setups)
    body = dict(MACHINE_FORMATS[kind].dump(framed, units))
    body.update(_setup_sections(framed, setups, fl))
    # home: the pose coordinates the platform moves along (x, y, z; the Euler angles of a
    # platform that rotates; x, y, phi of a planar one); as given, not moved with the bed's
    # frame (as this writer has always written it)
    P, R = machine.home
    pose = [float(v) / fl for v in np.asarray(P, float)]
    pose += [float(v) / fa for v in euler_from_matrix(np.asarray(R, float))] \
        if machine.rotates else [0.0] * 3
    space = list(machine.pose_space)
    home = [pose[i] for i in space]
    home_text = ", ".join(("x", "y", "z", "psi", "theta", "phi")[i] for i in space)
    lines = [f"pkmcal: {FORMAT_VERSION}", f"machine: {kind}"]
    if getattr(machine, "name", ""):
        lines.append(f"name: {_flow(str(machine.name))}")
    lines.append(f"units: {_flow(units)}")
    for key, value in body.items():
        if isinstance(value, list) and value and isinstance(value[0], dict):
            lines.append(f"{key}:")
            lines.extend(f"  - {_flow(item)}" for item in value)
        elif isinstance(value, dict) and value and all(isinstance(v, dict)
                                                      for v in value.values()):
            lines.append(f"{key}:")                     # e.g. measurement_frames
            lines.extend(f"  {k}: {_flow(v)}" for k, v in value.items())
        else:
            lines.append(f"{key}: {_flow(value)}")
    limits = _limits_text(machine, units)
    if limits is not None:
        lines.append(limits)
    lines.append(f"home: {_flow(home)}   # {home_text}")
    if calibration is not None:
        meta = _plain(calibration)
        if not isinstance(meta, dict):
            raise InputError("calibration metadata must be a mapping")
        dumped = yaml.safe_dump(meta, sort_keys=False, allow_unicode=True, width=100,
                                default_flow_style=False)
        lines.append("calibration:")
        lines.extend("  " + line for line in dumped.rstrip("\n").splitlines())
    return "\n".join(lines) + "\n"


def save_machine(machine: Machine, path, units: dict | None = None,
                 calibration: dict | None = None, setups: Setups | None = None) -> Path:
    """Write ``machine`` as a machine file (same schema as :func:`load_machine` reads).

    The file always carries ``home`` (``machine.home``); floats are written at full precision;
    the file is checked by parsing it back, then written atomically.

    Parameters
    ----------
    machine : Machine
        A Hexa Slide, Delta or Stewart machine.
    path : str or os.PathLike
        Output file.
    units : dict, optional
        ``{"length": "mm"|"m", "angle": "deg"|"rad"}``; default ``machine.file_units`` or
        mm/deg.
    calibration : dict, optional
        Metadata mapping written as the ``calibration:`` section.
    setups : Setups, optional
        The instruments' set-ups (:func:`machine_to_text`).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        As :func:`machine_to_text`, or when the text does not parse back.
    """
    path = Path(path)
    text = machine_to_text(machine, units, calibration, setups)
    parse_machine(text, str(path))  # never write a file we could not read back
    atomic_write_text(path, text)
    return path
