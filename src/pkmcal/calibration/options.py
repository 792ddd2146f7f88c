"""The options of a calibration: the generic arguments of
:func:`~pkmcal.calibration.calibrate` and each instrument's own, which its module declares
(its ``Options``: typed, with flag, help, default and choices;
:func:`~pkmcal.instruments.flow.option`).

One rule for every instrument: an option the data's instrument does not declare is refused
naming the flag and the instruments that take it; a value out of an option's choices is
refused naming the values it takes; the instrument then refuses what it declares but cannot
take together (:meth:`~pkmcal.instruments.base.Instrument.check_options`). A fit of several
files takes the options an instrument declares for its part of such a fit (``joint``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from ..errors import InputError
from ..paths import path_text

__all__ = ["GENERIC", "CommandOption", "check_instrument_options", "command_options",
           "command_values", "declared_options", "flag_of", "instrument_options", "noise_help",
           "options_for", "refuse_in_joint"]

#: the options of every calibration (arguments of ``calibrate`` itself), which an
#: instrument's ``Options`` may declare too to read them
GENERIC = ("noise", "robust")


def declared_options() -> dict[str, list]:
    """Every option an instrument declares, by name: ``[(instrument, field), ...]`` in the
    registry's order.

    Returns
    -------
    dict
        Option name -> the instruments declaring it, with their field.
    """
    from ..instruments.registry import INSTRUMENTS

    out: dict[str, list] = {}
    for inst in INSTRUMENTS.values():
        for f in dataclasses.fields(inst.Options) if inst.Options is not None else ():
            out.setdefault(f.name, []).append((inst, f))
    return out


def flag_of(name: str) -> str:
    """The command-line flag of an option (its first spelling: ``--estimate-lc``)."""
    owners = declared_options().get(name)
    flag = owners[0][1].metadata.get("flag") if owners else None
    return (flag or "--" + name.replace("_", "-")).split("/")[0]


def _is_default(value, default) -> bool:
    try:
        return bool(value is default or value == default)
    except (TypeError, ValueError):
        return False


def instrument_options(options: Mapping | None) -> dict:
    """The instruments' options given in ``options`` (the generic ones and those at their
    declared default left out).

    Parameters
    ----------
    options : mapping or None
        Option name -> value.

    Returns
    -------
    dict
        Option name -> value, each declared by an instrument.

    Raises
    ------
    InputError
        For a name no instrument declares.
    """
    declared = declared_options()
    out = {}
    for name, value in (options or {}).items():
        if name in GENERIC:
            continue
        if name not in declared:
            raise InputError(f"{name}: no instrument's calibration takes this option (they "
                             f"take: {', '.join(sorted(set(declared) - set(GENERIC)))})")
        if any(_is_default(value, f.default) for _, f in declared[name]):
            continue
        out[name] = value
    return out


def _words(inst) -> str:
    return inst.plural or f"{inst.name} data"


def _check_choices(inst, name: str, value) -> None:
    f = next(f for f in dataclasses.fields(inst.Options) if f.name == name)
    choices = f.metadata.get("choices")
    if choices and value not in choices:
        raise InputError(f"{flag_of(name)} {value}: {inst.name} data take "
                         f"{', '.join(choices[:-1])} or {choices[-1]}")


def check_instrument_options(options: Mapping, source, inst) -> None:
    """Refuse the options given that ``inst`` does not declare, and values out of an option's
    choices; then the instrument's own check
    (:meth:`~pkmcal.instruments.base.Instrument.check_options`).

    Parameters
    ----------
    options : mapping
        Every option of the calibration (generic and the instruments').
    source : str or os.PathLike
        The data file, named in messages.
    inst : Instrument
        The data's instrument.

    Raises
    ------
    InputError
        Naming the flag, the instruments that take it and what the data are.
    """
    own = ({f.name for f in dataclasses.fields(inst.Options)} if inst.Options is not None
           else set())
    given = instrument_options(options)
    for name in given:
        if name not in own:
            theirs = " or ".join(f"{i.name} data" for i, _ in declared_options()[name])
            mine = ", ".join(flag_of(n) for n in sorted(own | set(GENERIC)))
            raise InputError(f"{flag_of(name)}: applies to {theirs}; {path_text(source)} has "
                             f"{_words(inst)} (see {mine})")
    for name, value in given.items():
        _check_choices(inst, name, value)
    if inst.Options is not None:
        inst.check_options(options_for(inst, options), source)


def options_for(inst, options: Mapping):
    """The instrument's ``Options`` from the calibration's options (None: it declares none).

    Parameters
    ----------
    inst : Instrument
        The instrument.
    options : mapping
        Every option of the calibration.

    Returns
    -------
    object or None
        Its :attr:`~pkmcal.instruments.base.Instrument.Options`.
    """
    return inst.options_of(dict(options or {}))


def refuse_in_joint(options: Mapping, instruments) -> None:
    """Refuse the options a fit of several files does not take: those no file's instrument
    declares for its part of such a fit (``joint``), and values out of their choices.

    Parameters
    ----------
    options : mapping
        Every option of the calibration.
    instruments : list of Instrument
        The files' instruments.

    Raises
    ------
    InputError
        Naming the flag.
    """
    for name, value in instrument_options(options).items():
        takers = [i for i in instruments if i.Options is not None
                  and any(f.name == name and f.metadata.get("joint")
                          for f in dataclasses.fields(i.Options))]
        if not takers:
            raise InputError(f"{flag_of(name)}: does not apply to a fit of several data files "
                             "(one maximum-likelihood fit of every file's instrument); see "
                             "--noise FILE=VALUE, --robust and --holdout")
        _check_choices(takers[0], name, value)


@dataclass(frozen=True)
class CommandOption:
    """An option of ``pkmcal calibrate`` built from the instruments' declarations
    (:func:`command_options`).

    Attributes
    ----------
    name : str
        The option's name (the instruments' field, the command's parameter).
    flag : str
        Its flag (``--two-step``).
    kind : str
        ``"switch"`` (a flag, False unless given), ``"either"`` (``flag`` or ``negative``,
        None unless one is given) or ``"text"`` (a value, given at most once).
    metavar : str
        The value's name in the help (text options).
    help : str
        Its help: each declaring instrument's, led by the data it applies to.
    negative : str
        The ``--no-x`` flag of an ``"either"`` option.
    negative_help : str
        Its help.
    """

    name: str
    flag: str
    kind: str
    metavar: str
    help: str
    negative: str = ""
    negative_help: str = ""


def _led(inst, text: str) -> str:
    lead = text[:1].lower() + text[1:] if text[1:2].islower() or text[1:2] == " " else text
    return f"{inst.name} data: {lead}"


def command_options() -> list[CommandOption]:
    """The options of ``pkmcal calibrate`` the instruments declare (the generic ones,
    :data:`GENERIC`, aside), one per name in the registry's order; an option declared by
    several instruments (``--method``) has each one's help.

    Returns
    -------
    list of CommandOption
        The options.
    """
    out = []
    for name, owners in declared_options().items():
        if name in GENERIC:
            continue
        first = owners[0][1].metadata
        flags = first["flag"].split("/")
        helps = dict.fromkeys(_led(inst, f.metadata["help"]) for inst, f in owners)
        choices = list(dict.fromkeys(c for _, f in owners for c in f.metadata.get("choices")
                                     or ()))
        kind = ("either" if len(flags) > 1 else
                "switch" if str(owners[0][1].type) in ("bool", "<class 'bool'>") else "text")
        negative = flags[1] if len(flags) > 1 else ""
        out.append(CommandOption(
            name, flags[0], kind, first.get("metavar") or "|".join(choices) or "TEXT",
            " ".join(helps), negative,
            first.get("negative_help") or (f"The opposite of {flags[0]}." if negative else "")))
    return out


def noise_help() -> str:
    """What ``--noise`` is for each instrument that declares it, in words: each one's help up
    to its first semicolon (``tracker: leica (default) or a length ...``)."""
    parts = [f"{inst.name}: {f.metadata['help'].split(';')[0].rstrip('.')}."
             for inst, f in declared_options().get("noise", [])]
    return " ".join(parts)


def calibrate_help() -> str:
    """The instruments' paragraphs of ``pkmcal calibrate --help``
    (:meth:`~pkmcal.instruments.base.Instrument.help_paragraphs`), in the registry's order,
    blank-line separated."""
    from ..instruments.registry import INSTRUMENTS

    return "\n\n".join(inst.help_paragraphs() for inst in INSTRUMENTS.values())


def command_values(values: Mapping) -> dict:
    """The instruments' options from the command's parameters (:func:`command_options`):
    a ``--x/--no-x`` pair as True, False or None, a text given once as its value.

    Parameters
    ----------
    values : mapping
        Parameter name -> value, as the command received them (``no_<name>`` for the
        negative flag of an ``"either"`` option; a list for a text option).

    Returns
    -------
    dict
        Option name -> value of the options given (:func:`~pkmcal.calibration.calibrate`'s
        ``options``).

    Raises
    ------
    InputError
        For both flags of a pair, or a text option given more than once.
    """
    out = {}
    for opt in command_options():
        if opt.kind == "either":
            yes, no = bool(values.get(opt.name)), bool(values.get("no_" + opt.name))
            if yes and no:
                raise InputError(f"{opt.flag} and {opt.negative} together: give one")
            if yes or no:
                out[opt.name] = yes
        elif opt.kind == "switch":
            if values.get(opt.name):
                out[opt.name] = True
        else:
            texts = values.get(opt.name)
            texts = [texts] if isinstance(texts, str) else list(texts or [])
            if len(texts) > 1:
                raise InputError(f"{opt.flag}: given more than once ({', '.join(texts)}); "
                                 "give it once")
            if texts:
                out[opt.name] = texts[0]
    return out
