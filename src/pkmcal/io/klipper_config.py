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
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..paths import file_identity

#: the distance of one (micro)step a stepper can have, mm (a nanometre to a millimetre)
STEP_RANGE = (1e-6, 1.0)
#: the line that opens Klipper's auto-save block (``configfile.AUTOSAVE_HEADER``)
AUTOSAVE_MARK = "#*# <---------------------- SAVE_CONFIG ---------------------->"
AUTOSAVE_HEADER = ("\n" + AUTOSAVE_MARK + "\n#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents "
                   "are auto-generated.\n#*#\n")
_SECTION = re.compile(r"\[(?P<header>.+)\]")              # configparser's SECTCRE
_OPTION = re.compile(r"(?P<key>[^:=\s][^:=]*?)\s*[:=]\s*(?P<value>.*)$")


@dataclass
class Entry:
    """One option's value and where it stands.

    Attributes
    ----------
    value : str
        The value on the option's own line (comments stripped).
    file : str
        The file it was read from.
    line : int
        Its line number there.
    autosave : bool
        It comes from the ``SAVE_CONFIG`` block.
    more : list of str
        Continuation lines of a multi-line value (a ``bed_mesh`` mesh, a macro's gcode), as
        written (their leading whitespace kept).
    """

    value: str
    file: str
    line: int
    autosave: bool = False
    more: list = field(default_factory=list)

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
    ignored_block : str
        Why Klipper ignores this file's ``#*#`` block (empty: it reads it, or there is none).
    """

    path: str
    body: dict = field(default_factory=dict)
    autosave: dict = field(default_factory=dict)
    included: set = field(default_factory=set)
    ignored_block: str = ""

    # -- reading --------------------------------------------------------------------------
    @classmethod
    def read(cls, path, text: str | None = None) -> KlipperConfig:
        """Read a config file (and its includes), as ``configfile.py`` does.

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
            Naming file and line: a line Klipper's parser refuses (neither a section, an
            option nor a continuation; an option before any section), an include that does
            not exist, includes itself or is not a text file.
        """
        path = Path(path)
        if text is None:
            text = _read(path, "Klipper config")
        cfg = cls(str(path))
        regular, block, start, why = split_autosave(text)
        cfg.ignored_block = why
        cfg._parse(regular, path, set(), top=True)
        if block is not None:
            cfg._unit(list(enumerate(block, start)), str(path), cfg.autosave, False, True)
        return cfg

    def _parse(self, text: str, path: Path, visited: set, top: bool = False) -> None:
        key = file_identity(path)       # the same file by any name (links, ./x)
        if key in visited:
            raise InputError(f"{path}: included again from itself (recursive [include])")
        visited.add(key)
        buf: list[tuple[int, str]] = []
        for n, raw in enumerate(text.replace("\r\n", "\n").split("\n"), 1):
            line = raw.split("#", 1)[0]
            m = _SECTION.match(line)
            header = m.group("header").strip() if m else None
            if header is not None and header.startswith("include "):
                # configparser reads the lines between includes as one unit
                self._unit(buf, str(path), self.body, not top)
                buf = []
                spec = header[8:].strip()
                pattern = str(path.parent / spec)
                names = sorted(glob.glob(pattern))
                if not names and not glob.has_magic(pattern):
                    raise InputError(f"{path}: line {n}: [include {spec}]: {pattern} does not "
                                     "exist")
                for name in names:
                    self._parse(_read(Path(name), "included config file"), Path(name),
                                visited)
            else:
                buf.append((n, line))
        self._unit(buf, str(path), self.body, not top)
        visited.discard(key)

    def _unit(self, lines, file: str, target: dict, included: bool,
              autosave: bool = False) -> None:
        """One unit of configparser's reading (``RawConfigParser(strict=False,
        inline_comment_prefixes=(';', '#'))``): sections, options, continuation lines."""
        section, last, indent = None, None, 0
        for n, raw in lines:
            line = raw.split("#", 1)[0]             # Klipper cuts at the first '#'
            if not line.strip() or line.lstrip().startswith(";"):
                continue
            level = len(line) - len(line.lstrip())
            if last is not None and level > indent:     # deeper than its option: continued
                last.more.append(re.split(r"\s;", line, maxsplit=1)[0].rstrip())
                continue
            indent = level
            text = re.split(r"\s;", line, maxsplit=1)[0].strip()
            m = _SECTION.match(text)
            if m:
                section, last = m.group("header").strip(), None
                if autosave and section.startswith("include "):
                    raise InputError(f"{file}: line {n} (SAVE_CONFIG block): [{section}]: "
                                     "Klipper reads no [include] inside the SAVE_CONFIG block")
                target.setdefault(section, {})
                continue
            m = _OPTION.match(text.strip())
            where = f"{file}: line {n}" + (" (SAVE_CONFIG block)" if autosave else "")
            if m is None:
                raise InputError(f"{where}: {text.strip()!r} is neither a [section] nor an "
                                 "option (key: value); Klipper refuses the file")
            if section is None:
                raise InputError(f"{where}: {text.strip()!r} stands before any [section]; "
                                 "Klipper refuses the file")
            key = m.group("key").strip().lower()
            last = Entry(m.group("value").strip(), file, n, autosave)
            target.setdefault(section, {})[key] = last
            if included:
                self.included.add((section, key))

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
            step = self.number(section, "step_distance", above=0.0)
            if not STEP_RANGE[0] <= step <= STEP_RANGE[1]:
                e = self.entry(section, "step_distance")
                raise InputError(f"{e.where(section, 'step_distance')}: {e.value}: not a "
                                 f"stepper's step (between {STEP_RANGE[0]:g} and "
                                 f"{STEP_RANGE[1]:g} mm)")
            return step
        if self.entry(section, "rotation_distance") is None:
            raise InputError(f"{self.path}: [{section}] rotation_distance: missing (needed to "
                             "turn the saved step counts into millimetres)")
        rd = self.number(section, "rotation_distance", above=0.0)
        for key in ("microsteps", "full_steps_per_rotation"):
            e = self.entry(section, key)
            if e is not None and not re.fullmatch(r"[+-]?\d+", e.value.strip()):
                raise InputError(f"{e.where(section, key)}: {e.value!r}: a whole number "
                                 "(Klipper's getint)")
        micro = self.number(section, "microsteps", above=0.0)
        full = self.number(section, "full_steps_per_rotation", 200.0, above=0.0)
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
        step = rd / (full * micro * gearing)
        if not STEP_RANGE[0] <= step <= STEP_RANGE[1]:
            given = ", ".join(f"{key} {e.value!r} (line {e.line})" for key in (
                "rotation_distance", "microsteps", "full_steps_per_rotation", "gear_ratio")
                for e in [self.entry(section, key)] if e is not None)
            raise InputError(f"{self.entry(section, 'rotation_distance').file}: [{section}] "
                             f"{given}: a step of {step:.3g} mm is not a stepper's (between "
                             f"{STEP_RANGE[0]:g} and {STEP_RANGE[1]:g} mm)")
        return step

    def defines_in_include(self, section: str, key: str) -> bool:
        """Whether an ``[include]`` file defines the option."""
        return (section, key.lower()) in self.included


def _read(path: Path, kind: str) -> str:
    """A config file's text: UTF-8, no NUL byte, registered as an input of the command (no
    output may replace it)."""
    from .atomic import read_input_text

    return read_input_text(path, kind)


def split_autosave(text: str) -> tuple[str, list[str] | None, int, str]:
    """The body and the ``SAVE_CONFIG`` block's lines (``#*# `` stripped), as Klipper splits
    them (``ConfigAutoSave._find_autosave_data``).

    Parameters
    ----------
    text : str
        The main file's text.

    Returns
    -------
    body : str
        Everything before the block (the whole text when there is none or Klipper ignores
        it).
    block : list of str or None
        The block's lines without their ``#*# `` prefix; None without a block Klipper reads.
    start : int
        The file's line number of the block's first line.
    ignored : str
        Why Klipper ignores the block ("autosave state corrupted"), empty otherwise.
    """
    text = text.replace("\r\n", "\n")
    pos = text.find(AUTOSAVE_HEADER)
    body, rest = (text, "") if pos < 0 else (text[:pos], text[pos + len(AUTOSAVE_HEADER):])
    if "\n#*# " in body or AUTOSAVE_HEADER in rest:
        where = body.count("\n", 0, body.find("\n#*# ") + 1) + 1 if "\n#*# " in body else 0
        why = (f"a '#*# ' line stands at line {where}, above the block's header (a header "
               "changed by hand?)" if where else "a second SAVE_CONFIG header")
        return text, None, 0, f"Klipper ignores its SAVE_CONFIG block: {why}"
    if pos < 0:
        return text, None, 0, ""
    start = body.count("\n") + AUTOSAVE_HEADER.count("\n") + 1
    stripped = rest.strip()
    lead = len(rest) - len(rest.lstrip())
    start += rest[:lead].count("\n")
    lines = []
    for k, line in enumerate(stripped.split("\n")):
        if stripped and (not line.startswith("#*#") or (len(line) >= 4
                                                        and not line.startswith("#*# "))):
            return text, None, 0, (f"Klipper ignores its SAVE_CONFIG block: line {start + k} "
                                   "after the block's header does not start with '#*# '")
        lines.append(line[4:])
    return body, lines, start, ""


def save_config_text(text: str, values: dict, source: str,
                     cfg: KlipperConfig | None = None) -> str:
    """The file ``SAVE_CONFIG`` would write with ``values`` saved (see the module docstring).

    As ``ConfigAutoSave.cmd_SAVE_CONFIG``: the new block holds what Klipper read of the old
    one (its options the body does not define: ``_strip_duplicates`` at start-up; multi-line
    values such as a ``bed_mesh`` mesh kept as written) with ``values`` set; options of the
    body that the new block defines are commented out.

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
        The new file.

    Raises
    ------
    InputError
        When an included file defines one of the options (Klipper refuses SAVE_CONFIG then),
        or Klipper ignores the file's block (SAVE_CONFIG refuses it as corrupted).
    """
    cfg = KlipperConfig.read(source, text) if cfg is None else cfg
    if cfg.ignored_block:
        raise InputError(f"{source}: {cfg.ignored_block}; Klipper's SAVE_CONFIG refuses such a "
                         "file (\"Existing config autosave is corrupted\"): repair the block's "
                         "header or move the lines, then export again")
    for section, key in values:
        if cfg.defines_in_include(section, key):
            raise InputError(f"{source}: [{section}] {key} is defined in an [include] file; "
                             "Klipper's SAVE_CONFIG refuses to save it there (remove it from "
                             "the included file, then export again)")
    body, _, _, _ = split_autosave(text)
    # the block as Klipper holds it: the options the body (with its includes) does not define
    saved: dict[str, dict[str, Entry]] = {}
    for section, opts in cfg.autosave.items():
        kept = {k: e for k, e in opts.items() if k not in cfg.body.get(section, {})}
        if kept or not opts:
            saved[section] = kept
    for (section, key), value in values.items():
        saved.setdefault(section, {})[key.lower()] = Entry(value, source, 0, True)
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
        for key, entry in opts.items():
            out.append(f"#*# {key} = {entry.value}".rstrip())
            out += [f"#*# {more}" for more in entry.more]
    return "\n".join(out) + "\n"


def backup_name(path) -> Path:
    """Where ``SAVE_CONFIG`` keeps the previous file: ``printer-YYYYMMDD_HHMMSS.cfg`` (any
    other suffix likewise: ``config-override-YYYYMMDD_HHMMSS.g``; ``_1``, ``_2`` ... after the
    time where a backup of that second exists). The time is Klipper's (local), or
    ``SOURCE_DATE_EPOCH`` (UTC) when set: every time stamp pkmcal writes honours it."""
    path = Path(path)
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    stamp = time.strftime("-%Y%m%d_%H%M%S",
                          time.gmtime(int(epoch)) if epoch.isdigit() else time.localtime())
    for k in range(1000):           # never onto an earlier backup of the same second
        tail = stamp + (f"_{k}" if k else "")
        name = (path.stem + tail + path.suffix) if path.suffix else path.name + tail
        if not path.with_name(name).exists():
            return path.with_name(name)
    raise InputError(f"{path}: no free name for the previous file's backup ({stamp})")
