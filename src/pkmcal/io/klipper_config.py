"""Klipper's ``printer.cfg`` read as Klipper reads it, and updated as ``SAVE_CONFIG`` does.

Read in Klipper's source (``Klipper3d/klipper``, ``klippy/configfile.py``):

- ``ConfigFileReader._parse_config``: a ``#`` starts a comment anywhere on a line (``;`` too,
  as configparser's inline comment prefix); ``[include FILE]`` is read where it stands,
  ``FILE`` relative to the including file, a glob expanded in sorted order (no match is an
  error only without wildcards), a file including itself is an error; later values of an
  option replace earlier ones (``RawConfigParser(strict=False)``); option names are not case
  sensitive.
- ``ConfigAutoSave.load_main_config``: the ``#*# <---- SAVE_CONFIG ---->`` block at the end of
  the main file is read after the body, but every option the body (with its includes) defines
  is first struck out of it (``_strip_duplicates``): **the body wins**.
- ``cmd_SAVE_CONFIG``: the new block holds the previous block's options updated with the new
  values; options of the body that the block now defines are commented out with ``#``; an
  option that an ``[include]`` file defines is refused ("conflicts with included value"); the
  previous file is kept as ``printer-YYYYMMDD_HHMMSS.cfg``.

``klippy/stepper.py`` ``parse_step_distance``: a stepper's distance per step is
``rotation_distance / (full_steps_per_rotation x microsteps x gear_ratio)`` (defaults 200 full
steps, gear ratio 1; ``gear_ratio: 80:20, 3:1`` multiplies 80/20 and 3/1); configs from before
``rotation_distance`` (2020) give ``step_distance`` directly.
"""

from __future__ import annotations

import glob
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

#: the line that opens Klipper's auto-save block (``configfile.AUTOSAVE_HEADER``)
AUTOSAVE_MARK = "#*# <---------------------- SAVE_CONFIG ---------------------->"
AUTOSAVE_HEADER = ("\n" + AUTOSAVE_MARK + "\n#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents "
                   "are auto-generated.\n#*#\n")
_SECTION = re.compile(r"\[(?P<header>[^]]+)\]")
_OPTION = re.compile(r"(?P<key>[^:=\s][^:=]*?)\s*[:=]\s*(?P<value>.*)$")


@dataclass
class Entry:
    """One option's value and where it stands.

    Attributes
    ----------
    value : str
        The value (comments stripped).
    file : str
        The file it was read from.
    line : int
        Its line number there.
    autosave : bool
        It comes from the ``SAVE_CONFIG`` block.
    """

    value: str
    file: str
    line: int
    autosave: bool = False

    def where(self, section: str, key: str) -> str:
        """``printer.cfg: line 12: [stepper_a] arm_length`` for messages."""
        block = " (SAVE_CONFIG block)" if self.autosave else ""
        return f"{self.file}: line {self.line}{block}: [{section}] {key}"


