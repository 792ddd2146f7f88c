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

from ..errors import InputError
from ..paths import path_text

__all__ = ["GENERIC", "check_instrument_options", "declared_options", "flag_of",
           "instrument_options", "options_for", "refuse_in_joint"]

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
            theirs = " or ".join(f"{i.name} data"
                                 for i, _ in declared_options()[name])
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
