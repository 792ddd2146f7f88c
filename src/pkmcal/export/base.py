"""A controller's parameter format, and the best values it can hold for a calibrated machine.

A controller (Klipper, Marlin, RepRapFirmware, LinuxCNC) computes joint commands from target
positions with its own kinematics and its own, usually smaller, set of parameters. A
:class:`ControllerFormat` knows that kinematics (:meth:`ControllerFormat.ik`), how its
parameters map from a pkmcal machine when the machine is exactly representable
(:meth:`ControllerFormat.initial`), how they are written and read (:meth:`text`,
:meth:`parse`) and how to turn them back into a machine (:meth:`to_machine`).

The best values for a calibrated machine, fitted over a workspace, and the error they leave:
:mod:`pkmcal.export.fitting`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ..errors import InputError
from ..instruments.probe import BedSetup, Probe, bed_plane
from ..instruments.setups import Setups
from ..io.atomic import read_input_text
from ..machines.base import Machine


@dataclass(frozen=True)
class Origin:
    """Where a controller file holds a value: the file, the format's own word for it and the
    line.

    Attributes
    ----------
    file : str
        The file (an ``[include]`` of a Klipper config names its own file).
    key : str
        The format's letter or key: ``M665 L``, ``[printer] delta_radius``,
        ``setp lineardeltakins.R``.
    line : int or None
        1-based line number; None for a value the file does not state (a default).
    note : str
        Said after the line (``SAVE_CONFIG block``), or the default's origin.
    """

    file: str
    key: str
    line: int | None = None
    note: str = ""

    def text(self) -> str:
        """``M665 L (line 12)`` (the file is said once for several, see :func:`where`).

        Returns
        -------
        str
            The key and its line.
        """
        if self.line is None:
            return f"{self.key} ({self.note or 'not in the file: its default'})"
        return f"{self.key} (line {self.line}" + (f", {self.note})" if self.note else ")")


    def text_in_file(self) -> str:
        """``printer.cfg: [printer] delta_radius (line 3)``.

        Returns
        -------
        str
            The file, key and line.
        """
        return f"{self.file}: {self.text()}"


def where(origins) -> str:
    """Origins for a message: ``config.g: M665 H (line 3), M666 X (line 4)``.

    Parameters
    ----------
    origins : iterable of Origin
        The values' origins (repeats dropped).

    Returns
    -------
    str
        Grouped by file, in order.
    """
    by_file: dict = {}
    for o in origins:
        texts = by_file.setdefault(o.file, [])
        if o.text() not in texts:
            texts.append(o.text())
    return "; ".join(f"{f}: {', '.join(t)}" for f, t in by_file.items())


def origin_of(params, *names) -> str | None:
    """Where the file holds the values of ``names`` (:func:`where`); None when it holds none.

    Parameters
    ----------
    params : ControllerParameters
        The values read.
    *names : str
        Names of ``params.names`` or ``params.extras``.

    Returns
    -------
    str or None
        The origins in words.
    """
    found = [params.origins[n] for n in names if n in getattr(params, "origins", {})]
    stated = [o for o in found if o.line is not None] or found
    return where(stated) if stated else None


def refuse_implausible(params, name: str, shown: str, why: str, source: str) -> None:
    """Raise the refusal of a value that cannot be meant, naming the user's file, key, line.

    Parameters
    ----------
    params : ControllerParameters
        The values read (their :attr:`~ControllerParameters.origins`).
    name : str
        The value's name.
    shown : str
        The value as the file has it (``2000 mm``).
    why : str
        The bound in words.
    source : str
        The file's name (when the value has no origin).

    Raises
    ------
    InputError
        Always.
    """
    raise InputError(f"{origin_of(params, name) or f'{source}: {name}'}: {shown} cannot be "
                     f"meant ({why})")


@dataclass
class ControllerParameters:
    """A controller's parameter values, SI internally (m, rad, ratios).

    Attributes
    ----------
    names : list of str
        Parameter names in the controller's own words (``arm_length_a``, ``base.3.x``).
    values : ndarray, shape (n,)
        Values, SI.
    kinds : list of str
        ``length``, ``angle`` or ``ratio`` per parameter.
    fixed : ndarray of bool, shape (n,)
        Parameters the fit holds (a gauge the controller's format fixes, or a value the
        controller does not let the user set).
    extras : dict
        Values beside the kinematics (``print_radius``, ``probe_radius``, m).
    """

    names: list
    values: np.ndarray
    kinds: list
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]
    #: what the file holds beside the kinematics that a machine file keeps (a printer's
    #: ``print_radius`` and probing radius, m)
    extras: dict = field(default_factory=dict)
    #: where each value was read (a name of ``names`` or ``extras`` -> :class:`Origin`): the
    #: source map through which ``pkmcal import`` names the user's file, key and line
    origins: dict = field(default_factory=dict)
    #: what a reader of the file passed over or decided, in words (``pkmcal import`` prints
    #: each as a note)
    notes: list = field(default_factory=list)

    def __post_init__(self):
        self.values = np.asarray(self.values, float).reshape(-1)
        self.fixed = (np.zeros(len(self.values), bool) if self.fixed is None
                      else np.asarray(self.fixed, bool).reshape(-1))

    def with_values(self, values) -> ControllerParameters:
        """A copy with new values.

        Parameters
        ----------
        values : array_like, shape (n,)
            The values, SI.

        Returns
        -------
        ControllerParameters
            The copy.
        """
        return ControllerParameters(list(self.names), np.asarray(values, float),
                                    list(self.kinds), self.fixed.copy(), dict(self.extras),
                                    dict(self.origins), list(self.notes))

    def as_dict(self) -> dict:
        """Name -> value (SI).

        Returns
        -------
        dict
            The values.
        """
        return dict(zip(self.names, (float(v) for v in self.values), strict=True))


class ControllerFormat(ABC):
    """One controller's kinematics and parameter file (see the module docstring)."""

    #: the name of ``--to`` / ``--from``
    name: str = ""
    #: what it is, in words (controller, kinematics, where its convention was read)
    words: str = ""
    #: default file suffix of the written file
    suffix: str = ".txt"
    #: the format holds every machine it applies to exactly: :meth:`initial` is the best
    #: (:func:`fit_controller` returns it without a fit)
    exact: bool = False

    def values_text(self, params: ControllerParameters) -> list[tuple[str, str]]:
        """The values as the written file has them, for a printed table.

        The default: each value by name, lengths in mm, angles in degrees, ratios as they
        are; a format whose file has other units or groups its values overrides it.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        list of tuple
            ``(name, value in words)``.
        """
        out = []
        for name, value, kind in zip(params.names, params.values, params.kinds, strict=True):
            if kind == "length":
                out.append((name, f"{value * 1e3:.6f} mm"))
            elif kind == "angle":
                out.append((name, f"{np.degrees(value):.6f} deg"))
            else:
                out.append((name, f"{value:.9g}"))
        return out

    #: the machine type (``Machine.kind``) whose kinematics the controller runs, and its
    #: words; :meth:`applies` refuses other types with them
    machine_kind: str = ""
    machine_words: str = ""

    def applies(self, machine: Machine) -> str | None:
        """Why this format cannot hold ``machine`` (None: it can).

        A machine of another type than :attr:`machine_kind` is refused; then
        :meth:`layout_problem` (a controller's fixed layout, e.g. LinuxCNC's tower angles).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The reason in words.
        """
        kind = getattr(machine, "kind", type(machine).__name__)
        if self.machine_kind and kind != self.machine_kind:
            return (f"the {self.name} format is for a {self.machine_words} (machine: "
                    f"{self.machine_kind}), this is a {kind}")
        return self.layout_problem(machine)

    def layout_problem(self, machine: Machine) -> str | None:
        """Why the controller's fixed layout cannot hold a machine of the right type.

        Parameters
        ----------
        machine : Machine
            The machine (of :attr:`machine_kind`).

        Returns
        -------
        str or None
            The reason in words; None (the default): any layout.
        """
        return None

    def placed(self, params: ControllerParameters, machine: Machine,
               P) -> ControllerParameters:
        """The start values with the controller's frame placed for the workspace.

        A controller whose coordinates have an origin of their own (Klipper's bed at
        ``z = 0``, below every target and reachable at the centre) chooses it here, among the
        fixed values; the default keeps the values as :meth:`initial` gives them.

        Parameters
        ----------
        params : ControllerParameters
            The values of :meth:`initial`.
        machine : Machine
            The machine.
        P : ndarray, shape (K, 3)
            The workspace's positions, m (the machine file's frame).

        Returns
        -------
        ControllerParameters
            The values to fit from.

        Raises
        ------
        InputError
            When no place of the controller's origin lets it run the workspace, naming why.
        """
        return params

    def export_notes(self, params: ControllerParameters, machine: Machine,
                     P=None) -> list[str]:
        """What the user must know to use the written file, in words (the controller's frame
        against the machine file's, a relabelling of the joints); printed by ``pkmcal
        export`` and kept in its JSON record.

        Parameters
        ----------
        params : ControllerParameters
            The values written.
        machine : Machine
            The machine they are for.
        P : ndarray, shape (K, 3), optional
            The workspace's positions, m.

        Returns
        -------
        list of str
            The notes; none by default.
        """
        return []

    def written(self, params: ControllerParameters, machine: Machine,
                existing: str | None = None, source: str = "",
                setups=None) -> tuple[str, ControllerParameters]:
        """The file's text and the values as the controller reads them back from it.

        The text is :meth:`text`, or, onto an ``existing`` file, :meth:`update` of it (as the
        controller saves its values, e.g. Klipper's ``SAVE_CONFIG`` with ``%.6f``); the
        values are :meth:`parse` of that text: the fitted values rounded as written (in the
        form the file holds them: a firmware that writes its endstop adjustments relative to
        the highest has them so). A value the file does not state (no line in the parse's
        :attr:`~ControllerParameters.origins`: pkmcal's frame and joint order, which the
        controller does not read) is kept as it is.

        Parameters
        ----------
        params : ControllerParameters
            The fitted values.
        machine : Machine
            The machine they are for.
        existing : str, optional
            The controller's current file, updated in place of a new one.
        source : str, optional
            That file's name (its includes are read beside it).
        setups : Setups, optional
            The experiment's set-ups: a printer's bed
            (:class:`~pkmcal.instruments.probe.BedSetup`; the machine holds none).

        Returns
        -------
        text : str
            The file as written.
        written : ControllerParameters
            The values as the file holds them, the fixed ones ``params``'.
        """
        text = None if existing is None else self.update(existing, params, machine, source)
        if text is None:
            text = self.text(params, machine, setups)
        back = self.parse(text, source or f"{self.name} export")
        mine = params.as_dict()
        stated = {n for n, o in back.origins.items() if o.line is not None}
        values = np.array([v if n in stated or n not in mine else mine[n]
                           for n, v in zip(back.names, back.values, strict=True)])
        return text, back.with_values(values)

    @abstractmethod
    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """The controller's values read directly off a machine (its design values).

        Parameters
        ----------
        machine : Machine
            The machine (nominal or calibrated).
        setups : Setups, optional
            The experiment's set-ups: a printer's bed
            (:class:`~pkmcal.instruments.probe.BedSetup`; the machine holds none).

        Returns
        -------
        ControllerParameters
            The values (the start of :func:`fit_controller`; exact when the format can
            represent the machine).
        """

    @abstractmethod
    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """The joint readings the controller commands for target poses.

        In the machine's reading convention (``q1..qn`` as the machine's data files have
        them, internal units), so that ``machine.fk`` of them is where the machine goes.

        Parameters
        ----------
        params : ControllerParameters
            The controller's values.
        P : ndarray, shape (K, 3)
            Target positions, m (the calibrated file's base frame).
        R : ndarray, shape (K, 3, 3), optional
            Target orientations (platforms that rotate).

        Returns
        -------
        ndarray, shape (K, n_joints)
            Commanded readings; NaN where the controller cannot reach a target.
        """

    @abstractmethod
    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The file the controller reads, in its units and conventions.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        machine : Machine
            The machine they are for (name, joint count).
        setups : Setups, optional
            The experiment's set-ups: a printer's bed
            (:class:`~pkmcal.instruments.probe.BedSetup`; the machine holds none).

        Returns
        -------
        str
            The file's text.
        """

    def update(self, existing: str, params: ControllerParameters, machine: Machine,
               source: str) -> str | None:
        """The controller's existing file with these values saved, as the controller itself
        saves them; None: the format writes whole files only (an existing file is replaced).

        Parameters
        ----------
        existing : str
            The current file's text.
        params : ControllerParameters
            The values.
        machine : Machine
            The machine they are for.
        source : str
            The file's name, for messages.

        Returns
        -------
        str or None
            The new text.
        """
        return None

    def bed_mesh_height(self, text: str) -> float:
        """The nozzle's height above the bed (m) at which the controller's meshes hold the
        bed (its probe's trigger height); 0 by default."""
        return 0.0

    def with_bed_mesh(self, text: str, params: ControllerParameters,
                      machine: Machine, setups=None) -> str | None:
        """The controller's file with a bed mesh that carries what ``params`` leave of the
        nozzle's height at the bed (:mod:`pkmcal.export.bed_mesh`; the bed of the set-ups
        ``setups``), where the controller applies one from its file and the mesh is worth it;
        None: no mesh (the default)."""
        return None

    #: the files of a whole controller configuration the format writes into a directory
    #: (``pkmcal export -o DIR/``), name -> what it is; empty: the format writes one file
    configuration_files: Mapping[str, str] = MappingProxyType({})
    #: the configuration's file that holds the values (what ``-o FILE`` writes alone)
    configuration_values_file: str = ""
    #: what a written configuration is, in words ("the LinuxCNC configuration")
    configuration_words: str = ""

    def configuration(self, result, machine: Machine,
                      workspace) -> dict[str, str]:
        """The files of a controller configuration that starts, for an export: one text per
        name of :attr:`configuration_files`.

        Parameters
        ----------
        result : ExportResult
            The export (its values as written, its file's text).
        machine : Machine
            The calibrated machine.
        workspace : Workspace
            The export's workspace.

        Returns
        -------
        dict
            File name -> text.

        Raises
        ------
        NotImplementedError
            For a format that writes one file (no :attr:`configuration_files`).
        """
        raise NotImplementedError(f"{self.name} writes one file, not a configuration")

    def configuration_start(self, directory: Path) -> str:
        """The command that starts a configuration written in ``directory``, in words."""
        raise NotImplementedError(f"{self.name} writes one file, not a configuration")

    #: several of the format's saved files given together are one printer's sessions, read
    #: together (:meth:`read_measurements` gets them all); False: each file is read alone
    measurements_together: bool = False

    def holds_measurements(self, path: Path, head: str) -> bool:
        """Whether a data file given to ``calibrate`` is one of the controller's saved files
        holding measurements (a saved configuration with probe points, a pasted probe
        report) rather than a CSV file; the default: never.

        Parameters
        ----------
        path : Path
            The file.
        head : str
            Its first 4 kB.

        Returns
        -------
        bool
            True: :meth:`read_measurements` reads it.
        """
        return False

    def read_measurements(self, paths: list, machine: Machine) -> list:
        """The measurements the controller's saved files hold, as pkmcal data objects (for
        the formats whose :meth:`holds_measurements` says so).

        Parameters
        ----------
        paths : list of Path
            One file, or with :attr:`measurements_together` all the files of the format
            given together.
        machine : Machine
            The machine file given (the values the controller used where the file holds
            none).

        Returns
        -------
        list
            Data objects, each with a ``source`` naming its file (and part of it); empty:
            the file holds none and is read as a CSV file.

        Raises
        ------
        InputError
            Naming the file and line of what cannot be read.
        """
        raise NotImplementedError(f"{self.name} files hold no measurements pkmcal reads")

    def read_controller_file(self, path: Path):
        """The values of the controller's file at ``path`` (import), and the home pose and
        machine name it holds where it does; the default reads the one file with
        :meth:`parse` (a format that also reads a whole configuration overrides it).

        Parameters
        ----------
        path : Path
            The file (registered as an input of the active output set).

        Returns
        -------
        params : ControllerParameters
            The values.
        home : tuple of ndarray or None
            ``(P, R)`` of the home pose, m (None: the file holds none).
        name : str or None
            The machine's name.

        Raises
        ------
        InputError
            Naming the file, line and key of what cannot be read.
        """
        return self.parse(read_input_text(path, f"{self.name} file"), str(path)), None, None

    @abstractmethod
    def parse(self, text: str, source: str) -> ControllerParameters:
        """The values of a controller file (import).

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        ControllerParameters
            The values, SI.

        Raises
        ------
        InputError
            Naming the file, line and key of what cannot be read.
        """

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import: which values of the controller's file make each key
        of the machine file :meth:`to_machine` writes.

        Parameters
        ----------
        params : ControllerParameters
            The values read.

        Returns
        -------
        dict
            Machine-file key path (a tuple, a prefix of the keys a problem names:
            ``("position_endstop", 0)``) -> names of ``params`` (or of its ``extras``); the
            default: none (a problem is then named by the machine file's key).
        """
        return {}

    def imported_key(self, params: ControllerParameters, key: tuple) -> str | None:
        """The user's file, keys and lines behind a machine-file key path of an import
        (:meth:`machine_keys`, :func:`where`).

        Parameters
        ----------
        params : ControllerParameters
            The values read.
        key : tuple
            A key path of the machine file (``("arm_length",)``, ``("legs", 2, "dtheta")``).

        Returns
        -------
        str or None
            ``config.g: M665 L (line 12)``; None when no value of the file makes it.
        """
        keys = self.machine_keys(params)
        key = tuple(key)
        for k in range(len(key), 0, -1):
            if key[:k] in keys:
                return origin_of(params, *keys[key[:k]])
        names = [n for path, ns in keys.items() if path[:len(key)] == key for n in ns]
        return origin_of(params, *dict.fromkeys(names)) if names and key else None

    @abstractmethod
    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A pkmcal machine with the controller's values (import).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            A machine to take what the controller does not hold from (e.g. an effector
            offset); default the format's defaults.

        Returns
        -------
        Machine
            The machine.
        """

    def imported_bed(self, params: ControllerParameters) -> np.ndarray | None:
        """The bed plane the controller's values hold, ``(height m, tilt_x, tilt_y)`` (a
        printer's: its firmware commands heights above it); None (the default): none.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        ndarray, shape (3,) or None
            The plane.
        """
        return None

    def imported_setups(self, params: ControllerParameters) -> Setups:
        """The instruments' set-ups the controller's values state beside the machine of
        :meth:`to_machine`: the bed of :meth:`imported_bed` (:func:`bed_setups`), none
        without one.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        Setups
            The set-ups (:class:`~pkmcal.instruments.setups.Setups`).
        """
        bed = self.imported_bed(params)
        return Setups() if bed is None else bed_setups(bed)


def setups_bed(setups) -> np.ndarray:
    """The bed plane of an experiment's set-ups (a calibrated machine file's ``bed``
    section, :class:`~pkmcal.instruments.probe.BedSetup`), zeros without one.

    Parameters
    ----------
    setups : Setups or None
        The set-ups.

    Returns
    -------
    ndarray, shape (3,)
        ``(height m, tilt_x, tilt_y)``: the bed is ``z = height + tilt_x x + tilt_y y``.
    """
    bed = bed_plane(setups)
    return np.zeros(3) if bed is None else np.asarray(bed, float).reshape(3)


def bed_setups(bed) -> Setups:
    """The set-ups a controller's bed plane makes (a probe's
    :class:`~pkmcal.instruments.probe.BedSetup`; none for a bed at z = 0, untilted).

    Parameters
    ----------
    bed : array_like, shape (3,)
        ``(height m, tilt_x, tilt_y)``.

    Returns
    -------
    Setups
        The set-ups.
    """
    bed = np.asarray(bed, float).reshape(3)
    if not np.any(bed != 0):
        return Setups()
    return Setups({Probe.name: BedSetup(*(float(v) for v in bed))})


def finite_number(word: str, source: str, line: int, key: str) -> float:
    """A finite number of a controller file, or an error naming the line and key.

    Parameters
    ----------
    word : str
        The text of the value.
    source : str
        The file's name.
    line : int
        1-based line number.
    key : str
        The key, in the controller's words.

    Returns
    -------
    float
        The value.

    Raises
    ------
    InputError
        When the value is not a finite number.
    """
    try:
        v = float(word)
    except ValueError:
        raise InputError(f"{source}: line {line}: {key}: {word!r} is not a number") from None
    if not np.isfinite(v):
        raise InputError(f"{source}: line {line}: {key}: {word!r} is not a finite number")
    return v


#: the controller formats by name (:func:`register_format`; filled by :data:`FORMAT_MODULES`)
FORMATS: dict[str, ControllerFormat] = {}
#: the modules of ``pkmcal.export`` that register formats, one per controller family
FORMAT_MODULES = ("linuxcnc_hexapod", "linuxcnc_delta", "klipper", "klipper_rotary", "marlin",
                  "reprapfirmware")


def load_formats() -> dict[str, ControllerFormat]:
    """Import the format modules (once) and return :data:`FORMATS`.

    Returns
    -------
    dict
        Name -> format.
    """
    import importlib

    for module in FORMAT_MODULES:
        importlib.import_module(f"{__package__}.{module}")
    return FORMATS


def register_format(fmt: ControllerFormat) -> ControllerFormat:
    """Make a controller format known to ``pkmcal export`` / ``import``.

    Parameters
    ----------
    fmt : ControllerFormat
        The format.

    Returns
    -------
    ControllerFormat
        ``fmt``.
    """
    FORMATS[fmt.name] = fmt
    return fmt


def controller_format(name: str, option: str | None = None) -> ControllerFormat:
    """The format of a name.

    Parameters
    ----------
    name : str
        A key of :data:`FORMATS`.
    option : str, optional
        The command-line option that gave it (``--to``, ``--from``), named in the message.

    Returns
    -------
    ControllerFormat
        The format.

    Raises
    ------
    InputError
        For an unknown name, listing the known ones.
    """
    load_formats()
    if name not in FORMATS:
        raise InputError(f"{option + ': ' if option else ''}unknown controller format "
                         f"{name!r}; use one of {', '.join(sorted(FORMATS))}")
    return FORMATS[name]


#: a controller file whose first this many non-blank lines hold nothing of its format is none
FOREIGN_SCAN_LINES = 1000


def refuse_foreign_text(text: str, source: str, recognised, what: str, expected: str) -> int:
    """Refuse a text that is not the controller's format at once: none of its first
    :data:`FOREIGN_SCAN_LINES` lines that say something (``recognised(line)`` not None) is a
    line of the format (``recognised(line)`` True). A file of something else (words, a CSV
    table, another controller's file) is answered after those lines, whatever its size; the
    readers would otherwise pass over every line looking for their values (issue 37).

    Parameters
    ----------
    text : str
        The file's text.
    source : str
        Its name, for messages.
    recognised : callable
        ``recognised(raw line) -> True`` (a line of the format), ``False`` (a line that is
        not) or ``None`` (blank, a comment: not counted).
    what : str
        The format in words ("Marlin G-code").
    expected : str
        What its lines look like, for the message ("M665 / M666 lines").

    Returns
    -------
    int
        The number of lines looked at.

    Raises
    ------
    InputError
        Naming the file and its first line that is not of the format.
    """
    import io

    seen, first, looked = 0, None, 0
    for n, raw in enumerate(io.StringIO(text), 1):
        looked = n
        verdict = recognised(raw)
        if verdict is None:
            continue
        if verdict:
            return looked
        if first is None:
            first = (n, raw.strip())
        seen += 1
        if seen >= FOREIGN_SCAN_LINES:
            break
    if first is None:
        return looked
    shown = first[1] if len(first[1]) <= 60 else first[1][:57] + "..."
    raise InputError(f"{source}: line {first[0]}: {shown!r} is not {what}, and neither are the "
                     f"{seen - 1} line(s) after it that say something: not a {what} file "
                     f"(expected {expected})")


#: halcmd's commands (LinuxCNC's ``halcmd`` manual): the first word of a HAL file's lines
HAL_COMMANDS = frozenset((
    "loadrt", "loadusr", "unloadrt", "unloadusr", "unload", "waitusr", "setp", "sets", "getp",
    "gets", "ptype", "stype", "net", "newsig", "delsig", "linkps", "linksp", "linkpp",
    "unlinkp", "addf", "delf", "start", "stop", "show", "list", "source", "alias", "unalias",
    "lock", "unlock", "save", "status", "echo", "unecho", "print", "newcomp", "newpin",
    "newinst", "ready"))


def hal_line_kind(raw: str) -> bool | None:
    """Whether a line is HAL: a halcmd command True, a blank line or a ``#`` comment None,
    anything else False (for :func:`refuse_foreign_text`).

    Parameters
    ----------
    raw : str
        The line.

    Returns
    -------
    bool or None
        As above.
    """
    words = raw.split("#", 1)[0].split()
    if not words:
        return None
    return words[0].lower() in HAL_COMMANDS