@dataclass
class KlipperConfig:
    """A ``printer.cfg`` as Klipper resolves it (see the module docstring).

    Attributes
    ----------
    path : str
        The main file.
    body : dict
        ``{section: {option: Entry}}`` of the main body and its includes.
    autosave : dict
        The ``SAVE_CONFIG`` block's options, as written (before the body's precedence).
    included : set
        ``(section, option)`` pairs defined in an included file.
    """

    path: str
    body: dict = field(default_factory=dict)
    autosave: dict = field(default_factory=dict)
    included: set = field(default_factory=set)

    # -- reading --------------------------------------------------------------------------
    @classmethod
    def read(cls, path, text: str | None = None) -> KlipperConfig:
        """Read a config file (and its includes).

        Parameters
        ----------
        path : str or os.PathLike
            The main file; includes are resolved beside it.
        text : str, optional
            Its text when already read.

        Returns
        -------
        KlipperConfig
            The config.

        Raises
        ------
        InputError
            An include that does not exist or includes itself, or a file that cannot be read.
        """
        path = Path(path)
        if text is None:
            text = _read(path, None)
        cfg = cls(str(path))
        regular, block, start = split_autosave(text)
        cfg._parse(regular, path, set(), top=True)
        if block is not None:
            cfg._parse_lines(block, str(path), cfg.autosave, start, autosave=True)
        return cfg

    def _parse(self, text: str, path: Path, visited: set, top: bool = False) -> None:
        key = str(path.resolve()) if path.exists() else str(path)
        if key in visited:
            raise InputError(f"{path}: included again from itself (recursive [include])")
        visited.add(key)
        buf: list[tuple[int, str]] = []
        section: list = [None]
        for n, raw in enumerate(text.replace("\r\n", "\n").split("\n"), 1):
            line = raw.split("#", 1)[0]
            m = _SECTION.match(line)
            header = m.group("header").strip() if m else None
            if header is not None and header.startswith("include "):
                self._lines(buf, str(path), section, top)
                buf = []
                spec = header[8:].strip()
                pattern = str(path.parent / spec)
                names = sorted(glob.glob(pattern))
                if not names and not glob.has_magic(pattern):
                    raise InputError(f"{path}: line {n}: [include {spec}]: {pattern} does not "
                                     "exist")
                for name in names:
                    self._parse(_read(Path(name), f"{path}: line {n}"), Path(name), visited)
            else:
                buf.append((n, line))
        self._lines(buf, str(path), section, top)
        visited.discard(key)

    def _lines(self, buf, file: str, section: list, top: bool) -> None:
        # configparser reads each buffer as a unit: a section must be opened inside it
        section[0] = None
        for n, line in buf:
            self._one(line, n, file, section, self.body, not top)

    def _parse_lines(self, lines, file, target, start, autosave=False) -> None:
        section: list = [None]
        for n, line in enumerate(lines, start):
            self._one(line.split("#", 1)[0], n, file, section, target, False, autosave)

    def _one(self, line, n, file, section, target, included, autosave=False) -> None:
        if not line.strip() or line[0].isspace():
            return                    # blank, or a continuation line (gcode of a macro)
        line = re.split(r"\s;", line, maxsplit=1)[0].rstrip()
        m = _SECTION.match(line)
        if m:
            section[0] = m.group("header").strip()
            target.setdefault(section[0], {})
            return
        m = _OPTION.match(line)
        if m is None or section[0] is None:
            return
        key = m.group("key").strip().lower()
        target.setdefault(section[0], {})[key] = Entry(m.group("value").strip(), file, n,
                                                       autosave)
        if included:
            self.included.add((section[0], key))

    # -- access ---------------------------------------------------------------------------
    def entry(self, section: str, key: str) -> Entry | None:
        """An option as Klipper uses it: the body's, else the ``SAVE_CONFIG`` block's.

        Parameters
        ----------
        section : str
            Section name (``printer``, ``stepper_a``).
        key : str
            Option name (any case).

        Returns
        -------
        Entry or None
            The entry, None when neither defines it.
        """
        key = key.lower()
        for source in (self.body, self.autosave):
            e = source.get(section, {}).get(key)
            if e is not None:
                return e
        return None

    def has_section(self, section: str) -> bool:
        """Whether the body or the block has the section."""
        return section in self.body or section in self.autosave

    def options(self, section: str) -> dict:
        """The options of a section as Klipper uses them (the body's win)."""
        return {**self.autosave.get(section, {}), **self.body.get(section, {})}

    def number(self, section: str, key: str, default=None, *, above: float | None = None):
        """An option as a finite float (``default`` when absent).

        Raises
        ------
        InputError
            Naming file, line, section and option for a value that is not a finite number or
            not above ``above``; or the option missing without a default.
        """
        e = self.entry(section, key)
        if e is None:
            if default is None:
                raise InputError(f"{self.path}: [{section}] {key}: missing")
            return default
        try:
            v = float(e.value)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise InputError(f"{e.where(section, key)}: {e.value!r} is not a number")
        if above is not None and not v > above:
            raise InputError(f"{e.where(section, key)}: {e.value} must be above {above:g}")
        return v

    def numbers(self, section: str, key: str, count: int) -> list[float]:
        """A comma-separated list of ``count`` finite numbers (Klipper's ``getfloatlist``)."""
        e = self.entry(section, key)
        if e is None:
            raise InputError(f"{self.path}: [{section}] {key}: missing")
        parts = [p.strip() for p in e.value.split(",")]
        out = []
        for p in parts:
            try:
                v = float(p)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise InputError(f"{e.where(section, key)}: {e.value!r}: {count} numbers "
                                 "separated by commas expected")
            out.append(v)
        if len(out) != count:
            raise InputError(f"{e.where(section, key)}: {len(out)} value(s), {count} expected")
        return out

    def step_distance(self, section: str) -> float:
        """A stepper's distance per (micro)step, mm, as ``stepper.parse_step_distance``.

        Raises
        ------
        InputError
            Naming the option that is missing or not valid.
        """
        if self.entry(section, "rotation_distance") is None \
                and self.entry(section, "step_distance") is not None:
            return self.number(section, "step_distance", above=0.0)
        if self.entry(section, "rotation_distance") is None:
            raise InputError(f"{self.path}: [{section}] rotation_distance: missing (needed to "
                             "turn the saved step counts into millimetres)")
        rd = self.number(section, "rotation_distance", above=0.0)
        micro = self.number(section, "microsteps", above=0.0)
        full = self.number(section, "full_steps_per_rotation", 200.0, above=0.0)
        for key, v in (("microsteps", micro), ("full_steps_per_rotation", full)):
            if v != int(v):
                e = self.entry(section, key)
                raise InputError(f"{e.where(section, key)}: {e.value}: a whole number")
        if full % 4:
            e = self.entry(section, "full_steps_per_rotation")
            raise InputError(f"{e.where(section, 'full_steps_per_rotation')}: {e.value}: "
                             "a multiple of 4 (Klipper's rule)")
        gearing = 1.0
        e = self.entry(section, "gear_ratio")
        if e is not None and e.value.strip():
            for part in e.value.split(","):
                m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*:\s*([0-9.eE+-]+)\s*", part)
                try:
                    a, b = (float(m.group(1)), float(m.group(2))) if m else (math.nan, 1.0)
                except ValueError:
                    a, b = math.nan, 1.0
                if not (math.isfinite(a) and math.isfinite(b) and a > 0 and b > 0):
                    raise InputError(f"{e.where(section, 'gear_ratio')}: {e.value!r}: ratios "
                                     "such as 80:20, 3:1 expected")
                gearing *= a / b
        return rd / (full * micro * gearing)

    def defines_in_include(self, section: str, key: str) -> bool:
        """Whether an ``[include]`` file defines the option."""
        return (section, key.lower()) in self.included


def _read(path: Path, where: str | None) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        head = f"{where}: " if where else ""
        raise InputError(f"{head}{path}: cannot be read ({exc.strerror or exc})") from None


def split_autosave(text: str) -> tuple[str, list[str] | None, int]:
    """The body and the ``SAVE_CONFIG`` block's lines (``#*# `` stripped), as Klipper splits
    them (``_find_autosave_data``).

    Parameters
    ----------
    text : str
        The main file's text.

    Returns
    -------
    body : str
        Everything before the block (the whole text when there is none).
    block : list of str or None
        The block's lines without their ``#*#`` prefix; None without a block.
    start : int
        The file's line number of the block's first line.
    """
    text = text.replace("\r\n", "\n")
    pos = text.find(AUTOSAVE_HEADER)
    if pos < 0:
        # a block whose header lines lost a character is not Klipper's: treated as body
        return text, None, 0
    body = text[:pos]
    rest = text[pos + len(AUTOSAVE_HEADER):]
    start = body.count("\n") + AUTOSAVE_HEADER.count("\n") + 1
    lines = []
    for line in rest.split("\n"):
        lines.append(line[4:] if line.startswith("#*# ") else
                     ("" if line.strip() in ("#*#", "") else line))
    return body, lines, start


def save_config_text(text: str, values: dict, source: str,
                     cfg: KlipperConfig | None = None) -> str:
    """The file ``SAVE_CONFIG`` would write with ``values`` saved (see the module docstring).

    Parameters
    ----------
    text : str
        The current main file.
    values : dict
        ``{(section, option): text}`` to save.
    source : str
        The file's name, for messages.
    cfg : KlipperConfig, optional
        The file read (for its includes); default read from ``text``.

    Returns
    -------
    str
        The new file: the body with the saved options commented out where it defined them,
        and the block with the previous block's options and the new values.

    Raises
    ------
    InputError
        When an included file defines one of the options (Klipper refuses SAVE_CONFIG then).
    """
    cfg = KlipperConfig.read(source, text) if cfg is None else cfg
    for section, key in values:
        if cfg.defines_in_include(section, key):
            raise InputError(f"{source}: [{section}] {key} is defined in an [include] file; "
                             "Klipper's SAVE_CONFIG refuses to save it there (remove it from "
                             "the included file, then export again)")
    body, block, _ = split_autosave(text)
    saved: dict[str, dict[str, str]] = {}
    for section, opts in cfg.autosave.items():
        saved[section] = {k: e.value for k, e in opts.items()}
    for (section, key), value in values.items():
        saved.setdefault(section, {})[key.lower()] = value
    # comment out the body's own definitions of what the block now holds
    lines = body.split("\n")
    section = None
    dup = False
    for i, line in enumerate(lines):
        pruned = re.sub(r"[#;].*$", "", line).rstrip()
        if not pruned:
            continue
        if pruned[0].isspace():
            if dup:
                lines[i] = "#" + lines[i]
            continue
        dup = False
        if pruned[0] == "[":
            section = pruned[1:-1].strip()
            continue
        key = re.sub(r"[^A-Za-z0-9_].*$", "", pruned).lower()
        if key in saved.get(section, {}):
            dup = True
            lines[i] = "#" + lines[i]
    out = ["\n".join(lines).rstrip(), "", AUTOSAVE_MARK,
           "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.", "#*#"]
    for k, (section, opts) in enumerate(saved.items()):
        if k:
            out.append("#*#")
        out.append(f"#*# [{section}]")
        out += [f"#*# {key} = {value}" for key, value in opts.items()]
    return "\n".join(out) + "\n"


def backup_name(path) -> Path:
    """Where ``SAVE_CONFIG`` keeps the previous file: ``printer-YYYYMMDD_HHMMSS.cfg`` (any
    other suffix likewise: ``config-override-YYYYMMDD_HHMMSS.g``)."""
    path = Path(path)
    stamp = time.strftime("-%Y%m%d_%H%M%S")
    if path.suffix:
        return path.with_name(path.stem + stamp + path.suffix)
    return path.with_name(path.name + stamp)


#: the tower steppers of Klipper's delta kinematics, in tower order
TOWER_STEPPERS = ("stepper_a", "stepper_b", "stepper_c")


def _indexed(cfg: KlipperConfig, prefix: str) -> list[int]:
    """Klipper's ``prefix0``, ``prefix1``, ... up to the first missing index."""
    out = []
    opts = cfg.options("delta_calibrate")
    while f"{prefix}{len(out)}" in opts:
        out.append(len(out))
    return out


def delta_calibrate_data(cfg: KlipperConfig, n_joints: int = 3) -> list:
    """The measurements Klipper saved in ``[delta_calibrate]``, as pkmcal data (SI).

    Read as ``klippy/extras/delta_calibrate.py`` restores them: ``heightN`` (the probe's
    ``z_offset`` at the trigger: the nozzle's height above the bed, mm) with ``heightN_pos``
    (the "stable position": steps each carriage moved down since its endstop), then
    ``manual_heightN`` / ``manual_heightN_pos`` (DELTA_ANALYZE MANUAL_HEIGHT), and
    ``distanceN`` with ``distanceN_pos1`` / ``distanceN_pos2`` (DELTA_ANALYZE distances, mm);
    each list up to its first missing index. Steps become carriage travel with each tower
    stepper's :meth:`KlipperConfig.step_distance`.

    Parameters
    ----------
    cfg : KlipperConfig
        The config.
    n_joints : int, optional
        The machine's joints (3).

    Returns
    -------
    list of InstrumentData
        Probe heights (``kind="probe"``, source ``"<path> heights"``: saved heights then
        manual heights) and two-point distances (``kind="pair-distances"``, ``"<path>
        distances"``) when saved; their rows are the config's line numbers of ``heightN`` /
        ``distanceN``; empty without a ``[delta_calibrate]``.

    Raises
    ------
    InputError
        A value that is not a number or a position without three values (file, line,
        option named), a stepper without its step distance, or a machine that is not a
        three-tower delta.
    """
    from ..instruments import InstrumentData
    from ..instruments.pairs import pair_data

    if not cfg.has_section("delta_calibrate"):
        return []
    if n_joints != 3:
        raise InputError(f"{cfg.path}: Klipper's [delta_calibrate] data are for a three-tower "
                         f"delta; the machine has {n_joints} joints")
    heights = [(f"height{i}", f"height{i}_pos") for i in _indexed(cfg, "height")]
    heights += [(f"manual_height{i}", f"manual_height{i}_pos")
                for i in _indexed(cfg, "manual_height")]
    distances = _indexed(cfg, "distance")
    if not heights and not distances:
        return []
    step = np.array([cfg.step_distance(s) for s in TOWER_STEPPERS]) * 1e-3      # m / step
    out = []
    weights = (None, None)
    if heights and distances:
        weights = klipper_weights(len(_indexed(cfg, "height")), len(distances))
    if heights:
        q = np.array([cfg.numbers("delta_calibrate", pos, 3) for _, pos in heights]) * step
        h = np.array([cfg.number("delta_calibrate", key) for key, _ in heights]) * 1e-3
        rows = [cfg.entry("delta_calibrate", key).line for key, _ in heights]
        out.append(InstrumentData("probe", q, h[:, None], None, np.array(rows),
                                  f"{cfg.path} heights", weights=weights[0]))
    if distances:
        qa = np.array([cfg.numbers("delta_calibrate", f"distance{i}_pos1", 3)
                       for i in distances]) * step
        qb = np.array([cfg.numbers("delta_calibrate", f"distance{i}_pos2", 3)
                       for i in distances]) * step
        d = np.array([cfg.number("delta_calibrate", f"distance{i}", above=0.0)
                      for i in distances]) * 1e-3
        rows = [cfg.entry("delta_calibrate", f"distance{i}").line for i in distances]
        pairs = pair_data(qa, qb, d, rows, f"{cfg.path} distances")
        pairs.weights = weights[1]
        out.append(pairs)
    return out


#: Klipper's weight of a distance against a height (``delta_calibrate.MEASURE_WEIGHT``)
MEASURE_WEIGHT = 0.5


def klipper_weights(n_probed: int, n_distances: int) -> tuple:
    """The relative weights of Klipper's ``DELTA_CALIBRATE`` with DELTA_ANALYZE distances.

    ``calculate_params`` minimises ``z_weight * sum(height errors^2) + sum(distance
    errors^2)`` with ``z_weight = n_distances / (MEASURE_WEIGHT * n_probed)`` (probed
    heights; manual heights are weighed but not counted): as noise levels, a height's
    standard deviation is ``1 / sqrt(z_weight)`` times a distance's. The levels below keep
    the probe's default for the heights; their common scale is estimated from the residuals
    (held levels: the covariance scaled by the residual variance).

    Parameters
    ----------
    n_probed : int
        Probed heights (``heightN``).
    n_distances : int
        Distances.

    Returns
    -------
    tuple
        ``((IsotropicNoise, words), (IsotropicNoise, words))`` for the heights and the
        distances.
    """
    from ..instruments import IsotropicNoise
    from ..instruments.registry import PROBE_SIGMA

    z_weight = n_distances / (MEASURE_WEIGHT * max(n_probed, 1))
    sigma_d = PROBE_SIGMA * float(np.sqrt(z_weight))
    words = (f"weighed as Klipper's DELTA_CALIBRATE weighs them (z_weight {z_weight:.3g}: a "
             f"height's std {1 / np.sqrt(z_weight):.3g} of a distance's), their common level "
             "from the residuals")
    return ((IsotropicNoise(PROBE_SIGMA), words), (IsotropicNoise(sigma_d), words))


def is_klipper_config(path, head: str) -> bool:
    """Whether a data file is a Klipper config: a ``.cfg`` name, or sections in its first
    lines (``[printer]``, ``[stepper_a]``, ``[delta_calibrate]``, ``[include ...]``)."""
    if str(path).lower().endswith(".cfg"):
        return True
    return bool(re.search(r"^\s*(#\*#\s*)?\[(printer|stepper_[a-z]|delta_calibrate|include )",
                          head, re.M))


def read_klipper_data(path, machine) -> list:
    """A Klipper config's saved calibration data for ``machine`` (:func:`delta_calibrate_data`).

    Raises
    ------
    InputError
        When the config has no saved heights or distances (naming what it looked for).
    """
    cfg = KlipperConfig.read(path)
    data = delta_calibrate_data(cfg, machine.n_joints)
    if not data:
        raise InputError(f"{path}: no saved calibration data: Klipper's [delta_calibrate] "
                         "section (in the body or the SAVE_CONFIG block) has no height0/"
                         "height0_pos, manual_height0 or distance0 (run DELTA_CALIBRATE and "
                         "SAVE_CONFIG on the printer first)")
    return data
